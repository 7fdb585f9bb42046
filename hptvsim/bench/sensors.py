"""``hptvsim bench sensors``: geometric sonar rays/s and matched-filter estimates/s.

**Sonar.** The shipped ``target`` scenario's obstacle map (irregular rolling mountains cut at the
operating depth, 400 m x 300 m at 1 m) and ``B`` environments x 4 agents (3 work-class UUVs
and a spherical robot, as in that scenario) placed uniformly in free water with random
headings, each with the default sonar (16 beams over a full circle, 50 m). Rows: the compiled
kernel at ``B`` = 1, 64 and 1024 (1024 on one thread and split across up to 2), and the numpy
reference (the peer: same results, pure numpy). The floor is a compiled lower bound measured in
the same run: for every ray only the work any ray does whatever it meets (its direction and one
store), no traversal and no vehicle tests. The environments' budget is about 60 ns per ray at
``B`` = 1024 (770k agent-steps/s with 16 beams on 2 cores).

**Matched filter.** Range estimates of Eq. 1 on records of the default sonar (5494 samples,
160-sample LFM pulse): the FFT implementation in batches of 256 records, the same with echo
synthesis included (what the signal-level sonar does per beam), and the direct sum of Eq. 1a as
written (the peer). The floor is one real FFT of each record (any FFT correlator needs at least
that).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hptvsim._output import machine_summary
from hptvsim.bench.common import BenchResult, Row, best_of

__all__ = ["SensorsBench", "bench_sensors"]


@dataclass
class SensorsBench:
    """Several benchmark tables printed together."""

    results: list[BenchResult] = field(default_factory=list)

    def table(self) -> str:
        """All tables, one after another."""
        return "\n\n".join(r.table() for r in self.results)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {"machine": machine_summary(), "results": [r.as_dict() for r in self.results]}


def _poses(
    rng: np.random.Generator, free: np.ndarray, xy: tuple[np.ndarray, np.ndarray], b: int
) -> np.ndarray:
    ii, jj = np.nonzero(free)
    pick = rng.integers(0, ii.size, size=(b, 4))
    x = xy[0][ii[pick]] + rng.uniform(-0.5, 0.5, (b, 4))
    y = xy[1][jj[pick]] + rng.uniform(-0.5, 0.5, (b, 4))
    psi = rng.uniform(-np.pi, np.pi, (b, 4))
    return np.ascontiguousarray(np.stack([x, y, psi], axis=-1))


def bench_sonar(*, quick: bool = False) -> BenchResult:
    """Rays per second of the geometric sonar (see the module docstring).

    Every call casts a fresh batch of poses (from a pool of 4096 environments, 1024 in quick
    mode), so the CPU's branch predictors cannot learn one batch by heart.
    """
    from hptvsim.sensors.sonar import GeometricSonar, vehicle_radii
    from hptvsim.world.scenario import load_scenario
    from hptvsim.world.sensor_config import SonarConfig

    grid = load_scenario("target").build_world().obstacles
    cfg = SonarConfig()
    radii = vehicle_radii(["work_class"] * 3 + ["spherical"])
    free = grid.sdf > 1.5  # m, room for a work-class hull
    rng = np.random.default_rng(0)
    k = cfg.beams
    repeats = 3 if quick else 7
    pool = _poses(rng, free, grid.geometry.centres(), 1024 if quick else 4096)
    kernel = GeometricSonar(cfg, grid, threads=1)
    threads = GeometricSonar(cfg, grid).threads
    result = BenchResult(
        title=f"Geometric sonar ray casts ({k} beams, {cfg.max_range:g} m, target scenario map)",
        unit="ray",
        floor="floor: direction + store (C, B=1024)",
    )
    out = np.empty((1024, 4, k))
    head = np.ascontiguousarray(pool[:1024])

    def floor() -> None:
        kernel.floor(head, out=out)

    result.rows.append(
        Row(result.floor, best_of(floor, repeats=repeats * 2, units=1024 * 4 * k), "no traversal")
    )

    def timed(b: int, n_threads: int) -> float:
        batches = [np.ascontiguousarray(pool[i : i + b]) for i in range(0, pool.shape[0] - b + 1, b)]
        buf = np.empty((b, 4, k))

        def run() -> None:
            kernel.threads = n_threads
            for batch in batches:
                kernel.ranges(batch, radii, out=buf)

        return best_of(run, repeats=repeats, units=len(batches) * b * 4 * k)

    for b in (1, 64, 1024):
        per = timed(b, 1)
        result.rows.append(
            Row(f"C kernel, B={b} x 4 agents, 1 thread", per, f"{per * 1e9 * k:.0f} ns/agent-step")
        )
    if threads > 1:
        per = timed(1024, threads)
        note = f"{per * 1e9 * k:.0f} ns/agent-step; budget ~60 ns/ray"
        result.rows.append(Row(f"C kernel, B=1024 x 4 agents, {threads} threads", per, note))
    peer = GeometricSonar(cfg, grid, backend="numpy")
    b_peer = 8 if quick else 64
    few = np.ascontiguousarray(pool[:b_peer])

    def run_peer() -> None:
        peer.ranges(few, radii)

    per = best_of(run_peer, repeats=2 if quick else 3, units=b_peer * 4 * k)
    result.rows.append(Row(f"numpy reference (peer), B={b_peer} x 4 agents", per, "identical results"))
    return result


def bench_matched_filter(*, quick: bool = False) -> BenchResult:
    """Range estimates per second of the matched filter (see the module docstring)."""
    from scipy import fft as sp_fft

    from hptvsim.sensors.signal import (
        estimate_delay,
        matched_filter_direct,
        synthesize_echoes,
        transmit_pulse,
    )
    from hptvsim.world.sensor_config import SonarConfig

    cfg = SonarConfig(snr_db=10.0)
    pulse = transmit_pulse(cfg)
    rng = np.random.default_rng(0)
    batch = 64 if quick else 256
    ranges = rng.uniform(5.0, 45.0, batch)
    x = synthesize_echoes(ranges, cfg, rng)
    nfft = sp_fft.next_fast_len(x.shape[1], real=True)
    repeats = 3 if quick else 5
    few = x[:4] if quick else x[:16]
    result = BenchResult(
        title=f"Matched filter (Eq. 1), {x.shape[1]}-sample records, {pulse.size}-sample LFM pulse",
        unit="estimate",
        floor="floor: one real FFT per record (scipy)",
    )

    def floor() -> None:
        sp_fft.rfft(x, nfft, axis=1)

    def fft_mf() -> None:
        estimate_delay(x, pulse)

    def with_echoes() -> None:
        estimate_delay(synthesize_echoes(ranges, cfg, rng), pulse)

    def direct() -> None:
        np.argmax(matched_filter_direct(few, pulse), axis=1)

    result.rows.append(Row(result.floor, best_of(floor, repeats=repeats, units=batch)))
    per = best_of(fft_mf, repeats=repeats, units=batch)
    result.rows.append(Row(f"FFT matched filter + argmax, batch {batch}", per))
    per = best_of(with_echoes, repeats=repeats, units=batch)
    result.rows.append(
        Row(f"echo synthesis + FFT matched filter, batch {batch}", per, "per beam, signal level")
    )
    per = best_of(direct, repeats=2, units=few.shape[0])
    result.rows.append(Row(f"direct sum of Eq. 1a (peer), batch {few.shape[0]}", per, "same J[D] as the FFT"))
    return result


def bench_sensors(*, quick: bool = False) -> SensorsBench:
    """Both sensor benchmarks."""
    return SensorsBench(results=[bench_sonar(quick=quick), bench_matched_filter(quick=quick)])
