"""What an episode will cost, estimated at admission: memory, CPU time and disk.

:func:`estimate_costs` is the one estimate; :func:`~hptvsim.service.validation.resolve_request`
(every surface that admits an episode: runs and interactive episodes, shipped and inline
scenarios, the dashboard and the live view) refuses an episode whose estimate exceeds
``HPTVSIM_EPISODE_MEMORY_MB``, ``HPTVSIM_EPISODE_DISK_MB`` or ``HPTVSIM_EPISODE_CPU_S``, naming the
fields that drive it. The estimate is a sum of terms, each the product of what drives it (vehicles,
sonar beams, sonar fidelity and record length, maximum range over the grid resolution, acoustic
link reports, terrain grid cells, steps, recording) and a coefficient measured here. It is meant to
be an upper bound for the usual cases, not exact; the hard limits of the simulating processes
(:mod:`hptvsim.service.limits`) end an episode the estimate got wrong.

**How the coefficients were measured.** One episode per fresh process, run as a pool worker runs
it (:func:`hptvsim.service.workers._child_setup`, then :func:`~hptvsim.service.engine.run_job`
with recording, ``OMP_NUM_THREADS=1``, rerun's allocator capped as the workers cap it), on the
project's 2-core development machine: CPU time from :func:`time.process_time`, memory as the
growth of the process's private writable memory (``VmData``, sampled every 20 ms, which is what
the hard limit counts), disk as the sizes of the files written. Scenarios: ``source_goto`` (flat,
400 m x 300 m) and ``target`` (24 hills, 1 m grid) with scripted policies, 4 to 16 vehicles, 16 to
1024 beams, 20 to 400 steps; each coefficient below says which runs gave it. Each is rounded up
from the largest value measured.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

__all__ = ["EpisodeCosts", "Term", "estimate_costs"]

Resource = Literal["memory", "cpu", "disk"]

MIB = 1 << 20

# --- memory [bytes] -----------------------------------------------------------------------------------
MEM_BASE = 160 * MIB
"""Per episode, whatever its size: its world, static part, recorder and first frames. Measured:
``VmData`` grew 103-123 MiB over 4-vehicle, 16-beam episodes of 20-400 steps."""
MEM_TRAINED = 256 * MIB
"""When a trained policy drives an agent: torch, SB3 and the models. Measured: +210 MiB of
``VmData`` for ``import torch``, ``stable_baselines3`` and the four shipped SAC models."""
MEM_PER_BEAM_STEP = 24
"""Per sonar range kept for the trajectory (vehicle x beam x step: the trajectory's float64
columns, the frames' events, the recording's buffers and the Parquet table at the end), with a
third more than measured. Measured (2026-11-29, the worker's whole job, :func:`run_job` with a
recording, 16 vehicles x 1024 beams, flat site, peak resident memory): 215, 297, 333, 386 and
556 MiB after 50, 150, 300, 600 and 1200 steps: 11 to 18 B per range between 300 and 1200 steps
(52 B between 50 and 150, while the first buffers fill; the fixed terms cover that). It was 150 B
while the trajectory kept Python floats."""
MEM_PER_AGENT_STEP = 1024
"""Per trajectory row (vehicle x step): 21 columns of Python floats (32 B each with the list
slot) and their arrays at the end (counted; too small to see in the runs above)."""
MEM_PER_CELL = 110
"""Per terrain grid cell (height map, obstacle map, distance fields, meshes). Measured: a
2000 m x 2000 m site at 1 m (4e6 cells) took 69 MiB more to build and 311 MiB more to run than
the 400 m x 300 m one: 95 B a cell."""
MEM_PER_SIGNAL_SAMPLE = 48
"""Per sample of the signal-level sonar's block of records (at most
:data:`~hptvsim.sensors.signal._CHUNK_SAMPLES` = 2e6 samples, or one record: float64 echoes,
complex FFT buffers). Measured: 4 x 64 beams, records of 5494 and 21494 samples (1.4e6 and 2e6
samples a block): +40 and +74 MiB over the geometric sonar."""
MEM_PER_LINK_SLOT = 48
"""Per slot of an acoustic link's report queue, per evader and pursuer: 32 B of arrays
(:func:`~hptvsim.sensors.acoustic.queue_length`) and the 9 B temporaries of each delivery."""

# --- CPU time [s] ---------------------------------------------------------------------------------
CPU_BASE = 2.0
"""Per episode: building its world, static part and policies. Measured 0.8-1.0 s for 4 vehicles
over 20-100 steps (imports of a worker's first episode included)."""
CPU_TRAINED = 8.0
"""When a trained policy drives an agent: importing torch and SB3, loading the models (once a
worker). Measured: a fresh worker's ``source`` episode of 100 steps with the four shipped SAC
models took 7.7 s of CPU, against 1.0 s with scripted policies."""
CPU_PER_AGENT_STEP = 1e-3
"""Per vehicle and step: dynamics, policy, frame, trajectory row. Measured 0.34 ms (4 vehicles,
scripted policies, 100 and 400 steps); a trained policy's inference adds some 0.2 ms."""
CPU_PER_BEAM_STEP = 1.5e-6
"""Per beam and step with the geometric sonar, without recording: the ray cast's fixed part, the
range's frame and trajectory entries. Measured 0.6 us (16 x 1024 beams, 150 steps)."""
CPU_PER_BEAM_STEP_RECORDED = 1.0e-6
"""Added per beam and step when recording. Measured +0.6 us (16 x 1024, 150 steps: 2.35 s without,
3.86 s with); 1.9 us in all on the ``target`` terrain (8 x 1024)."""
CPU_PER_RAY_CELL = 5e-9
"""Per grid cell a ray crosses (``max_range / resolution`` per beam and step). Measured: 8 x 1024
beams, 150 steps on a 1 m grid, 50 -> 400 m maximum range: +1.32 s, 3.1 ns a cell; the 3-D game
(``ridge_3d``, 4 x 64 x 16 beams, 90 steps, 2 m grid, 50 -> 300 m): 4.7 ns."""
CPU_PER_SIGNAL_SAMPLE = 1.2e-7
"""Per sample of the signal-level sonar's records (one record per beam and step: echo synthesis
and the matched filter of Eq. 1). Measured 92 and 73 ns (4 x 64 beams, 20 steps, records of 5494
and 21494 samples)."""
CPU_PER_REPORT = 1e-4
"""Per acoustic-link report (per evader): a loop iteration of numpy calls on small arrays. Not
measurable at the schema's shortest period (0.1 s: 2.5 reports a 0.25 s step, 15 pursuers, 200
steps: 1.92 s against 1.90 s at 1 s), so this is a bound of the loop's cost."""
CPU_PER_LINK_SLOT = 1e-8
"""Per queue slot of a link, per evader, pursuer and step (each delivery scans the queue)."""
CPU_PER_CELL = 5e-7
"""Per terrain grid cell (building and drawing the world). Measured: 4e6 cells, +1.7 s."""

# --- disk [bytes] -------------------------------------------------------------------------------------
DISK_BASE = 2 * MIB
"""Per episode: ``static.json`` (the terrain mesh and obstacle summary are decimated: 0.45-0.8 MB
measured), ``result.json``, and the recording's static scene (0.65-0.76 MB measured)."""
DISK_PER_BEAM_STEP = 5
"""Per sonar range in ``trajectory.parquet`` (float32 lists, incompressible at worst). Measured
0.4 B (flat, ranges mostly max_range) to 4.6 B (``target`` terrain, 400 m range)."""
DISK_PER_AGENT_STEP = 200
"""Per trajectory row: ~20 float64 columns, step, time, agent (before compression)."""
DISK_PER_BEAM_STEP_RECORDED = 9
"""Per beam and step in ``recording.rrd``: every 4th step a ray (2 x 3 float32) and a hit point
(3 float32) per beam. Measured 0.75 B (flat) to 5.7 B (``target`` terrain, 400 m range)."""
DISK_PER_AGENT_STEP_RECORDED = 400
"""Per vehicle and step in ``recording.rrd``: pose, plots, trails. Measured 340 B (4 x 16 beams)."""


@dataclass(frozen=True)
class Term:
    """One part of an estimate.

    Attributes:
        resource: ``"memory"`` [bytes], ``"cpu"`` [s] or ``"disk"`` [bytes].
        amount: Its size, in the resource's unit.
        fields: The request fields that drive it, the one to change first first.
        what: What it is, with the numbers that make it (for the client).
        per_step: The part of ``amount`` that each step adds (0: none).
    """

    resource: Resource
    amount: float
    fields: tuple[str, ...]
    what: str
    per_step: float = 0.0


@dataclass(frozen=True)
class EpisodeCosts:
    """An episode's estimated costs (:func:`estimate_costs`).

    Attributes:
        steps: The steps it was estimated for.
        terms: Every part of the estimate.
    """

    steps: int
    terms: tuple[Term, ...] = field(default_factory=tuple)

    def total(self, resource: Resource) -> float:
        """The estimate of ``resource`` (memory and disk in bytes, CPU in seconds)."""
        return float(sum(t.amount for t in self.terms if t.resource == resource))

    @property
    def memory_bytes(self) -> float:
        """Estimated peak memory of the episode [bytes] (beyond an idle process)."""
        return self.total("memory")

    @property
    def cpu_s(self) -> float:
        """Estimated CPU time of the episode [s]."""
        return self.total("cpu")

    @property
    def disk_bytes(self) -> float:
        """Estimated size of the episode's files [bytes]."""
        return self.total("disk")

    def drivers(self, resource: Resource) -> list[Term]:
        """The largest terms of ``resource``, until they make up 80 % of it (at most three)."""
        terms = sorted((t for t in self.terms if t.resource == resource), key=lambda t: -t.amount)
        total, out, running = self.total(resource), [], 0.0
        for t in terms[:3]:
            out.append(t)
            running += t.amount
            if running >= 0.8 * total:
                break
        return out

    def steps_within(self, resource: Resource, limit: float) -> int | None:
        """The most steps whose estimate of ``resource`` stays within ``limit`` (None: none would)."""
        per_step = sum(t.per_step for t in self.terms if t.resource == resource)
        if per_step <= 0.0:
            return None
        fixed = self.total(resource) - per_step * (self.steps + 1)  # rows: steps + the reset
        fits = math.floor((limit - fixed) / per_step) - 1
        return fits if fits >= 1 else None


def _trained(policies: Mapping[str, str] | None) -> bool:
    return any(not (p.startswith("scripted:") or p == "external") for p in (policies or {}).values())


def estimate_costs(
    scenario: Any,
    *,
    max_steps: int,
    record: bool,
    sensor_fidelity: str | None = None,
    policies: Mapping[str, str] | None = None,
) -> EpisodeCosts:
    """Estimate what an episode of ``scenario`` will cost (see the module docstring).

    Args:
        scenario: The built :class:`~hptvsim.world.scenario.Scenario`.
        max_steps: The episode's step limit.
        record: Whether it writes a rerun recording.
        sensor_fidelity: The request's sonar fidelity for every vehicle (None: the scenario's).
        policies: Agent -> policy of the agents the server drives (trained ones cost more).

    Returns:
        The estimate, term by term.
    """
    from hptvsim.sensors.acoustic import queue_length, reports_per_step

    rows = int(max_steps) + 1  # the reset's frame and one per step
    agents = scenario.agents
    n = len(agents)
    sim = scenario.simulation
    game3d = sim.game == "3d"
    geometry = scenario.grid_geometry()
    cells = int(geometry.shape[0]) * int(geometry.shape[1])
    resolution = float(geometry.resolution)
    terms: list[Term] = []

    def add(resource: Resource, per_step: float, fixed: float, fields: tuple[str, ...], what: str) -> None:
        amount = fixed + per_step * rows
        if amount > 0.0:
            terms.append(Term(resource, amount, fields, what, per_step))

    # which sonar field to name: a group's own sonar, else [sensors.sonar]
    def sonar_field(name: str) -> str:
        if game3d and name == "beams":
            return "scenario.sensors.sonar3d"
        own = [a.group for a in agents if scenario.vehicles[a.group].sonar is not None]
        return f"scenario.vehicles[{own[0]}].sonar.{name}" if own else f"scenario.sensors.sonar.{name}"

    beams = [int(scenario.sensors.sonar3d.beams) if game3d else int(a.sonar.beams) for a in agents]
    beam_sum = sum(beams)
    beams_text = f"{n} vehicles x {max(beams)} beams" if len(set(beams)) == 1 else f"{beam_sum} beams"
    steps_text = f"{rows} steps"
    beam_fields = (sonar_field("beams"), "scenario.vehicles", "max_steps")
    trained = _trained(policies)

    # memory
    add("memory", 0.0, MEM_BASE, ("scenario",), "the episode's fixed part")
    if trained:
        add("memory", 0.0, MEM_TRAINED, ("policies",), "trained policies (torch)")
    add(
        "memory",
        MEM_PER_BEAM_STEP * beam_sum,
        0.0,
        beam_fields,
        f"sonar ranges kept for the trajectory ({beams_text} x {steps_text})",
    )
    add(
        "memory",
        MEM_PER_AGENT_STEP * n,
        0.0,
        ("max_steps", "scenario.vehicles"),
        f"trajectory rows ({n} x {rows})",
    )
    terrain_fields = ("scenario.terrain.resolution", "scenario.site.size")
    add("memory", 0.0, MEM_PER_CELL * cells, terrain_fields, f"the terrain grid ({cells} cells)")
    # the signal-level sonar (planar game only): one block of records at a time
    fidelity_field = "sensor_fidelity" if sensor_fidelity is not None else sonar_field("fidelity")
    signal_samples = 0  # samples synthesised per step
    block = 0
    if not game3d:
        for a, k in zip(agents, beams, strict=True):
            fidelity = sensor_fidelity or a.sonar.fidelity
            if fidelity == "signal":
                record_samples = int(a.sonar.record_samples)
                signal_samples += k * record_samples
                per_block = max(1, 2_000_000 // record_samples)
                block = max(block, min(k * n, per_block) * record_samples)
    if signal_samples:
        signal_fields = (fidelity_field, sonar_field("max_range"), sonar_field("sampling_rate"))
        add(
            "memory",
            0.0,
            MEM_PER_SIGNAL_SAMPLE * block,
            signal_fields,
            f"signal-level records ({block} samples)",
        )
    # the acoustic link: one per evader, each with a queue per pursuer
    link = scenario.sensors.link
    pursuers = sum(1 for a in agents if a.role == "pursuer")
    evaders = n - pursuers
    link_fields = ("scenario.sensors.link.report_period", "scenario.sensors.link.max_range")
    if pursuers and evaders:
        slots = queue_length(link, float(sim.dt))
        add(
            "memory",
            0.0,
            MEM_PER_LINK_SLOT * evaders * pursuers * slots,
            link_fields,
            f"acoustic-link queues ({evaders} x {pursuers} x {slots} reports)",
        )

    # CPU time
    add("cpu", 0.0, CPU_BASE + (CPU_TRAINED if trained else 0.0), ("scenario",), "building the episode")
    add(
        "cpu", CPU_PER_AGENT_STEP * n, 0.0, ("max_steps", "scenario.vehicles"), f"{n} vehicles x {steps_text}"
    )
    per_beam = CPU_PER_BEAM_STEP + (CPU_PER_BEAM_STEP_RECORDED if record else 0.0)
    add("cpu", per_beam * beam_sum, 0.0, beam_fields, f"sonar beams ({beams_text} x {steps_text})")
    ray_cells = sum(k * float(a.sonar.max_range) / resolution for a, k in zip(agents, beams, strict=True))
    add(
        "cpu",
        CPU_PER_RAY_CELL * ray_cells,
        0.0,
        (sonar_field("max_range"), "scenario.terrain.resolution", "max_steps"),
        f"ray casts ({ray_cells:.3g} grid cells a step: max_range / resolution per beam)",
    )
    if signal_samples:
        add(
            "cpu",
            CPU_PER_SIGNAL_SAMPLE * signal_samples,
            0.0,
            (fidelity_field, sonar_field("max_range"), sonar_field("sampling_rate"), "max_steps"),
            f"signal-level echoes ({signal_samples:.3g} samples a step x {steps_text})",
        )
    add("cpu", 0.0, CPU_PER_CELL * cells, terrain_fields, f"the terrain grid ({cells} cells)")
    if pursuers and evaders:
        reports = reports_per_step(link, float(sim.dt))
        slots = queue_length(link, float(sim.dt))
        per_step = evaders * (CPU_PER_REPORT * reports + CPU_PER_LINK_SLOT * pursuers * slots)
        add(
            "cpu",
            per_step,
            0.0,
            (*link_fields, "max_steps"),
            f"acoustic-link reports ({evaders} x {reports} a step of {float(sim.dt):g} s x {steps_text})",
        )

    # disk
    add("disk", 0.0, DISK_BASE, ("scenario",), "the episode's static part")
    add(
        "disk",
        DISK_PER_BEAM_STEP * beam_sum,
        0.0,
        beam_fields,
        f"trajectory ranges ({beams_text} x {steps_text})",
    )
    add(
        "disk",
        DISK_PER_AGENT_STEP * n,
        0.0,
        ("max_steps", "scenario.vehicles"),
        f"trajectory rows ({n} x {rows})",
    )
    if record:
        add(
            "disk",
            DISK_PER_BEAM_STEP_RECORDED * beam_sum + DISK_PER_AGENT_STEP_RECORDED * n,
            0.0,
            ("record", *beam_fields),
            f"the recording ({beams_text} x {steps_text})",
        )
    return EpisodeCosts(steps=int(max_steps), terms=tuple(terms))
