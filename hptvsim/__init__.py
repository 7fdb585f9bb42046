"""hptvsim: a multi-vehicle underwater pursuit-evasion simulator and training stack.

Layers, each importing only the ones before it: :mod:`hptvsim.dynamics` (pure CasADi) →
:mod:`hptvsim.fmu` and :mod:`hptvsim.cosim` (FMI 2.0 co-simulation) → world and sensors →
environments → training and offline RL → visualisation and recording → the service
(:mod:`hptvsim.service`), which only the command line (:mod:`hptvsim.cli`) imports.
"""

__version__ = "0.1.0"
