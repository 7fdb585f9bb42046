"""Evaluation, figures and sweeps over real (tiny) training runs."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from train_helpers import toy_config

from hptvsim.cli import main
from hptvsim.experiments.policies import policies_from_specs, policy_from_spec
from hptvsim.experiments.sweeps import load_sweep, plan_jobs, run_sweep
from hptvsim.train.envs import EnvSpec, make_env_factory
from hptvsim.train.evaluate import evaluate
from hptvsim.train.trainer import train

PURSUIT = EnvSpec(kind="toy", task="pursuit", options={"n_pursuers": 2, "max_steps": 120})


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "maisac"
    train(toy_config(), out, progress=False, tensorboard=False)
    return out


def test_metrics_come_from_infos_over_fixed_seeds() -> None:
    greedy = evaluate(make_env_factory(PURSUIT), policies_from_specs("toy:greedy"), episodes=10)
    again = evaluate(make_env_factory(PURSUIT), policies_from_specs("toy:greedy"), episodes=10)
    assert greedy.summary == again.summary  # fixed seeds: the same numbers
    s = greedy.summary
    assert s["capture_rate"]["mean"] == 1.0  # faster pursuers heading straight at the evader
    assert s["time_to_capture_s"]["mean"] is not None and 0 < s["time_to_capture_s"]["mean"] < 30.0
    assert s["min_distance"]["mean"] is not None and s["min_distance"]["mean"] < 3.0  # the capture radius
    assert s["success_rate"]["mean"] is None  # no goals in pursuit
    still = evaluate(
        make_env_factory(PURSUIT), policies_from_specs("toy:greedy", {"pursuer": "random"}), episodes=10
    )
    assert (still.summary["capture_rate"]["mean"] or 0.0) < 0.5


def test_policy_specs_are_checked(run_dir: Path) -> None:
    env = make_env_factory(PURSUIT)()
    with pytest.raises(ValueError, match="valid: run:RUN_DIR"):
        policy_from_spec("magic:x", env, "pursuer_0")
    with pytest.raises(FileNotFoundError, match="finished stages: source, target"):
        policy_from_spec(f"run:{run_dir}@middle", env, "pursuer_0")
    act = policy_from_spec(f"run:{run_dir}@source", env, "pursuer_0")
    assert act(env.reset(seed=0)[0]["pursuer_0"]).shape == (2,)


def test_run_specs_take_a_one_game_runs_stage_folders(run_dir: Path) -> None:
    """A one-game run's ``stages/<stage>`` folder names its models too (issue 50.3)."""
    from hptvsim.train.runs import locate, open_run

    run = open_run(run_dir)
    assert (run.regime, run.stage_names, run.finished_stages()) == (
        "game",
        ["source", "target"],
        ["source", "target"],
    )
    assert locate(run_dir)[1:] == (run_dir / "stages" / "target", run.stage("target"))
    assert locate(run_dir / "stages" / "source")[1] == run_dir / "stages" / "source"
    with pytest.raises(FileNotFoundError, match="is the models of 'source', not of 'target'"):
        locate(run_dir / "stages" / "source", "target")
    env = make_env_factory(PURSUIT)()
    act = policy_from_spec(f"run:{run_dir}/stages/source", env, "pursuer_0")
    assert act(env.reset(seed=0)[0]["pursuer_0"]).shape == (2,)


def test_evaluate_command_writes_json_and_markdown(run_dir: Path, tmp_path: Path) -> None:
    res = CliRunner().invoke(
        main,
        [
            "evaluate",
            str(run_dir),
            str(run_dir),
            "--episodes",
            "5",
            "--json",
            str(tmp_path / "e.json"),
            "--md",
            str(tmp_path / "e.md"),
        ],
    )
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "e.json").read_text())
    assert len(data["runs"]) == 2 and len(data["runs"][0]["episodes"]) == 5
    assert data["across_runs"]["capture_rate"]["std"] == 0.0  # the same run twice
    table = (tmp_path / "e.md").read_text()
    assert "| maisac |" in table and "mean over 2 runs" in table and "capture rate" in table
    res = CliRunner().invoke(
        main, ["evaluate", "--env", "toy:source/pursuit", "--policy", "toy:greedy", "--episodes", "3"]
    )
    assert res.exit_code == 0 and "all=toy:greedy" in res.output


def test_figures_for_runs_with_two_algorithms(run_dir: Path, tmp_path: Path) -> None:
    ippo = tmp_path / "ippo"
    train(toy_config(algo="ippo"), ippo, progress=False, tensorboard=False)
    res = CliRunner().invoke(main, ["figures", str(run_dir), str(ippo), "--out", str(tmp_path / "fig")])
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in (tmp_path / "fig").glob("*.png"))
    assert names == [
        "final_reward_mean_variance.png",
        "reward_agents.png",
        "reward_evader.png",
        "reward_pursuer.png",
        "trajectories_source.png",
        "trajectories_target.png",
    ]
    assert all((tmp_path / "fig" / n).stat().st_size > 10_000 for n in names)


SWEEP = """
name = "tiny"
config = "base.toml"
seeds = [0, 1]
[set]
"stage.0.budget_steps" = 60
"stage.1.budget_episodes" = 2
[grid]
"sac.ent_coef" = ["auto_0.1", "auto_0.4"]
"""


def _sweep_file(tmp_path: Path) -> Path:
    from hptvsim.train.config import config_to_dict, dump_toml

    (tmp_path / "base.toml").write_text(dump_toml(config_to_dict(toy_config())))
    path = tmp_path / "sweep.toml"
    path.write_text(SWEEP)
    return path


def test_sweep_plans_one_job_per_setting_and_seed(tmp_path: Path) -> None:
    spec = load_sweep(_sweep_file(tmp_path))
    jobs = plan_jobs(spec)
    assert [(j.label, j.seed) for j in jobs] == [
        ("ent_coef=auto_0.1", 0),
        ("ent_coef=auto_0.1", 1),
        ("ent_coef=auto_0.4", 0),
        ("ent_coef=auto_0.4", 1),
    ]
    bad = tmp_path / "bad.toml"
    bad.write_text(SWEEP.replace('"sac.ent_coef"', '"sac.entropy"'))
    with pytest.raises(ValueError, match="'entropy'"):
        load_sweep(bad)


def test_sweep_runs_serially_and_skips_finished_jobs(tmp_path: Path) -> None:
    spec = load_sweep(_sweep_file(tmp_path))
    results = run_sweep(spec, tmp_path / "out", serial=True, progress=False)
    assert [r["status"] for r in results] == ["finished"] * 4
    labels = {
        json.loads((tmp_path / "out" / j.run_dir / "run.json").read_text())["label"] for j in plan_jobs(spec)
    }
    assert labels == {"ent_coef=auto_0.1", "ent_coef=auto_0.4"}
    again = run_sweep(spec, tmp_path / "out", serial=True, progress=False)
    assert [r["status"] for r in again] == ["done before"] * 4


@pytest.mark.slow
def test_sweep_on_a_local_ray(tmp_path: Path) -> None:
    spec = load_sweep(_sweep_file(tmp_path))
    results = run_sweep(spec, tmp_path / "out", num_cpus=2, progress=False)
    assert [r["status"] for r in results] == ["finished"] * 4
    res = CliRunner().invoke(main, ["figures", str(tmp_path / "out"), "--no-trajectories"])
    assert res.exit_code == 0, res.output


def test_every_figure_of_a_tiny_sweep_with_one_colour_per_agent_and_series(tmp_path: Path) -> None:
    from matplotlib.colors import to_hex

    from hptvsim.experiments.figures import reward_agents_figure

    spec = load_sweep(_sweep_file(tmp_path))
    run_sweep(spec, tmp_path / "out", serial=True, progress=False)
    res = CliRunner().invoke(main, ["figures", str(tmp_path / "out"), "--out", str(tmp_path / "fig")])
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in (tmp_path / "fig").glob("*.png"))
    assert names == [
        "final_reward_mean_variance.png",  # Fig. 11
        "reward_agents.png",
        "reward_evader.png",  # Figs. 8, 10
        "reward_pursuer.png",  # Figs. 7, 9
        "trajectories_source.png",  # Figs. 12-13
        "trajectories_target.png",
    ]
    runs = sorted((tmp_path / "out").glob("*-seed*"))
    fig = reward_agents_figure(runs)
    try:
        assert len(fig.axes) == 2  # one panel per setting
        for ax in fig.axes:
            agents = {
                line.get_label(): to_hex(line.get_color()) for line in ax.lines if line.get_label()[0] != "_"
            }
            assert set(agents) == {"pursuer_0", "pursuer_1", "evader_0"}
            assert len(set(agents.values())) == len(agents)  # every agent its own colour
            assert ax.get_xlabel() and ax.get_title()
        assert fig.axes[0].get_ylabel().endswith("(dimensionless)")
        assert "95 % band" in fig.texts[-1].get_text()  # the caption line
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_a_stage_still_training_is_drawn_apart_and_not_counted_as_a_seed(tmp_path: Path) -> None:
    """Figures made mid-sweep: a run that has not finished a stage is no seed of that stage."""
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import (
        _expand,
        final_reward_figure,
        finished_stages,
        reward_agents_figure,
        reward_curve_figures,
    )

    spec = load_sweep(_sweep_file(tmp_path))
    run_sweep(spec, tmp_path / "out", serial=True, progress=False)
    runs = sorted((tmp_path / "out").glob("*-seed*"))
    training = next(r for r in runs if "auto_0.1" in r.name and r.name.endswith("seed1"))
    assert finished_stages(training) == {"source", "target"}
    (training / "stages" / "target" / "stage.json").unlink()  # as if killed while training in target
    (training / "summary.json").unlink()
    assert finished_stages(training) == {"source"}
    assert _expand([tmp_path / "out"])[3].endswith(": 4 runs (1 still training)")
    figs = reward_curve_figures(runs)
    agents = reward_agents_figure(runs)
    bars = final_reward_figure(runs, stage="target")
    try:
        for fig in figs.values():
            ax = fig.axes[0]
            legend = [t.get_text() for t in ax.get_legend().get_texts()]
            assert legend == [
                "ent_coef=auto_0.1 (seeds per stage: 2, 1)",
                "ent_coef=auto_0.4 (2 seeds)",
                "ent_coef=auto_0.1, still training (not counted)",
            ], legend
            assert sum(1 for line in ax.lines if line.get_linestyle() == ":") == 2  # its line and legend key
        titles = [ax.get_title() for ax in agents.axes]
        assert titles == ["ent_coef=auto_0.1 (seeds per stage: 2, 1)", "ent_coef=auto_0.4 (2 seeds)"]
        ticks = [t.get_text() for t in bars.axes[0].get_xticklabels()]
        assert ticks == ["ent_coef=auto_0.1\n(n = 1)", "ent_coef=auto_0.4\n(n = 2)"]
        for ax in bars.axes[1::2]:  # the variance column: error bars cut at 0, never below
            assert "variance" in ax.get_title()
            bar = next(c for c in ax.containers if hasattr(c, "errorbar"))
            segments = bar.errorbar.lines[2][0].get_segments()
            ends = np.concatenate([np.asarray(seg, dtype=float).reshape(-1, 2)[:, 1] for seg in segments])
            ends = ends[np.isfinite(ends)]  # a one-seed group has no error bar
            assert ends.size and ends.min() >= 0.0, segments
    finally:
        for fig in [*figs.values(), agents, bars]:
            plt.close(fig)


def test_stages_of_different_curricula_share_a_segment_by_name() -> None:
    """A run trained in the target scenario alone is drawn over the STT runs' target stage."""
    from hptvsim.experiments.figures import stage_segments

    stt: dict[tuple[int, str], dict[str, list[float]]] = {
        (0, "source"): {},
        (1, "transition"): {},
        (2, "target"): {},
    }
    target_only: dict[tuple[int, str], dict[str, list[float]]] = {(0, "target"): {}}
    assert stage_segments([stt, target_only]) == ["source", "transition", "target"]
    assert stage_segments([target_only, stt]) == ["source", "transition", "target"]
    assert stage_segments([target_only]) == ["target"]


def test_zoo_policies_act_in_the_3d_envs_units() -> None:
    """The 3-D envs take normalised actions, the zoo acts in SI: evaluating a zoo spec on a 3-D
    env feeds the env the policy's normalised actions (not SI values clipped to [-1, 1])."""
    from hptvsim.envs.game3d import parallel_env_3d
    from hptvsim.zoo import load_policy

    env = parallel_env_3d("dive_flat", max_steps=2500)
    obs, _ = env.reset(seed=1)
    zoo = load_policy("scripted:pure_pursuit", env.core, "pursuer_0")
    for spec in ("scripted:pure_pursuit", "pure_pursuit"):  # the scripted kind and the zoo's name
        action = policy_from_spec(spec, env, "pursuer_0")(obs["pursuer_0"])
        assert np.all(np.abs(action) <= 1.0)
        si = zoo.act(obs["pursuer_0"][None])[0]
        np.testing.assert_allclose(env.core.commands_of(action, 0), si, rtol=0, atol=1e-5)
    env.close()
    result = evaluate(
        lambda: parallel_env_3d("dive_flat", max_steps=2500),
        policies_from_specs("scripted:pure_pursuit", {"evader": "scripted:stationary"}),
        episodes=3,
    )
    assert result.summary["capture_rate"]["mean"] == 1.0, result.summary


def test_names_of_narrow_stages_do_not_print_over_each_other() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import _stage_labels

    fig, ax = plt.subplots(figsize=(5, 3))
    ax.set_xlim(0, 330)
    raised = _stage_labels(ax, [(0, 27, "source"), (27, 25, "transition"), (52, 278, "target")], fontsize=8)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert [t.get_text() for t in ax.texts] == ["source", "transition", "target"]
    assert raised > 0.0 and boxes[1].y0 > boxes[0].y1  # the second name went up a row
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.set_xlim(0, 300)
    assert (
        _stage_labels(ax, [(0, 100, "source"), (100, 100, "transition"), (200, 100, "target")], fontsize=8)
        == 0.0
    )
    plt.close(fig)


def _write_run(run: Path, stages: Sequence[tuple[str, int]]) -> None:
    """A run folder as the trainer leaves it, as far as the figures read it: ``episodes.csv``
    (one row per agent and episode) and ``stages/<name>/stage.json`` for each finished stage."""
    rows = ["stage_index,stage,episode,agent,return"]
    for index, (stage, episodes) in enumerate(stages):
        for ep in range(episodes):
            for k, agent in enumerate(("pursuer_0", "pursuer_1", "pursuer_2", "evader_0")):
                rows.append(f"{index},{stage},{ep},{agent},{100.0 * k + ep}")
        (run / "stages" / stage).mkdir(parents=True)
        (run / "stages" / stage / "stage.json").write_text("{}")
    (run / "episodes.csv").write_text("\n".join(rows) + "\n")


def test_every_panel_title_of_the_per_agent_figure_stands_at_one_height(tmp_path: Path) -> None:
    """One panel raises a narrow stage's name, the other does not: their titles still line up."""
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import reward_agents_figure
    from hptvsim.palette import color_of

    narrow, even = tmp_path / "narrow-seed0", tmp_path / "even-seed0"
    _write_run(narrow, [("source", 30), ("transition", 3), ("target", 120)])
    _write_run(even, [("source", 50), ("transition", 50), ("target", 50)])
    fig = reward_agents_figure([narrow, even], labels=["narrow", "even"], smooth=1)
    try:
        renderer = fig.canvas.get_renderer()
        stage_rows = [{round(t.get_position()[1], 3) for t in ax.texts} for ax in fig.axes]
        assert len(stage_rows[0]) == 2 and len(stage_rows[1]) == 1  # only the first raised a name
        heights = [ax.title.get_window_extent(renderer).y0 for ax in fig.axes]
        assert heights[0] == pytest.approx(heights[1], abs=0.5), heights
        palette = {a: color_of(a) for a in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0")}
        for ax in fig.axes:  # each agent in its palette colour
            drawn = {ln.get_label(): ln.get_color() for ln in ax.lines if not ln.get_label().startswith("_")}
            assert drawn == palette
    finally:
        plt.close(fig)


def test_a_setting_with_no_episode_yet_gets_a_panel_that_says_so(tmp_path: Path) -> None:
    """A run just started (its episodes.csv has the header only) beside one with episodes: no
    matplotlib warning about an empty legend, and its panel says why it is empty."""
    import warnings

    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import reward_agents_figure

    ran, fresh = tmp_path / "ran-seed0", tmp_path / "fresh-seed0"
    _write_run(ran, [("source", 20)])
    fresh.mkdir()
    _write_run(fresh, [])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = reward_agents_figure([ran, fresh], labels=["ran", "fresh"], smooth=1)
    try:
        assert [ln.get_label() for ln in fig.axes[1].lines] == []
        assert [t.get_text() for t in fig.axes[1].texts] == ["no episodes yet"]
        assert fig.axes[0].get_legend() is not None and fig.axes[1].get_legend() is None
    finally:
        plt.close(fig)


def test_a_sweeps_curves_use_its_window_and_end_at_the_final_reward(tmp_path: Path) -> None:
    """A sweep folder naming ``smooth`` (as ``hptvsim reproduce`` writes it): ``hptvsim figures``
    smooths with that window and says so under the figure; at the window of the final reward, a
    group's curve ends at the mean over seeds of the final training reward of the report's tables."""
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import _expand, reward_curve_figures
    from hptvsim.experiments.reproduce import _training_metrics

    rng = np.random.default_rng(3)
    runs = [tmp_path / f"runs/s-seed{k}" for k in range(3)]
    for run in runs:
        run.mkdir(parents=True)
        rows = ["stage_index,stage,episode,agent,env_step,return"]
        for ep in range(30):
            for agent in ("pursuer_0", "pursuer_1", "evader_0"):
                rows.append(f"0,source,{ep},{agent},{100 * (ep + 1)},{rng.normal(10.0 * ep, 50.0):.6f}")
        (run / "episodes.csv").write_text("\n".join(rows) + "\n")
        (run / "stages/source").mkdir(parents=True)
        (run / "stages/source/stage.json").write_text("{}")
    sweep = tmp_path / "experiments/x"
    sweep.mkdir(parents=True)
    jobs = [{"label": "S", "run_dir": f"../../runs/{r.name}"} for r in runs]
    manifest = {"name": "t/x", "stages": ["source"], "smooth": 7, "last_episodes": 7, "jobs": jobs}
    (sweep / "sweep.json").write_text(json.dumps(manifest))
    assert _expand([sweep])[4] == {"smooth": 7, "last_episodes": 7}

    figs = reward_curve_figures(runs, smooth=7, labels=["S"] * 3, stages=["source"])
    try:
        for role, fig in figs.items():
            (line,) = [ln for ln in fig.axes[0].lines if ln.get_label().startswith("S (")]
            final = np.mean([_training_metrics(r, 7)["source"][f"train_final.{role}"] for r in runs])
            assert line.get_ydata()[-1] == pytest.approx(final, rel=1e-12)
    finally:
        for fig in figs.values():
            plt.close(fig)

    drawn = {}
    for name, extra in (("sweep", []), ("7", ["--smooth", "7"]), ("5", ["--smooth", "5"])):
        out = tmp_path / f"f{name}"
        args = ["figures", str(sweep), "--out", str(out), "--no-trajectories", *extra]
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, res.output
        drawn[name] = (out / "reward_pursuer.png").read_bytes()
    assert len(drawn["sweep"]) > 10_000
    assert drawn["sweep"] == drawn["7"] != drawn["5"]  # the sweep's window, unless --smooth says another
    bad = CliRunner().invoke(main, ["figures", str(sweep), "--smooth", "0", "--no-trajectories"])
    assert bad.exit_code == 2 and "--smooth" in bad.output and "1<=x<=1000" in bad.output
    for edited in (0, 2.5, "7", True):  # a hand-edited sweep.json: a short error naming file and key
        (sweep / "sweep.json").write_text(json.dumps({**manifest, "smooth": edited}))
        args = ["figures", str(sweep), "--out", str(tmp_path / "e"), "--no-trajectories"]
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 1 and res.exception is not None and isinstance(res.exception, SystemExit)
        assert "sweep.json: 'smooth' is " in res.output and "1..1000" in res.output, res.output
        assert "Traceback" not in res.output
    (sweep / "sweep.json").write_text(json.dumps(manifest))
    old_csv = runs[1] / "episodes.csv"  # a file from before env_step was written: one line naming it
    header = old_csv.read_text().splitlines()[0]
    old_csv.write_text(header.replace(",env_step", "") + "\n")
    res = CliRunner().invoke(main, ["figures", str(sweep), "--out", str(tmp_path / "o"), "--no-trajectories"])
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    assert "runs/s-seed1/episodes.csv: no column env_step; " in res.output, res.output


def _noisy_runs(root: Path, spreads: Sequence[float]) -> list[Path]:
    """One run per spread: 40 source episodes, each agent's return 10 x episode + N(0, spread)."""
    rng = np.random.default_rng(0)
    runs = []
    for k, spread in enumerate(spreads):
        run = root / f"s-seed{k}"
        (run / "stages/source").mkdir(parents=True)
        (run / "stages/source/stage.json").write_text("{}")
        rows = ["stage_index,stage,episode,agent,return"]
        for ep in range(40):
            for agent in ("pursuer_0", "evader_0"):
                rows.append(f"0,source,{ep},{agent},{10.0 * ep + rng.normal(0.0, spread):.6f}")
        (run / "episodes.csv").write_text("\n".join(rows) + "\n")
        runs.append(run)
    return runs


@pytest.mark.parametrize("spreads", [(1.0, 1.0, 1.0), (1.0, 1.0, 5000.0)])
def test_bands_much_wider_than_the_curves_are_cut_at_the_axes_and_the_caption_says_so(
    tmp_path: Path, spreads: tuple[float, ...]
) -> None:
    """Seeds that agree: the whole band is shown. One wild seed: the band is cut at the axes so
    the mean stays readable (whole, within the limits), and the line under the figure says so."""
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import BAND_CUT, reward_agents_figure, reward_curve_figures

    runs = _noisy_runs(tmp_path, spreads)
    wild = max(spreads) > 100.0
    figs = reward_curve_figures(runs, smooth=3, labels=["S"] * 3, caption="c")
    figs["agents"] = reward_agents_figure(runs, smooth=3, labels=["S"] * 3)
    try:
        for fig in figs.values():
            ax = fig.axes[0]
            low, high = ax.get_ylim()
            means = np.concatenate([ln.get_ydata() for ln in ax.lines if ln.get_label() != "_nolegend_"])
            assert low <= means.min() and means.max() <= high  # every line whole
            band = ax.collections[0].get_paths()[0].vertices[:, 1]
            assert (band.min() < low or band.max() > high) == wild  # cut only where far wider
            if wild:
                assert high - low <= 3.0 * (means.max() - means.min()) + 1e-9
            assert any(BAND_CUT in " ".join(t.get_text().split()) for t in fig.texts) == wild
    finally:
        for fig in figs.values():
            plt.close(fig)


@pytest.mark.parametrize("cut", [0, 12])
def test_a_curve_over_seeds_of_unequal_length_says_where_it_stops(tmp_path: Path, cut: int) -> None:
    """Seeds whose stage ran different numbers of episodes: the group's curve stops at the fewest,
    and the line under the figure says so (and that the tables use each seed's own last episodes)."""
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import UNEVEN, reward_agents_figure, reward_curve_figures

    runs = _noisy_runs(tmp_path, (1.0, 1.0, 1.0))
    csv_path = runs[2] / "episodes.csv"
    rows = csv_path.read_text().splitlines()
    csv_path.write_text("\n".join(rows[: len(rows) - 2 * cut]) + "\n")  # two agents per episode
    figs = reward_curve_figures(runs, smooth=3, labels=["S"] * 3, caption="c")
    figs["agents"] = reward_agents_figure(runs, smooth=3, labels=["S"] * 3)
    try:
        for name, fig in figs.items():
            start = "pursuer_0" if name == "agents" else "S ("
            (line,) = [ln for ln in fig.axes[0].lines if ln.get_label().startswith(start)]
            assert len(line.get_xdata()) == 40 - cut
            caption = " ".join(" ".join(t.get_text().split()) for t in fig.texts)
            assert (UNEVEN in caption) == bool(cut), caption
    finally:
        for fig in figs.values():
            plt.close(fig)


def test_the_claims_figure_shows_every_seed_in_its_colour_and_the_intervals_the_report_uses() -> None:
    """One panel per claim; a seed's dots have one colour in every panel; a comparison's black
    interval is the mean's t interval cut to the metric's range (a rate's to [0, 1]); a trend's
    dashed line has the least-squares slope of the claim's interval."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_hex

    from hptvsim.experiments.figures import SEED_COLORS, ClaimPanel, claims_figure
    from hptvsim.experiments.stats import mean_interval, slope

    assert len(set(SEED_COLORS)) == len(SEED_COLORS) >= 10  # a ten-seed plan repeats no colour
    rate = ClaimPanel(
        title="R: capture rate",
        ylabel="capture rate (fraction of episodes)",
        groups=(("A", None, ((0, 0.4), (1, 0.0))), ("B", None, ((0, 0.0), (1, 0.02), (2, 0.0)))),
        summary="A - B",
        limits=(0.0, 1.0),
    )
    trend_points = {0.1: ((0, 5.0), (1, 4.0)), 0.2: ((0, 3.0), (1, 3.5)), 0.4: ((0, 1.0),)}
    trend = ClaimPanel(
        title="T: final reward",
        ylabel="total reward (dimensionless)",
        groups=tuple((f"x = {x}", x, pts) for x, pts in trend_points.items()),
        summary="slope",
        xlabel="x (dimensionless)",
    )
    empty = ClaimPanel(title="E", ylabel="r", groups=(("A", None, ()), ("B", None, ())), summary="none")
    fig = claims_figure([rate, trend, empty], columns=2)
    try:
        axes = [ax for ax in fig.axes if ax.get_visible()]
        assert len(axes) == 3 and not fig.axes[3].get_visible()
        for ax, panel in zip(axes, (rate, trend, empty), strict=True):
            dots = [ln for ln in ax.lines if ln.get_marker() == "o"]
            points = [p for _, _, pts in panel.groups for p in pts]
            assert len(dots) == len(points)
            for ln, (seed, value) in zip(dots, points, strict=True):
                assert to_hex(ln.get_color()) == SEED_COLORS[seed] and ln.get_ydata()[0] == value
            assert ax.get_ylabel() == panel.ylabel and panel.title in ax.get_title()
        # the rate's interval: A's t interval at n = 2 reaches far beyond [0, 1] and is cut there
        raw = mean_interval([0.4, 0.0])
        assert raw.low < -1.0 and raw.high > 2.0
        ends = [s[:, 1] for c in axes[0].collections for s in c.get_segments()]
        assert min(float(e.min()) for e in ends) == 0.0 and max(float(e.max()) for e in ends) == 1.0
        (line,) = [ln for ln in axes[1].lines if ln.get_linestyle() == "--"]
        (x0, x1), (y0, y1) = line.get_xdata(), line.get_ydata()
        xs = [x for x, pts in trend_points.items() for _ in pts]
        ys = [v for pts in trend_points.values() for _, v in pts]
        assert (y1 - y0) / (x1 - x0) == pytest.approx(slope(xs, ys).value, rel=1e-9)
        assert axes[1].get_xlabel() == "x (dimensionless)"
        assert any(t.get_text() == "no finished runs yet" for t in axes[2].texts)
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        assert legend[:3] == ["seed 0", "seed 1", "seed 2"]
    finally:
        plt.close(fig)


def test_a_long_figure_caption_is_wrapped_to_the_figures_width() -> None:
    """A caption longer than its figure is wide wraps instead of running off the edge."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.experiments.figures import _caption

    fig = plt.figure(figsize=(4.0, 3.0))
    _caption(fig, "word " * 60)
    fig.canvas.draw()
    (text,) = fig.texts
    box = text.get_window_extent()
    assert "\n" in text.get_text() and box.x1 <= fig.bbox.x1  # within the figure
    plt.close(fig)
