"""``hptvsim reproduce``: the plan, its checks, the report from partial results, and (slow) the
whole toy-size plan end to end, killed and resumed."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from train_helpers import ROOT

from hptvsim.experiments.repro_dt import ARCHIVE_FILES, add_example_positions
from hptvsim.experiments.reproduce import build_config, expert_game, load_plan, plan_jobs, write_report
from hptvsim.train.batched_run import BatchedRunConfig
from hptvsim.train.config import ConfigError, TrainConfig, load_config

PLANS = ROOT / "configs" / "reproduce"
HPTVSIM = [sys.executable, "-m", "hptvsim.cli"]


def _paper(cfg: object) -> TrainConfig:
    assert isinstance(cfg, TrainConfig)
    return cfg


def _fast(cfg: object) -> BatchedRunConfig:
    assert isinstance(cfg, BatchedRunConfig)
    return cfg


def test_the_shipped_plan_runs_every_experiment_on_the_pursuit_game_with_three_seeds() -> None:
    plan = load_plan(PLANS / "section5.toml")
    assert plan.seeds == (0, 1, 2) and plan.evaluation.episodes >= 100
    assert {e.id for e in plan.experiments} == {"algo", "stt", "vmax", "omega", "ent_coef"}
    jobs = plan_jobs(plan)
    # deduplicated: the base run serves four experiments once per seed; seed-major order
    assert [j.run_dir for j in jobs].count("runs/base-seed0") == 1
    assert [j.seed for j in jobs] == sorted(j.seed for j in jobs)
    assert len(jobs) == 9 * 3
    for setting in plan.settings.values():  # every run trains at least 150k env steps
        cfg = _paper(build_config(setting, 0, plan.fixed))
        assert sum(s.budget_steps or 0 for s in cfg.stages) >= 150_000, setting.label
    base = _paper(build_config(plan.settings["base"], 0, plan.fixed))
    assert [s.name for s in base.stages] == ["source", "transition", "target"]
    assert all(s.env.task == "pursuit" for s in base.stages)
    assert sum(s.budget_steps or 0 for s in base.stages) >= 150_000
    assert base.checkpoint_at_episode_end
    ippo = _paper(build_config(plan.settings["ippo"], 0, plan.fixed))
    assert ippo.algo == "ippo" and [s.budget_steps for s in ippo.stages] == [
        s.budget_steps for s in base.stages
    ]
    only = _paper(build_config(plan.settings["target_only"], 1, plan.fixed))
    assert [s.name for s in only.stages] == ["target"] and only.seed == 1
    assert only.stages[0].budget_steps == sum(s.budget_steps or 0 for s in base.stages)
    for k in range(1, 5):  # Fig. 11: every alpha_0 in the source scenario alone, 150k env steps each
        ent = _paper(build_config(plan.settings[f"src_alpha0{k}"], 2, plan.fixed))
        assert [s.name for s in ent.stages] == ["source"] and ent.sac.ent_coef == f"auto_0.{k}"
        assert ent.stages[0].budget_steps == 150_000 and ent.stages[0].env.scenario == "source"
    vmax = _paper(build_config(plan.settings["vmax35"], 0, plan.fixed))
    assert all(s.env.options["vehicle_parameters"]["pursuer"]["v_max"] == 3.5 for s in vmax.stages)


def test_the_scaled_plan_has_ten_seeds_and_the_papers_budget_in_the_fast_regime() -> None:
    """configs/reproduce/section5-scale.toml (issue 36): section5's settings, experiments and claims,
    >= 10 seeds, 600k env steps per stage, the seeds of a setting trained together."""
    from hptvsim.experiments.reproduce import plan_units

    small, plan = load_plan(PLANS / "section5.toml"), load_plan(PLANS / "section5-scale.toml")
    assert plan.regime == "fast" and small.regime == "paper"
    assert len(plan.seeds) >= 10 and plan.evaluation == small.evaluation
    assert set(plan.settings) == set(small.settings)
    assert plan.experiments == small.experiments and plan.claims == small.claims
    for sid, setting in plan.settings.items():
        cfg = _fast(build_config(setting, 7, plan.fixed))
        assert cfg.seeds == (7,)
        one = build_config(small.settings[sid], 0, small.fixed)
        assert [st.name for st in cfg.stages] == [st.name for st in one.stages]
        assert cfg.algo == one.algo
        assert all(st.budget_steps >= 600_000 for st in cfg.stages), sid
        if len(cfg.stages) == 3:
            assert sum(st.budget_steps for st in cfg.stages) >= 1_200_000
    base = _fast(build_config(plan.settings["base"], 0))
    only = _fast(build_config(plan.settings["target_only"], 0))
    assert only.stages[0].budget_steps == sum(st.budget_steps for st in base.stages)  # the same budget
    vmax = _fast(build_config(plan.settings["vmax35"], 0))
    assert all(st.options["vehicle_parameters"]["pursuer"]["v_max"] == 3.5 for st in vmax.stages)
    omega = _fast(build_config(plan.settings["omega40"], 0))
    assert all(st.options["vehicle_parameters"]["evader"]["omega_max"] == 4.0 for st in omega.stages)
    for k in range(1, 5):
        ent = _fast(build_config(plan.settings[f"src_alpha0{k}"], 0))
        assert ent.sac.initial_ent_coef == pytest.approx(k / 10)
    assert not base.fixed  # every agent learns, as in the Table II runs
    units = plan_units(plan, plan_jobs(plan))
    assert len(units) == 9  # one process per setting, its ten seeds together
    assert all(len(u.run_dirs) == len(plan.seeds) for u in units)  # type: ignore[union-attr]


def _claim(metric: str, stage: str, compare: str) -> str:
    head = '[[claim]]\nid = "C9"\nexperiment = "algo"\n'
    return head + f'metric = "{metric}"\nstage = "{stage}"\ncompare = {compare}'


def _plan(tmp_path: Path, text: str) -> Path:
    base = (
        (PLANS / "toy.toml")
        .read_text()
        .replace('config = "pursuit-stt.toml"', f'config = "{PLANS / "pursuit-stt.toml"}"')
    )
    p = tmp_path / "plan.toml"
    p.write_text(base + "\n" + text)
    return p


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("bogus = 1", "unknown key(s) bogus"),
        (
            '[[experiment]]\nid = "x"\nentries = [{ setting = "base" }, { setting = "nope" }]',
            "unknown setting 'nope'; valid: base",
        ),
        (
            _claim("train_final.shark", "target", '["MAISAC", "IPPO"]'),
            "metric 'train_final.shark' is invalid",
        ),
        (
            _claim("train_final.evader", "target", '["MAISAC", "SAC"]'),
            "compare must be two of the experiment's labels (MAISAC, IPPO)",
        ),
        (
            _claim("train_final.evader", "harbour", '["MAISAC", "IPPO"]'),
            "stage 'harbour' is not a stage",
        ),
        ('[setting.bad]\nstages = ["harbour"]', "stage(s) harbour not in"),
    ],
)
def test_a_bad_plan_is_refused_with_the_key_and_the_valid_values(
    tmp_path: Path, extra: str, message: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_plan(_plan(tmp_path, extra))
    assert message in str(err.value)


def test_a_report_without_runs_says_what_is_missing(tmp_path: Path) -> None:
    plan = load_plan(PLANS / "toy.toml")
    stale = tmp_path / "report" / "ent_coef" / "reward_agents.png"  # from an earlier report
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"\x89PNG\r\n\x1a\n")
    report = write_report(plan, tmp_path / "out", tmp_path / "report.md")
    assert not stale.exists()  # a figure the report does not show is not left beside it
    text = report.read_text()
    assert "Runs finished: 0 of 18" in text
    assert "**Missing:** 18 run(s)" in text
    assert text.count("**not resolved** (no finished runs)") == len(plan.claims)
    n = len(plan.claims)
    assert f"At 0 of 18 runs: **0 of {n} claims hold, 0 do not hold, {n} are not resolved**." in text
    assert "Unfinished runs may change any verdict." in text
    assert plan.dt is not None
    n_dt = len(plan.dt.claims)
    assert f"no correction for testing {n + n_dt} claims at once" in text  # the DT claims count too
    assert text.count("**not resolved** (no finished DT runs)") == n_dt
    assert (
        f"DT claims, at 0 of 2 DT steps: **0 of {n_dt} hold, 0 do not hold, {n_dt} are not resolved**" in text
    )
    assert "No finished DT step yet: no figures." in text and "**Missing:** 2 DT step(s)" in text
    for exp in plan.experiments:
        assert f"({exp.figure})" in text
    assert "![claims](report/claims.png)" in text and (tmp_path / "report/claims.png").is_file()
    seed_rows = [line for line in text.splitlines() if re.match(r"\| C\w+ \| .* \| - \| - \|$", line)]
    assert len(seed_rows) == sum(
        2 if c.compare else len(plan.experiment(c.experiment).entries) for c in plan.claims
    )


def test_the_report_lists_every_seed_behind_each_claim(tmp_path: Path) -> None:
    """The table under the verdicts gives each claim's metric per setting and seed (``-`` where a
    run has not finished the stage), and the figure beside it is drawn."""
    from hptvsim.experiments.reproduce import Results, _seeds_section, claim_result

    plan = load_plan(PLANS / "toy.toml")
    c1 = next(c for c in plan.claims if c.compare is not None)
    c5 = next(c for c in plan.claims if c.trend is not None)
    by_label = {e.label: e for e in plan.experiment(c1.experiment).entries}
    a, b = (by_label[x].setting for x in c1.compare or ())
    values: dict[tuple[str, int], dict[str, dict[str, float]]] = {
        (a, 0): {c1.stage: {c1.metric: 0.125}},
        (a, 1): {c1.stage: {c1.metric: -2.5}},
        (b, 1): {c1.stage: {c1.metric: 1234.5}, "other": {c1.metric: 9.0}},
    }
    trend = plan.experiment(c5.experiment)
    for k, e in enumerate(trend.entries):
        values[(e.setting, 0)] = {c5.stage: {c5.metric: 10.0 * k}}
    results = Results(values=values, progress={})
    lines: list[str] = []
    verdicts = {c.id: claim_result(plan, results, c) for c in plan.claims}
    _seeds_section(
        plan,
        results,
        verdicts,
        tmp_path / "fig",
        True,
        lines.append,
        "3 of 8 runs finished",
        tmp_path / "r.md",
    )
    text = "\n".join(lines)
    assert f"| {c1.id} | {c1.compare[0]} | 0.125 | -2.5 |" in text  # type: ignore[index]
    assert f"| {c1.id} | {c1.compare[1]} | - | 1.23e+03 |" in text  # type: ignore[index]
    for k, e in enumerate(trend.entries):
        assert f"| {c5.id} | {e.label} | {10.0 * k:.3g} | - |" in text
    assert "![claims](fig/claims.png)" in text
    assert (tmp_path / "fig/claims.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert trend.x_text() == "initial entropy coefficient alpha_0 (dimensionless)"
    from hptvsim.experiments.reproduce import Entry, Experiment

    def unnamed(*labels: str) -> Experiment:
        return Experiment("e", "", "", tuple(Entry(lb, "s", float(k)) for k, lb in enumerate(labels)))

    assert unnamed("a = 1", "a = 2").x_text() == "a"  # without x_label: the labels' shared name
    assert unnamed("a = 1", "b = 2").x_text() == unnamed("a = 1", "plain").x_text() == "x"


def test_cli_user_errors_are_one_line(tmp_path: Path) -> None:
    for args, needle in (
        (
            ["--plan", "nope"],
            "neither a file nor a shipped plan; shipped: section5, section5-scale, toy, toy-fast",
        ),
        (["--plan", "toy", "--experiment", "fig99"], "--experiment 'fig99' is unknown; valid: algo, stt"),
        (["--plan", "toy", "--seed", "7"], "--seed 7 is not a seed of the plan; valid: 0, 1"),
    ):
        r = subprocess.run(
            [*HPTVSIM, "reproduce", *args, "--out", str(tmp_path)], capture_output=True, text=True, cwd=ROOT
        )
        assert r.returncode == 1, r.stderr
        assert needle in r.stderr and "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1


# --- slow: the whole plan at toy size ---------------------------------------------------------------


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def _reproduce(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            *HPTVSIM,
            "reproduce",
            "--plan",
            "toy",
            "--out",
            str(out / "runs-root"),
            "--report",
            str(out / "report.md"),
            *extra,
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=_env(),
        timeout=1800,
    )


@pytest.mark.slow
def test_reproduce_end_to_end_at_toy_size(tmp_path: Path) -> None:
    r = _reproduce(tmp_path)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    plan = load_plan(PLANS / "toy.toml")
    assert plan.dt is not None
    for k in plan.dt.seeds:  # each DT step once its expert run had finished
        log = r.stdout
        assert f"trained dt/base-seed{k}" in log
        assert log.index(f"trained runs/base-seed{k}") < log.index(f"start dt/base-seed{k}")
    text = (tmp_path / "report.md").read_text()
    assert "Runs finished: 18 of 18" in text and "**Missing:**" not in text
    assert "## Budget" in text and "## Verdicts" in text and "## Runs" in text
    for exp in plan.experiments:
        assert f"## {exp.title} ({exp.figure})" in text
    verdicts_table = text.split("## Verdicts")[1].split("### Every seed")[0]  # not the seeds' table
    rows = [line for line in verdicts_table.splitlines() if re.match(r"\| C\d", line)]
    assert [r.split("|")[1].strip() for r in rows] == [c.id for c in plan.claims]
    for row in rows:
        assert re.search(r"\*\*(holds|does not hold|not resolved)\*\*", row), row
        assert re.search(r"\| (2 \+ 2 seeds|\d+ runs over \d+ values) \|", row), f"no seed count: {row}"
        assert re.search(r"\[-?[\d.e+-]+, -?[\d.e+-]+\]", row), (
            f"no interval: {row}"
        )  # 2 seeds: intervals exist
    dt_rows = [line for line in verdicts_table.splitlines() if re.match(r"\| D\d", line)]
    assert [r.split("|")[1].strip() for r in dt_rows] == [c.id for c in plan.dt.claims]
    for row in dt_rows:  # the DT claims: 2 DT seeds each, an interval, a verdict
        assert re.search(r"\*\*(holds|does not hold|not resolved)\*\*", row), row
        assert "| 2 DT seeds |" in row and re.search(r"\[-?[\d.e+-]+, -?[\d.e+-]+\]", row), row
    assert re.search(r"DT claims, at 2 of 2 DT steps: \*\*\d+ of 4 hold", text)
    dt_section = text.split("## Decision Transformer pursuers")[1].split("\n## ")[0]
    assert "**Missing:**" not in dt_section
    for k in plan.dt.seeds:
        assert re.search(
            rf"\| {k} \| `runs/base-seed{k}` \| 4, \d+/\d+/\d+ \| [\d.]+ \| .* \| finished \|", dt_section
        )
        step = tmp_path / "runs-root" / "dt" / f"base-seed{k}"
        ev = json.loads((step / "eval.json").read_text())
        assert (
            len(ev["episodes"]) == plan.evaluation.episodes
            and ev["evaluation"]["seed"] == plan.evaluation.seed
        )
        assert (step / "run" / "dt.pt").is_file()
        # Fig. 15: the first fixed episode's tracks are kept, and replaying that episode (as a step
        # evaluated before they were kept gets them) gives the very same positions
        xy = ev["example_xy"]
        assert set(xy) == set(ev["pursuers"]) | {"evader_0"}
        assert all(len(track) == ev["episodes"][0]["length"] + 1 for track in xy.values())
        del ev["example_xy"]
        (step / "eval.json").write_text(json.dumps(ev))
        root, expert_dir = tmp_path / "runs-root", f"runs/base-seed{k}"
        models = root / expert_dir / "stages" / plan.dt.stage
        experts = {a: f"sb3:{models / f'{a}.zip'}" for a in xy}
        game = expert_game(plan, root, expert_dir)
        assert add_example_positions(step, experts, game, plan.fixed_episodes, plan.dt.target, print)
        assert json.loads((step / "eval.json").read_text())["example_xy"] == xy
        assert (
            len((step / "run" / "loss.csv").read_text().splitlines()) == 1 + 3 * 3
        )  # 6 updates, logged every 2
        kept = tmp_path / "report" / "results" / f"dt-base-seed{k}"  # archived: results only
        assert {str(p.relative_to(kept)) for p in kept.rglob("*") if p.is_file()} == set(ARCHIVE_FILES)
    tally = re.search(r"At 18 of 18 runs: \*\*(\d+) of (\d+) claims hold, (\d+) do not hold, (\d+) are", text)
    assert tally is not None and "Unfinished runs may change" not in text
    verdicts = [re.search(r"\*\*(holds|does not hold|not resolved)\*\*", row) for row in rows]
    counted = [
        sum(1 for m in verdicts if m and m.group(1) == v) for v in ("holds", "does not hold", "not resolved")
    ]
    assert [int(tally.group(i)) for i in (1, 3, 4)] == counted and int(tally.group(2)) == len(rows)
    # intervals stay in the range of their quantity: rates in [0, 1], variances and times >= 0
    for line in text.splitlines():
        name = line.split("|")[1].strip() if line.startswith("| ") else ""
        bounded = name.startswith(("capture rate", "collision rate", "variance", "time to capture"))
        for low, high in re.findall(r"\[(-?[\d.e+-]+), (-?[\d.e+-]+)\]", line) if bounded else []:
            assert float(low) >= 0.0 and (not name.endswith("rate") or float(high) <= 1.0), line
    figs = sorted((tmp_path / "report").rglob("*.png"))
    assert {p.parent.name for p in figs} == {e.id for e in plan.experiments} | {"report", "dt"}
    assert [p.name for p in figs if p.parent.name == "dt"] == [
        "dt_distance.png",
        "dt_loss.png",
        "dt_trajectories.png",
    ]
    assert [p.name for p in figs if p.parent.name == "report"] == ["claims.png"]
    seed_rows = [
        line
        for line in text.splitlines()
        if re.match(r"\| C\w+ \| [^|]+ \| -?[\d.e+]+ \| -?[\d.e+]+ \|$", line)
    ]
    dt_seed_rows = [line for line in text.splitlines() if re.match(r"\| D\w+ \| DT pursuers", line)]
    assert len(dt_seed_rows) == len(plan.dt.claims)
    assert len(seed_rows) == sum(
        2 if c.compare else len(plan.experiment(c.experiment).entries) for c in plan.claims
    )
    for p in figs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({p.relative_to(tmp_path)})" in text
    # every run evaluated each of its stages with 3 matchups on the same episodes
    for job in plan_jobs(plan):
        cfg = build_config(plan.settings[job.setting], job.seed, plan.fixed)
        for st in cfg.stages:
            data = json.loads((tmp_path / "runs-root" / job.run_dir / "eval" / f"{st.name}.json").read_text())
            assert data["episodes"] == plan.evaluation.episodes
            assert {"self", "vs_scripted_evader", "vs_scripted_pursuers"} <= set(data)
    # the figures come from the experiment folders as `hptvsim figures` draws them
    again = subprocess.run(
        [
            *HPTVSIM,
            "figures",
            str(tmp_path / "runs-root/experiments/ent_coef"),
            "--out",
            str(tmp_path / "f"),
            "--no-trajectories",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert again.returncode == 0, again.stderr
    assert {Path(p).name for p in again.stdout.split()} == {
        p.name for p in figs if p.parent.name == "ent_coef"
    }
    # --status lists the DT steps
    status = _reproduce(tmp_path, "--status")
    assert status.returncode == 0, status.stderr
    for k in plan.dt.seeds:
        assert re.search(rf"^dt/base-seed{k} +DT step +finished$", status.stdout, re.M), status.stdout
    assert "; 2 of 2 DT steps finished" in status.stdout
    # a fresh clone has the runs' results but not their models: a DT step not archived trains its
    # expert run again beside them (the same run, bit for bit, in this regime), then itself
    import shutil

    shutil.rmtree(tmp_path / "report" / "results" / "dt-base-seed1")
    clone = _reproduce(
        tmp_path, "--experiment", "dt", "--seed", "1", "--no-figures", "--out", str(tmp_path / "clone")
    )
    assert clone.returncode == 0, clone.stdout[-3000:] + clone.stderr[-3000:]
    assert "trained dt/base-seed1/expert" in clone.stdout and "trained dt/base-seed1 " in clone.stdout
    retrained = tmp_path / "clone" / "dt" / "base-seed1" / "expert"
    assert not (tmp_path / "clone" / "runs" / "base-seed1" / "stages" / "target" / "pursuer_0.zip").exists()
    first = tmp_path / "runs-root" / "runs" / "base-seed1"
    for name in ("episodes.csv", "eval/target.json"):
        assert (retrained / name).read_bytes() == (first / name).read_bytes(), name
    summary = json.loads((tmp_path / "clone" / "dt" / "base-seed1" / "summary.json").read_text())
    assert summary["experts_from"] == "dt/base-seed1/expert"
    assert (tmp_path / "report" / "results" / "dt-base-seed1" / "summary.json").is_file()  # archived again


def _snapshot(root: Path) -> dict[str, str]:
    out = {}
    for p in sorted((root / "runs").rglob("*")):
        if p.name == "episodes.csv" or (p.parent.name == "eval" and p.suffix == ".json"):
            out[str(p.relative_to(root))] = p.read_text()
    return out


@pytest.mark.slow
def test_two_regimes_end_to_end_at_toy_size_side_by_side(tmp_path: Path) -> None:
    """toy.toml (one game, 2 seeds) then toy-fast.toml (batched games, 3 seeds per setting on 2
    workers, one process per setting): one report with both regimes' verdicts per claim."""
    paper = _reproduce_plan(PLANS / "toy.toml", tmp_path / "toy")
    assert paper.returncode == 0, paper.stdout[-3000:] + paper.stderr[-3000:]
    r = _reproduce_plan(PLANS / "toy-fast.toml", tmp_path / "toy-fast")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    plan = load_plan(PLANS / "toy-fast.toml")
    assert plan.beside == (PLANS / "toy.toml").resolve() and len(plan.seeds) > plan.workers
    text = (tmp_path / "toy-fast" / "r.md").read_text()
    assert "Runs finished: 18 of 18" in text and f"Runs finished: {9 * len(plan.seeds)} of 27" in text
    both = text.split("## Verdicts of both regimes")[1].split("\n## ")[0]
    rows = [line for line in both.splitlines() if re.match(r"\| C\d", line)]
    assert [row.split("|")[1].strip() for row in rows] == [c.id for c in plan.claims]
    for row in rows:
        assert len(re.findall(r"\*\*(holds|does not hold|not resolved)\*\*", row)) == 2, row
        assert re.search(r"\| (2 \+ 2 seeds|8 runs over 4 values) \|", row), row  # toy: 2 seeds
        assert re.search(r"\| (3 \+ 3 seeds|12 runs over 4 values) \|", row), row  # toy-fast: 3 seeds
        assert row.rstrip().endswith(("| agree |", "| **differ** |")), row
    assert re.search(r"- toy, at 18 of 18 runs: \*\*\d+ of 12 claims hold", both)
    assert re.search(r"- toy-fast, at 27 of 27 runs: \*\*\d+ of 12 claims hold", both)
    assert plan.dt is not None
    dt_rows = [line for line in both.splitlines() if re.match(r"\| D\d", line)]
    assert [row.split("|")[1].strip() for row in dt_rows] == [c.id for c in plan.dt.claims]
    for row in dt_rows:  # the DT claims side by side: toy's 2 DT seeds, toy-fast's 3
        assert len(re.findall(r"\*\*(holds|does not hold|not resolved)\*\*", row)) == 2, row
        assert "| 2 DT seeds |" in row and "| 3 DT seeds |" in row, row
        assert row.rstrip().endswith(("| agree |", "| **differ** |")), row
    assert re.search(r"- toy-fast, DT claims, at 3 of 3 DT steps: \*\*\d+ of 4 hold", both)
    assert "## toy: one game, Table II" in text and "## toy-fast: batched games, fast regime" in text
    log = r.stdout + r.stderr
    for sid in plan.settings:  # each setting's seeds in one worker
        assert f"runs/{sid}-seed0..2" in log
    for job in plan_jobs(plan):
        run = tmp_path / "toy-fast" / job.run_dir
        assert (run / "summary.json").is_file() and (run / "episodes.csv").is_file()
        assert not (run / "checkpoint" / "replay.npz").exists()  # deleted once evaluated
        cfg = build_config(plan.settings[job.setting], job.seed, plan.fixed)
        for st in cfg.stages:
            data = json.loads((run / "eval" / f"{st.name}.json").read_text())
            assert {"self", "vs_scripted_evader", "vs_scripted_pursuers"} <= set(data)
        archived = tmp_path / "toy-fast" / "r" / "results-toy-fast" / Path(job.run_dir).name
        assert (archived / "summary.json").is_file()  # the fast regime's own archive


@pytest.mark.slow
def test_killed_mid_sweep_it_resumes_to_the_same_results(tmp_path: Path) -> None:
    args = ("--experiment", "stt", "--seed", "0", "--no-figures")
    clean = _reproduce(tmp_path / "clean", *args)
    assert clean.returncode == 0, clean.stderr[-3000:]
    cut = tmp_path / "cut"
    cut.mkdir()
    proc = subprocess.Popen(
        [
            *HPTVSIM,
            "reproduce",
            "--plan",
            "toy",
            "--out",
            str(cut / "runs-root"),
            "--report",
            str(cut / "report.md"),
            *args,
        ],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    state = cut / "runs-root" / "runs" / "target_only-seed0" / "checkpoint" / "state.json"
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        try:  # the checkpoint folder is swapped for a new one as we read: try again
            if json.loads(state.read_text())["global_step"] >= 100:
                break
        except (OSError, json.JSONDecodeError, KeyError):
            pass
        time.sleep(0.2)
    else:
        proc.kill()
        pytest.fail("no checkpoint within 10 minutes")
    assert not (cut / "runs-root" / "runs" / "target_only-seed0" / "summary.json").exists()
    proc.send_signal(signal.SIGKILL)  # the parent only: its workers must end with it
    proc.wait()
    resumed = _reproduce(cut, *args)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "resumed runs/target_only-seed0" in resumed.stdout
    a, b = _snapshot(tmp_path / "clean" / "runs-root"), _snapshot(cut / "runs-root")
    assert a.keys() == b.keys() and len(a) == 2 + 4  # 2 runs' episodes.csv, 4 stage evaluations
    for k in a:
        assert a[k] == b[k], k


def _one_run_plan(root: Path, name: str, *, budget: int, max_steps: int, checkpoint_every: int) -> Path:
    """A plan of one MAISAC run in the source scenario with small networks, evaluated on 2 episodes."""
    plan = root / f"{name}.toml"
    plan.write_text(
        f"""name = "{name}"
config = "{PLANS / "pursuit-stt.toml"}"
seeds = [0]
workers = 1

[set]
"stage.0.budget_steps" = {budget}
"stage.*.env.options.max_steps" = {max_steps}
"sac.learning_starts" = 64
"sac.batch_size" = 32
"sac.net_arch" = [32, 32]
checkpoint_every = {checkpoint_every}
log_every = 50

[evaluation]
episodes = 2
num_envs = 2
seed = 0
last_episodes = 2

[setting.base]
label = "MAISAC"
stages = ["source"]

[[experiment]]
id = "only"
figure = "none"
title = "One run"
entries = [{{ label = "MAISAC", setting = "base" }}, {{ label = "the same", setting = "base" }}]
"""
    )
    return plan


def _stop_plan(root: Path) -> Path:
    """One run long enough to be interrupted, that takes no periodic checkpoint: whatever
    checkpoint it has after an interruption, the interruption wrote."""
    return _one_run_plan(root, "stop", budget=1800, max_steps=60, checkpoint_every=1_000_000)


def _tiny_plan(root: Path, budget: int = 200) -> Path:
    """One run of ``budget`` env steps, checkpointed every 100."""
    return _one_run_plan(root, f"tiny{budget}", budget=budget, max_steps=50, checkpoint_every=100)


def _episodes_done(run: Path) -> int:
    try:
        return len({line.split(",")[2] for line in (run / "episodes.csv").read_text().splitlines()[1:]})
    except OSError:
        return 0


def _interrupt(plan: Path, out: Path, *, after_episodes: int, group: bool) -> tuple[int, str]:
    """Start the sweep, let its run reach ``after_episodes`` episodes, then Ctrl-C the terminal's
    process group (``group``) or SIGTERM the sweep's process alone; its exit code and output."""
    proc = subprocess.Popen(
        [*HPTVSIM, "reproduce", "--plan", str(plan), "--out", str(out), "--report", str(out / "r.md")],
        cwd=ROOT,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # a process group of its own, as a terminal gives a command
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 300
    while _episodes_done(out / "runs" / "base-seed0") < after_episodes and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[0]
        time.sleep(0.1)
    if group:
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGTERM)
    output = proc.communicate(timeout=300)[0]
    return proc.returncode, output


@pytest.mark.slow
def test_interrupted_it_stops_at_an_episode_end_and_resumes_bit_identically(tmp_path: Path) -> None:
    plan = _stop_plan(tmp_path)
    clean = _reproduce_plan(plan, tmp_path / "clean")
    assert clean.returncode == 0, clean.stdout[-3000:] + clean.stderr[-3000:]
    out = tmp_path / "cut"
    run = out / "runs" / "base-seed0"
    steps: list[int] = []
    for n, group in ((3, True), (12, False)):  # Ctrl-C in a terminal, then SIGTERM (kill, docker stop)
        code, output = _interrupt(plan, out, after_episodes=n, group=group)
        assert code == 130, output
        state = json.loads((run / "checkpoint" / "state.json").read_text())
        assert state["at_boundary"] and state["global_step"] > (steps[-1] if steps else 0), state
        assert f"stopped runs/base-seed0 (at env step {state['global_step']:,}, checkpoint written)" in output
        assert not (run / "summary.json").exists() and (out / "r.md").is_file()
        steps.append(state["global_step"])
    resumed = _reproduce_plan(plan, out)
    assert resumed.returncode == 0, resumed.stdout[-3000:] + resumed.stderr[-3000:]
    assert "resumed runs/base-seed0" in resumed.stdout
    # the bar counts env steps over the sweep, from where the interrupted runs stopped
    assert "1.80k/1.80k" in resumed.stderr and "runs finished 1/1" in resumed.stderr, resumed.stderr[-2000:]
    for name in ("episodes.csv", "eval/source.json"):
        assert (run / name).read_text() == (tmp_path / "clean" / "runs" / "base-seed0" / name).read_text(), (
            name
        )


def _reproduce_plan(plan: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            *HPTVSIM,
            "reproduce",
            "--plan",
            str(plan),
            "--out",
            str(out),
            "--report",
            str(out / "r.md"),
            "--no-figures",
        ],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=900,
    )


def test_the_sweep_bar_counts_the_env_steps_of_every_run(tmp_path: Path) -> None:
    """What the progress bar of ``hptvsim reproduce`` shows, from the run folders alone: a finished
    run counts its budget, a run training the env step of its last logged episode, read from the
    end of a long ``episodes.csv``."""
    from hptvsim.experiments.reproduce import steps_done, sweep_progress

    header = "stage_index,stage,episode,agent,env_step,return,length,terminated,truncated,info\n"
    training = tmp_path / "runs" / "a-seed0"
    training.mkdir(parents=True)
    rows = [f'0,source,{k},pursuer_0,{60 * (k + 1)},1.5,60,0,1,"{{""d"":1,""x"":2}}"\n' for k in range(3000)]
    (training / "episodes.csv").write_text(header + "".join(rows))  # ~150 kB: only its end is read
    assert steps_done(training) == 180_000
    (training / "episodes.csv").write_text(header + "".join(rows[:2]) + "0,source,2,purs")  # cut mid-line
    assert steps_done(training) == 120
    finished = tmp_path / "runs" / "b-seed0"
    finished.mkdir()
    (finished / "summary.json").write_text("{}")
    assert steps_done(tmp_path / "runs" / "c-seed0") == 0
    budgets = {"runs/a-seed0": 1_000, "runs/b-seed0": 30_000, "runs/c-seed0": 5_000}
    assert sweep_progress(tmp_path, budgets) == (120 + 30_000, 1, ["runs/a-seed0"])


def test_a_run_started_before_its_first_checkpoint_is_not_called_not_started(tmp_path: Path) -> None:
    """``--status`` and the report's run table: a run is "not started" only until its run.json."""
    from hptvsim.experiments.reproduce import _progress_of, budget_steps

    cfg = load_config(ROOT / "configs" / "train" / "quick.toml")
    run_dir = tmp_path / "runs" / "a-seed0"
    assert _progress_of(run_dir, cfg) == "not started"
    run_dir.mkdir(parents=True)
    (run_dir / "run.json").write_text("{}")
    assert _progress_of(run_dir, cfg) == "training (no checkpoint yet: a restart begins at env step 0)"
    (run_dir / "checkpoint").mkdir()
    (run_dir / "checkpoint" / "state.json").write_text(json.dumps({"global_step": 1234}))
    total = budget_steps(cfg.stages)
    assert _progress_of(run_dir, cfg) == f"training (1,234/{total:,} env steps at the last checkpoint)"


def test_status_gives_the_running_sweeps_rate_and_the_time_left(tmp_path: Path) -> None:
    """``--status`` reads the ``sweep.json`` a sweep rewrites every 10 s: running or not (its pid
    alive and the record fresh), its rate over the last 15 min, and the time the rest takes."""
    from hptvsim.experiments.reproduce import _RateMeter, sweep_eta, write_sweep_record

    meter = _RateMeter(window_s=900.0)
    assert meter.add(0.0, 0) is None and meter.add(30.0, 3_000) is None  # under a minute: no rate
    assert meter.add(60.0, 6_000) == pytest.approx(100.0)
    for t in range(70, 2001, 10):  # 100 env steps/s, then 50 from t = 1000 s
        rate = meter.add(float(t), 100 * min(t, 1000) + 50 * max(0, t - 1000))
    assert rate == pytest.approx(50.0)  # the first 1000 s are out of the window
    assert meter.span_s == pytest.approx(900.0, abs=10.0)

    assert sweep_eta(tmp_path, 1_000) == "no sweep has recorded a rate here yet"
    write_sweep_record(tmp_path, 40_000, 100_000, 100.0, now=1_000.0)
    assert json.loads((tmp_path / "sweep.json").read_text())["pid"] == os.getpid()
    assert sweep_eta(tmp_path, 60_000, now=1_030.0) == (
        f"sweep running (pid {os.getpid()}): 6,000 env steps/min over its last 15 min; "
        "about 10 min left at that rate"
    )
    assert sweep_eta(tmp_path, 2_000_000, now=1_030.0).endswith("about 5 h 33 min left at that rate")
    write_sweep_record(tmp_path, 40_000, 100_000, 100.0, now=1_000.0, span_s=80.0)  # a sweep's first minutes
    assert "6,000 env steps/min over its last 1 min; about 10 min" in sweep_eta(tmp_path, 60_000, now=1_030.0)
    stale = sweep_eta(tmp_path, 60_000, now=1_000.0 + 600.0)
    assert stale.startswith("no sweep running (the last one was seen at ") and "about 10 min left" in stale
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    record = json.loads((tmp_path / "sweep.json").read_text()) | {"pid": int(dead.stdout)}
    (tmp_path / "sweep.json").write_text(json.dumps(record))
    assert sweep_eta(tmp_path, 60_000, now=1_030.0).startswith("no sweep running")
    write_sweep_record(tmp_path, 0, 100_000, None, now=1_000.0)
    assert sweep_eta(tmp_path, 100_000, now=1_030.0).endswith("no rate measured yet (it takes a minute)")
    assert sweep_eta(tmp_path, 0, now=1_030.0).endswith("nothing left to train")
    (tmp_path / "sweep.json").write_text("{not json")
    assert sweep_eta(tmp_path, 1_000) == "no sweep has recorded a rate here yet"


def _tables(report: Path) -> list[str]:
    return [line for line in report.read_text().splitlines() if line.startswith("|")]


def test_finished_runs_are_archived_beside_the_report_and_a_fresh_clone_trains_only_the_rest(
    tmp_path: Path,
) -> None:
    plan = _tiny_plan(tmp_path)
    report = tmp_path / "docs" / "repro.md"

    def run(out: str, *extra: str) -> subprocess.CompletedProcess[str]:
        args = ["--plan", str(plan), "--out", str(tmp_path / out), "--report", str(report), "--no-figures"]
        r = subprocess.run(
            [*HPTVSIM, "reproduce", *args, *extra], capture_output=True, text=True, cwd=ROOT, env=_env()
        )
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
        return r

    first = run("a")
    assert "trained runs/base-seed0" in first.stdout
    archived = tmp_path / "docs" / "repro" / "results" / "base-seed0"
    files = {str(p.relative_to(archived)) for p in archived.rglob("*") if p.is_file()}
    assert files == {
        "config.toml",
        "run.json",
        "summary.json",
        "episodes.csv.gz",
        "updates.csv.gz",
        "stages/source/stage.json",
        "eval/source.json",
    }  # results only, the logs gzipped: no models, no checkpoint
    assert "docs/repro/results/<setting>-seed<k>/" in report.read_text().replace(str(tmp_path) + "/", "")
    tables = _tables(report)
    assert any("capture rate" in t for t in tables)

    # --status reads, writes nothing: finished here, or finished in the archive only
    for out, state, sweep in (
        ("a", "finished", "no sweep running (the last one was seen at "),  # its sweep.json
        ("fresh", "finished (archived)", "no sweep has recorded a rate here yet"),
    ):
        status = run(out, "--status").stdout.splitlines()
        assert status[0].split() == ["runs/base-seed0", "200", "/", "200", "env", "steps", *state.split()]
        assert status[-2].startswith("1 of 1 runs finished; 200 of 200 env steps (100.0 %)")
        assert status[-1].startswith(sweep), status[-1]
    assert not (tmp_path / "fresh").exists()
    # a fresh clone has the report and the archive, not the run folders: the report regenerates
    report.write_text("")
    run("b", "--report-only")
    assert _tables(report) == tables
    assert (tmp_path / "b" / "runs" / "base-seed0" / "summary.json").is_file()
    # and its sweep trains nothing: the archived run is done
    again = run("c")
    assert "restored from" in again.stdout and "done before runs/base-seed0" in again.stdout
    assert not (tmp_path / "c" / "runs" / "base-seed0" / "checkpoint").exists()
    assert _tables(report) == tables

    # an archive the plan no longer builds is not restored: that run would train again
    from hptvsim.experiments.reproduce import restore_archived

    said: list[str] = []
    changed = load_plan(_tiny_plan(tmp_path, budget=300))
    assert restore_archived(changed, tmp_path / "d", archived.parent, said.append) == []
    assert said and "trained with another config than the plan builds now: base-seed0 trains again" in said[0]
    assert not (tmp_path / "d" / "runs" / "base-seed0" / "summary.json").exists()
    # and an archived run of another config is replaced whole when the run of this one finishes
    from hptvsim.experiments.reproduce import archive_finished

    (archived / "config.toml").write_text((archived / "config.toml").read_text() + "# another plan\n")
    (archived / "eval" / "gone.json").write_text("{}")
    assert archive_finished(load_plan(plan), tmp_path / "a", archived.parent) == ["base-seed0"]
    assert {str(p.relative_to(archived)) for p in archived.rglob("*") if p.is_file()} == files


def test_more_workers_than_cores_gets_a_warning_naming_the_faster_setting() -> None:
    """Runs beyond the core count only share the cores (measured: 3 on 2 cores is slower in
    total), so the sweep warns and names the worker count to use; at or under it, nothing."""
    from hptvsim.experiments.reproduce import workers_warning

    assert workers_warning(2, cpus=2) is None
    assert workers_warning(1, cpus=2) is None
    note = workers_warning(3, cpus=2)
    assert note is not None and "3 workers on 2 cores" in note and "--workers 2" in note
    assert workers_warning(4, cpus=1) == (
        "warning: 4 workers on 1 core: runs beyond the core count share the cores and the sweep "
        "is slower in total; --workers 1 is faster"
    )
    assert workers_warning(10**6) is not None  # the default reads this machine's cores
