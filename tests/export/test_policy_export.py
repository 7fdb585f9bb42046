"""``hptvsim policy export`` and the ONNX runtime (issue 51, point 1).

Every shipped SB3 policy exports to ``<agent>.onnx`` whose onnxruntime actions agree with the
project's own SB3 policy (:class:`hptvsim.train.policy.SB3Policy`, SB3's deterministic
``predict`` clipped to the action space: what the game's ``step`` is fed) to 1e-4 on
observations of real episodes and of the observation space. The default suite exports a PPO
planar pursuer, the SAC 3-D evader and one pursuer's Decision Transformer (context as inputs,
checked against :class:`hptvsim.offline.policy.DTPolicy`); the rest are slow.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from hptvsim.cli import main
from hptvsim.envs.games import make_game
from hptvsim.export import build
from hptvsim.export.build import TOLERANCE, ExportError, export_policy, sample_observations
from hptvsim.export.runtime import ExportedPolicy, ExportedPolicyError, load_policies, read_metadata
from hptvsim.train.policy import SB3Policy, load_sb3_model
from hptvsim.zoo import list_policies

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

SHIPPED = {p.name: p for p in list_policies() if p.kind == "sb3"}
FAST = {"ippo-pursuers": ("pursuer_1",), "maisac-3d-evader": (), "dt-pursuers": ("pursuer_1",)}
"""Default-suite exports: a PPO planar pursuer, the SAC 3-D evader (``()``: every agent), a DT."""


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The default suite's exports, through the command line."""
    out = {}
    for name, agents in FAST.items():
        folder = tmp_path_factory.mktemp(name)
        code, text = _cli("policy", "export", name, "--out", str(folder), *[f"--agent={a}" for a in agents])
        assert code == 0, text
        assert f"max |onnxruntime - {'DTPolicy' if name.startswith('dt') else 'SB3'}|" in text
        out[name] = folder
    return out


def _scenario_of(name: str) -> tuple[str, dict[str, Any]]:
    prov = SHIPPED[name].provenance
    options = {k: v for k, v in prov.get("options", {}).items() if k == "extended_obs"}
    return str(prov["stage"]), options


def _check_against_sb3(name: str, folder: Path) -> int:
    """Compare every file of ``folder`` with SB3; returns how many agents were checked."""
    info = SHIPPED[name]
    scenario, options = _scenario_of(name)
    game = make_game(scenario, **options)
    policies = load_policies(folder)
    assert policies
    for agent, exported_policy in policies.items():
        file = info.files.get(agent, info.path)
        assert file is not None
        model = load_sb3_model(file)
        obs = sample_observations(game, agent, model, count=320, seed=3)
        assert obs.shape == (320, exported_policy.n_obs)
        real = obs[:160]
        assert np.ptp(real, axis=0).max() > 0.1  # states of a real episode, not one repeated row
        want = SB3Policy(model).act(obs)  # what the project feeds the game's step
        got = exported_policy.act(obs)
        assert got.dtype == np.float32
        assert got.shape == want.shape == (320, exported_policy.n_act)
        assert np.max(np.abs(got - want)) <= TOLERANCE, (name, agent)
        np.testing.assert_allclose(exported_policy.act(obs[7]), want[7], atol=TOLERANCE)  # one row
        low, high = exported_policy.action_low, exported_policy.action_high
        assert np.all(got >= low) and np.all(got <= high)
        assert np.ptp(got, axis=0).min() > 0.0  # the network acts, not a constant
    return len(policies)


@pytest.mark.parametrize("name", sorted(set(FAST) & set(SHIPPED)))
def test_export_agrees_with_sb3_predict(exported: dict[str, Path], name: str) -> None:
    assert _check_against_sb3(name, exported[name]) == max(len(FAST[name]), 1)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_every_shipped_sb3_policy_exports(tmp_path: Path, name: str) -> None:
    done = export_policy(name, tmp_path)
    info = SHIPPED[name]
    assert [e.agent for e in done] == (list(info.files) if info.files else [e.agent for e in done])
    assert len(done) == (len(info.files) if info.files else 1)
    assert _check_against_sb3(name, tmp_path) == len(done)


def test_metadata_read_back_with_onnx(exported: dict[str, Path]) -> None:
    path = exported["maisac-3d-evader"] / "evader_0.onnx"
    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    meta = {p.key: p.value for p in proto.metadata_props}
    info = SHIPPED["maisac-3d-evader"]
    assert meta["game"] == "3d"
    assert meta["agent"] == "evader_0" and meta["role"] == "evader"
    assert meta["algorithm"] == "SAC"
    assert meta["hptvsim_version"] == "0.1.0"
    assert info.path is not None
    assert meta["source_sha256"] == hashlib.sha256(info.path.read_bytes()).hexdigest()
    assert meta["source_sha256"] == info.provenance["sha256"]
    provenance = json.loads(meta["provenance"])
    assert provenance["command"] == info.provenance["command"] and provenance["seed"] == 0
    observation = json.loads(meta["observation"])
    assert [i.name for i in proto.graph.input] == ["obs"] and [o.name for o in proto.graph.output] == [
        "action"
    ]
    dims = proto.graph.input[0].type.tensor_type.shape.dim
    assert dims[0].dim_param == "batch" and dims[1].dim_value == len(observation)
    named = {f["name"]: f for f in observation}
    assert named["depth"]["unit"] == "m" and named["psi"]["scale"] == pytest.approx(np.pi)
    assert named["u"]["unit"] == "m/s" and named["z_dot"]["unit"] == "m/s"
    action = json.loads(meta["action"])
    assert [a["name"] for a in action] == ["a_v", "a_omega", "a_w_z"]
    assert all(a["low"] == -1.0 and a["high"] == 1.0 and a["unit"] == "1" for a in action)
    commands = json.loads(meta["commands"])
    assert [(c["name"], c["unit"]) for c in commands] == [("v", "m/s"), ("omega", "rad/s"), ("w_z", "m/s")]
    assert json.loads(meta["action_convention"])["normalised"] is True
    # the runtime reads the same
    assert read_metadata(path)["observation"] == observation


def test_planar_metadata_names_the_extended_observation(exported: dict[str, Path]) -> None:
    meta = read_metadata(exported["ippo-pursuers"] / "pursuer_1.onnx")
    names = [f["name"] for f in meta["observation"]]
    assert names[-10:] == [
        "distance",
        "min_range",
        "yaw",
        "azimuth",
        "sin_bearing",
        "cos_bearing",
        "u",
        "r",
        "north",
        "east",
    ]
    assert meta["game"] == "planar" and meta["algorithm"] == "PPO"
    assert [(a["name"], a["unit"]) for a in meta["action"]] == [("v", "m/s"), ("omega", "rad/s")]
    assert meta["provenance"]["sha256"] == SHIPPED["ippo-pursuers"].provenance["sha256"]["pursuer_1"]


def test_runtime_needs_neither_torch_nor_sb3(exported: dict[str, Path]) -> None:
    folder = exported["ippo-pursuers"]
    dt_file = exported["dt-pursuers"] / "pursuer_1.onnx"
    code = (
        "import sys, numpy as np\n"
        "from hptvsim.export.runtime import load_policies\n"
        f"p = load_policies({str(folder)!r})['pursuer_1']\n"
        "a = p.act(np.zeros((4, p.n_obs), np.float32))\n"
        "assert a.shape == (4, 2), a.shape\n"
        "heavy = ('torch', 'stable_baselines3', 'gymnasium')\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in heavy)\n"
        "ours = sorted(m for m in sys.modules if m.startswith('hptvsim'))\n"
        "print(bad, ours)\n"
        "assert not bad, bad[:3]\n"
        "assert ours == ['hptvsim', 'hptvsim.export', 'hptvsim.export.runtime'], ours\n"
        "from hptvsim.export.runtime import ExportedDT\n"
        f"dt = ExportedDT({str(dt_file)!r})\n"
        "dt.reset(2)\n"
        "for _ in range(3):\n"
        "    assert dt.act(np.zeros((2, dt.n_obs), np.float32), reward=np.ones(2)).shape == (2, 2)\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in heavy]\n"
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr


def test_runtime_refuses_bad_inputs(exported: dict[str, Path], tmp_path: Path) -> None:
    p = ExportedPolicy(exported["ippo-pursuers"] / "pursuer_1.onnx")
    with pytest.raises(ExportedPolicyError, match=r"expected \(26,\) or \(B, 26\)"):
        p.act(np.zeros(25, np.float32))
    with pytest.raises(ExportedPolicyError, match="no exported policies"):
        load_policies(tmp_path)
    (tmp_path / "x.onnx").write_bytes(b"not onnx")
    with pytest.raises(ExportedPolicyError, match="not a readable ONNX model"):
        load_policies(tmp_path)


@pytest.mark.parametrize(
    ("spec", "expect"),
    [
        ("nonsense", "unknown policy spec 'nonsense'; valid: a trained zoo policy ("),
        ("scripted:pure_pursuit", "is scripted, not a trained network; valid:"),
        ("zip:/no/such.zip", "policy file not found: /no/such.zip"),
        ("run:/no/such-run", "/no/such-run "),
        ("dt:/no/such.pt", "policy file not found: /no/such.pt"),
    ],
)
def test_bad_spec_refused_in_one_line(tmp_path: Path, spec: str, expect: str) -> None:
    code, text = _cli("policy", "export", spec, "--out", str(tmp_path / "out"))
    assert code == 1
    lines = text.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), text
    if spec.startswith(("run:", "zip:", "dt:")):
        assert f"(spec {spec!r})" in lines[0]
    assert expect in lines[0]
    if "valid:" in expect:
        assert "run:DIR[@STAGE], zip:PATH" in lines[0] and "maisac-pursuers" in lines[0]
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


@pytest.mark.parametrize(
    ("args", "expect"),
    [
        (["maisac-evader", "--scenario", "nosuch"], "--scenario 'nosuch': nosuch: no shipped scenario"),
        (
            ["maisac-evader", "--scenario", "ridge_3d"],
            "--scenario 'ridge_3d' is a scenario of the 3d game; maisac-evader plays the planar game",
        ),
        (
            ["maisac-3d-pursuers", "--scenario", "target"],
            "--scenario 'target' is a scenario of the planar game; maisac-3d-pursuers plays the 3d game",
        ),
        (
            ["ippo-pursuers", "--agent", "evader_0"],
            "agent 'evader_0' is not one it drives in target; valid: pursuer_0, pursuer_1, pursuer_2",
        ),
    ],
)
def test_bad_scenario_or_agent_refused_in_one_line(tmp_path: Path, args: list[str], expect: str) -> None:
    code, text = _cli("policy", "export", *args, "--out", str(tmp_path / "out"))
    assert code == 1
    lines = text.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and expect in lines[0], text
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_bench_policy_measures_both_ways() -> None:
    code, text = _cli("bench", "policy", "--quick", "--json")
    assert code == 0, text
    decoder, tables, at = json.JSONDecoder(), [], 0
    while text[at:].strip():
        at += len(text[at:]) - len(text[at:].lstrip())
        table, at = decoder.raw_decode(text, at)
        tables.append(table)
    assert len(tables) == 2
    assert "ippo-pursuers pursuer_0 (PPO" in tables[0]["title"]
    assert "maisac-3d-pursuers pursuer_0 (SAC" in tables[1]["title"]
    for table in tables:
        rows = {r["name"]: r for r in table["rows"]}
        assert table["floor"] == "SB3 predict (torch, 1 thread), batch 1"
        assert rows[table["floor"]]["ratio_to_floor"] == 1.0
        assert rows["ExportedPolicy.act (onnxruntime), batch 1"]["us_per_unit"] > 0.0


def test_run_and_zip_specs(tmp_path: Path) -> None:
    info = SHIPPED["maisac-pursuers"]
    stage = tmp_path / "run" / "stages" / "target"
    stage.mkdir(parents=True)
    (stage / "pursuer_2.zip").write_bytes(info.files["pursuer_2"].read_bytes())
    (stage / "stage.json").write_text("{}")
    (tmp_path / "run" / "summary.json").write_text(json.dumps({"stages": [{"stage": "target"}]}))
    config = Path(__file__).parents[2] / "configs" / "train" / "shipped-pursuers.toml"
    (tmp_path / "run" / "config.toml").write_text(config.read_text())  # the run that made them
    done = export_policy(f"run:{tmp_path / 'run'}", tmp_path / "a")
    assert [(e.agent, e.n_obs, e.n_act) for e in done] == [("pursuer_2", 26, 2)]
    assert done[0].max_abs_diff <= TOLERANCE
    meta = read_metadata(done[0].path)
    assert meta["scenario"] == "target" and meta["provenance"]["stage"] == "target"
    assert meta["options"]["extended_obs"] is True  # read from the run's config
    # a lone file whose name is no agent's: the agent must be named
    with pytest.raises(
        ExportError, match=r"agent 'maisac-evader' is not one it drives in target; valid: .*evader_0"
    ):
        export_policy("zip:policies/maisac-evader.zip", tmp_path / "b")


def test_an_export_that_disagrees_is_not_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(build, "TOLERANCE", -1.0)  # any difference, even 0, is too much
    with pytest.raises(ExportError, match=r"export differs from SB3 by .* not written"):
        export_policy("ippo-pursuers", tmp_path, agents=["pursuer_0"])
    assert list(tmp_path.iterdir()) == []


# --- the Decision Transformer: its context as inputs ----------------------------------------------


def test_dt_exports_with_its_context_as_inputs(exported: dict[str, Path]) -> None:
    path = exported["dt-pursuers"] / "pursuer_1.onnx"
    proto = onnx.load(str(path))
    assert [i.name for i in proto.graph.input] == ["returns_to_go", "states", "actions", "timesteps", "at"]
    meta = read_metadata(path)
    info = next(p for p in list_policies() if p.name == "dt-pursuers")
    assert meta["kind"] == "dt" and meta["game"] == "planar" and meta["agent"] == "pursuer_1"
    assert meta["context"] == "20" and meta["returns"]["q50"] < meta["returns"]["q90"]
    assert meta["source_sha256"] == info.provenance["sha256"]
    assert [f["name"] for f in meta["observation"]][-4:] == ["distance", "min_range", "yaw", "azimuth"]
    assert set(meta["reward_weights"]) >= {"delta_C", "delta_E1", "delta_E2"}
    with pytest.raises(ExportedPolicyError, match="a Decision Transformer: load it with ExportedDT"):
        ExportedPolicy(path)


@pytest.mark.parametrize("hide_actions", [True, False])
def test_exported_dt_keeps_the_window_as_dt_policy_does(
    exported: dict[str, Path], tmp_path: Path, hide_actions: bool
) -> None:
    """A 60-step rollout (the window of 20 fills, then slides) with the same rewards given to both.

    The shipped DT hides its action tokens (trained with ``action_dropout = 1``); the same model
    reading them, exported the same way, checks the actions' path through the graph.
    """
    from hptvsim.export.dt import export_dt_graph
    from hptvsim.export.runtime import ExportedDT
    from hptvsim.offline.policy import DTPolicy, load_dt

    zoo = next(p for p in list_policies() if p.name == "dt-pursuers")
    assert zoo.path is not None
    game = make_game("target", num_envs=3)
    loaded = load_dt(zoo.path, game, "pursuer_1")
    assert loaded.hide_actions
    reference = DTPolicy(  # as the zoo loads it, but taking the rewards it is given
        loaded.model, loaded.stats, target_return="q90", hide_actions=hide_actions
    )
    path = exported["dt-pursuers"] / "pursuer_1.onnx"
    if not hide_actions:
        export_dt_graph(reference, tmp_path / "shown.onnx", 17)
        proto = onnx.load(str(tmp_path / "shown.onnx"))
        for p in onnx.load(str(path)).metadata_props:
            proto.metadata_props.add(key=p.key, value="false" if p.key == "hide_actions" else p.value)
        path = tmp_path / "shown.onnx"
        onnx.save(proto, str(path))
    dt = ExportedDT(path)
    i = game.agents.index("pursuer_1")
    obs = game.reset(seed=5)
    dt.reset(3, "q90")
    rng = np.random.default_rng(1)
    low, high = game.action_bounds
    reward = None
    worst, moved = 0.0, []
    for _ in range(60):
        want = reference.act(obs[:, i], reward=reward)
        got = dt.act(obs[:, i], reward=reward)
        worst = max(worst, float(np.max(np.abs(got - want))))
        moved.append(want)
        actions = rng.uniform(low, high, size=(3, *low.shape))
        actions[:, i] = want
        result = game.step(actions)
        # the game's reward, scaled up so that the returns-to-go move the actions measurably
        obs, reward = result.obs, 2000.0 * result.reward[:, i] + rng.uniform(-3000.0, 3000.0, 3)
    assert worst <= TOLERANCE
    assert np.ptp(np.array(moved), axis=0).min() > 0.0  # it acts, not a constant
