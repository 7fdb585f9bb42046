"""``hptvsim reproduce``'s DT steps (issue 36): the plans' ``[dt]`` tables, the DT claims' statistics
on synthetic values, the per-episode measures, a step's spec, and the report from synthetic DT
results (no training: the slow toy-size test in test_train_reproduce.py trains them)."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from train_helpers import ROOT

from hptvsim.experiments.repro_archive import GZIP_SUFFIX, is_packed
from hptvsim.experiments.repro_dt import (
    ARCHIVE_FILES,
    DTClaim,
    DTSpec,
    FixedEpisodes,
    _bring_to_spec,
    dt_claim_result,
    dt_progress,
    dt_spec,
    episode_record,
    evaluation_record,
    seed_metrics,
)
from hptvsim.experiments.reproduce import load_plan, plan_dt_jobs, plan_jobs, write_report
from hptvsim.offline.rollout import Episode
from hptvsim.train.config import ConfigError

PLANS = ROOT / "configs" / "reproduce"


def _claims() -> dict[str, DTClaim]:
    plan = load_plan(PLANS / "section5-scale.toml")
    assert plan.dt is not None
    return {c.id: c for c in plan.dt.claims}


def test_both_section5_plans_run_the_same_dt_steps_on_their_base_runs() -> None:
    """Three DT seeds, one per expert run of the MAISAC STT setting, on its target-stage models,
    collected on seeds apart from the fixed evaluation episodes; the same in both regimes."""
    small, scale = load_plan(PLANS / "section5.toml"), load_plan(PLANS / "section5-scale.toml")
    assert small.dt is not None and scale.dt is not None
    assert small.dt == scale.dt
    dt = scale.dt
    assert dt.setting == "base" and dt.stage == "target" and len(dt.seeds) >= 3
    assert set(dt.seeds) <= set(scale.seeds) and dt.episodes >= 100 and dt.updates >= 1000
    assert dt.config == (ROOT / "configs" / "dt" / "target.toml").resolve()
    collected = set(FixedEpisodes(dt.episodes, dt.num_envs, dt.collect_seed).batch_seeds())
    assert not collected & set(scale.fixed_episodes.batch_seeds())
    assert [c.id for c in dt.claims] == ["D1a", "D1b", "D2", "D3"]
    assert {c.id for c in dt.claims}.isdisjoint(c.id for c in scale.claims)
    # `--experiment dt`: the DT steps and the expert runs they need, nothing else
    assert [j.run_dir for j in plan_jobs(scale, experiments=["dt"])] == [
        f"runs/base-seed{k}" for k in dt.seeds
    ]
    assert [j.run_dir for j in plan_dt_jobs(scale)] == [f"dt/base-seed{k}" for k in dt.seeds]
    assert plan_dt_jobs(scale, experiments=["algo"]) == []
    assert [j.seed for j in plan_dt_jobs(scale, seeds=[1, 7])] == [1]
    cfg = dt.train_config(2, ["a", "b", "c"], "/data")
    assert cfg.seed == 2 and cfg.updates == dt.updates and cfg.datasets == ("a", "b", "c")


def _plan(tmp_path: Path, dt_text: str) -> Path:
    text = (
        (PLANS / "toy.toml")
        .read_text()
        .replace('config = "pursuit-stt.toml"', f'config = "{PLANS / "pursuit-stt.toml"}"', 1)
    )
    head, _, _ = text.partition("\n[dt]\n")
    p = tmp_path / "plan.toml"
    p.write_text(head + "\n[dt]\n" + dt_text)
    return p


@pytest.mark.parametrize(
    ("dt_text", "message"),
    [
        ("bogus = 1", "[dt]: unknown key(s) bogus"),
        ('setting = "nope"', "[dt] setting 'nope' is unknown; valid: base"),
        ("seeds = [0, 5]", "[dt] seed 5 is not a seed of the plan"),
        ('stage = "harbour"', "[dt] stage 'harbour' is not a stage of base (source, transition, target)"),
        ("collect_seed = 0", "include the evaluation's (0)"),
        ('target = "q99"', "[dt] target 'q99' is invalid; valid: a number or one of mean"),
        ("set = { seed = 3 }", "[dt] set: seed come from the plan"),
        ("set = { bogus_key = 1 }", "[dt] training config: "),
        ("updates = 0", "[dt] updates must be an integer >= 1"),
        (
            '[[dt.claim]]\nid = "D9"\nmetric = "speed"',
            "DT claim 'D9': metric 'speed' is invalid; valid: loss_change",
        ),
        ('[[dt.claim]]\nid = "C1a"\nmetric = "loss_change"', "[[dt.claim]] id 'C1a' is empty or taken"),
        (
            '[[dt.claim]]\nid = "D9"\nmetric = "loss_change"\ndirection = "up"',
            "direction must be 'greater' or",
        ),
    ],
)
def test_a_bad_dt_table_is_refused_with_the_key_and_the_valid_values(
    tmp_path: Path, dt_text: str, message: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_plan(_plan(tmp_path, dt_text))
    assert message in str(err.value)


@pytest.mark.parametrize(
    ("claim_id", "holds", "fails", "unresolved"),
    [
        ("D1a", [-0.7, -0.75, -0.8], [0.02, 0.03, 0.025], [-0.5, 0.4, 0.1]),
        ("D1b", [0.08, 0.085, 0.09], [0.3, 0.25, 0.35], [0.05, 0.15, 0.1]),
        ("D2", [-0.3, -0.2, -0.25], [0.1, 0.2, 0.15], [-0.5, 0.5, 0.1]),
        ("D3", [0.3, 0.35, 0.25], None, [0.0, 0.02, 0.0]),
    ],
)
def test_each_dt_claim_can_hold_fail_or_stay_unresolved(
    claim_id: str, holds: list[float], fails: list[float] | None, unresolved: list[float]
) -> None:
    """The shipped DT claims under the plan's verdict rule, on made-up values per DT seed: each
    verdict comes out where the interval says so; a rate claimed above 0 (D3) cannot fail."""
    from hptvsim.experiments.reproduce import excluded_effect

    c = _claims()[claim_id]
    iv, v = dt_claim_result(c, holds)
    assert v == "holds" and iv.n == 3
    assert iv.value == pytest.approx(float(np.mean(holds)) - c.threshold)
    if fails is not None:
        assert dt_claim_result(c, fails)[1] == "does not hold"
    iv, v = dt_claim_result(c, unresolved)
    assert v == "not resolved" and iv.resolved
    assert excluded_effect(iv).startswith("no difference larger than ")
    assert dt_claim_result(c, holds[:1])[1] == "not resolved"  # one seed: no interval
    assert dt_claim_result(c, [])[0].n == 0
    if fails is None:  # D3: all zeros is resolved ([0, 0]) but never "does not hold"
        iv, v = dt_claim_result(c, [0.0, 0.0, 0.0])
        assert v == "not resolved" and (iv.low, iv.high) == (0.0, 0.0)


def test_the_interval_is_of_the_mean_less_the_threshold_and_stays_in_the_metrics_range() -> None:
    ratio = DTClaim("X", "", "loss_ratio", "less", 0.1)
    iv, v = dt_claim_result(ratio, [0.01, 0.5, 0.02])  # the mean's t interval reaches below 0
    assert v == "not resolved" and iv.low == pytest.approx(-0.1)  # a ratio is >= 0: cut, then shifted
    rate = DTClaim("Y", "", "within_l_max_rate", "greater", 0.0)
    assert dt_claim_result(rate, [0.9, 1.0, 0.2])[0].high == 1.0


def _episode(
    distance: np.ndarray,
    *,
    captured_at: int | None = None,
    collision: bool = False,
    positions: np.ndarray | None = None,
) -> Episode:
    n = distance.shape[1]
    return Episode(
        agents=(*(f"pursuer_{i}" for i in range(n - 1)), "evader_0"),
        pursuer=np.array([True] * (n - 1) + [False]),
        batch_seed=0,
        env_index=0,
        length=distance.shape[0] - 1,
        captured_at=captured_at,
        collision=collision,
        out_of_site=False,
        returns=np.arange(n, dtype=np.float64),
        distance=distance,
        positions=positions,
    )


def test_an_episode_gives_each_pursuers_distance_slope_in_metres_per_second_and_its_closest_approach() -> (
    None
):
    dt = 0.25  # s per step
    t = np.arange(41) * dt
    d = np.stack([200.0 - 2.0 * t, 150.0 + 1.0 * t, 100.0 - 4.0 * t, np.full(41, 9.0)], axis=1)  # [m]
    rec = episode_record(_episode(d), dt)
    assert rec["slopes_mps"] == pytest.approx(
        [-2.0, 1.0, -4.0]
    )  # the evader's own distance is not a pursuer's
    assert rec["slope_mps"] == pytest.approx(-5.0 / 3.0)
    assert rec["min_distance_m"] == pytest.approx(100.0 - 4.0 * 10.0)
    assert rec["length"] == 40 and not rec["captured"]
    assert rec["return_pursuer"] == pytest.approx(1.0)  # mean of the pursuers' returns 0, 1, 2
    short = _episode(d[:6], captured_at=5)
    record = evaluation_record([_episode(d), short], dt, l_max=25.0, l_min=15.0)
    assert record["running"][:6] == [2] * 6 and record["running"][6:] == [1] * 35
    first_mean = float(np.mean(d[0, :3]))
    assert record["mean_distance_m"][0] == pytest.approx(first_mean, abs=0.01)
    assert record["mean_distance_m"][40] == pytest.approx(float(np.mean(d[40, :3])), abs=0.01)
    assert record["example"]["pursuer_2"][-1] == pytest.approx(60.0)
    assert record["pursuers"] == ["pursuer_0", "pursuer_1", "pursuer_2"]


def _write_step(
    folder: Path,
    *,
    first: list[float],
    last: list[float],
    closest: list[float],
    slope: float,
    tracks: bool = False,
) -> None:
    """A DT step's result files as `run_dt` writes them, with made-up numbers."""
    (folder / "run").mkdir(parents=True, exist_ok=True)
    with (folder / "run" / "loss.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("update", "model", "agents", "loss", "lr", "grad_norm", "wall_s"))
        for u, losses in (
            (10, first),
            (20, [(a + b) / 2 for a, b in zip(first, last, strict=True)]),
            (30, last),
        ):
            for m, loss in enumerate(losses):
                w.writerow((u, m, f"pursuer_{m}", loss, 1e-4, 0.1, u / 10))
    dt = 0.25  # s per step
    eps = []
    for c in closest:  # every pursuer closes on the evader at `slope` [m/s], ending `c` m from it
        d = c - slope * dt * (20 - np.arange(21))
        # with tracks: the evader still at (300, 200) m, the pursuers coming from the west, apart
        xy = np.tile(np.array([300.0, 200.0]), (21, 4, 1))
        xy[:, :3, 1] -= d[:, None]
        xy[:, :3, 0] += [-20.0, 0.0, 20.0]
        eps.append(
            _episode(
                np.stack([d, d, d, np.zeros(21)], axis=1),
                captured_at=20 if c < 25.0 else None,
                positions=xy if tracks else None,
            )
        )
    (folder / "eval.json").write_text(json.dumps(evaluation_record(eps, dt, l_max=25.0, l_min=15.0)))
    (folder / "summary.json").write_text(
        json.dumps(
            {
                "collect": {"episodes": [4] * 3, "steps": [80] * 3},
                "train": {"first_loss": first, "last_loss": last},
            }
        )
    )


def test_a_steps_metrics_come_from_its_loss_log_and_evaluation(tmp_path: Path) -> None:
    _write_step(
        tmp_path, first=[0.8, 0.4, 0.6], last=[0.08, 0.02, 0.06], closest=[20.0, 40.0, 30.0, 10.0], slope=-2.0
    )
    m = seed_metrics(tmp_path)
    assert m["loss_change"] == pytest.approx(np.mean([-0.72, -0.38, -0.54]))
    assert m["loss_ratio"] == pytest.approx(np.mean([0.1, 0.05, 0.1]))
    assert m["distance_slope"] == pytest.approx(-2.0)
    assert m["within_l_max_rate"] == pytest.approx(0.5) and m["below_l_min_rate"] == pytest.approx(0.25)
    assert m["capture_rate"] == pytest.approx(0.5) and m["collision_rate"] == 0.0
    assert seed_metrics(tmp_path / "none") == {}


def _spec(**kw: object) -> DTSpec:
    plan = load_plan(PLANS / "toy.toml")
    assert plan.dt is not None
    from dataclasses import replace

    return replace(plan.dt, **kw)  # type: ignore[arg-type]


def test_a_steps_folder_is_redone_from_the_first_part_the_plan_changed(tmp_path: Path) -> None:
    """spec.json says what a step was asked; a new collection redoes everything, more updates
    train on (same warm-up), a new evaluation replays only the evaluation."""
    ev = FixedEpisodes(4, 4, 0)
    spec = _spec()
    job = spec.jobs()[0]
    folder = tmp_path / job.run_dir
    said: list[str] = []

    def fill() -> None:
        for rel in ("datasets/done.json", "run/loss.csv", "eval.json", "summary.json"):
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).write_text("{}")

    _bring_to_spec(folder, dt_spec(spec, job, tmp_path, ev), said.append)
    fill()
    assert dt_progress(folder, dt_spec(spec, job, tmp_path, ev), spec.updates) == "finished"
    _bring_to_spec(folder, dt_spec(spec, job, tmp_path, ev), said.append)  # the same: nothing goes
    assert said == [] and (folder / "summary.json").is_file()
    more = _spec(updates=spec.updates + 4)
    assert dt_progress(folder, dt_spec(more, job, tmp_path, ev), more.updates).startswith("stale: its train")
    _bring_to_spec(folder, dt_spec(more, job, tmp_path, ev), said.append)
    assert (folder / "run/loss.csv").is_file() and not (folder / "eval.json").exists()  # trains on
    fill()
    _bring_to_spec(folder, dt_spec(more, job, tmp_path, FixedEpisodes(8, 4, 0)), said.append)
    assert (folder / "run/loss.csv").is_file() and not (folder / "summary.json").exists()
    fill()
    fewer = _spec(episodes=2)
    _bring_to_spec(folder, dt_spec(fewer, job, tmp_path, ev), said.append)
    assert not (folder / "datasets").exists() and not (folder / "run").exists()
    assert [line.split(": its ")[1].split(" ")[0] for line in said] == ["train", "evaluate", "collect"]
    (tmp_path / job.expert_dir).mkdir(parents=True)
    (tmp_path / job.expert_dir / "config.toml").write_text("a = 1\n")
    fill()
    _bring_to_spec(folder, dt_spec(fewer, job, tmp_path, ev), said.append)  # the expert's config appears
    assert (folder / "datasets").exists()  # an unknown hash is no change
    (tmp_path / job.expert_dir / "config.toml").write_text("a = 2\n")  # the expert run was retrained
    assert dt_progress(folder, dt_spec(fewer, job, tmp_path, ev), 6).startswith("stale: its expert")


def test_the_report_judges_the_dt_claims_from_the_dt_steps_and_archives_them(tmp_path: Path) -> None:
    """Synthetic DT results (no training) in the toy plan's folders: the verdict table has a row per
    DT claim with its interval over the DT seeds and its verdict, the seeds' table a row, the DT
    section its figures and a row per DT seed; the results are archived and a fresh folder's
    report restores them to the same tables."""
    plan = load_plan(PLANS / "toy.toml")
    assert plan.dt is not None
    out, report = tmp_path / "out", tmp_path / "docs" / "r.md"
    for job, closest in zip(plan.dt.jobs(), ([20.0, 30.0], [22.0, 40.0]), strict=True):
        folder = out / job.run_dir
        folder.mkdir(parents=True)
        (folder / "spec.json").write_text(json.dumps(dt_spec(plan.dt, job, out, plan.fixed_episodes)))
        first, last = [0.8 + 0.01 * job.seed] * 3, [0.05 + 0.01 * job.seed] * 3
        seed_slope = -1.0 - 0.1 * job.seed
        _write_step(folder, first=first, last=last, closest=closest, slope=seed_slope, tracks=job.seed == 0)
    write_report(plan, out, report)
    text = report.read_text()
    table = text.split("## Verdicts")[1].split("### Every seed")[0]
    rows = {r.split("|")[1].strip(): r for r in table.splitlines() if re.match(r"\| D\d", r)}
    assert list(rows) == ["D1a", "D1b", "D2", "D3"]
    assert all("| 2 DT seeds |" in r for r in rows.values())
    assert "**holds**" in rows["D1a"] and "**holds**" in rows["D2"]  # every seed well below 0
    assert "mean over DT seeds - 0.1 (< 0 claimed): -0.0317 [" in rows["D1b"]  # ratios 0.0625, 0.0741
    assert "mean over DT seeds (> 0 claimed): 0.5 [0.5, 0.5]" in rows["D3"] and "**holds**" in rows["D3"]
    assert "DT claims, at 2 of 2 DT steps: **" in text
    assert f"no correction for testing {len(plan.claims) + len(plan.dt.claims)} claims at once" in text
    assert "| D2 | DT pursuers (DT seed = expert run's seed) | -1 | -1.1 |" in text
    section = text.split("## Decision Transformer pursuers")[1].split("\n## ")[0]
    for name in ("dt_loss", "dt_trajectories", "dt_distance"):  # tracks: DT seed 0 kept them
        assert f"![{name}](r/dt/{name}.png)" in section
        assert (tmp_path / "docs" / "r" / "dt" / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (
        "| 0 | `runs/base-seed0` | 4, 80/80/80 | - | 0.8 -> 0.05; 0.8 -> 0.05; 0.8 -> 0.05 | 0.5 |" in section
    )
    for job in plan.dt.jobs():
        kept = tmp_path / "docs" / "r" / "results" / f"dt-{job.name}"
        had = set(ARCHIVE_FILES) - {
            "datasets/done.json",
            "run/config.toml",
            "run.json",
        }  # run.json: Ray tasks
        assert {str(p.relative_to(kept)) for p in kept.rglob("*") if p.is_file()} == {
            f"{rel}{GZIP_SUFFIX}" if is_packed(rel) else rel for rel in had
        }  # what the step had, no more (CSV logs gzipped)
    tables = [line for line in text.splitlines() if line.startswith("|")]
    write_report(plan, tmp_path / "fresh", report, figures=False)
    assert [line for line in report.read_text().splitlines() if line.startswith("|")] == tables
    assert (tmp_path / "fresh" / "dt" / "base-seed1" / "summary.json").is_file()
    assert math.isfinite(seed_metrics(tmp_path / "fresh" / "dt" / "base-seed1")["distance_slope"])


def _finished_run(folder: Path, stages: list[str], *, models: bool) -> None:
    """A run folder as the sweep leaves a finished run: its summary and one evaluation per stage."""
    for st in stages:
        (folder / "eval").mkdir(parents=True, exist_ok=True)
        (folder / "eval" / f"{st}.json").write_text(json.dumps({"stage": st, "self": {"capture_rate": 0.25}}))
        (folder / "stages" / st).mkdir(parents=True, exist_ok=True)
        if models:
            (folder / "stages" / st / "pursuer_0.zip").write_bytes(b"PK")
    (folder / "summary.json").write_text("{}")


def test_experts_restored_without_models_are_trained_again_beside_their_results(tmp_path: Path) -> None:
    """A DT step takes its experts from its expert run; one restored from the archive has results
    only, so the sweep trains the same setting and seed again in ``dt/<name>/expert`` and the
    step waits for that; a run not finished yet is trained where it is, as always."""
    from hptvsim.experiments.reproduce import dt_blocker, expert_retraining, expert_source

    plan = load_plan(PLANS / "toy.toml")
    assert plan.dt is not None
    job0, job1 = plan.dt.jobs()
    stages = ["source", "transition", "target"]
    assert expert_retraining(plan, tmp_path, [job0, job1]) == []  # nothing finished: trained in runs/
    assert dt_blocker(plan, tmp_path, job0) == "waits for runs/base-seed0 (not started)"
    _finished_run(tmp_path / job0.expert_dir, stages, models=True)
    _finished_run(tmp_path / job1.expert_dir, stages, models=False)  # restored: results only
    assert (
        expert_source(plan, tmp_path, job0) == "runs/base-seed0" and dt_blocker(plan, tmp_path, job0) is None
    )
    assert expert_source(plan, tmp_path, job1) is None
    (again,) = expert_retraining(plan, tmp_path, [job0, job1])
    assert (again.setting, again.seed, again.run_dir) == ("base", 1, "dt/base-seed1/expert")
    assert dt_blocker(plan, tmp_path, job1) == (
        "waits for dt/base-seed1/expert, runs/base-seed1 trained again for its models (not started)"
    )
    _finished_run(tmp_path / job1.retrain_dir, stages, models=True)
    assert expert_source(plan, tmp_path, job1) == "dt/base-seed1/expert"
    assert dt_blocker(plan, tmp_path, job1) is None and expert_retraining(plan, tmp_path, [job1]) == []
