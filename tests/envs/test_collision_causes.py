"""Collisions with a cause (issue 37): each agent's info, frame and episode summary say what it
touched (seabed, surface, an obstacle, the site's edge or another vehicle by name) and where; the
recording and the CLI say it too.

The collisions are made for real: vehicles are put where they touch (on an obstacle cell of the
seabed of ``target``, at the fence, on top of each other, below the seabed, at the surface)
and one step of the game is taken.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from hptvsim.catalog import shipped_scenario
from hptvsim.envs import parallel_env_3d
from hptvsim.envs.core import GameCore
from hptvsim.envs.core3d import Game3DCore
from hptvsim.envs.games import make_game
from hptvsim.episodes.frames import EpisodeSummary
from hptvsim.episodes.stepper import EXTERNAL, EpisodeStepper


def _free_point_near_the_edge(core: GameCore) -> tuple[float, float]:
    """A point inside the fence ring (0.5 m from the west edge) far from any obstacle."""
    lx, _ = core.site
    for x in np.linspace(0.1 * lx, 0.9 * lx, 81):
        p = np.array([x, 0.5])
        if float(core.world.obstacles.distance(p)) > 20.0:
            return float(x), 0.5
    raise AssertionError("no free stretch of the edge")


def _free_point(core: GameCore) -> tuple[float, float]:
    """A point of the site more than 10 m from every obstacle and the edge."""
    lx, ly = core.site
    for x in np.linspace(20.0, lx - 20.0, 40):
        for y in np.linspace(20.0, ly - 20.0, 30):
            if float(core.world.obstacles.distance(np.array([x, y]))) > 10.0:
                return float(x), float(y)
    raise AssertionError("no free point")


def _obstacle_point(core: GameCore) -> tuple[float, float]:
    """The centre of an occupied cell of the real seabed's obstacle map, away from the edge."""
    grid = core.world.obstacles
    xs, ys = grid.geometry.centres()
    cells = np.argwhere(grid.occupied)
    lx, ly = core.site
    for i, j in cells:
        x, y = float(xs[i]), float(ys[j])
        if 30.0 < x < lx - 30.0 and 30.0 < y < ly - 30.0 and float(grid.distance(np.array([x, y]))) < -2.0:
            return x, y
    raise AssertionError("target has no obstacle cell away from its edge")


def test_the_planar_game_names_the_obstacle_the_site_edge_and_the_vehicles() -> None:
    core = make_game("target", num_envs=1, seed=3)
    assert isinstance(core, GameCore)
    core.reset()
    names = list(core.agents)
    assert names == ["pursuer_0", "pursuer_1", "pursuer_2", "evader_0"]
    poses = np.zeros((1, 4, 3))  # x [m], y [m], psi [rad]
    poses[0, 0, 0:2] = _obstacle_point(core)
    x, y = _free_point(core)
    poses[0, 1, 0:2] = (x, y)
    poses[0, 2, 0:2] = (x, y + 1.0)  # 1 m apart: closer than their radii's sum
    poses[0, 3, 0:2] = _free_point_near_the_edge(core)
    core.system.reset([0], poses=poses)
    result = core.step(np.zeros((1, 4, 2)))
    assert result.flags.collision[0].all()
    assert core.collided_with(result, 0) == ["obstacle", "pursuer_2", "pursuer_1", "site edge"]
    # the views report it in every agent's info; no collision, no cause
    infos = core.infos(result, 0)
    assert [i["collided_with"] for i in infos] == ["obstacle", "pursuer_2", "pursuer_1", "site edge"]
    clear = make_game("target", num_envs=1, seed=3)
    clear.reset()
    r = clear.step(np.tile(np.array([0.5, 0.0]), (1, 4, 1)))
    assert not r.flags.collision.any()
    assert [i["collided_with"] for i in clear.infos(r, 0)] == [""] * 4
    core.close()
    clear.close()


def test_the_3d_game_names_the_seabed_the_surface_and_the_vehicles() -> None:
    core = Game3DCore("dive_flat", num_envs=1, seed=1)
    core.reset()
    depth = 60.0  # m, dive_flat's flat seabed
    assert shipped_scenario("dive_flat").to_dict()["terrain"]["depth"] == depth
    poses = np.zeros((1, 4, 6))  # x, y, z [m], phi, theta, psi [rad]
    poses[0, :, 0] = [100.0, 100.0, 100.5, 250.0]
    poses[0, :, 1] = [50.0, 200.0, 200.0, 300.0]
    poses[0, :, 2] = [depth - 0.2, 30.0, 30.0, 0.0]  # on the seabed; two together; at the surface
    core.system.reset([0], poses=poses)
    result = core.step(np.zeros((1, 4, 3)))
    assert core.collided_with(result, 0) == ["seabed", "pursuer_2", "pursuer_1", "surface"]
    core.close()


@pytest.mark.parametrize(("w", "flag"), [(1.0, "seabed"), (-1.0, "surface")])
def test_diving_into_the_seabed_or_out_of_the_water_is_reported_by_the_parallel_env(
    w: float, flag: str
) -> None:
    env = parallel_env_3d("dive_flat", max_steps=600)
    env.reset(seed=3)
    infos: dict[str, dict[str, Any]] = {}
    for _ in range(600):
        actions = {a: np.array([-1.0, 0.0, 0.0], dtype=np.float32) for a in env.agents}
        actions["pursuer_0"] = np.array([-1.0, 0.0, w], dtype=np.float32)
        _, _, _, _, infos = env.step(actions)
        if not env.agents:
            break
    assert infos["pursuer_0"]["collided_with"] == flag
    assert all(infos[a]["collided_with"] == "" for a in infos if a != "pursuer_0")
    env.close()


def _stepper_with_a_collision(tmp_path: Path) -> tuple[EpisodeStepper, Path]:
    from hptvsim.viz.recording import recorder

    rrd = tmp_path / "collision.rrd"
    stepper = EpisodeStepper(
        "source",
        dict.fromkeys(["pursuer_0", "pursuer_1", "pursuer_2"], EXTERNAL),
        seed=2,
        recorder=recorder(rrd),
    )
    core = stepper.core
    assert isinstance(core, GameCore)
    poses = np.concatenate([core.state.positions, core.state.yaw[..., None]], -1).copy()
    poses[0, 1, 0:2] = (150.0, 150.0)
    poses[0, 2, 0:2] = (150.0, 151.5)
    core.system.reset([0], poses=poses)
    return stepper, rrd


def test_the_frame_the_summary_and_the_recording_say_who_collided_with_what_and_where(tmp_path: Path) -> None:
    from hptvsim.viz.recording import read_recording

    stepper, rrd = _stepper_with_a_collision(tmp_path)
    still = {a: [0.5, 0.0] for a in ("pursuer_0", "pursuer_1", "pursuer_2")}
    frame = stepper.step(still)
    p1 = frame.agent("pursuer_1")
    assert p1.collision and p1.collided_with == "pursuer_2"
    assert frame.agent("pursuer_0").collided_with is None
    assert frame.done and frame.outcome == "collision"
    summary = stepper.summary()
    got = [(c.agent, c.collided_with, c.step) for c in summary.collisions]
    assert got == [("pursuer_1", "pursuer_2", 1), ("pursuer_2", "pursuer_1", 1)]
    c = summary.collisions[0]
    assert (c.x, c.y, c.z) == (p1.x, p1.y, None) and c.time == frame.time
    # the summary's JSON (what the API serves) round-trips
    again = EpisodeSummary.from_dict(json.loads(summary.to_json()))
    assert again.collisions == summary.collisions
    stepper.close()
    rec = read_recording(rrd)
    assert rec.summary is not None and rec.summary.collisions == summary.collisions


GOTO_THE_FENCE = Path(__file__).with_name("goto_the_fence.toml")
"""A planar goto scenario whose vehicle runs into the site's edge."""


def test_the_cli_prints_each_collision(tmp_path: Path) -> None:
    from hptvsim.cli import main

    scenario = GOTO_THE_FENCE
    rrd = tmp_path / "fence.rrd"
    out = CliRunner().invoke(
        main,
        [
            "episode",
            "--scenario",
            str(scenario),
            "--policy",
            "evader_0=scripted:pure_pursuit",
            "--record",
            str(rrd),
        ],
    )
    assert out.exit_code == 0, out.output
    assert (
        "collision after" in out.output and "collision: evader_0 with site edge at (80.0, " in out.output
    ), out.output


def test_evaluate_counts_what_collided_with_what(tmp_path: Path) -> None:
    """``hptvsim evaluate`` (a scenario file in ``--env``) prints the causes under its table and
    writes them per episode and per run in its JSON."""
    from hptvsim.cli import main

    js = tmp_path / "ev.json"
    out = CliRunner().invoke(
        main,
        [
            "evaluate",
            "--env",
            f"hptvsim:{GOTO_THE_FENCE}/goto",
            "--policy",
            "scripted:pure_pursuit",
            "--episodes",
            "2",
            "--json",
            str(js),
        ],
    )
    assert out.exit_code == 0, out.output
    assert "collisions, all=scripted:pure_pursuit: evader: site edge 2 (in 2 of 2 episodes)" in out.output
    run = json.loads(js.read_text())["runs"][0]
    assert run["collision_causes"] == {"evader: site edge": 2}
    assert [e["collided_with"] for e in run["episodes"]] == [{"evader_0": "site edge"}] * 2


def test_collision_causes_add_up_by_role() -> None:
    from hptvsim.envs.metrics import EpisodeMetrics, collision_causes

    def ep(hits: dict[str, str]) -> EpisodeMetrics:
        return EpisodeMetrics(
            seed=0, length=1, captured=False, time_to_capture_steps=None, time_to_capture_s=None,
            collision=bool(hits), min_distance=None, final_distance=None, success_rate=None,
            collided_with=hits,
        )  # fmt: skip

    eps = [
        ep({"pursuer_0": "pursuer_1", "pursuer_1": "pursuer_0"}),
        ep({"pursuer_2": "seabed, evader_0", "evader_0": "pursuer_2"}),
        ep({}),
    ]
    assert collision_causes(eps) == {
        "pursuer: pursuer": 2,
        "evader: pursuer": 1,
        "pursuer: evader": 1,
        "pursuer: seabed": 1,
    }
