"""World: scenario files, seabed terrain, obstacle maps and ocean currents.

* :mod:`hptvsim.world.scenario` -- the scenario schema, :func:`load_scenario`,
  :class:`Scenario` and the runtime :class:`World` it builds;
* :mod:`hptvsim.world.terrain` -- :class:`HeightMap` and the seabed generators;
* :mod:`hptvsim.world.importers` -- GeoTIFF, ESRI ASCII, PNG, XYZ/CSV and S-57 charts to height maps;
* :mod:`hptvsim.world.currents` -- uniform, shear, vortex and tidal current fields;
* :mod:`hptvsim.world.grid` -- grid geometry and the obstacle map with its signed distance field.

Every name is imported lazily (on first use), so that importing one submodule pulls in only
what it needs: the sensor settings declare their fields with :mod:`hptvsim.world._schema`
(standard library only) without loading numpy, scipy or the scenario schema.
"""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hptvsim.world.currents import (
        CurrentField,
        CurrentSum,
        ShearCurrent,
        TidalCurrent,
        UniformCurrent,
        VortexCurrent,
        still_water,
    )
    from hptvsim.world.grid import GridGeometry, OccupancyGrid
    from hptvsim.world.importers import ImportOptions, TerrainImportError, import_heightmap, import_terrain
    from hptvsim.world.scenario import (
        Scenario,
        ScenarioError,
        World,
        list_scenarios,
        load_scenario,
        scenario_dir,
    )
    from hptvsim.world.terrain import FlatSeabed, HeightMap, RollingMountains

_LAZY = {
    "CurrentField": "hptvsim.world.currents",
    "CurrentSum": "hptvsim.world.currents",
    "ShearCurrent": "hptvsim.world.currents",
    "TidalCurrent": "hptvsim.world.currents",
    "UniformCurrent": "hptvsim.world.currents",
    "VortexCurrent": "hptvsim.world.currents",
    "still_water": "hptvsim.world.currents",
    "GridGeometry": "hptvsim.world.grid",
    "OccupancyGrid": "hptvsim.world.grid",
    "FlatSeabed": "hptvsim.world.terrain",
    "HeightMap": "hptvsim.world.terrain",
    "RollingMountains": "hptvsim.world.terrain",
    "Scenario": "hptvsim.world.scenario",
    "ScenarioError": "hptvsim.world.scenario",
    "World": "hptvsim.world.scenario",
    "list_scenarios": "hptvsim.world.scenario",
    "load_scenario": "hptvsim.world.scenario",
    "scenario_dir": "hptvsim.world.scenario",
    "ImportOptions": "hptvsim.world.importers",
    "TerrainImportError": "hptvsim.world.importers",
    "import_heightmap": "hptvsim.world.importers",
    "import_terrain": "hptvsim.world.importers",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'hptvsim.world' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


__all__ = [
    "CurrentField",
    "CurrentSum",
    "FlatSeabed",
    "GridGeometry",
    "HeightMap",
    "ImportOptions",
    "OccupancyGrid",
    "RollingMountains",
    "Scenario",
    "ScenarioError",
    "ShearCurrent",
    "TerrainImportError",
    "TidalCurrent",
    "UniformCurrent",
    "VortexCurrent",
    "World",
    "import_heightmap",
    "import_terrain",
    "list_scenarios",
    "load_scenario",
    "scenario_dir",
    "still_water",
]
