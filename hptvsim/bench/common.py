"""Shared benchmark machinery: timing, the compiled C floor, tables with ratios.

Benchmarks print, for every way of doing the same work, its cost and its ratio to a floor
measured in the same run (machines are shared and noisy: compare ratios, not seconds).
Timing assertions never go into tests; they live here.
"""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hptvsim._output import machine_summary
from hptvsim.native import compile_c

__all__ = ["BenchResult", "Row", "best_of", "compile_floor", "run_floor"]


@dataclass
class Row:
    """One measured way of doing the benchmark's unit of work.

    Attributes:
        name: What was measured.
        per_unit_s: Seconds per unit of work (e.g. per vehicle-step).
        note: Free text shown beside the row.
    """

    name: str
    per_unit_s: float
    note: str = ""


@dataclass
class BenchResult:
    """A benchmark's rows and the floor they are compared with."""

    title: str
    unit: str
    floor: str
    rows: list[Row] = field(default_factory=list)
    targets: dict[str, float] = field(default_factory=dict)  # row name -> max ratio to floor

    def ratio(self, name: str) -> float:
        """Ratio of a row's cost to the floor's."""
        floor = next(r for r in self.rows if r.name == self.floor)
        row = next(r for r in self.rows if r.name == name)
        return row.per_unit_s / floor.per_unit_s

    def table(self) -> str:
        """Render as a fixed-width text table."""
        lines = [self.title, f"  machine: {machine_summary()}", ""]
        header = f"  {'what':<46} {'µs/' + self.unit:>14} {self.unit + '/s':>16} {'x floor':>9}  note"
        lines += [header, "  " + "-" * (len(header) - 2)]
        for r in self.rows:
            ratio = self.ratio(r.name)
            target = self.targets.get(r.name)
            note = r.note
            if target is not None:
                verdict = "meets" if ratio <= target else "MISSES"
                note = (note + "; " if note else "") + f"target <= {target:g}x: {verdict}"
            cost = f"{r.per_unit_s * 1e6:>14.4f} {1.0 / r.per_unit_s:>16,.0f}"
            lines.append(f"  {r.name:<46} {cost} {ratio:>9.2f}  {note}")
        return "\n".join(lines)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {
            "title": self.title,
            "unit": self.unit,
            "floor": self.floor,
            "machine": machine_summary(),
            "rows": [
                {
                    "name": r.name,
                    "us_per_unit": r.per_unit_s * 1e6,
                    "ratio_to_floor": self.ratio(r.name),
                    "note": r.note,
                }
                for r in self.rows
            ],
            "targets": self.targets,
        }


def best_of(fn: Callable[[], None], *, repeats: int, units: int) -> float:
    """Run ``fn`` ``repeats`` times; return the best seconds per unit (``units`` per run)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best / units


def compile_floor() -> Path:
    """Compile (once, cached by source content) the C floor harness ``floor.c``."""
    import fmpy

    include = Path(fmpy.__file__).parent / "c-code"
    return compile_c(
        Path(__file__).with_name("floor.c"), flags=("-O2", "-std=c99"), libs=("-ldl",),
        include_dirs=(include,), executable=True, what="the dynamics benchmark's C floor",
    )  # fmt: skip


def run_floor(binary: Path, guid: str, *, steps: int, vehicles: int, dt: float) -> dict[str, float]:
    """Run the C floor harness on an FMU binary; returns its JSON line as a dict."""
    exe = compile_floor()
    out = subprocess.run(
        [str(exe), str(binary), guid, str(steps), str(vehicles), str(dt)],
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return result
