"""Vehicle dynamics: the paper's 3-DOF Fossen model (Eqs. 4-8) and low-level controller.

Pure CasADi, no I/O. :func:`vehicle_model` builds the symbolic model once; its functions are
the single source of the numbers that the FMUs and the batched backend compute.
"""

from hptvsim.dynamics.model import (
    INPUT_NAMES,
    OUTPUT_NAMES,
    STATE_NAMES,
    VehicleModel,
    vehicle_model,
    wrap_angle,
)
from hptvsim.dynamics.parameters import (
    MODEL_PARAMETER_NAMES,
    PARAMETER_SPECS,
    ParameterError,
    ParameterSpec,
    VehicleParameters,
)
from hptvsim.dynamics.vehicles import (
    FMU_NAMES,
    SETTLING_TIME_95,
    SPHERICAL_UUV,
    VEHICLE_RADIUS,
    VEHICLE_TYPES,
    WORK_CLASS_UUV,
    actuator_limits,
    vehicle_parameters,
)

__all__ = [
    "FMU_NAMES",
    "INPUT_NAMES",
    "MODEL_PARAMETER_NAMES",
    "OUTPUT_NAMES",
    "PARAMETER_SPECS",
    "SETTLING_TIME_95",
    "SPHERICAL_UUV",
    "STATE_NAMES",
    "VEHICLE_RADIUS",
    "VEHICLE_TYPES",
    "WORK_CLASS_UUV",
    "ParameterError",
    "ParameterSpec",
    "VehicleModel",
    "VehicleParameters",
    "actuator_limits",
    "vehicle_model",
    "vehicle_parameters",
    "wrap_angle",
]
