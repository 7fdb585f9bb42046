"""Co-simulation: FMI 2.0 CS FMUs stepped through FMPy's library with lean, checked calls."""

from hptvsim.cosim.fmi2 import Fmu2Instance, FmuError, FmuModel, FmuVariableError, Variable

__all__ = ["Fmu2Instance", "FmuError", "FmuModel", "FmuVariableError", "Variable"]
