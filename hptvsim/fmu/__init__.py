"""FMI 2.0 Co-Simulation FMUs of the vehicle types: generation, compilation, location.

:func:`fmu_path` finds the shipped FMU of a vehicle type: ``$HPTVSIM_FMU_DIR`` if set, else the
``fmus/`` folder of a source checkout, else the copy packed into an installed wheel.
"""

from __future__ import annotations

from pathlib import Path

from hptvsim._paths import shipped_dir
from hptvsim.dynamics import FMU_NAMES, VEHICLE_TYPES

__all__ = ["fmu_dir", "fmu_path"]


def fmu_dir() -> Path:
    """Return the folder that holds the shipped FMUs."""
    return shipped_dir("fmus", env="HPTVSIM_FMU_DIR")


def fmu_path(vehicle_type: str) -> Path:
    """Return the path of the shipped FMU of a vehicle type.

    Raises:
        KeyError: Unknown vehicle type (the message lists the valid ones).
        FileNotFoundError: The FMU is missing (build it with ``hptvsim fmu build``).
    """
    if vehicle_type not in FMU_NAMES:
        raise KeyError(f"unknown vehicle type {vehicle_type!r}; valid types: {', '.join(VEHICLE_TYPES)}")
    path = fmu_dir() / f"{FMU_NAMES[vehicle_type]}.fmu"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; build it with `hptvsim fmu build`")
    return path
