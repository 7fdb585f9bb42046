"""``hptvsim bench train --algo ippo``: today's one-game IPPO against the fast preset, for real."""

from __future__ import annotations

from click.testing import CliRunner

from hptvsim.bench.train import IPPO_FLOOR, bench_train_ippo
from hptvsim.cli import main


def test_the_ippo_rows_train_both_paths_and_compare_env_steps_per_second() -> None:
    result = bench_train_ippo(quick=True, fast_seconds=3.0)
    names = [r.name for r in result.rows]
    assert names[0] == IPPO_FLOOR and names[1].startswith("fast preset: B = ")
    fast = result.rows[1]
    assert 0.0 < fast.per_unit_s < result.rows[0].per_unit_s  # batched games step faster per env step
    assert "steps)" in fast.note and result.targets == {fast.name: 0.1}
    assert "target <= 0.1x" in result.table()


def test_ippo_refuses_the_3d_game_in_one_line() -> None:
    res = CliRunner().invoke(main, ["bench", "train", "--algo", "ippo", "--env", "3d"])
    assert res.exit_code == 2 and "--algo ippo runs on the planar game" in res.output
    assert "Traceback" not in res.output
