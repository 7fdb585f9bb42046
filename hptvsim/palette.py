"""The display colours of the agents: one palette for every view.

The dashboard (through the frame schema's ``AgentInfo.color`` and the scenario list the service
serves), the viser live view, the rerun recordings, the ``rgb_array`` renderer, the scenario maps
and the ``hptvsim demo`` figures all take an agent's colour from here, so ``pursuer_1`` has the
same colour everywhere. An agent's colour follows from its role and its index within the role
(the number in its name, ``{role}_{index}``).

The map colours live here too (the seabed's depth ramp :data:`DEPTH_STOPS`, obstacles, land,
sonar), and the dashboard's generated module ``web/js/frames.gen.js`` carries them
(:func:`display_constants`), so the browser draws with the same colours as Python.

The colours are chosen to be told apart from each other (the three pursuers and the evader of
the shipped scenarios at least 35 CIEDE2000 units apart, every pair of the palette at least 12),
from the seabed's depth ramp (sand to dark blue, :data:`DEPTH_STOPS`), from the dashboard's dark
page and from the white of the figures: pursuers are crimson, violet, green, ...; evaders are
bright and never blue or cyan (gold first), so an evader stays visible over deep water.

This module imports nothing of hptvsim, so every layer may use it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Final

__all__ = [
    "DEPTH_STOPS",
    "EVADER_COLORS",
    "LAND_COLOR",
    "OBSTACLE_COLOR",
    "PURSUER_COLORS",
    "ROLES",
    "SONAR_HIT_COLOR",
    "SONAR_RANGE_STOPS",
    "agent_color",
    "agent_colors",
    "agent_rgb",
    "color_of",
    "display_constants",
    "hex_rgb",
]

ROLES: Final = ("pursuer", "evader")
"""The roles an agent can have."""

PURSUER_COLORS: Final = ("#e8203a", "#a970ff", "#3fcf6f", "#ff5ec8", "#ff7a1a", "#ff9e9e")
"""Pursuer ``k`` gets ``PURSUER_COLORS[k % 6]``: crimson, violet, green, pink, orange, salmon.

No warm second or third pursuer: an orange ``pursuer_1`` was 23 CIEDE2000 units from the gold
evader, hard to tell apart in a figure's legend on white."""

EVADER_COLORS: Final = ("#f2b400", "#9be22d", "#f2f2f2", "#ffe4a0")
"""Evader ``k`` gets ``EVADER_COLORS[k % 4]``: gold, lime, white, apricot (no blue, no cyan)."""

SONAR_HIT_COLOR: Final = "#1ee6ff"
"""Sonar hit points (the same for every vehicle): cyan, a hue no agent has.

It was red (``#ff3c3c``), 7 CIEDE2000 units from the crimson ``pursuer_0``, and the dashboard's
range ramp ran on through orange to pale yellow, beside the gold evader: an echo near a
vehicle read as the vehicle."""

SONAR_RANGE_STOPS: Final[tuple[tuple[float, tuple[int, int, int]], ...]] = (
    (0.0, (30, 230, 255)),  # an echo at the vehicle: SONAR_HIT_COLOR
    (0.5, (110, 200, 255)),
    (1.0, (165, 225, 255)),  # at the sonar's maximum range: pale
)
"""Colour ramp of a sonar echo's range, from 0 to the maximum range (the dashboard's sonar fans),
all cyan to sky blue: at least 25 CIEDE2000 units from the shipped scenarios' agents."""

DEPTH_STOPS: Final[tuple[tuple[float, tuple[int, int, int]], ...]] = (
    (0.0, (222, 196, 140)),  # shallow: sand
    (0.35, (120, 170, 150)),
    (0.7, (50, 110, 150)),
    (1.0, (20, 40, 90)),  # deep: dark blue
)
"""Colour ramp of seabed depth, from the shallowest (0) to the deepest (1) depth of a scene."""

OBSTACLE_COLOR: Final = "#7a5c3a"
"""Obstacles at the operating depth (terrain the vehicles would hit)."""

LAND_COLOR: Final = "#d9c79a"
"""Seabed above the surface."""


def agent_color(role: str, index: int) -> str:
    """Display colour ``#rrggbb`` of the ``index``-th agent of ``role``.

    Args:
        role: ``pursuer`` or ``evader``.
        index: The agent's index within its role (0 for ``pursuer_0``); colours repeat after
            ``len(PURSUER_COLORS)`` pursuers or ``len(EVADER_COLORS)`` evaders.

    Raises:
        ValueError: An unknown role or a negative index.
    """
    if role not in ROLES:
        raise ValueError(f"role = {role!r} is invalid; valid: {', '.join(repr(r) for r in ROLES)}")
    if index < 0:
        raise ValueError(f"index = {index} is invalid; valid: an integer >= 0")
    colors = PURSUER_COLORS if role == "pursuer" else EVADER_COLORS
    return colors[index % len(colors)]


def color_of(agent: str) -> str:
    """Display colour of an agent named ``{role}_{index}`` (``pursuer_0``, ``evader_0``, ...).

    Raises:
        ValueError: A name not of that form.
    """
    role, sep, number = agent.rpartition("_")
    if not sep or role not in ROLES or not number.isdigit():
        raise ValueError(f"agent = {agent!r} is invalid; valid: a name like 'pursuer_0' or 'evader_0'")
    return agent_color(role, int(number))


def agent_colors(roles: Mapping[str, str] | Iterable[tuple[str, str]]) -> dict[str, str]:
    """Colours of a scenario's agents, each numbered within its role in the given order.

    Args:
        roles: ``{agent name: role}`` or ``(name, role)`` pairs, in the scenario's agent order.

    Returns:
        ``{agent name: "#rrggbb"}``; distinct as long as a role has no more agents than colours.
    """
    pairs = roles.items() if isinstance(roles, Mapping) else roles
    counts: dict[str, int] = {}
    out: dict[str, str] = {}
    for name, role in pairs:
        k = counts.get(role, 0)
        counts[role] = k + 1
        out[name] = agent_color(role, k)
    return out


def hex_rgb(color: str) -> tuple[int, int, int]:
    """``"#rrggbb"`` as an ``(r, g, b)`` tuple of 0-255 integers.

    Raises:
        ValueError: A string not of the form ``#rrggbb``.
    """
    c = color.lstrip("#")
    if len(c) != 6:
        raise ValueError(f"colour {color!r} is not of the form #rrggbb")
    try:
        return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16)
    except ValueError:
        raise ValueError(f"colour {color!r} is not of the form #rrggbb") from None


def agent_rgb(role: str, index: int) -> tuple[int, int, int]:
    """:func:`agent_color` as an ``(r, g, b)`` tuple of 0-255 integers."""
    return hex_rgb(agent_color(role, index))


def display_constants() -> dict[str, object]:
    """Every colour above as JSON-ready data (what the dashboard's generated module carries)."""
    return {
        "pursuer_colors": list(PURSUER_COLORS),
        "evader_colors": list(EVADER_COLORS),
        "sonar_hit_color": SONAR_HIT_COLOR,
        "sonar_range_stops": [[t, list(rgb)] for t, rgb in SONAR_RANGE_STOPS],
        "depth_stops": [[t, list(rgb)] for t, rgb in DEPTH_STOPS],
        "obstacle_color": OBSTACLE_COLOR,
        "land_color": LAND_COLOR,
    }
