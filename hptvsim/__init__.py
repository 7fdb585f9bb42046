"""hptvsim: a multi-vehicle underwater pursuit-evasion simulator and training stack.

Layers, each importing only the ones before it: :mod:`hptvsim.dynamics` (pure CasADi) →
:mod:`hptvsim.fmu` and :mod:`hptvsim.cosim` (FMI 2.0 co-simulation) → world and sensors →
environments → training and offline RL → visualisation and recording. The service in
``services/`` sits on top and is never imported from here.
"""

__version__ = "0.1.0"
