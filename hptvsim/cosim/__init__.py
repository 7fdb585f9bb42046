"""Co-simulation: FMI 2.0 and 3.0 CS FMUs wired by a graph, the vehicle composition, a batched backend.

* :mod:`hptvsim.cosim.fmi`: what FMI 2.0 and 3.0 instances share: variables, value types and
  units, the FMI errors;
* :mod:`hptvsim.cosim.fmi2`: lean, checked FMI 2.0 calls on preallocated buffers;
* :mod:`hptvsim.cosim.fmi3`: FMI 3.0 instances with the same interface;
* :mod:`hptvsim.cosim.fmu_model`: an FMU loaded once (model description, extraction), which
  makes instances of either version;
* :mod:`hptvsim.cosim.graph`: the graph description (dataclasses; TOML/JSON files);
* :mod:`hptvsim.cosim.orchestrator`: the master (fixed macro steps, Jacobi or Gauss-Seidel);
* :mod:`hptvsim.cosim.interface`: the vehicle system's spec, array layouts and interface;
* :mod:`hptvsim.cosim.system`: B sub-environments x N vehicles (reset, pause, resume,
  snapshot, restore) on the FMU path, and :func:`make_system` for either backend;
* :mod:`hptvsim.cosim.batched`: the same system, bit for bit, through the FMU binaries'
  batch entry points, for training speed.
* :mod:`hptvsim.cosim.trajectory`: the one trajectory schema (column names, SI units, stored
  types, order and layouts) that the master's output table and every writer above it use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hptvsim._lazy import lazy_getattr

if TYPE_CHECKING:
    from hptvsim.cosim.batched import BatchedSnapshot, BatchedVehicleSystem, NonFiniteStateError
    from hptvsim.cosim.fmi import FmuError, FmuLoadError, FmuVariableError, Variable
    from hptvsim.cosim.fmi2 import Fmu2Instance
    from hptvsim.cosim.fmu_model import FmuModel, load_model
    from hptvsim.cosim.graph import (
        Component,
        Connection,
        ExternalInput,
        ExternalOutput,
        Graph,
        GraphError,
        Port,
        load_graph,
        save_graph,
    )
    from hptvsim.cosim.interface import SystemSpec, VehicleSpec, VehicleSystem
    from hptvsim.cosim.orchestrator import (
        Orchestrator,
        SimulationFailedError,
        SimulationPausedError,
        Snapshot,
    )
    from hptvsim.cosim.system import FmuSystemSnapshot, FmuVehicleSystem, make_system, vehicle_graph

__all__ = [
    "BatchedSnapshot",
    "BatchedVehicleSystem",
    "Component",
    "Connection",
    "ExternalInput",
    "ExternalOutput",
    "Fmu2Instance",
    "FmuError",
    "FmuLoadError",
    "FmuModel",
    "FmuSystemSnapshot",
    "FmuVariableError",
    "FmuVehicleSystem",
    "Graph",
    "GraphError",
    "NonFiniteStateError",
    "Orchestrator",
    "Port",
    "SimulationFailedError",
    "SimulationPausedError",
    "Snapshot",
    "SystemSpec",
    "Variable",
    "VehicleSpec",
    "VehicleSystem",
    "load_graph",
    "load_model",
    "make_system",
    "save_graph",
    "vehicle_graph",
]

_WHERE = {
    "BatchedSnapshot": "hptvsim.cosim.batched",
    "BatchedVehicleSystem": "hptvsim.cosim.batched",
    "Component": "hptvsim.cosim.graph",
    "Connection": "hptvsim.cosim.graph",
    "ExternalInput": "hptvsim.cosim.graph",
    "ExternalOutput": "hptvsim.cosim.graph",
    "Fmu2Instance": "hptvsim.cosim.fmi2",
    "FmuError": "hptvsim.cosim.fmi",
    "FmuLoadError": "hptvsim.cosim.fmi",
    "FmuModel": "hptvsim.cosim.fmu_model",
    "FmuSystemSnapshot": "hptvsim.cosim.system",
    "FmuVariableError": "hptvsim.cosim.fmi",
    "FmuVehicleSystem": "hptvsim.cosim.system",
    "Graph": "hptvsim.cosim.graph",
    "GraphError": "hptvsim.cosim.graph",
    "NonFiniteStateError": "hptvsim.cosim.batched",
    "Orchestrator": "hptvsim.cosim.orchestrator",
    "Port": "hptvsim.cosim.graph",
    "SimulationFailedError": "hptvsim.cosim.orchestrator",
    "SimulationPausedError": "hptvsim.cosim.orchestrator",
    "Snapshot": "hptvsim.cosim.orchestrator",
    "SystemSpec": "hptvsim.cosim.interface",
    "Variable": "hptvsim.cosim.fmi",
    "VehicleSpec": "hptvsim.cosim.interface",
    "VehicleSystem": "hptvsim.cosim.interface",
    "load_graph": "hptvsim.cosim.graph",
    "load_model": "hptvsim.cosim.fmu_model",
    "make_system": "hptvsim.cosim.system",
    "save_graph": "hptvsim.cosim.graph",
    "vehicle_graph": "hptvsim.cosim.system",
}

__getattr__ = lazy_getattr(__name__, _WHERE)
