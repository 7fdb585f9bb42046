"""Every command and snippet of README.md runs for real, at reduced sizes (issue: README commands).

README.md's fenced blocks are parsed: each ```python block runs as a script in a fresh
interpreter, made small by the textual substitutions of :data:`PYTHON_SUBSTITUTIONS`; each line
of a ```sh block (its ``# comment`` stripped) must be a key of :data:`COMMANDS`, which maps it
to what runs instead: a :class:`Run` (a concrete, reduced invocation of the same command, in
a fresh ``python -m hptvsim.cli`` process as in ``tests/test_cli_user_errors.py``, writing to
pytest's temporary folders), or, for what cannot run inside a test (servers, hours of
training, a fresh set-up), a :class:`Help` with the reason and a check of the same command
(``--help``, ``make -n``). Every step must exit 0, print no ``Traceback`` and show what it did
(a regex on its output, the files it writes). A README line missing from the table, a table
line no longer in the README, a substitution whose text the README (or the config it edits)
no longer holds, or a fenced block of another language fails the tests.

The default run stays within about 90 s on a busy 2-core machine; what would take longer (the
trained policies' full demo episode, the DT chain, Ray, the toy reproduction) is marked ``slow``.
Commands that build on another's output (evaluating a training run, training a DT on collected
datasets) name it in ``after``: :class:`Shared` runs that one once per module in a shared folder.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
from documented import agrees
from test_cli_user_errors import ENV as CLI_ENV
from test_cli_user_errors import HPTVSIM, hptvsim_many
from twin_fixtures import ardusub_log

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
ENV = {**CLI_ENV, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TORCH_ONE_THREAD = "import torch\n\ntorch.set_num_threads(1)\n"
"""Prepended to every Python block."""


# --- the README's fenced blocks ------------------------------------------------------------------


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """Every fenced code block of a Markdown text as ``(language, body)``, in order."""
    return [
        (m.group(1), m.group(2)) for m in re.finditer(r"^```(\S*)[ \t]*\n(.*?)^```[ \t]*$", text, re.M | re.S)
    ]


def command_line(line: str) -> str:
    """A shell line without its ``# comment`` and with single spaces ("" for a comment line)."""
    return " ".join(line.split("#", 1)[0].split())


def readme_blocks(language: str) -> list[str]:
    """The bodies of the README's blocks in one language."""
    return [body for lang, body in fenced_blocks(README.read_text(encoding="utf-8")) if lang == language]


def readme_commands() -> list[str]:
    """Every command line of the README's ``sh`` blocks, in order."""
    lines = (command_line(line) for body in readme_blocks("sh") for line in body.splitlines())
    return [line for line in lines if line]


# --- the Python blocks --------------------------------------------------------------------------

PYTHON_SUBSTITUTIONS: dict[str, str] = {
    "learn(10_000)": "learn(300)",  # SAC: 300 steps, a few episodes
    "max_steps=400,": "max_steps=50,",  # so that 300 steps end episodes (and SAC logs them)
    "make_sb3_vec_env(1024,": "make_sb3_vec_env(8,",
}
"""README text -> what runs in the test; every key must be in a ``python`` block."""

PYTHON_OUTPUT: dict[str, str] = {
    "from hptvsim.cosim.vehicles import load_vehicle_file  # your own vehicle type on both backends": (
        r"fmu (\[[^\]]+\])\s+batched \1"  # the same numbers on both backends
    ),
    "from hptvsim.envs import parallel_env  # PettingZoo ParallelEnv, 3 vs 1": (
        r"ep_rew_mean[\s\S]*return -?\d+, captured: (True|False), collision: (True|False)\s+\(8, 20\)"
    ),
}
"""First line of each ``python`` block -> a regex its output must match."""


# --- the sh blocks ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    """A reduced invocation of a README command, run for real.

    Attributes:
        cmd: The command line (``hptvsim ...`` runs as ``python -m hptvsim.cli ...``), split with
            shlex; ``{tmp}`` is the test's own folder, ``{shared}`` the module's (see :class:`Shared`),
            ``{repo}`` the repository, ``{vmax}`` a reduced copy of ``configs/train/sweeps/vmax.toml``.
        expect: A regex the output (stdout and stderr) must match.
        writes: Files the command must write (same placeholders); PNGs must be PNGs.
        after: The README line whose run this one builds on (it runs first, in ``{shared}``).
        slow: Longer than the default test run can take: marked ``slow``.
    """

    cmd: str
    expect: str
    writes: tuple[str, ...] = ()
    after: str | None = None
    slow: bool = False


@dataclass(frozen=True)
class Help:
    """A README command that does not run in a test: why, and the check that runs instead.

    Attributes:
        reason: One line: why the command itself does not run here.
        cmd: What runs instead (``hptvsim ... --help``, ``make -n TARGET``).
        expect: A regex its output must match.
    """

    reason: str
    cmd: str
    expect: str


EVALUATE_SHIPPED = (
    "hptvsim evaluate --env hptvsim:target/pursuit --pursuers maisac-pursuers --evaders maisac-evader"
)
"""The README's evaluation of the shipped policies, whose numbers its table states (no
``extended_obs``: the policies' layout comes from ``policies/index.toml``)."""

QUICK = (
    "--no-progress --no-tensorboard --set stage.0.budget_steps=60 --set stage.1.budget_steps=60"
    " --set stage.2.budget_steps=60 --set stage.*.env.options.max_steps=30 --set sac.learning_starts=20"
    " --set sac.batch_size=16 --set 'sac.net_arch=[16, 16]' --set sac.buffer_size=1000"
    " --set checkpoint_every=30 --set log_every=30"
)
"""``hptvsim train quick`` in seconds: 60 env steps per stage, episodes of 30 steps, small nets."""

DT_SMALL = (
    "--set model.layers=1 --set model.embed_dim=16 --set model.context=5 --set batch_size=4 --no-progress"
)
"""A Decision Transformer that trains in a second."""

DATASETS = " ".join(f"--dataset hptvsim/target/expert-pursuer_{i}-v0" for i in range(3))
"""The dataset ids ``hptvsim collect`` writes on the target scenario."""

SWEEP_SUBSTITUTIONS: dict[str, str] = {
    'config = "../paper.toml"': 'config = "paper"',  # the shipped config by name: the copy is elsewhere
    "seeds = [0, 1, 2]": "seeds = [0]",
    "= [3.0, 3.25, 3.5]": "= [3.0, 3.5]",
    '"sac.backend" = "batched"\n': (
        '"sac.backend" = "batched"\n"stage.*.budget_episodes" = 1\n"stage.*.env.options.max_steps" = 20\n'
        '"sac.learning_starts" = 10\n"sac.batch_size" = 8\n"sac.net_arch" = [16, 16]\n'
        '"sac.buffer_size" = 1000\ncheckpoint_every = 20\nlog_every = 10\n'
    ),
}
"""``configs/train/sweeps/vmax.toml`` -> its reduced copy: 2 settings x 1 seed of one 20-step episode."""

PAPER_SMALL = (
    "--no-progress --no-tensorboard --set stage.*.budget_episodes=1 --set stage.*.env.options.max_steps=20"
    " --set sac.learning_starts=10 --set sac.batch_size=8 --set 'sac.net_arch=[16, 16]'"
    " --set sac.buffer_size=1000 --set checkpoint_every=20 --set log_every=10"
)
"""``hptvsim train paper``: one 20-step episode per stage."""

COMMANDS: dict[str, tuple[Run | Help, ...]] = {
    "make run": (
        Help(
            "sets up .venv (pip) and serves until stopped", "make -n run", r"(?m)^\.venv/bin/hptvsim serve$"
        ),
        Help("make run starts this service", "hptvsim serve --help", r"Usage: hptvsim serve"),
    ),
    "make test": (
        Help(
            "installs system packages and runs the whole suite (about 11 minutes)",
            "make -n test",
            r"ruff check[\s\S]*mypy[\s\S]*pytest -n",
        ),
    ),
    "hptvsim train fast": (
        Run(
            "hptvsim train fast --out {tmp}/fast --no-progress --set ppo.num_envs=8 --set ppo.n_steps=8"
            " --set stage.0.budget_steps=128 --set eval.episodes=4",
            r"capture \d\.\d\d of 4 fixed episodes[\s\S]*128 game steps per seed",
            ("{tmp}/fast/seed0/models/pursuer_0.zip", "{tmp}/fast/seed0/curve.csv"),
        ),
    ),
    "hptvsim train fast --seeds 0-9": (
        Run(
            "hptvsim train fast --seeds 0-1 --out {tmp}/fast --no-progress --set ppo.num_envs=8"
            " --set ppo.n_steps=8 --set stage.0.budget_steps=64 --set eval.episodes=2",
            r"seed0: capture[\s\S]*seed1: capture",
            ("{tmp}/fast/seed0/eval.json", "{tmp}/fast/seed1/eval.json"),
        ),
    ),
    "hptvsim train quick": (
        Run(
            f"hptvsim train quick --out {{shared}}/run {QUICK}",
            r"env steps: 180",
            ("{shared}/run/summary.json",),
        ),
    ),
    "hptvsim train paper": (
        Help(
            "Table II budget: 100 episodes x 6000 steps per stage, hours each",
            "hptvsim train --help",
            "paper",
        ),
        Run(
            f"hptvsim train paper --out {{tmp}}/run {PAPER_SMALL}",
            r"env steps: \d+",
            ("{tmp}/run/summary.json", "{tmp}/run/stages/target/pursuer_0.zip"),
            slow=True,
        ),
    ),
    "hptvsim train CONFIG --resume": (
        Run(
            f"hptvsim train quick --resume --out {{shared}}/run {QUICK}",
            r"env steps: 180",
            after="hptvsim train quick",
            slow=True,
        ),
    ),
    "hptvsim evaluate RUN_DIR": (
        Run(
            "hptvsim evaluate {shared}/run --episodes 2 --env-option max_steps=30 --json {tmp}/eval.json",
            r"\| run \| \d\.\d\d ± \d\.\d\d \|.* \| 2 \|",
            ("{tmp}/eval.json",),
            after="hptvsim train quick",
        ),
    ),
    EVALUATE_SHIPPED: (
        Run(
            f"{EVALUATE_SHIPPED} --episodes 2 --env-option max_steps=30 --json {{tmp}}/eval.json",
            r"\| pursuer=maisac-pursuers, evader=maisac-evader \| \d\.\d\d ± .* \| 2 \|",
            ("{tmp}/eval.json",),
            slow=True,
        ),
    ),
    "hptvsim figures RUN_DIR_OR_SWEEP": (
        Run(  # the trajectory plots run an episode per stage
            "hptvsim figures {shared}/run --out {tmp}/figures",
            r"reward_pursuer\.png",
            ("{tmp}/figures/reward_pursuer.png", "{tmp}/figures/reward_evader.png"),
            after="hptvsim train quick",
            slow=True,
        ),
    ),
    "hptvsim sweep configs/train/sweeps/vmax.toml [--address ray://...]": (
        Run(  # on a local Ray (the cluster of --address is not here): half a minute to start
            "hptvsim sweep {vmax} --num-cpus 2 --out {tmp}/sweep",
            r"finished .*v_max=3\.0-seed0[\s\S]*finished .*v_max=3\.5-seed0",
            ("{tmp}/sweep/sweep.json", "{tmp}/sweep/v_max=3.5-seed0/summary.json"),
            slow=True,
        ),
    ),
    "hptvsim reproduce": (
        Help("section5.toml: 27 runs, many hours on 2 cores", "hptvsim reproduce --help", r"--report-only"),
        Help("make reproduce runs it", "make -n reproduce", r"(?m)^\.venv/bin/hptvsim reproduce$"),
        Run(  # the toy plan, one experiment, one seed
            "hptvsim reproduce --plan toy --experiment vmax --seed 0 --workers 1 --out {tmp}/rep"
            " --report {tmp}/report.md",
            r"report: .*report\.md",
            ("{tmp}/report.md", "{tmp}/rep/runs/vmax35-seed0/summary.json"),
            slow=True,
        ),
    ),
    "hptvsim reproduce --status": (
        Run(
            "hptvsim reproduce --plan toy --status --out {tmp}/rep --report {tmp}/report.md",
            r"0 of 18 runs finished; 0 of [\d,]+ env steps \(0\.0 %\).*\n"
            r"no sweep has recorded a rate here yet",
            (),
        ),
    ),
    "hptvsim reproduce --plan section5-scale": (
        Run(  # the scaled plan's status against its committed archive (runs finished before)
            "hptvsim reproduce --plan section5-scale --status --out {tmp}/rep"
            " --report {repo}/docs/reproduction.md",
            r"(?m)^runs/base-seed0 .* finished \(archived\)$[\s\S]*^([3-8]\d|90) of 90 runs finished",
            (),
        ),
    ),
    "hptvsim reproduce --plan section5-scale --address HEAD:6379 --out /shared/repro/section5-scale": (
        Help(
            "needs a Ray cluster and shared storage (tests/train/test_repro_cluster.py: two raylets)",
            "hptvsim reproduce --help",
            r"--address TEXT",
        ),
    ),
    "RAY_ADDRESS=HEAD:6379 hptvsim reproduce --status --out /shared/repro/section5-scale": (
        Help(
            "needs a Ray cluster (tests/train/test_repro_cluster.py asks one for its status)",
            "hptvsim reproduce --help",
            r"\$RAY_ADDRESS",
        ),
    ),
    "hptvsim reproduce --report-only": (
        Run(
            "hptvsim reproduce --report-only --out {tmp}/rep --report {tmp}/report.md",
            r"report\.md",
            ("{tmp}/report.md",),
        ),
    ),
    "hptvsim collect --episodes 200": (
        Run(
            "hptvsim collect --episodes 2 --max-steps 30 --num-envs 2 --ref-episodes 2"
            " --out {shared}/datasets --no-progress",
            r"hptvsim/target/expert-pursuer_2-v0: 2 episodes, \d+ steps",
            ("{shared}/datasets/hptvsim/target/expert-pursuer_0-v0/data/main_data.hdf5",),
            slow=True,
        ),
    ),
    "hptvsim dt train configs/dt/target.toml --dataset ID ...": (
        Run(
            f"hptvsim dt train {{repo}}/configs/dt/target.toml {DATASETS} --dataset-dir {{shared}}/datasets"
            f" --updates 4 {DT_SMALL} --no-tensorboard --out {{shared}}/dt",
            r"policy: dt:.*dt\.pt",
            ("{shared}/dt/dt.pt",),
            after="hptvsim collect --episodes 200",
            slow=True,
        ),
    ),
    "hptvsim dt evaluate RUN/dt.pt --target q50": (
        Run(
            "hptvsim dt evaluate {shared}/dt/dt.pt --target q50 --episodes 2 --max-steps 30 --no-progress"
            " --out {tmp}/eval",
            r"\| DT @ q50 \| \d\.\d\d",
            ("{tmp}/eval/eval.json",),
            after="hptvsim dt train configs/dt/target.toml --dataset ID ...",
            slow=True,
        ),
    ),
    "hptvsim dt pipeline": (
        Run(
            "hptvsim dt pipeline --out {tmp}/dtp --episodes 2 --eval-episodes 2 --max-steps 30"
            f" --set updates=4 {DT_SMALL}",
            r"\| DT @ q50 \|[\s\S]*done: .*summary\.json",
            ("{tmp}/dtp/summary.json", "{tmp}/dtp/run/dt.pt", "{tmp}/dtp/figures/dt_loss.png"),
            slow=True,
        ),
    ),
    "hptvsim demo": (
        Run(
            "hptvsim demo --out {tmp} --duration 10 --no-episode",
            r"trajectory plot: ",
            ("{tmp}/trajectories.png",),
        ),
        Run(  # with the pursuit episode of the shipped policies (up to 1200 steps)
            "hptvsim demo --out {tmp} --duration 10",
            r"outcome: [\s\S]*episode plot: ",
            ("{tmp}/trajectories.png", "{tmp}/episode.png"),
            slow=True,
        ),
    ),
    "hptvsim demo --scenario ridge_3d --out hptvsim-out": (
        Run(  # the 3-D episode with its depth plot: the shipped 3-D MAISAC policies (issue 37)
            # capture at step 294 on AMD EPYC, 295 on an AVX-512 Intel Xeon (MKL's GEMM kernels
            # differ; README "Numbers and CPUs"): the outcome and a time near the README's, not a step
            "hptvsim demo --scenario ridge_3d --out {tmp} --duration 5",
            r"policies: pursuer_0, pursuer_1, pursuer_2: maisac-3d-pursuers; evader_0: maisac-3d-evader"
            r"\noutcome: captured at 7[2-6]\.\d\d s[\s\S]*episode plot: ",  # README: "at about 74 s"
            ("{tmp}/trajectories.png", "{tmp}/episode.png"),
        ),
    ),
    "hptvsim episode --scenario target": (
        Run(
            "hptvsim episode --scenario target --max-steps 50 --json {tmp}/episode.json",
            r"target: \w+ after \d+ steps",
            ("{tmp}/episode.json",),
        ),
    ),
    "hptvsim twin replay LOG.tlog --record OUT.rrd": (
        Run(
            "hptvsim twin replay {repo}/../shared/data/ardusub/small.tlog --record {tmp}/small.rrd",
            r"small\.tlog: 263\.\d s, \d+ frames[\s\S]*recording: ",
            ("{tmp}/small.rrd",),
        ),
    ),
    "hptvsim twin replay LOG.tlog --csv OUT.csv": (
        Run(
            "hptvsim twin replay {repo}/../shared/data/ardusub/small.BIN --csv {tmp}/small.csv",
            r"calibration CSV: ",
            ("{tmp}/small.csv",),
        ),
    ),
    "hptvsim twin replay LOG.tlog --store DATA_DIR": (
        Run(
            "hptvsim twin replay {repo}/../shared/data/ardusub/small.tlog --store {tmp}/svc",
            r"stored episode [0-9a-f]{16} \(twin: small\.tlog\)",
            ("{tmp}/svc/hptvsim.db",),
        ),
    ),
    "hptvsim twin listen udp:127.0.0.1:14550 --viser": (
        Help(
            "follows a live stream until it stops (tests/twin/test_twin_listen.py plays one over UDP)",
            "hptvsim twin listen --help",
            r"--idle-timeout",
        ),
    ),
    "hptvsim view": (Help("a live view served until stopped", "hptvsim view --help", r"--port"),),
    "hptvsim fmu build | check": (
        Run(
            "hptvsim fmu build --out {tmp}",
            r"built .*WorkClassUUV\.fmu",
            ("{tmp}/WorkClassUUV.fmu", "{tmp}/SphericalUUV.fmu"),
        ),
        Run("hptvsim fmu check", r"WorkClassUUV\.fmu: up to date[\s\S]*SphericalUUV\.fmu: up to date"),
    ),
    "hptvsim fmu build --vehicle-file FILE --out DIR": (
        Run(
            "hptvsim fmu build --vehicle-file {repo}/scenarios/vehicles/bluerov2_heavy.toml --out {tmp}",
            r"built .*BlueROV2Heavy\.fmu",
            ("{tmp}/BlueROV2Heavy.fmu",),
        ),
    ),
    (
        "hptvsim vehicle fit my_dive.csv --vehicle scenarios/vehicles/bluerov2_heavy.toml"
        " --free X_udot,N_rdot,X_u,X_uu,Y_vv,N_rr --out my_rov.toml"
    ): (
        Help(
            "needs the reader's own dive log; the fit runs on simulated logs in tests/twin/test_fit.py",
            "hptvsim vehicle fit --help",
            r"Usage: hptvsim vehicle fit \[OPTIONS\] LOG[\s\S]*--free",
        ),
    ),
    "hptvsim twin predict my_dive.csv --vehicle my_rov.toml --resync-s 10 --out my_rov_twin": (
        Help(
            "needs the reader's own dive log and fitted vehicle; tests/twin/test_beside.py runs it",
            "hptvsim twin predict --help",
            r"Usage: hptvsim twin predict \[OPTIONS\] LOG[\s\S]*--resync-s",
        ),
    ),
    "hptvsim cosim run GRAPH.toml": (
        Run(  # the README's example graph, on the next line of the block
            "hptvsim cosim run {repo}/configs/cosim/follow-the-turn.toml --stop-time 5 --set turn=0.3"
            " --out {tmp}/follow-the-turn.csv",
            r"20 steps of 0\.25 s",
            ("{tmp}/follow-the-turn.csv",),
        ),
    ),
    "hptvsim cosim export-ssp GRAPH.toml --out SYSTEM.ssp": (
        Run(
            "hptvsim cosim export-ssp {repo}/configs/cosim/follow-the-turn.toml --out {shared}/turn.ssp",
            r"turn\.ssp",
            ("{shared}/turn.ssp",),
        ),
    ),
    "hptvsim cosim run SYSTEM.ssp": (
        Run(
            "hptvsim cosim run {shared}/turn.ssp --stop-time 5 --set turn=0.3 --out {tmp}/turn.csv",
            r"20 steps of 0\.25 s",
            ("{tmp}/turn.csv",),
            after="hptvsim cosim export-ssp GRAPH.toml --out SYSTEM.ssp",
        ),
    ),
    "hptvsim scenario list | validate FILE | show FILE --out PNG | schema": (
        Run("hptvsim scenario list", r"(?m)^target +Irregular"),
        Run("hptvsim scenario validate {repo}/scenarios/target.toml", r"ok: .*target\.toml"),
        Run(
            "hptvsim scenario show {repo}/scenarios/target.toml --out {tmp}/target.png",
            r"target\.png",
            ("{tmp}/target.png",),
        ),
        Run("hptvsim scenario schema", r"max_steps"),
    ),
    "hptvsim terrain import SRC --out OUT.npz": (
        Run(
            "hptvsim terrain import {repo}/scenarios/data/salish_sea.tif --out {tmp}/salish.npz",
            r"height map: .*salish\.npz",
            ("{tmp}/salish.npz", "{tmp}/salish.png"),
        ),
    ),
    "hptvsim sonar snr-plot --out PNG": (
        Run(
            "hptvsim sonar snr-plot --out {tmp}/snr.png --trials 10 --snr-step 10",
            r"RMS error +\d",
            ("{tmp}/snr.png",),
        ),
    ),
}
"""Every command line of the README's ``sh`` blocks -> what runs in its place."""


# --- running -------------------------------------------------------------------------------------


def small_sweep(folder: Path) -> Path:
    """``configs/train/sweeps/vmax.toml`` reduced by :data:`SWEEP_SUBSTITUTIONS`, written into FOLDER."""
    text = (REPO / "configs/train/sweeps/vmax.toml").read_text(encoding="utf-8")
    for old, new in SWEEP_SUBSTITUTIONS.items():
        assert old in text, (
            f"configs/train/sweeps/vmax.toml no longer holds {old!r}: update SWEEP_SUBSTITUTIONS"
        )
        text = text.replace(old, new)
    path = folder / "vmax.toml"
    path.write_text(text, encoding="utf-8")
    return path


def argv(cmd: str, tmp: Path, shared: Path) -> list[str]:
    """A table command as arguments: placeholders filled, ``hptvsim`` as ``python -m hptvsim.cli``."""
    places = {"tmp": str(tmp), "shared": str(shared), "repo": str(REPO)}
    if "{vmax}" in cmd:
        places["vmax"] = str(small_sweep(tmp))
    args = [token.format(**places) for token in shlex.split(cmd)]
    return [*HPTVSIM, *args[1:]] if args[0] == "hptvsim" else args


def run(args: list[str], cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    """Run a command in a fresh process (outputs captured)."""
    return subprocess.run(args, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)


def check(res: subprocess.CompletedProcess[str], expect: str, writes: Sequence[Path] = ()) -> None:
    """Exit 0, no traceback, EXPECT in the output and every file of WRITES written."""
    out = res.stdout + res.stderr
    shown = f"{shlex.join(res.args)}\nexit {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"
    assert res.returncode == 0, shown
    assert "Traceback" not in out, shown
    assert re.search(expect, out), f"no match for {expect!r}\n{shown}"
    for path in writes:
        assert path.is_file() and path.stat().st_size > 0, f"{path} not written\n{shown}"
        if path.suffix == ".png":
            assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", path


class Shared:
    """The README commands others build on (``after``), each run once per module in one folder."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.results: dict[str, subprocess.CompletedProcess[str]] = {}

    def result(self, line: str) -> subprocess.CompletedProcess[str]:
        """What LINE's first :class:`Run` did (run now if it has not run yet)."""
        if line not in self.results:
            step = COMMANDS[line][0]
            assert isinstance(step, Run)
            if step.after is not None:
                self.ok(step.after)
            self.results[line] = run(argv(step.cmd, self.folder, self.folder), self.folder)
        return self.results[line]

    def ok(self, line: str) -> None:
        """Fail unless LINE's run (which another builds on) succeeded."""
        step = COMMANDS[line][0]
        assert isinstance(step, Run)
        check(self.result(line), step.expect, self.files(step))

    def files(self, step: Run) -> list[Path]:
        """The files a shared run must have written."""
        return [Path(w.format(shared=self.folder, tmp=self.folder)) for w in step.writes]


@pytest.fixture(scope="module")
def shared(tmp_path_factory: pytest.TempPathFactory) -> Shared:
    """The module's folder for the runs others build on."""
    return Shared(tmp_path_factory.mktemp("readme-shared"))


@pytest.fixture(scope="module")
def helps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, subprocess.CompletedProcess[str]]:
    """Every ``hptvsim ... --help`` of the table, run in one other interpreter."""
    cases = {
        step.cmd: shlex.split(step.cmd)[1:]
        for steps in COMMANDS.values()
        for step in steps
        if isinstance(step, Help) and step.cmd.startswith("hptvsim ")
    }
    return hptvsim_many(cases, tmp_path_factory.mktemp("readme-help"))


PROVIDERS = {
    step.after for steps in COMMANDS.values() for step in steps if isinstance(step, Run) and step.after
}
"""README lines whose run others build on."""


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=-]+", "-", text).strip("-")[:60]


CASES = [
    pytest.param(
        line,
        i,
        id=f"{_slug(line)}-{i}",
        marks=[pytest.mark.slow] if isinstance(step, Run) and step.slow else [],
    )
    for line, steps in COMMANDS.items()
    for i, step in enumerate(steps)
]


# --- the tests -----------------------------------------------------------------------------------


def test_the_readme_has_only_sh_and_python_blocks() -> None:
    languages = [lang for lang, _ in fenced_blocks(README.read_text(encoding="utf-8"))]
    assert languages and set(languages) <= {"sh", "python"}, languages


def test_every_readme_command_is_in_the_table() -> None:
    missing = [line for line in readme_commands() if line not in COMMANDS]
    assert not missing, f"README command lines without an entry in COMMANDS: {missing}"


def test_every_table_command_is_in_the_readme() -> None:
    stale = sorted(set(COMMANDS) - set(readme_commands()))
    assert not stale, f"COMMANDS entries the README no longer has: {stale}"


def test_every_command_that_does_not_run_says_why() -> None:
    for line, steps in COMMANDS.items():
        assert steps, line
        for step in steps:
            if isinstance(step, Help):
                assert step.reason.strip() and "\n" not in step.reason, line


def test_every_python_substitution_is_in_the_readme() -> None:
    text = "\n".join(readme_blocks("python"))
    stale = [old for old in PYTHON_SUBSTITUTIONS if old not in text]
    assert not stale, f"PYTHON_SUBSTITUTIONS the README's python blocks no longer hold: {stale}"


def test_every_python_block_has_an_expected_output() -> None:
    firsts = [body.splitlines()[0] for body in readme_blocks("python")]
    assert sorted(firsts) == sorted(PYTHON_OUTPUT), "update PYTHON_OUTPUT (first line of each block)"


@pytest.mark.parametrize("index", range(len(readme_blocks("python"))))
def test_python_block_runs(index: int, tmp_path: Path) -> None:
    body = readme_blocks("python")[index]
    for old, new in PYTHON_SUBSTITUTIONS.items():
        body = body.replace(old, new)
    script = tmp_path / f"readme_block_{index}.py"
    script.write_text(TORCH_ONE_THREAD + body, encoding="utf-8")
    res = run([sys.executable, str(script)], tmp_path, timeout=600)
    check(res, PYTHON_OUTPUT.get(body.splitlines()[0], r"\S"))


@pytest.mark.parametrize(("line", "index"), CASES)
def test_readme_command(
    line: str,
    index: int,
    tmp_path: Path,
    shared: Shared,
    helps: dict[str, subprocess.CompletedProcess[str]],
) -> None:
    step = COMMANDS[line][index]
    if isinstance(step, Help):
        res = helps[step.cmd] if step.cmd in helps else run(shlex.split(step.cmd), REPO, timeout=60)
        check(res, step.expect)
        return
    if index == 0 and line in PROVIDERS:
        shared.ok(line)
        return
    if step.after is not None:
        shared.ok(step.after)
    for word in shlex.split(step.cmd):  # the shared ArduSub logs: fail under CI, else skip if missing
        if word.startswith("{repo}/../shared/data/ardusub/"):
            ardusub_log(Path(word).name)
    writes = [Path(w.format(tmp=tmp_path, shared=shared.folder)) for w in step.writes]
    check(run(argv(step.cmd, tmp_path, shared.folder), tmp_path), step.expect, writes)


# --- the README's numbers are what its commands print ----------------------------------------------

SHIPPED_ROW = re.compile(
    r"^\| shipped MAISAC pursuers \| shipped MAISAC evader \| (\d\.\d\d) \+- (\d\.\d\d) \| (\d\.\d\d) \|$",
    re.M,
)
"""The table row of the shipped pursuers against the shipped evader (target scenario)."""


def _index_evaluation() -> list[str]:
    """The command behind the shipped pursuers' numbers, as recorded in ``policies/index.toml``."""
    import tomllib

    index = tomllib.loads((REPO / "policies" / "index.toml").read_text())["policies"]
    recorded = re.match(
        r"(hptvsim evaluate .*?) --episodes 100: ", index["maisac-pursuers"]["provenance"]["evaluation"]
    )
    assert recorded is not None, (
        "policies/index.toml: maisac-pursuers records no 100-episode evaluate command"
    )
    return shlex.split(recorded.group(1))


def _episodes(args: list[str], tmp: Path, name: str) -> list[dict[str, object]]:
    import json

    out = tmp / f"{name}.json"
    res = run([*args, "--json", str(out)], tmp)
    check(res, r"\| pursuer=maisac-pursuers, evader=maisac-evader \|")
    return list(json.loads(out.read_text())["runs"][0]["episodes"])


def test_the_readme_evaluation_plays_the_episodes_behind_its_table(tmp_path: Path) -> None:
    """A fast subset: the README's command plays the recorded measurement's first episodes exactly.

    The table's numbers were measured with the command recorded in ``policies/index.toml``
    (explicit ``extended_obs`` and ``max_steps``); the README's own command, which names neither,
    must play the same episodes (the layout from the policies' metadata, the step limit from the
    scenario), so that it prints the table's numbers (the slow test below runs all 100).
    """
    assert EVALUATE_SHIPPED in readme_commands()
    assert SHIPPED_ROW.search(README.read_text(encoding="utf-8")), "the README's table lost its shipped row"
    keys = ("captured", "collision", "length", "returns")
    ours = _episodes([*argv(EVALUATE_SHIPPED, tmp_path, tmp_path), "--episodes", "3"], tmp_path, "readme")
    theirs = _episodes([*HPTVSIM, *_index_evaluation()[1:], "--episodes", "3"], tmp_path, "recorded")
    assert [{k: e[k] for k in keys} for e in ours] == [{k: e[k] for k in keys} for e in theirs]


@pytest.mark.slow
def test_the_readme_evaluation_prints_the_numbers_of_its_table(tmp_path: Path) -> None:
    """The README's command, all 100 episodes (minutes): the capture and collision rates its table states."""
    match = SHIPPED_ROW.search(README.read_text(encoding="utf-8"))
    assert match is not None
    capture, _, collision = (float(v) for v in match.groups())
    res = run(argv(EVALUATE_SHIPPED, tmp_path, tmp_path), tmp_path, timeout=3600)
    row = r"\| pursuer=maisac-pursuers, evader=maisac-evader \| (\d\.\d\d) ± \d\.\d\d \|[^|]*\| (\d\.\d\d) ± "
    check(res, row)
    printed = re.search(row, res.stdout + res.stderr)
    assert printed is not None
    # the same 100 episodes; another CPU may end one or two of them otherwise (tests/documented.py)
    assert agrees(float(printed.group(1)), capture, 100), (printed.group(0), capture)
    assert agrees(float(printed.group(2)), collision, 100), (printed.group(0), collision)
