"""The one palette of agent colours: distinct colours, an evader that shows over deep water, and the
lower layers (the ``rgb_array`` renderer, the scenario maps) drawing with it."""

from __future__ import annotations

import colorsys
import itertools

import numpy as np
import pytest

from hptvsim import palette
from hptvsim.catalog import scenario_names, shipped_scenario
from hptvsim.palette import (
    EVADER_COLORS,
    PURSUER_COLORS,
    agent_color,
    agent_colors,
    agent_rgb,
    color_of,
    hex_rgb,
)


def _lab(rgb: tuple[int, int, int]) -> np.ndarray:
    """CIE L*a*b* (D65) of an sRGB colour."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = m @ linear / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16.0 / 116.0)
    return np.array([116.0 * f[1] - 16.0, 500.0 * (f[0] - f[1]), 200.0 * (f[1] - f[2])])


def _distance(a: str, b: str | tuple[int, int, int]) -> float:
    """Perceptual difference of two colours (CIE76 delta E: about 2.3 is just noticeable)."""
    rgb_b = hex_rgb(b) if isinstance(b, str) else b
    return float(np.linalg.norm(_lab(hex_rgb(a)) - _lab(rgb_b)))


def test_every_agent_of_every_shipped_scenario_has_its_own_colour() -> None:
    for name in scenario_names():
        agents = shipped_scenario(name).agents
        colors = agent_colors((a.name, a.role) for a in agents)
        assert list(colors) == [a.name for a in agents]
        assert len(set(colors.values())) == len(agents), (name, colors)
        assert all(colors[a.name] == color_of(a.name) for a in agents)  # the name says it all


def test_pursuers_do_not_share_a_red_and_every_colour_is_distinct() -> None:
    every = PURSUER_COLORS + EVADER_COLORS
    assert len(set(every)) == len(every)
    for a, b in itertools.combinations(every, 2):
        assert _distance(a, b) > 20.0, (a, b)
    shipped = [agent_color("pursuer", k) for k in range(3)] + [agent_color("evader", 0)]
    for a, b in itertools.combinations(shipped, 2):
        assert _distance(a, b) > 35.0, (a, b)  # the shipped scenarios' agents: far apart


@pytest.mark.parametrize("color", EVADER_COLORS)
def test_evaders_are_neither_blue_nor_cyan_and_show_over_the_seabed(color: str) -> None:
    from hptvsim.viz.style import DEPTH_STOPS

    r, g, b = (c / 255.0 for c in hex_rgb(color))
    hue, saturation, _ = colorsys.rgb_to_hsv(r, g, b)
    assert saturation < 0.25 or not 160.0 <= 360.0 * hue <= 270.0, f"{color} is blue or cyan"
    for t, rgb in DEPTH_STOPS:
        if t >= 0.3:  # water a vehicle moves over (the shallowest sand is obstacles)
            assert _distance(color, rgb) > 30.0, (color, t)
    assert _distance(color, "#132338") > 70.0  # the dashboard's dark page


def test_names_roles_and_refusals() -> None:
    assert color_of("pursuer_1") == PURSUER_COLORS[1] == agent_color("pursuer", 1)
    assert color_of("evader_0") == EVADER_COLORS[0]
    assert color_of(f"pursuer_{len(PURSUER_COLORS)}") == PURSUER_COLORS[0]  # colours repeat after six
    assert agent_colors({"pursuer_0": "pursuer", "evader_0": "evader", "pursuer_1": "pursuer"}) == {
        "pursuer_0": PURSUER_COLORS[0],
        "evader_0": EVADER_COLORS[0],
        "pursuer_1": PURSUER_COLORS[1],
    }
    assert agent_rgb("evader", 0) == hex_rgb(EVADER_COLORS[0])
    assert hex_rgb("#ff7a1a") == (255, 122, 26)
    for bad in ("boss_0", "pursuer", "pursuer_x", "evader_-1"):
        with pytest.raises(ValueError, match="valid: a name like"):
            color_of(bad)
    with pytest.raises(ValueError, match="valid: 'pursuer', 'evader'"):
        agent_color("boss", 0)
    with pytest.raises(ValueError, match="index"):
        agent_color("pursuer", -1)
    for bad in ("#12345", "#gggggg"):
        with pytest.raises(ValueError, match="#rrggbb"):
            hex_rgb(bad)


def test_the_palette_is_the_one_the_other_modules_use() -> None:
    from hptvsim.viz import frames, style

    assert frames.agent_color is palette.agent_color
    assert style.hex_rgb is palette.hex_rgb


def test_the_rgb_array_renderer_draws_each_agent_in_its_colour() -> None:
    from hptvsim.envs.render import TopDownRenderer

    roles = np.array([True, True, True, False])
    renderer = TopDownRenderer(
        site=(100.0, 100.0),
        depth=None,
        occupied=None,
        extent=(0.0, 100.0, 0.0, 100.0),
        pursuer=roles,
        beam_angles=np.zeros(1),
        width=200,
    )  # 2 px per m
    positions = np.array([[20.0, 20.0], [20.0, 80.0], [80.0, 20.0], [80.0, 80.0]])
    img = renderer.render(
        positions=positions, yaw=np.zeros(4), ranges=np.zeros((4, 1)), radii=np.full(4, 4.0)
    )
    names = ["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]
    for (x, y), name in zip(positions, names, strict=True):
        col, row = round(2 * y), round(2 * (100.0 - x))
        pixel = tuple(int(v) for v in img[row + 4, col])  # inside the disc, south of its heading line
        assert pixel == hex_rgb(color_of(name)), name


def test_the_scenario_map_draws_spawn_regions_in_the_roles_first_colours() -> None:
    from hptvsim.world import render

    assert {"pursuer": color_of("pursuer_0"), "evader": color_of("evader_0")} == render._ROLE_COLOURS
