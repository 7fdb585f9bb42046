"""The one palette of agent colours: distinct colours, an evader that shows over deep water, and the
lower layers (the ``rgb_array`` renderer, the scenario maps) drawing with it."""

from __future__ import annotations

import colorsys
import itertools
import math
from collections.abc import Sequence

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


def _ciede2000(a: str, b: str) -> float:
    """CIEDE2000 colour difference of two sRGB colours: CIE76 overstates how far apart yellows
    and oranges look, this does not."""
    return _ciede2000_lab(tuple(_lab(hex_rgb(a))), tuple(_lab(hex_rgb(b))))


def _ciede2000_lab(lab1: Sequence[float], lab2: Sequence[float]) -> float:
    """CIEDE2000 of two L*a*b* colours (Sharma, Wu & Dalal 2005, eqs. 1-22)."""
    (l1, a1, b1), (l2, a2, b2) = lab1, lab2
    c_bar = (math.hypot(a1, b1) + math.hypot(a2, b2)) / 2.0
    g = 0.5 * (1.0 - math.sqrt(c_bar**7 / (c_bar**7 + 25.0**7)))
    a1p, a2p = (1.0 + g) * a1, (1.0 + g) * a2
    c1, c2 = math.hypot(a1p, b1), math.hypot(a2p, b2)
    h1, h2 = math.degrees(math.atan2(b1, a1p)) % 360.0, math.degrees(math.atan2(b2, a2p)) % 360.0
    dh = 0.0 if c1 * c2 == 0.0 else (h2 - h1 + 180.0) % 360.0 - 180.0
    d_l, d_c = l2 - l1, c2 - c1
    d_h = 2.0 * math.sqrt(c1 * c2) * math.sin(math.radians(dh / 2.0))
    l_bar, cp_bar = (l1 + l2) / 2.0, (c1 + c2) / 2.0
    if c1 * c2 == 0.0:
        h_bar = h1 + h2
    elif abs(h1 - h2) <= 180.0:
        h_bar = (h1 + h2) / 2.0
    else:
        h_bar = (h1 + h2 + 360.0) / 2.0 if h1 + h2 < 360.0 else (h1 + h2 - 360.0) / 2.0
    t = (
        1.0
        - 0.17 * math.cos(math.radians(h_bar - 30.0))
        + 0.24 * math.cos(math.radians(2.0 * h_bar))
        + 0.32 * math.cos(math.radians(3.0 * h_bar + 6.0))
        - 0.20 * math.cos(math.radians(4.0 * h_bar - 63.0))
    )
    r_c = 2.0 * math.sqrt(cp_bar**7 / (cp_bar**7 + 25.0**7))
    r_t = -math.sin(math.radians(60.0 * math.exp(-(((h_bar - 275.0) / 25.0) ** 2)))) * r_c
    s_l = 1.0 + 0.015 * (l_bar - 50.0) ** 2 / math.sqrt(20.0 + (l_bar - 50.0) ** 2)
    s_c, s_h = 1.0 + 0.045 * cp_bar, 1.0 + 0.015 * cp_bar * t
    return math.sqrt((d_l / s_l) ** 2 + (d_c / s_c) ** 2 + (d_h / s_h) ** 2 + r_t * (d_c / s_c) * (d_h / s_h))


def test_ciede2000_matches_the_published_test_pairs() -> None:
    """Sharma et al.'s test data (pairs 1, 7 and 17), then sRGB colours through our sRGB -> Lab."""
    assert _ciede2000_lab((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485)) == pytest.approx(2.0425, abs=1e-4)
    assert _ciede2000_lab((50.0, 0.0, 0.0), (50.0, -1.0, 2.0)) == pytest.approx(2.3669, abs=1e-4)
    assert _ciede2000_lab((50.0, 2.5, 0.0), (73.0, 25.0, -18.0)) == pytest.approx(27.1492, abs=1e-4)
    assert _ciede2000("#ffffff", "#ffffff") == 0.0
    assert _ciede2000("#f2b400", "#ff7a1a") == pytest.approx(_ciede2000("#ff7a1a", "#f2b400"))
    assert _ciede2000("#000000", "#ffffff") == pytest.approx(100.0, abs=0.01)


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
        assert _ciede2000(a, b) > 12.0, (a, b)
    shipped = [agent_color("pursuer", k) for k in range(3)] + [agent_color("evader", 0)]
    for a, b in itertools.combinations(shipped, 2):
        assert _ciede2000(a, b) > 35.0, (a, b)  # the shipped scenarios' agents: far apart
    for c in shipped:  # each shows on the figures' white and on the dashboard's dark page
        assert _ciede2000(c, "#ffffff") > 25.0 and _ciede2000(c, "#132338") > 40.0, c


def test_sonar_echoes_are_not_read_as_vehicles() -> None:
    """Every colour of the sonar's range ramp (the dashboard's fans; its first stop is the hit
    colour of viser and rerun) is far from the shipped scenarios' agents and apart from every
    agent colour; it was red through orange to pale yellow, 7 units from the crimson pursuer."""
    ramp = ["#{:02x}{:02x}{:02x}".format(*rgb) for _, rgb in palette.SONAR_RANGE_STOPS]
    assert ramp[0] == palette.SONAR_HIT_COLOR
    assert [t for t, _ in palette.SONAR_RANGE_STOPS] == sorted(
        {0.0, 1.0, *(t for t, _ in palette.SONAR_RANGE_STOPS)}
    )
    shipped = [agent_color("pursuer", k) for k in range(3)] + [agent_color("evader", 0)]
    for c in ramp:
        assert min(_ciede2000(c, a) for a in shipped) > 25.0, c
        assert min(_ciede2000(c, a) for a in PURSUER_COLORS + EVADER_COLORS) > 15.0, c
        assert _ciede2000(c, "#132338") > 40.0, c  # shows on the dashboard's dark page
    assert palette.display_constants()["sonar_range_stops"] == [
        [t, list(rgb)] for t, rgb in palette.SONAR_RANGE_STOPS
    ]


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
    from hptvsim.episodes import frames
    from hptvsim.viz import style

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
