"""A twin of a real vehicle: its logs and live telemetry in the frame schema (issue 39).

* :mod:`hptvsim.twin.log`: :class:`~hptvsim.twin.log.VehicleLog`, a log on one time base, and
  the calibration CSV;
* :mod:`hptvsim.twin.mavlink`: reading ``.tlog`` and ``.BIN`` files with pymavlink;
* :mod:`hptvsim.twin.replay`: a log as an episode (frames, rerun recording, a service's stored
  episode);
* :mod:`hptvsim.twin.listen`: following a live MAVLink stream;
* :mod:`hptvsim.twin.cli`: ``hptvsim twin replay`` and ``hptvsim twin listen``.

The twin layer sits above the visualisation layer: it may import the episodes, the views and
everything below them; the service and the command line import it.
"""
