"""``hptvsim bench env``: the 3-D game at B = 1024 beside the planar game, and their ratio (issue 37).

No timing is asserted: the rows are made up or their measurement is replaced, so these check the
table's wiring and arithmetic only.
"""

from __future__ import annotations

from typing import Any

import pytest

from hptvsim.bench import env as bench
from hptvsim.bench.env import GAME3D_TARGET, EnvBenchResult, EnvBenchRow


def _result(planar: float, game3d: float) -> EnvBenchResult:
    result = EnvBenchResult(scenario="source")
    result.rows += [
        EnvBenchRow("hptvsim batched backend, B=64", 64, 4, 9.0e9),
        EnvBenchRow("hptvsim batched backend, B=1024", 1024, 4, planar),
        EnvBenchRow("hptvsim 3-D game batched, B=1024", 1024, 4, game3d),
        EnvBenchRow("hptvsim 3-D game batched, B=64", 64, 4, 1.0),
    ]
    return result


def test_the_ratio_is_the_3d_over_the_planar_agent_steps_at_b1024() -> None:
    result = _result(planar=40_000.0, game3d=22_000.0)
    assert result.game3d_vs_planar() == pytest.approx(0.55)
    text = result.table()
    assert "3-D / planar agent-steps/s at B = 1024: 0.55x (target >= 0.5x: meets)" in text
    assert result.as_dict()["game3d_vs_planar_b1024"] == pytest.approx(0.55)
    low = _result(planar=40_000.0, game3d=12_000.0).table()
    assert "3-D / planar agent-steps/s at B = 1024: 0.30x (target >= 0.5x: MISSES)" in low
    assert GAME3D_TARGET == 0.5


def test_no_ratio_without_both_rows() -> None:
    result = EnvBenchResult(scenario="source")
    result.rows.append(EnvBenchRow("hptvsim batched backend, B=1024", 1024, 4, 100.0))
    assert result.game3d_vs_planar() is None
    assert "3-D / planar" not in result.table()


def test_the_b1024_pair_is_measured_in_turns(monkeypatch: pytest.MonkeyPatch) -> None:
    """Planar, 3-D, planar, 3-D, ...: each game's best turn is its row (a passing load hits both)."""
    calls: list[str] = []

    def stepper(name: str) -> tuple[Any, Any]:
        def step(k: int) -> None:
            calls.append(name)

        return step, lambda: calls.append(f"close {name}")

    monkeypatch.setattr(bench, "_planar_stepper", lambda scenario, num_envs: stepper("planar"))
    monkeypatch.setattr(bench, "_game3d_stepper", lambda num_envs: stepper("3-D"))
    turns = iter([100.0, 30.0, 120.0, 25.0, 90.0, 40.0])  # calls/s of each turn, in order
    monkeypatch.setattr(bench, "_rate", lambda step, *, seconds, min_steps: (step(0), next(turns))[1])
    planar, game3d = bench._paired_b1024("source", 0.3, rounds=3)
    assert calls == ["planar", "3-D"] * 3 + ["close planar", "close 3-D"]
    assert planar.name == "hptvsim batched backend, B=1024" and planar.env_steps_per_s == 120.0 * 1024
    assert game3d.name == "hptvsim 3-D game batched, B=1024" and game3d.env_steps_per_s == 40.0 * 1024


def test_bench_env_measures_the_3d_game_at_b1024_right_after_the_planar_row(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def planar(scenario: str, num_envs: int, seconds: float) -> EnvBenchRow:
        return EnvBenchRow(f"hptvsim batched backend, B={num_envs}", num_envs, 4, 10.0)

    def game3d(num_envs: int, seconds: float) -> EnvBenchRow:
        return EnvBenchRow(f"hptvsim 3-D game batched, B={num_envs}", num_envs, 4, 6.0)

    def pair(scenario: str, seconds: float) -> tuple[EnvBenchRow, EnvBenchRow]:
        return planar(scenario, 1024, seconds), game3d(1024, seconds)

    monkeypatch.setattr(bench, "_ours_fmu", lambda scenario, seconds: EnvBenchRow("hptvsim FMU", 1, 4, 1.0))
    monkeypatch.setattr(bench, "_ours_batched", planar)
    monkeypatch.setattr(bench, "_ours_3d", game3d)
    monkeypatch.setattr(bench, "_paired_b1024", pair)
    monkeypatch.setattr(bench, "_mpe", lambda seconds: "mpe2 not installed (test)")
    monkeypatch.setattr(bench, "_vmas", lambda num_envs, seconds: "vmas not installed (test)")
    monkeypatch.setattr(bench, "step_parts", lambda seconds: [])
    result = bench.bench_env(quick=True)
    names = [r.name for r in result.rows]
    i = names.index("hptvsim batched backend, B=1024")
    assert names[i + 1] == "hptvsim 3-D game batched, B=1024"
    assert result.game3d_vs_planar() == pytest.approx(0.6)
    assert "3-D / planar agent-steps/s at B = 1024: 0.60x" in result.table()


def test_the_parts_table_says_what_0_5x_leaves_the_3d_step() -> None:
    result = _result(planar=40_000.0, game3d=12_000.0)
    result.parts = [
        bench.StepPart(bench.PART_DYNAMICS, 16.0, 5.0),
        bench.StepPart(bench.PART_RAYS, 10.0, 2.0),
        bench.StepPart(bench.PART_NORMALS, 5.0, 1.0),
        bench.StepPart(bench.PART_WHOLE, 35.0, 9.0),
    ]
    assert result.parts_floor() == pytest.approx((18.0, 20.0))
    text = result.table()
    assert "  dynamics (RK4 in the FMU binaries)          16.00     5.00       3.20x" in text
    assert (
        "0.5x allows the 3-D step 18.00 ms on one thread; its dynamics and bookkeeping alone take 20.00 ms"
        in text
    )
    assert "(more: sonar speed-ups alone cannot reach it)" in text
    result.parts[3] = bench.StepPart(bench.PART_WHOLE, 25.0, 12.0)  # 24 ms allowed, 10 ms kept
    assert "(more:" not in result.table()
    assert result.as_dict()["step_parts_ms"][0] == {  # type: ignore[index]
        "part": bench.PART_DYNAMICS,
        "game3d": 16.0,
        "planar": 5.0,
    }


def test_step_parts_measures_both_games_on_one_thread() -> None:
    parts = bench.step_parts(0.02)
    assert [p.name for p in parts] == [
        bench.PART_DYNAMICS,
        bench.PART_RAYS,
        bench.PART_NORMALS,
        bench.PART_WHOLE,
    ]
    assert all(p.game3d_ms > 0.0 and p.planar_ms > 0.0 for p in parts)
    whole = parts[-1]
    assert whole.game3d_ms > parts[0].game3d_ms and whole.planar_ms > parts[0].planar_ms
