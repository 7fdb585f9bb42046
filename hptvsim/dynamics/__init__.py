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
from hptvsim.dynamics.parameters6 import (
    PLANAR_SHARED_NAMES,
    SIXDOF_PARAMETER_NAMES,
    SIXDOF_PARAMETER_SPECS,
    SIXDOF_VEHICLE_TYPES,
    SPHERICAL_UUV_6DOF,
    WORK_CLASS_UUV_6DOF,
    SixDofParameters,
    sixdof_from_planar,
)
from hptvsim.dynamics.sixdof import (
    COS_THETA_MIN,
    PLANAR_HELD,
    SIXDOF_STATE_NAMES,
    SixDofModel,
    sixdof_dynamics,
    sixdof_model,
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
    "COS_THETA_MIN",
    "FMU_NAMES",
    "INPUT_NAMES",
    "MODEL_PARAMETER_NAMES",
    "OUTPUT_NAMES",
    "PARAMETER_SPECS",
    "PLANAR_HELD",
    "PLANAR_SHARED_NAMES",
    "SETTLING_TIME_95",
    "SIXDOF_PARAMETER_NAMES",
    "SIXDOF_PARAMETER_SPECS",
    "SIXDOF_STATE_NAMES",
    "SIXDOF_VEHICLE_TYPES",
    "SPHERICAL_UUV",
    "SPHERICAL_UUV_6DOF",
    "STATE_NAMES",
    "VEHICLE_RADIUS",
    "VEHICLE_TYPES",
    "WORK_CLASS_UUV",
    "WORK_CLASS_UUV_6DOF",
    "ParameterError",
    "ParameterSpec",
    "SixDofModel",
    "SixDofParameters",
    "VehicleModel",
    "VehicleParameters",
    "actuator_limits",
    "sixdof_dynamics",
    "sixdof_from_planar",
    "sixdof_model",
    "vehicle_model",
    "vehicle_parameters",
    "wrap_angle",
]
