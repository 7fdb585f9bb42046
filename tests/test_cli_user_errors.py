"""A user's mistake on the command line ends in one line naming it, never in a traceback (issue 17).

Every ``hptvsim`` command is run with a typical wrong argument (an unknown name, a missing or
broken file, a bad number, an invalid config key or value) and must exit with 1 or 2, print one
error line (click's ``Usage:`` and ``Try ...`` lines aside) that names the bad value and the valid
ones, and no ``Traceback``. The commands run outside the test process: a few as ``python -m
hptvsim.cli ...``, and the long list in one more interpreter that imports the command line once
and runs each argument list as the interpreter runs a command (an exception that escapes prints
its traceback), which keeps the file within a minute of CPU.

Then: ``hptvsim episode`` refuses a policy made for another role as the service does, ``hptvsim
train`` checks every stage before its first step, and ``--resume`` takes a corrected config for
the stages that have not started yet while refusing a change to what is trained already.
"""

from __future__ import annotations

import csv
import itertools
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any, Literal

import pytest

from hptvsim.catalog import CatalogError, check_policy, policies
from hptvsim.train.checkpoint import LoopState
from hptvsim.train.config import ConfigError, TrainConfig, config_from_dict, load_config, raw_config
from hptvsim.zoo import check_policy_spec

HPTVSIM = [sys.executable, "-m", "hptvsim.cli"]
PLANAR_MODEL = Path(__file__).resolve().parents[1] / "policies" / "maisac-pursuer_0.zip"
"""A shipped model of the planar game (2 actions), which no 3-D scenario can play."""

TOY_SMALL: dict[str, Any] = {
    "seed": 3,
    "checkpoint_every": 100,
    "log_every": 50,
    "sac.net_arch": [16, 16],
    "sac.batch_size": 16,
    "sac.buffer_size": 2000,
    "sac.learning_starts": 40,
    "stage.0.budget_steps": 120,
    "stage.1.budget_steps": 60,
    "stage.*.env.options.max_steps": 30,
    "stage.*.env.options.n_pursuers": 2,
}
"""Overrides that make the shipped ``toy`` config train in about a second."""


ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}

DRIVER = """
import contextlib, io, json, sys, traceback
from hptvsim.cli import main
results = {}
for name, args in json.load(sys.stdin).items():
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main.main(args, prog_name="hptvsim", standalone_mode=True)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
        except BaseException:  # what the interpreter does with an exception that escapes
            traceback.print_exc()
            code = 1
    results[name] = [code, out.getvalue(), err.getvalue()]
json.dump(results, sys.stdout)
"""
"""Runs many argument lists (JSON on stdin) through ``hptvsim`` in one interpreter."""


def hptvsim(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run ``hptvsim ARGS`` in a fresh interpreter."""
    return subprocess.run([*HPTVSIM, *args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=300)


def hptvsim_many(cases: dict[str, list[str]], cwd: Path) -> dict[str, subprocess.CompletedProcess[str]]:
    """Run each argument list through ``hptvsim`` in one other interpreter (see :data:`DRIVER`)."""
    res = subprocess.run(
        [sys.executable, "-c", DRIVER],
        input=json.dumps(cases),
        cwd=cwd,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    return {
        name: subprocess.CompletedProcess(cases[name], code, out, err)
        for name, (code, out, err) in json.loads(res.stdout).items()
    }


def error_line(res: subprocess.CompletedProcess[str]) -> str:
    """The one error line of a failed command (asserting exit code, one line, no traceback)."""
    shown = f"exit {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"
    assert "Traceback" not in res.stderr + res.stdout, shown
    assert res.returncode in (1, 2), shown
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    message = [ln for ln in lines if not ln.startswith(("Usage: ", "Try '"))]
    assert len(message) == 1, shown
    assert message[0].startswith("Error: "), shown  # click's prefix, the same in every command
    return message[0]


def toy_config(**overrides: Any) -> TrainConfig:
    """The shipped toy curriculum (source goto, target pursuit), small, with dotted-key overrides."""
    return load_config("toy", {**TOY_SMALL, **overrides})


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a broken TOML file, a file of garbage and an empty folder."""
    folder = tmp_path_factory.mktemp("cli-errors")
    (folder / "bad.toml").write_text("not toml [[\n")
    (folder / "garbage.bin").write_bytes(b"\x00garbage\xff" * 8)
    (folder / "garbage.pt").write_bytes(b"\x00garbage\xff" * 8)
    (folder / "empty").mkdir()
    # the target scenario with 8 sonar beams: the shipped planar models observe 16
    import tomllib

    from hptvsim._paths import shipped_dir
    from hptvsim._toml import dump_toml

    data = tomllib.loads((shipped_dir("scenarios") / "target.toml").read_text())
    data.setdefault("sensors", {}).setdefault("sonar", {})["beams"] = 8
    (folder / "beams8.toml").write_text(dump_toml(data))
    return folder


# (args, what the error line must contain: the bad value, then something of the valid ones)
CASES: dict[str, tuple[list[str], tuple[str, ...]]] = {
    "episode-scenario": (["episode", "--scenario", "nosuch"], ("nosuch", "target")),
    "episode-policy": (["episode", "--policy", "pursuer_0=nosuch"], ("nosuch", "scripted:pure_pursuit")),
    "episode-agent": (["episode", "--policy", "nobody=scripted:pure_pursuit"], ("nobody", "pursuer_0")),
    "episode-role": (
        ["episode", "--policy", "evader_0=maisac-pursuers"],
        ("'maisac-pursuers' drives pursuer, not evader_0", "maisac-evader"),
    ),
    "episode-max-steps": (["episode", "--max-steps", "0"], ("0", ">= 1")),
    "episode-model-of-another-game": (  # a planar model in a 3-D scenario: was a 39-line traceback
        [
            "episode",
            "--scenario",
            "dive_flat",
            "--policy",
            f"pursuer_0=sb3:{PLANAR_MODEL}",
            "--max-steps",
            "2",
        ],
        ("maisac-pursuer_0.zip", "acts in (2,)", "3d game takes 3"),
    ),
    "episode-model-of-another-layout": (  # named neither the model nor the agent before
        [
            "episode",
            "--scenario",
            "beams8.toml",
            "--policy",
            f"pursuer_0=sb3:{PLANAR_MODEL}",
            "--max-steps",
            "2",
        ],
        ("maisac-pursuer_0.zip: the model observes (26,) but pursuer_0's observation has 12 values",),
    ),
    "evaluate-model-of-another-layout": (
        [
            "evaluate",
            "--env",
            "hptvsim:beams8.toml/pursuit",
            "--pursuers",
            f"sb3:{PLANAR_MODEL}",
            "--evaders",
            "scripted:potential_field",
            "--episodes",
            "1",
        ],
        ("maisac-pursuer_0.zip: the model observes (26,) but pursuer_0's observation has 12 values",),
    ),
    "evaluate-zip-of-another-layout": (  # zip: skipped the check before ("Error: Error: ...")
        [
            "evaluate",
            "--env",
            "hptvsim:beams8.toml/pursuit",
            "--pursuers",
            f"zip:{PLANAR_MODEL}",
            "--evaders",
            "scripted:potential_field",
            "--episodes",
            "1",
        ],
        ("maisac-pursuer_0.zip: the model observes (26,) but pursuer_0's observation has 12 values",),
    ),
    "episode-model-garbage": (
        ["episode", "--policy", "pursuer_0=sb3:garbage.bin", "--max-steps", "2"],
        ("garbage.bin", "not an SB3 SAC or PPO file"),
    ),
    "episode-model-missing": (
        ["episode", "--policy", "pursuer_0=sb3:missing.zip", "--max-steps", "2"],
        ("missing.zip", "not found"),
    ),
    "episode-backend": (["episode", "--backend", "nosuch"], ("nosuch", "batched")),
    "scenario-show-garbage": (["scenario", "show", "garbage.bin"], ("garbage.bin",)),
    "scenario-validate-garbage": (["scenario", "validate", "bad.toml"], ("bad.toml",)),
    "evaluate-model-missing": (
        ["evaluate", "--env", "toy:source/goto", "--policy", "sb3:missing.zip", "--episodes", "1"],
        ("missing.zip",),
    ),
    "view-scenario": (["view", "--scenario", "nosuch", "--port", "0"], ("nosuch", "target")),
    "replay-missing": (["replay", "missing.rrd"], ("missing.rrd", "does not exist")),
    "viz-schema": (["viz", "schema", "--out", "bad.toml/web"], ("bad.toml/web", "cannot make")),
    "demo-duration": (["demo", "--duration", "-1"], ("-1", "x>0")),
    "demo-scenario": (["demo", "--scenario", "atlantis", "--no-episode"], ("atlantis", "ridge_3d")),
    "fmu-build": (["fmu", "build", "--type", "nosuch", "--out", "fmus"], ("nosuch", "work_class")),
    "fmu-build-vehicle-file": (
        ["fmu", "build", "--vehicle-file", "bad.toml", "--out", "fmus"],
        ("bad.toml", "not valid TOML"),
    ),
    "fmu-check": (["fmu", "check", "--dir", "empty"], ("empty", "WorkClassUUV.fmu")),
    "vehicle-fit-log": (
        ["vehicle", "fit", "garbage.bin", "--vehicle", "work_class", "--free", "X_u", "--out", "o.toml"],
        ("garbage.bin", "'time'"),
    ),
    "vehicle-fit-vehicle": (
        ["vehicle", "fit", "bad.toml", "--vehicle", "nosuch", "--free", "X_u", "--out", "o.toml"],
        ("nosuch", "work_class"),
    ),
    "twin-predict": (["twin", "predict", "garbage.bin", "--vehicle", "spherical"], ("garbage.bin", "'time'")),
    "vehicle-sitl": (
        ["vehicle", "sitl", "--vehicle", "nosuch", "--mavlink", "udpout:127.0.0.1:9"],
        ("nosuch", "work_class"),
    ),
    "vehicle-sitl-mavlink": (
        ["vehicle", "sitl", "--vehicle", "work_class", "--mavlink", "serial:/dev/nosuch"],
        ("serial:/dev/nosuch", "udpout:HOST:PORT"),
    ),
    "cosim-run-broken": (["cosim", "run", "bad.toml"], ("bad.toml", "line 1")),
    "cosim-run-missing": (["cosim", "run", "missing.toml"], ("missing.toml", "does not exist")),
    "cosim-export-ssp": (["cosim", "export-ssp", "bad.toml", "--out", "x.ssp"], ("bad.toml", "line 1")),
    "scenario-validate": (["scenario", "validate", "nosuch"], ("nosuch", "target")),
    "scenario-show": (["scenario", "show", "nosuch"], ("nosuch", "target")),
    "scenario-list": (["scenario", "list", "--nosuch"], ("--nosuch", "No such option")),
    "scenario-schema": (["scenario", "schema", "--nosuch"], ("--nosuch", "No such option")),
    "terrain-import": (["terrain", "import", "garbage.bin", "--out", "t.npz"], ("garbage.bin", ".tif")),
    "sonar-snr-plot": (["sonar", "snr-plot", "--trials", "3"], ("3", "x>=10")),
    "train-config": (["train", "nosuch"], ("nosuch", "quick")),
    "train-key": (["train", "toy", "--set", "sac.nosuch=1"], ("nosuch", "batch_size")),
    "train-stage-option": (
        ["train", "toy", "--set", "stage.1.env.options.max_stepz=5", "--out", "run"],
        ("stage 'target'", "max_stepz", "max_steps"),
    ),
    "train-resume": (["train", "--resume", "--out", "empty"], ("empty", "config.toml")),
    "train-3d-option": (
        [
            "train",
            "quick",
            "--set",
            "stage.0.env.scenario=dive_goto",
            "--set",
            "stage.0.env.options.azimuth_beamz=8",
            "--out",
            "run3d",
        ],
        ("azimuth_beamz", "azimuth_beams", "elevation_beams"),  # the 3-D env's options
    ),
    "evaluate-run": (["evaluate", "empty"], ("empty", "config.toml")),
    "evaluate-policy": (
        ["evaluate", "--env", "toy:source/goto", "--policy", "nosuch", "--episodes", "1"],
        ("nosuch", "random"),
    ),
    "evaluate-kind": (["evaluate", "--env", "nosuch:source/goto", "--policy", "random"], ("nosuch", "toy")),
    "figures": (["figures", "empty"], ("empty", "episodes.csv")),
    "sweep": (["sweep", "bad.toml", "--serial"], ("bad.toml", "not valid TOML")),
    "reproduce": (
        ["reproduce", "--plan", "nosuch", "--out", "rep", "--report", "rep/r.md"],
        ("nosuch", "section5"),
    ),
    "reproduce-status-and-report": (
        ["reproduce", "--status", "--report-only", "--out", "rep", "--report", "rep/r.md"],
        ("--status", "--report-only"),
    ),
    "collect": (["collect", "--scenario", "nosuch", "--out", "ds"], ("nosuch", "target")),
    "collect-3d-scenario": (
        ["collect", "--scenario", "dive_flat", "--out", "ds3d"],
        ("dive_flat", "3d game", "hptvsim collect plays the planar game only"),
    ),
    "dt-pipeline-3d-scenario": (
        ["dt", "pipeline", "--scenario", "ridge_3d", "--out", "dtp3d"],
        ("ridge_3d", "3d game", "planar game only"),
    ),
    "dt-train": (["dt", "train", "--dataset", "nosuch", "--out", "dt"], ("nosuch", "hptvsim collect")),
    "dt-evaluate": (["dt", "evaluate", "garbage.pt"], ("garbage.pt", "not a readable DT policy")),
    "dt-figures": (["dt", "figures", "empty"], ("empty", "dt.pt")),
    "dt-pipeline": (["dt", "pipeline", "--scenario", "nosuch", "--out", "dtp"], ("nosuch", "target")),
    "twin-replay": (["twin", "replay", "nosuch.tlog"], ("nosuch.tlog", "no such file", ".tlog", ".BIN")),
    "twin-listen": (["twin", "listen", "tcp:1.2.3.4:5"], ("tcp:1.2.3.4:5", "udp:HOST:PORT")),
    "serve": (["serve", "--port", "99999", "--data-dir", "svc"], ("99999", "0..65535")),
    "serve-view": (["serve", "view", "--port", "99999"], ("99999", "0<=x<=65535")),
    "bench-dynamics": (["bench", "dynamics", "--type", "nosuch"], ("nosuch", "work_class")),
    "bench-cosim": (["bench", "cosim", "--h-max", "-1"], ("-1", "x>0")),
    "bench-sensors": (["bench", "sensors", "--nosuch"], ("--nosuch", "No such option")),
    "bench-env": (["bench", "env", "--scenario", "nosuch"], ("nosuch", "target")),
    "bench-episode": (["bench", "episode", "--scenario", "nosuch"], ("nosuch", "target")),
    "bench-threads": (["bench", "threads", "--scenario", "nosuch"], ("nosuch", "target")),
    "bench-world": (["bench", "world", "--nosuch"], ("--nosuch", "No such option")),
    "bench-train": (["bench", "train", "--env", "nosuch"], ("nosuch", "hptvsim")),
    "bench-learn": (["bench", "learn", "--trainer", "nosuch"], ("nosuch", "fast ippo")),
    "bench-env-3d": (
        ["bench", "env", "--quick", "--scenario", "ridge_3d"],
        ("ridge_3d", "3d game", "planar"),
    ),
    "bench-dt": (["bench", "dt", "--nosuch"], ("--nosuch", "No such option")),
    "bench-policy": (["bench", "policy", "--nosuch"], ("--nosuch", "No such option")),
    "policy-export": (
        ["policy", "export", "nosuch", "--out", "x"],
        ("nosuch", "maisac-pursuers", "zip:PATH"),
    ),
    "policy-export-scenario": (
        ["policy", "export", "maisac-evader", "--scenario", "ridge_3d", "--out", "x"],
        ("ridge_3d", "planar game"),
    ),
    "bench-service": (["bench", "service", "--url", "http://127.0.0.1:9"], ("127.0.0.1:9", "no hptvsim")),
}


@pytest.fixture(scope="module")
def outcomes(work: Path) -> dict[str, subprocess.CompletedProcess[str]]:
    """What every case of :data:`CASES` printed and returned."""
    return hptvsim_many({name: args for name, (args, _) in CASES.items()}, work)


@pytest.mark.parametrize("case", list(CASES))
def test_a_wrong_argument_gives_one_line_without_a_traceback(
    case: str, outcomes: dict[str, subprocess.CompletedProcess[str]]
) -> None:
    line = error_line(outcomes[case])
    for text in CASES[case][1]:
        assert text in line, line


def test_episode_and_evaluate_refuse_a_model_that_does_not_fit_alike(
    outcomes: dict[str, subprocess.CompletedProcess[str]],
) -> None:
    """One check of a model against the scenario (:func:`hptvsim.train.policy.check_observation`
    through the zoo's loader): the same line and exit code from both commands."""
    for pair in (("episode-model-of-another-layout", "evaluate-model-of-another-layout"),):
        episode, evaluate = (outcomes[name] for name in pair)
        assert error_line(episode) == error_line(evaluate)
        assert episode.returncode == evaluate.returncode == 1


def test_every_command_has_a_case() -> None:
    import click

    from hptvsim.cli import main

    def leaves(group: click.Group, prefix: str) -> set[str]:
        out = set()
        for name, cmd in group.commands.items():
            if isinstance(cmd, click.Group):
                out |= leaves(cmd, f"{prefix}{name} ")
                if cmd.invoke_without_command:  # `hptvsim serve` runs by itself too
                    out.add(f"{prefix}{name}")
            else:
                out.add(f"{prefix}{name}")
        return out

    covered = set()
    for args, _ in CASES.values():
        words = [a for a in args if not a.startswith("-")]
        for n in (2, 1):
            if " ".join(words[:n]) in leaves(main, ""):
                covered.add(" ".join(words[:n]))
                break
    assert leaves(main, "") - covered == set()


# --- roles ---------------------------------------------------------------------------------------


def test_episode_refuses_a_policy_made_for_another_role(work: Path) -> None:
    spec = "scripted:proportional_navigation"  # before, the episode ran with it (maisac-* gave a traceback)
    line = error_line(hptvsim(["episode", "--policy", f"evader_0={spec}", "--max-steps", "3"], work))
    assert f"policy {spec!r} drives pursuer, not evader_0 (an evader)" in line
    assert "scripted:potential_field" in line and "maisac-evader" in line


def test_the_command_line_and_the_service_agree_on_roles() -> None:
    roles: tuple[Literal["pursuer", "evader"], ...] = ("pursuer", "evader")
    for entry in policies():
        for role, game in itertools.product(roles, ("planar", "3d")):
            allowed = role in entry.roles and game in entry.games
            try:
                check_policy_spec(entry.name, role, game=game)
                zoo_ok = True
            except ValueError:
                zoo_ok = False
            try:
                check_policy(entry.name, role, game)
                service_ok = True
            except CatalogError:
                service_ok = False
            assert zoo_ok == service_ok == allowed, (entry.name, role, game)


# --- every stage checked before the first step ---------------------------------------------------


def three_stages(**last: Any) -> TrainConfig:
    """The toy curriculum with a third stage whose ``env`` table is updated with ``last``."""
    data = raw_config("toy")
    data["stage"].append(
        {
            "name": "final",
            "budget_steps": 60,
            "env": {"kind": "toy", "task": "pursuit", "options": {"max_steps": 30}, **last},
        }
    )
    return config_from_dict(data, "three stages")


@pytest.mark.parametrize(
    ("last", "expected"),
    [
        ({"options": {"max_stepz": 30}}, ("stage 'final'", "'max_stepz'", "valid: ", "max_steps")),
        ({"options": {"max_steps": "long"}}, ("stage 'final'", "env.options.max_steps", "an integer")),
        ({"options": {"n_pursuers": 0, "n_evaders": 0}}, ("stage 'final'", "at least one agent")),
        ({"kind": "tyo"}, ("stage 'final'", "'tyo'", "toy")),
    ],
    ids=["option-name", "option-type", "option-value", "kind"],
)
def test_train_checks_the_last_stage_before_the_first_step(
    tmp_path: Path, last: dict[str, Any], expected: tuple[str, ...]
) -> None:
    from hptvsim.train.trainer import train

    with pytest.raises(ConfigError) as info:
        train(three_stages(**last), tmp_path / "run", progress=False, tensorboard=False)
    message = str(info.value)
    assert "\n" not in message
    for text in expected:
        assert text in message, message
    assert not (tmp_path / "run" / "episodes.csv").exists()  # no step, no row, not even a folder
    assert not (tmp_path / "run").exists()


def test_train_checks_the_fixed_policies_of_every_stage(tmp_path: Path) -> None:
    from hptvsim.train.trainer import check_stages

    with pytest.raises(ConfigError, match=r"stage 'source': fixed\.evader: unknown policy spec 'nosuch'"):
        check_stages(toy_config(**{"fixed.evader": "nosuch"}))
    with pytest.raises(ConfigError, match="'evadr' names no agent or role of any stage; valid: evader"):
        check_stages(toy_config(**{"fixed.evadr": "random"}))
    with pytest.raises(ConfigError, match="every agent is fixed"):
        check_stages(toy_config(**{"fixed.evader": "random", "fixed.pursuer": "toy:greedy"}))
    check_stages(toy_config(**{"fixed.evader": "toy:greedy"}))


# --- resume with a corrected config --------------------------------------------------------------


def test_resume_changes_allows_only_stages_not_started() -> None:
    from hptvsim.train.trainer import resume_changes

    saved = toy_config()
    later = toy_config(**{"stage.1.env.options.max_steps": 20})
    assert resume_changes(saved, saved, LoopState(stage_index=1)) == []
    assert resume_changes(saved, later, LoopState(stage_index=1)) == ["stage 'target'"]
    assert resume_changes(saved, toy_config(log_every=10), LoopState(stage_index=1)) == ["log_every"]
    with pytest.raises(ConfigError, match=r"stage 'target' is in progress; its config differs at "):
        resume_changes(saved, later, LoopState(stage_index=1, stage_started=True))
    with pytest.raises(ConfigError, match=r"differs at sac\.batch_size \(saved 16, given 32\)"):
        resume_changes(saved, toy_config(**{"sac.batch_size": 32}), LoopState(stage_index=1))
    with pytest.raises(ConfigError, match=r"differs at algo \(saved \"maisac\", given \"ippo\"\)"):
        resume_changes(saved, toy_config(algo="ippo"), LoopState())


@pytest.fixture(scope="module")
def stopped_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A toy run stopped right after its first stage (``source``) finished."""
    from hptvsim.train.trainer import train

    run = tmp_path_factory.mktemp("stopped") / "run"
    result = train(toy_config(), run, progress=False, tensorboard=False, stop_after=120)
    assert not result.finished and len(result.stage_dirs) == 1
    return run


def _config_file(folder: Path, cfg_overrides: dict[str, Any]) -> Path:
    from hptvsim.train.config import config_to_dict, dump_toml

    path = folder / "corrected.toml"
    path.write_text(dump_toml(config_to_dict(toy_config(**cfg_overrides))))
    return path


def test_resume_takes_a_corrected_config_for_a_stage_not_started(stopped_run: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(stopped_run, run)
    config = _config_file(tmp_path, {"stage.1.env.options.max_steps": 20})
    res = hptvsim(
        ["train", str(config), "--out", str(run), "--resume", "--no-progress", "--no-tensorboard"], tmp_path
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Traceback" not in res.stderr
    assert "changes stage 'target' (not started yet)" in res.stderr
    assert "max_steps = 20" in (run / "config.toml").read_text()
    info = json.loads((run / "run.json").read_text())
    assert len(info["config_updated_at"]) == 1 and len(info["resumed_at"]) == 1
    with (run / "episodes.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    target = [int(r["length"]) for r in rows if r["stage"] == "target"]
    assert target and max(target) <= 20
    assert json.loads((run / "summary.json").read_text())["global_step"] == 180


def test_resume_refuses_a_change_to_a_finished_stage(stopped_run: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(stopped_run, run)
    before = (run / "config.toml").read_text()
    config = _config_file(tmp_path, {"stage.0.env.options.max_steps": 20})
    line = error_line(
        hptvsim(["train", str(config), "--out", str(run), "--resume", "--no-progress"], tmp_path)
    )
    assert line == (
        "Error: --resume: stage 'source' is finished; its config differs at env.options.max_steps "
        "(saved 30, given 20)"
    )
    assert (run / "config.toml").read_text() == before
    assert "config_updated_at" not in json.loads((run / "run.json").read_text())
