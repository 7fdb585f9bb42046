"""``hptvsim demo``: it prints the episode's outcome and metrics, and its figures give every agent
its own palette colour, label their axes with units and leave no blank gap (looked at as pixels)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.colors import to_hex

from hptvsim.demo import (
    VEHICLE_COLORS,
    episode_figure,
    episode_report,
    simulate_manoeuvre,
    trajectories_figure,
)
from hptvsim.episodes import EpisodeResult, run_episode
from hptvsim.palette import agent_color, color_of, hex_rgb

matplotlib.use("Agg")


@pytest.fixture(scope="module")
def short_episode() -> EpisodeResult:
    """200 steps (50 s) of the demo's episode."""
    return run_episode("target", {}, seed=0, max_steps=200, backend="fmu")


def _pixels(fig: Any, ax: Any, tmp_path: Path) -> np.ndarray:
    """The RGB pixels of ``ax`` in ``fig`` rendered to a PNG (frame and ticks excluded)."""
    from PIL import Image

    png = tmp_path / "figure.png"
    fig.savefig(png, dpi=100)
    img = np.asarray(Image.open(png).convert("RGB")).astype(np.int64)
    box = ax.get_window_extent()  # display pixels, origin at the bottom
    height = img.shape[0]
    return img[height - int(box.y1) + 3 : height - int(box.y0) - 3, int(box.x0) + 3 : int(box.x1) - 3]


def _count(pixels: np.ndarray, color: str, tolerance: float = 12.0) -> int:
    """Pixels within ``tolerance`` (RGB, 0-255) of ``color``."""
    return int((np.linalg.norm(pixels - np.array(hex_rgb(color)), axis=-1) <= tolerance).sum())


def _longest_white_run(png: Path) -> float:
    """The widest band of all-white pixel columns between the title and the legend, as a fraction
    of the width (a blank gap between panels)."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"))
    height, width = int(img.shape[0]), int(img.shape[1])
    body = img[int(0.06 * height) : int(0.9 * height)]
    white = [bool((body[:, j] >= 250).all()) for j in range(width)]
    best = run = 0
    for w in white:
        run = run + 1 if w else 0
        best = max(best, run)
    return best / width


def test_the_demo_prints_the_outcome_and_metrics_and_writes_both_figures(tmp_path: Path) -> None:
    from hptvsim.cli import main

    result = CliRunner().invoke(main, ["demo", "--out", str(tmp_path), "--duration", "20"])
    assert result.exit_code == 0, result.output
    out = result.output
    assert re.search(
        r"^outcome: (captured at \d+\.\d\d s \(step \d+\)|not captured \(\w+ after [\d.]+ s\))$", out, re.M
    )
    assert re.search(r"^collisions: (none|yes|.+ at [\d.]+ s)$", out, re.M)
    assert re.search(r"^min distance: \d+\.\d\d m, pursuer to evader \(capture within 25 m\)$", out, re.M)
    assert re.search(r"^steps: \d+ of at most 1200 \(dt 0\.25 s: [\d.]+ s simulated", out, re.M)
    returns = re.search(r"^returns: (.+)$", out, re.M)
    assert returns is not None
    assert [p.split()[0] for p in returns.group(1).split(", ")] == [
        "pursuer_0",
        "pursuer_1",
        "pursuer_2",
        "evader_0",
    ]
    assert "Traceback" not in out
    for name in ("trajectories.png", "episode.png"):
        png = tmp_path / name
        assert png.is_file() and str(png.resolve()) in out
        assert _longest_white_run(png) < 0.05, name  # no blank gap between the panels


def test_the_report_says_when_there_was_no_capture(short_episode: EpisodeResult) -> None:
    lines = episode_report(short_episode, {"pursuer_1": 12.5})
    text = "\n".join(lines)
    assert "outcome: not captured (truncated after 50.00 s)" in text
    assert "collisions: pursuer_1 at 12.50 s" in text
    m = short_episode.summary.metrics
    assert f"min distance: {m.min_distance:.2f} m" in text
    assert "steps: 200 of at most 200" in text
    assert f"pursuer_0 {m.returns['pursuer_0']:.1f}" in text
    assert episode_report(short_episode)[3] == "collisions: none"


def test_the_episode_figure_gives_each_agent_its_palette_colour(
    short_episode: EpisodeResult, tmp_path: Path
) -> None:
    import matplotlib.pyplot as plt

    fig = episode_figure(short_episode)
    try:
        ax_map, ax_d = fig.axes[0], fig.axes[1]
        tracks = {
            ln.get_label(): to_hex(ln.get_color())
            for ln in ax_map.lines
            if not ln.get_label().startswith("_")
        }
        names = [a.name for a in short_episode.static.agents]
        assert tracks == {n: color_of(n) for n in names}
        assert len(set(tracks.values())) == len(names) == 4
        distances = {
            ln.get_label(): to_hex(ln.get_color())
            for ln in ax_d.lines
            if ln.get_label().startswith("pursuer")
        }
        assert distances == {f"pursuer_{k}": agent_color("pursuer", k) for k in range(3)}
        for ax in (ax_map, ax_d):
            assert "[m]" in ax.get_ylabel() and re.search(r"\[(m|s)\]", ax.get_xlabel())
        assert fig.axes[2].get_ylabel().startswith("seabed depth [m]")  # the depth bar
        pixels = _pixels(fig, ax_map, tmp_path)
        for name in names:  # every track, the evader's too, shows over the seabed
            assert _count(pixels, color_of(name)) > 40, name
    finally:
        plt.close(fig)


def test_the_trajectories_figure_uses_the_palette_and_labels_its_axes(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    runs = {vt: simulate_manoeuvre(vt, 15.0) for vt in ("work_class", "spherical")}
    assert {"work_class": color_of("pursuer_0"), "spherical": color_of("evader_0")} == VEHICLE_COLORS
    fig = trajectories_figure(runs, 15.0)
    try:
        maps, (ax_u, ax_r) = fig.axes[:2], fig.axes[2:4]
        for ax, vt in zip(maps, runs, strict=True):
            assert {to_hex(ln.get_color()) for ln in ax.lines} == {VEHICLE_COLORS[vt]}
            assert (ax.get_xlabel(), ax.get_ylabel()) == ("east y [m]", "north x [m]")
            assert _count(_pixels(fig, ax, tmp_path), VEHICLE_COLORS[vt]) > 40, vt
        assert ax_u.get_ylabel() == "surge speed u [m/s]" and ax_r.get_ylabel() == "yaw rate r [rad/s]"
        assert ax_r.get_xlabel() == "time [s]"
        for ax in (ax_u, ax_r):
            assert {to_hex(ln.get_color()) for ln in ax.lines} == set(VEHICLE_COLORS.values())
    finally:
        plt.close(fig)


def test_the_3d_episode_figure_adds_each_agents_depth_over_time(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    result = run_episode("ridge_3d", {}, seed=0, max_steps=300)
    fig = episode_figure(result)
    try:
        ax_z = fig.axes[2]
        assert ax_z.get_ylabel() == "depth z [m]" and ax_z.get_xlabel() == "time [s]"
        low, high = ax_z.get_ylim()
        assert low > high == 0.0  # depth grows downwards: the surface at the top
        depth = {ln.get_label(): ln for ln in ax_z.lines if not ln.get_label().startswith("_")}
        names = [a.name for a in result.static.agents]
        assert {n: to_hex(depth[n].get_color()) for n in names} == {n: color_of(n) for n in names}
        for a in result.trajectories.agents:  # the plotted depths are the trajectories'
            assert a.z is not None
            np.testing.assert_array_equal(depth[a.name].get_ydata(), a.z)
        # the seabed under each agent (dashed) reaches the ridge's crest, shallower than 60 m
        seabeds = [ln for ln in ax_z.lines if ln.get_linestyle() == "--" and ln.get_label().startswith("_")]
        assert len(seabeds) == len(names)
        assert min(float(np.min(ln.get_ydata())) for ln in seabeds) < 59.0
        assert fig.axes[3].get_ylabel() == "seabed depth [m]"  # no planar obstacles drawn in 3-D
        pixels = _pixels(fig, ax_z, tmp_path)
        for name in names:
            assert _count(pixels, color_of(name)) > 40, name
    finally:
        plt.close(fig)


def test_the_trajectories_figure_says_why_the_current_does_not_drift_and_shows_raw_mode_drift(
    tmp_path: Path,
) -> None:
    """Issue 50, point 9: with the built-in controller (speed over ground from the DVL, sway held
    at zero) the 0.3 m/s current does not carry a vehicle off; with raw forces it does. The figure
    says so and draws the raw mode's tracks on a map of their own, each vehicle in its colour."""
    duration = 40.0  # s
    runs = {vt: simulate_manoeuvre(vt, duration) for vt in VEHICLE_COLORS}
    raw = {vt: simulate_manoeuvre(vt, duration, raw=True) for vt in VEHICLE_COLORS}
    carried = 0.3 * duration * np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])  # m, current x time
    for vt in VEHICLE_COLORS:
        for mode, run in (("controller", runs[vt]), ("raw", raw[vt])):
            still = simulate_manoeuvre(vt, duration, raw=mode == "raw", current=(0.0, 0.0))
            shift = np.array([run["x"][-1] - still["x"][-1], run["y"][-1] - still["y"][-1]])  # m
            if mode == "controller":  # holds its track: the current moves it little
                assert np.hypot(*shift) < 0.25 * np.hypot(*carried), (vt, shift)
            else:  # the current carries it about as far as the water moved, north-east
                assert shift @ carried / (carried @ carried) > 0.6, (vt, shift)
                assert np.hypot(*shift) > 0.6 * np.hypot(*carried), (vt, shift)
    fig = trajectories_figure(runs, duration, raw)
    title = fig._suptitle.get_text()
    assert "holds the speed over ground (DVL) and zero sway" in title
    assert "does not drift" in title and "raw forces" in title
    axes = {ax.get_title(): ax for ax in fig.axes}
    raw_ax = next(ax for t, ax in axes.items() if t.startswith("raw forces"))
    assert sum("no drift" in t for t in axes) == 2
    assert raw_ax.get_xlabel() == "east y [m]" and raw_ax.get_ylabel() == "north x [m]"
    pixels = _pixels(fig, raw_ax, tmp_path)
    for vt, color in VEHICLE_COLORS.items():
        assert _count(pixels, color) > 30, vt
