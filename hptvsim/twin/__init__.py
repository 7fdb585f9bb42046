"""A twin of a real vehicle: telemetry in, the model beside it, calibration from logs (issue 39).

Its logs and live telemetry in the frame schema, the model run beside it, and the model
calibrated from its logs.

* :mod:`hptvsim.twin.log`: :class:`~hptvsim.twin.log.VehicleLog`, a log on one time base, and
  the calibration CSV;
* :mod:`hptvsim.twin.mavlink`: reading ``.tlog`` and ``.BIN`` files with pymavlink;
* :mod:`hptvsim.twin.replay`: a log as an episode (frames, rerun recording, a service's stored
  episode);
* :mod:`hptvsim.twin.listen`: following a live MAVLink stream;
* :mod:`hptvsim.twin.cli`: ``hptvsim twin replay`` and ``hptvsim twin listen``;
* :mod:`hptvsim.twin.table`: a calibration CSV as the model's inputs and measurements;
* :mod:`hptvsim.twin.thrusters`: the BlueROV2 T200 thruster curve and the vectored frame's
  allocation (PWM to body forces);
* :mod:`hptvsim.twin.plant`: the project's own RK4 steps behind one interface;
* :mod:`hptvsim.twin.beside`: the twin beside the vehicle (its FMU driven by the logged
  commands, re-synchronised; k-step prediction errors);
* :mod:`hptvsim.twin.fit`, :mod:`hptvsim.twin.fit_report`, :mod:`hptvsim.twin.fit_cli`: the
  grey-box calibration (``hptvsim vehicle fit``, ``hptvsim twin predict``);
* :mod:`hptvsim.twin.sitl`, :mod:`hptvsim.twin.sitl_cli`: a simulated vehicle that speaks
  ArduSub's MAVLink (``hptvsim vehicle sitl``).

The twin layer sits above the visualisation layer: it may import the episodes, the views and
everything below them; the service and the command line import it.
"""
