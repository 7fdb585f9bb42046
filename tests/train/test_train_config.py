"""Training configs: shipped files load, bad files are named precisely, overrides and round trips."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from hptvsim.train.config import (
    ConfigError,
    apply_overrides,
    config_dir,
    config_from_dict,
    config_to_dict,
    dump_toml,
    load_config,
    raw_config,
)


def _batched(name: str) -> bool:
    return raw_config(name).get("regime") == "fast"


@pytest.mark.parametrize(
    "name", sorted(p.stem for p in config_dir().glob("*.toml") if p.stem != "stt" and not _batched(p.stem))
)
def test_shipped_configs_load(name: str) -> None:
    cfg = load_config(name)
    assert cfg.stages
    again = config_from_dict(tomllib.loads(dump_toml(config_to_dict(cfg))), "round trip")
    assert again == cfg


@pytest.mark.parametrize("name", sorted(p.stem for p in config_dir().glob("*.toml") if _batched(p.stem)))
def test_shipped_batched_configs_load_and_are_refused_by_the_one_game_loader(name: str) -> None:
    from hptvsim.train.batched_run import load_batched_config

    cfg = load_batched_config(name)
    assert cfg.stages and cfg.budget_steps == sum(s.budget_steps for s in cfg.stages)
    with pytest.raises(ConfigError, match="a batched config"):
        load_config(name)


def test_paper_config_is_table_ii() -> None:
    cfg = load_config("paper")
    s = cfg.sac
    assert (s.learning_rate, s.gamma, s.tau, s.ent_coef, s.buffer_size, s.batch_size, s.net_arch) == (
        3e-4,
        0.99,
        0.01,
        "auto_0.1",
        500_000,
        256,
        (256, 256),
    )
    assert s.initial_ent_coef == pytest.approx(0.1)
    assert [st.budget_episodes for st in cfg.stages] == [100, 100]
    assert [st.env.scenario for st in cfg.stages] == ["source", "target"]


def test_curriculum_file_is_read_relative_to_the_config() -> None:
    cfg = load_config("pursuit")
    assert [s.name for s in cfg.stages] == ["source", "transition", "target"]
    assert cfg.sac.backend == "batched"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


STAGE = '[[stage]]\nname = "a"\nbudget_steps = 10\nenv = { kind = "toy" }\n'


def test_unknown_keys_name_file_key_and_valid_keys(tmp_path: Path) -> None:
    path = _write(tmp_path, 'algo = "maisac"\nlearnin_rate = 1\n' + STAGE)
    with pytest.raises(ConfigError, match=r"c\.toml.*'learnin_rate'.*valid keys: name, algo"):
        load_config(path)
    path = _write(tmp_path, "[sac]\nbach_size = 3\n" + STAGE)
    with pytest.raises(ConfigError, match=r"sac.*'bach_size'.*batch_size"):
        load_config(path)
    path = _write(tmp_path, STAGE + "carry = { weigths = true }\n")
    with pytest.raises(ConfigError, match=r"stages\[0\]\.carry.*'weigths'"):
        load_config(path)


def test_wrong_types_and_values_are_explained(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"sac\.batch_size: expected an integer, got 'big'"):
        load_config(_write(tmp_path, '[sac]\nbatch_size = "big"\n' + STAGE))
    with pytest.raises(ConfigError, match=r"algo: expected 'maisac' or 'ippo'"):
        load_config(_write(tmp_path, 'algo = "dqn"\n' + STAGE))
    with pytest.raises(ConfigError, match="exactly one of budget_steps and budget_episodes"):
        load_config(_write(tmp_path, '[[stage]]\nname = "a"\n'))
    with pytest.raises(ConfigError, match="gamma must be in"):
        load_config(_write(tmp_path, "[sac]\ngamma = 1.5\n" + STAGE))
    with pytest.raises(ConfigError, match="ent_coef"):
        load_config(_write(tmp_path, '[sac]\nent_coef = "automatic"\n' + STAGE))
    with pytest.raises(ConfigError, match="at least one stage"):
        load_config(_write(tmp_path, 'algo = "ippo"\n'))
    with pytest.raises(ConfigError, match=r"shipped configs: .*paper"):
        load_config("no-such-config")


def test_overrides_reach_nested_keys_and_stages() -> None:
    cfg = load_config("toy", {"sac.utd": 0.25, "stage.1.budget_steps": 99, "seed": 5})
    assert (cfg.sac.utd, cfg.stages[1].budget_steps, cfg.seed) == (0.25, 99, 5)
    with pytest.raises(ConfigError, match="no item '7'"):
        apply_overrides({"stage": [{}]}, {"stage.7.name": "x"})


@pytest.mark.parametrize("path", sorted((config_dir() / "sweeps").glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_sweeps_make_valid_configs(path: Path) -> None:
    from hptvsim.experiments.sweeps import load_sweep, plan_jobs

    spec = load_sweep(path)  # builds every job's config: a bad grid key fails here
    assert len(plan_jobs(spec)) == len(spec.seeds) * int(np.prod([len(v) for v in spec.grid.values()]))


def test_override_wildcard_sets_every_stage() -> None:
    from hptvsim.train.config import apply_overrides

    data = {"stage": [{"env": {"options": {"a": 1}}}, {"env": {}}]}
    out = apply_overrides(data, {"stage.*.env.options.vehicle_parameters.pursuer.v_max": 3.25})
    assert [s["env"]["options"]["vehicle_parameters"] for s in out["stage"]] == [
        {"pursuer": {"v_max": 3.25}}
    ] * 2
    assert out["stage"][0]["env"]["options"]["a"] == 1
    assert data == {"stage": [{"env": {"options": {"a": 1}}}, {"env": {}}]}  # the input is not changed
