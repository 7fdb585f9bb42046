"""Sensors: multi-beam sonar (geometric and signal-level), shared error model, acoustic link.

* :class:`SonarConfig`, :class:`GaussMarkovConfig`, :class:`AcousticLinkConfig`: settings
  (frozen dataclasses, loaded from scenario files; they live with the scenario schema, in
  :mod:`hptvsim.world.sensor_config`, and are re-exported here);
* :class:`Sonar`: the sonar as environments use it (fidelity plus Eq. 3 errors), built on
  :class:`GeometricSonar` (batched ray casts, compiled kernel) and :class:`SignalSonar`
  (echoes, the matched filter of Eq. 1, the spatial periodogram of Eq. 2);
* :class:`GaussMarkov`: the error model of Eq. 3;
* :class:`AcousticLink`: the IoUT link that reports the target's position (section IV-A);
* :class:`Sonar3d`, :class:`GeometricSonar3d`, :class:`Sonar3dConfig`: the 3-D multibeam sonar
  (azimuth x elevation beams ray-marched against the seabed, Eq. 3 per beam) of the 3-D game.

The classes other than the settings are imported on first use, so that importing the settings
(as the scenario loader and the command line do) stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hptvsim._lazy import lazy_getattr
from hptvsim.world.sensor_config import AcousticLinkConfig, GaussMarkovConfig, SonarConfig

if TYPE_CHECKING:
    from hptvsim.sensors.acoustic import AcousticLink
    from hptvsim.sensors.errors import GaussMarkov
    from hptvsim.sensors.measured import Sonar
    from hptvsim.sensors.signal import SignalSonar
    from hptvsim.sensors.sonar import GeometricSonar, SonarScan, vehicle_radii
    from hptvsim.sensors.sonar3d import GeometricSonar3d, Sonar3d, Sonar3dConfig, Sonar3dScan

__all__ = [
    "AcousticLink",
    "AcousticLinkConfig",
    "GaussMarkov",
    "GaussMarkovConfig",
    "GeometricSonar",
    "GeometricSonar3d",
    "SignalSonar",
    "Sonar",
    "Sonar3d",
    "Sonar3dConfig",
    "Sonar3dScan",
    "SonarConfig",
    "SonarScan",
    "vehicle_radii",
]

_LAZY = {
    "AcousticLink": "hptvsim.sensors.acoustic",
    "GaussMarkov": "hptvsim.sensors.errors",
    "SignalSonar": "hptvsim.sensors.signal",
    "GeometricSonar": "hptvsim.sensors.sonar",
    "Sonar": "hptvsim.sensors.measured",
    "SonarScan": "hptvsim.sensors.sonar",
    "vehicle_radii": "hptvsim.sensors.sonar",
    "GeometricSonar3d": "hptvsim.sensors.sonar3d",
    "Sonar3d": "hptvsim.sensors.sonar3d",
    "Sonar3dConfig": "hptvsim.sensors.sonar3d",
    "Sonar3dScan": "hptvsim.sensors.sonar3d",
}

__getattr__ = lazy_getattr(__name__, _LAZY)
