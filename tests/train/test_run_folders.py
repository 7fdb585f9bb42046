"""Every folder ``hptvsim train`` writes is taken by the commands the README pairs it with (issue 50.3).

``hptvsim train fast --out OUT`` writes ``OUT/seed<k>/`` (a batched run per seed); the README pairs
it with ``hptvsim evaluate RUN_DIR``, ``hptvsim figures RUN_DIR_OR_SWEEP``, ``run:DIR`` policy specs
(``hptvsim episode``, ``hptvsim collect``) and ``sb3:RUN/stages/STAGE/<agent>.zip``. Tiny real runs:
8 games, 320 game steps, 30-step episodes, evaluated on 2 episodes each.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from hptvsim.cli import main
from hptvsim.experiments.policies import layout_env, policy_from_spec, policy_obs_layout
from hptvsim.train.envs import EnvSpec, make_env_factory
from hptvsim.train.runs import expand_runs, locate, open_run
from hptvsim.zoo import check_policy_spec

TINY = [
    "--no-progress",
    "--set",
    "ppo.num_envs=8",
    "--set",
    "ppo.n_steps=8",
    "--set",
    "stage.0.budget_steps=320",  # 40 steps of 8 games: every game ends an episode
    "--set",
    "eval.episodes=2",
    "--set",
    "stage.0.options.max_steps=30",
]
SHORT = ["--episodes", "2", "--env-option", "max_steps=20"]  # the runs trained on 30
TARGET = EnvSpec(kind="hptvsim", scenario="target", options={"extended_obs": True, "max_steps": 30})


def invoke(*args: str | Path) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def ok(*args: str | Path) -> str:
    res = invoke(*args)
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output
    return res.output


@pytest.fixture(scope="module")
def one(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``hptvsim train fast --out OUT``: one seed, OUT/seed0."""
    out = tmp_path_factory.mktemp("fast") / "one"
    ok("train", "fast", "--out", out, *TINY)
    return out


@pytest.fixture(scope="module")
def two(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``hptvsim train fast --seeds 0-1 --out OUT``: OUT/seed0 and OUT/seed1."""
    out = tmp_path_factory.mktemp("fast") / "two"
    ok("train", "fast", "--seeds", "0-1", "--out", out, *TINY)
    return out


def rows(output: str) -> list[str]:
    """The first cell of every table row (the policies' label)."""
    return re.findall(r"^\| ([^|]+?) \| \d\.\d\d ± ", output, re.M)


def test_evaluate_takes_the_folder_of_train_fast_and_its_seed(one: Path) -> None:
    assert rows(ok("evaluate", one, *SHORT)) == ["seed0"]  # was: "not a training run: it has no config.toml"
    assert rows(ok("evaluate", one / "seed0", *SHORT)) == ["seed0"]  # was: "a batched config"


def test_evaluate_gives_a_row_per_seed_and_the_mean(two: Path, tmp_path: Path) -> None:
    out = ok("evaluate", two, *SHORT, "--json", tmp_path / "e.json")
    assert rows(out) == ["two/seed0", "two/seed1", "mean over 2 runs"]
    data = json.loads((tmp_path / "e.json").read_text())
    assert [r["label"] for r in data["runs"]] == ["two/seed0", "two/seed1"]
    assert all(len(r["episodes"]) == 2 for r in data["runs"])
    lengths = [e["length"] for r in data["runs"] for e in r["episodes"]]
    assert max(lengths) <= 20, lengths  # --env-option reaches the run's own env (trained on 30)
    assert data["across_runs"]["capture_rate"]["n"] == 2


def test_evaluate_takes_each_stage_and_model_folder(one: Path) -> None:
    for stage in ("target", "models", "best"):
        assert rows(ok("evaluate", one, "--stage", stage, *SHORT)) == ["seed0"]
    res = invoke("evaluate", one, "--stage", "middle", *SHORT)
    assert res.exit_code == 2
    assert "has no stage 'middle'; finished stages: target (or models or best)" in res.output
    assert "Traceback" not in res.output


def test_evaluate_names_what_a_run_folder_is(tmp_path: Path) -> None:
    res = invoke("evaluate", tmp_path, *SHORT)
    assert res.exit_code == 1
    assert res.output.count("\n") == 1, res.output
    assert "is not a training run: it has no config.toml; valid: a run folder" in res.output


def test_run_specs_take_every_folder_a_run_writes(one: Path, two: Path) -> None:
    seed0 = one / "seed0"
    assert open_run(seed0).regime == "batched" and [s.name for s in open_run(seed0).stages] == ["target"]
    assert expand_runs(two) == [two / "seed0", two / "seed1"]
    cases = {
        f"run:{one}": seed0 / "stages" / "target",
        f"run:{seed0}": seed0 / "stages" / "target",
        f"run:{seed0}@target": seed0 / "stages" / "target",
        f"run:{seed0}@best": seed0 / "best",
        f"run:{seed0}/models": seed0 / "models",
        f"run:{seed0}/stages/target": seed0 / "stages" / "target",
        f"run:{two}/seed1": two / "seed1" / "stages" / "target",
    }
    env = make_env_factory(TARGET)()
    try:
        obs = env.reset(seed=0)[0]["pursuer_0"]
        for spec, folder in cases.items():
            path, _, which = spec.removeprefix("run:").partition("@")
            assert locate(Path(path), which or None)[1] == folder, spec
            assert policy_from_spec(spec, env, "pursuer_0")(obs).shape == (2,), spec
        with pytest.raises(FileNotFoundError, match=r"holds 2 runs \(seed0, seed1\), not one: name one"):
            policy_from_spec(f"run:{two}", env, "pursuer_0")
    finally:
        env.close()


def test_the_zoo_takes_run_specs_where_paths_are_allowed_only(one: Path) -> None:
    check_policy_spec(f"run:{one}", "pursuer", allow_paths=True, agent="pursuer_0")
    with pytest.raises(ValueError, match="names a training run's folder, which is not allowed here"):
        check_policy_spec(f"run:{one}", "pursuer", agent="pursuer_0")  # the service's rule
    with pytest.raises(ValueError, match="has no model for evader_0"):
        check_policy_spec(f"run:{one}", "evader", allow_paths=True, agent="evader_0")


def test_episode_and_collect_play_a_run(one: Path, two: Path, tmp_path: Path) -> None:
    out = ok(
        "episode", "--scenario", "target", "--max-steps", "20", "--policy", f"pursuer_0=run:{two}/seed1@best"
    )
    assert "target:" in out
    out = ok(
        "collect",
        "--pursuers",
        f"run:{one}",
        "--episodes",
        "2",
        "--max-steps",
        "20",
        "--num-envs",
        "2",
        "--ref-episodes",
        "0",
        "--out",
        tmp_path / "datasets",
        "--no-progress",
    )
    assert f"pursuer_0=run:{one}" in out
    assert (tmp_path / "datasets/hptvsim/target/expert-pursuer_2-v0/data/main_data.hdf5").is_file()


def test_figures_take_a_folder_of_seeds(two: Path, tmp_path: Path) -> None:
    out = ok("figures", two, "--out", tmp_path / "figures")
    for name in ("reward_pursuer.png", "reward_agents.png", "trajectories_target.png"):
        assert (tmp_path / "figures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", out


def test_a_runs_models_observe_the_layout_it_trained_in(one: Path) -> None:
    found = policy_obs_layout(f"run:{one}")  # fast.toml trains with extended_obs = true
    assert found is not None and found[0] == {"extended_obs": True, "fence": True}
    assert found[1].endswith("seed0/config.toml, stage 'target'")
    assert policy_obs_layout(f"sb3:{one}/seed0/best/pursuer_0.zip") == found
    assert policy_obs_layout(f"run:{one}/seed0/stages/target") == found
    plain = EnvSpec(kind="hptvsim", scenario="target")
    assert layout_env(plain, [f"run:{one}"] * 3 + ["maisac-evader"]).options["extended_obs"] is True


def test_evaluate_refuses_an_option_against_a_runs_layout(one: Path) -> None:
    res = invoke("evaluate", one, "--env-option", "extended_obs=false", "--episodes", "1")
    assert res.exit_code == 1
    assert res.output.startswith(
        f"Error: --env-option extended_obs=false contradicts run:{one}/seed0, trained"
    )
    assert res.output.count("\n") == 1, res.output
