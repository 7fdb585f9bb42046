"""World: scenario files, seabed terrain, obstacle maps and ocean currents."""

from hptvsim.world.grid import GridGeometry, OccupancyGrid

__all__ = ["GridGeometry", "OccupancyGrid"]
