"""What a worker process does with an episode, on top of the episode engine (:mod:`hptvsim.episodes`).

An episode is described by a :class:`JobSpec` (plain, picklable data the API validated). The
simulation and the frames (the one frame schema, :mod:`hptvsim.episodes.frames`) come from the
episode engine, the rerun recording from :func:`hptvsim.viz.recording.recorder`; this module adds
what the service needs around them:

* ``run`` mode: :func:`run_job` plays the episode with :func:`hptvsim.episodes.runner.run_episode`,
  forwarding frames and progress at a bounded rate and stopping on cancel or timeout;
* ``interactive`` mode: :class:`InteractiveEpisode` wraps an
  :class:`~hptvsim.episodes.stepper.EpisodeStepper` in which the client's agents are ``external``.

When an episode ends the worker writes, in the episode's folder, ``static.json`` (the frames'
static part), ``trajectory.parquet`` (:meth:`~hptvsim.episodes.frames.Trajectories.columns`: one row
per step and agent), ``recording.rrd`` (when recording) and, last and atomically,
``result.json`` (the summary and the file names). ``result.json`` also lets a restarted API
recover an episode whose worker completed while the API was down.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import math
import platform
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hptvsim._files import atomic_path, write_atomic

if TYPE_CHECKING:
    from hptvsim.episodes.frames import AgentInfo

__all__ = [
    "RECORDING_FILE",
    "RESULT_FILE",
    "STATIC_FILE",
    "TRAJECTORY_FILE",
    "InteractiveEpisode",
    "JobSpec",
    "client_message",
    "read_result",
    "run_job",
    "versions",
]

_PATH = re.compile(r"(?<![\w.])(?:~|\.{1,2})?/(?:[^\s/:'\"]+/)*([^\s/:'\"]+)")


class JobFailedError(RuntimeError):
    """A run-mode episode failed after it started; the files of what ran are written.

    Attributes:
        message: What the client is told (:func:`client_message` of the cause).
        result: What ``result.json`` holds for the partial episode (:func:`write_outputs`).
    """

    def __init__(self, message: str, result: dict[str, Any]) -> None:
        super().__init__(message)
        self.message = message
        self.result = result


def client_message(exc: BaseException) -> str:
    """A short message about ``exc`` that is safe to show a client (no traceback, no server paths).

    The log gets the traceback; this is what the episode's ``error`` and the API's answers say.
    """
    from hptvsim.episodes.stepper import SimulationError

    if isinstance(exc, SimulationError):
        return str(exc)
    if isinstance(exc, PermissionError | FileNotFoundError | IsADirectoryError | NotADirectoryError):
        return f"the service could not write the episode's files ({exc.strerror or 'permission denied'})"
    if isinstance(exc, OSError):
        return f"the service could not write the episode's files ({exc.strerror or type(exc).__name__})"
    if isinstance(exc, ValueError):  # ours name the field; paths become file names
        text = _PATH.sub(lambda m: m.group(1), str(exc).splitlines()[0] if str(exc) else "")
        return text[:500] or type(exc).__name__
    return f"internal error ({type(exc).__name__}); the service logged the details"


RESULT_FILE = "result.json"
STATIC_FILE = "static.json"
TRAJECTORY_FILE = "trajectory.parquet"
RECORDING_FILE = "recording.rrd"


@dataclass(frozen=True, kw_only=True)
class JobSpec:
    """One episode as the API validated it; crosses process boundaries as plain data.

    Attributes:
        id: Episode id.
        mode: ``"run"`` or ``"interactive"``.
        scenario: A shipped scenario's name, or the client's validated scenario tables.
        policies: Zoo spec of every agent the server drives.
        control: Agents the client steps (interactive mode).
        seed: Seed of spawn poses, sensor noise and stochastic policies.
        max_steps: Step limit.
        backend: ``"batched"`` or ``"fmu"``.
        sensor_fidelity: ``"geometric"``, ``"signal"`` or None (the scenario's).
        record: Whether to write a rerun recording.
        out_dir: The episode's folder.
        event_hz: Progress/frame events per second (run mode).
        timeout_s: Wall-clock limit of a run [s].
    """

    id: str
    mode: str = "run"
    scenario: str | dict[str, Any]
    policies: dict[str, str]
    control: tuple[str, ...] = ()
    seed: int = 0
    max_steps: int = 6000
    backend: str = "batched"
    sensor_fidelity: str | None = None
    record: bool = True
    out_dir: str
    event_hz: float = 10.0
    timeout_s: float = 3600.0

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-able)."""
        d = asdict(self)
        d["control"] = list(self.control)
        return d

    @property
    def recording_path(self) -> Path | None:
        """Where the recording goes (None when not recording)."""
        return Path(self.out_dir) / RECORDING_FILE if self.record else None


def versions() -> dict[str, str]:
    """Versions of what produced an episode's numbers.

    The packages' versions, Python's minor version and the processor architecture: what a
    number depends on. Not the kernel, the C library or Python's patch level, which a client
    (any key holder) could use to pick exploits and which change no result.
    """
    from importlib.metadata import PackageNotFoundError, version

    import numpy as np

    import hptvsim

    out = {
        "hptvsim": hptvsim.__version__,
        "python": ".".join(platform.python_version_tuple()[:2]),
        "numpy": np.__version__,
        "machine": platform.machine(),
    }
    for dist in ("rerun-sdk", "casadi", "fastapi"):
        with contextlib.suppress(PackageNotFoundError):  # all are dependencies of the service
            out[dist.replace("-", "_")] = version(dist)
    return out


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON so that readers see the old file or the whole new one, never a part.

    A write that fails (a full disk) leaves the old file and no temporary (:mod:`hptvsim._files`).
    """
    write_atomic(path, json.dumps(data, allow_nan=False))


_PARTS: collections.OrderedDict[tuple[str, Any], Any] = collections.OrderedDict()


def static_dict(static: Any) -> dict[str, Any]:
    """``static.to_dict()`` of an :class:`~hptvsim.episodes.frames.EpisodeStatic`, faster for repeats.

    The terrain mesh and obstacle map are most of the work and the same for every episode of a
    scenario; their plain data is kept for the last few scenarios a process saw.
    """
    from hptvsim.episodes.frames import to_dict

    out: dict[str, Any] = {}
    for f in dataclasses.fields(static):
        if not f.init:
            continue
        value = getattr(static, f.name)
        if f.name in ("terrain", "obstacles"):
            key = (f.name, value)
            if key in _PARTS:
                _PARTS.move_to_end(key)
            else:
                _PARTS[key] = to_dict(value)
                while len(_PARTS) > 8:
                    _PARTS.popitem(last=False)
            out[f.name] = _PARTS[key]
        else:
            out[f.name] = to_dict(value)
    return out


def summary_dict(summary: Any) -> dict[str, Any]:
    """An :class:`~hptvsim.episodes.frames.EpisodeSummary` as the API stores it (no server paths)."""
    data: dict[str, Any] = summary.to_dict()
    data.pop("recording", None)
    return data


def write_outputs(
    out_dir: Path, result: Any, *, error: str | None = None, static: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Write an :class:`~hptvsim.episodes.stepper.EpisodeResult`'s files; returns what ``result.json`` holds.

    Args:
        out_dir: The episode's folder.
        result: What the episode produced.
        error: Why it stopped early, if it did.
        static: ``result.static.to_dict()`` if already made (it is not cheap: the terrain mesh).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from hptvsim.cosim import trajectory
    from hptvsim.service.downloads import row_group_rows

    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / STATIC_FILE, json.dumps(static if static is not None else result.static.to_dict()))
    cols = result.trajectories.columns()  # the schema's long layout, in its order
    fields = []
    arrays = []
    for name, values in cols.items():
        col = trajectory.column(name)
        kind = trajectory.arrow_type(col.dtype)
        # text and lists from Python objects; numbers straight from their arrays
        arrays.append(pa.array(values.tolist() if values.dtype == object else values, kind))
        fields.append(pa.field(name, kind, metadata=trajectory.field_metadata(col.unit)))  # SI unit
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields))
    traj = out_dir / TRAJECTORY_FILE
    with atomic_path(traj) as tmp:
        # row groups of a few MB, so that a download reads any range of rows in bounded memory
        pq.write_table(table, tmp, row_group_size=row_group_rows(table))
    recording = result.recording_path
    data = {
        "summary": summary_dict(result.summary),
        "steps": int(result.summary.steps),
        "seed": int(result.static.seed),
        "trajectory_path": str(traj),
        "recording_path": str(recording) if recording is not None and Path(recording).is_file() else None,
        "error": error,
    }
    write_json_atomic(out_dir / RESULT_FILE, data)
    return data


def read_result(out_dir: str | Path) -> dict[str, Any] | None:
    """The ``result.json`` an episode's worker wrote, or None."""
    path = Path(out_dir) / RESULT_FILE
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data


def _action_space(a: AgentInfo) -> dict[str, Any]:
    """An agent's action box: ``[v, omega]`` (m/s, rad/s), or ``[v, omega, w_z]`` in the 3-D game."""
    if a.w_z_max is not None:
        return {
            "low": [a.v_min, -a.omega_max, -a.w_z_max],
            "high": [a.v_max, a.omega_max, a.w_z_max],
            "shape": [3],
        }
    return {"low": [a.v_min, -a.omega_max], "high": [a.v_max, a.omega_max], "shape": [2]}


def _progress(step: int, max_steps: int, sim_time: float, started: float) -> dict[str, Any]:
    return {"step": step, "max_steps": max_steps, "t": sim_time, "wall_s": time.perf_counter() - started}


Emit = Callable[[str, dict[str, Any]], None]


def run_job(spec: JobSpec, emit: Emit, should_stop: Callable[[], str | None]) -> dict[str, Any]:
    """Run an episode to its end with every agent on its policy.

    Args:
        spec: The episode (``mode="run"``).
        emit: ``emit(kind, data)`` for ``"static"`` (once), ``"progress"`` and ``"frame"``
            (frame schema) events, at most ``spec.event_hz`` per second plus the first and last.
        should_stop: Polled between steps; returns a reason (``"cancelled"``) to stop, else None.

    Returns:
        What ``result.json`` holds (summary, steps, seed, file paths, error).
    """
    from hptvsim.episodes.runner import run_episode
    from hptvsim.episodes.stepper import SimulationError
    from hptvsim.viz.recording import recorder

    started = time.perf_counter()
    deadline = started + spec.timeout_s
    period = 1.0 / spec.event_hz if spec.event_hz > 0 else math.inf
    state: dict[str, Any] = {"next": 0.0, "max_steps": spec.max_steps, "reason": None, "k": 0}

    def on_static(static: Any) -> None:
        state["max_steps"] = static.max_steps
        state["static"] = static_dict(static)
        emit("static", state["static"])

    def on_frame(frame: Any) -> None:
        now = time.perf_counter()
        if frame.step == 0 or frame.done or now >= state["next"]:
            state["next"] = now + period
            emit("progress", _progress(frame.step, state["max_steps"], frame.time, started))
            emit("frame", frame.to_dict())

    def cancel() -> bool:
        state["k"] += 1
        if state["k"] % 8:
            return False
        reason = should_stop()
        if reason is None and time.perf_counter() > deadline:
            reason = "timeout"
        state["reason"] = reason
        return reason is not None

    try:
        result = run_episode(
            spec.scenario,
            spec.policies,
            seed=spec.seed,
            max_steps=spec.max_steps,
            sensor_fidelity=spec.sensor_fidelity,  # type: ignore[arg-type]  # validated by the API
            backend=spec.backend,  # type: ignore[arg-type]  # validated by the API
            on_static=on_static,
            on_frame=on_frame,
            cancel=cancel,
            recorder=recorder(spec.recording_path),
        )
    except SimulationError as exc:
        if exc.partial is None:
            raise
        message = client_message(exc)  # nothing is lost: the steps before the failure are kept
        files = write_outputs(Path(spec.out_dir), exc.partial, error=message, static=state.get("static"))
        raise JobFailedError(message, files) from exc
    frame = result.final_frame
    emit("progress", _progress(frame.step, state["max_steps"], frame.time, started))
    emit("frame", frame.to_dict())
    reason = state["reason"]
    error = None
    if reason == "timeout":
        error = f"stopped after running longer than {spec.timeout_s:g} s"
    elif reason == "shutdown":
        error = "the service stopped"
    elif reason is not None:
        error = "cancelled by request"
    return write_outputs(Path(spec.out_dir), result, error=error, static=state.get("static"))


class InteractiveEpisode:
    """An episode a client steps: the agents in ``spec.control``, the rest on their policies.

    A controlled agent without a policy in ``spec.policies`` is external: every step must give
    its action. One with a policy (a fallback) follows it in the steps that leave it out.

    Args:
        spec: The episode (``mode="interactive"``).
    """

    def __init__(self, spec: JobSpec) -> None:
        from hptvsim.episodes.stepper import EXTERNAL, EpisodeStepper
        from hptvsim.viz.recording import recorder

        self.spec = spec
        policies = dict(spec.policies)
        for agent in spec.control:
            policies.setdefault(agent, EXTERNAL)
        self.stepper = EpisodeStepper(
            spec.scenario,
            policies,
            seed=spec.seed,
            max_steps=spec.max_steps,
            sensor_fidelity=spec.sensor_fidelity,  # type: ignore[arg-type]  # validated by the API
            backend=spec.backend,  # type: ignore[arg-type]  # validated by the API
            recorder=recorder(spec.recording_path),
        )
        self.control = tuple(spec.control)
        self._must_act = tuple(a for a in self.control if a not in spec.policies)
        self.started = time.perf_counter()
        self._next_frame = 0.0
        unknown = [a for a in self.control if a not in self.stepper.agents]
        if unknown:
            self.stepper.close()
            raise ValueError(f"control: unknown agents {unknown}; agents: {', '.join(self.stepper.agents)}")

    @property
    def done(self) -> bool:
        """Whether the episode is over."""
        return bool(self.stepper.done)

    def observations(self) -> dict[str, list[float]]:
        """The controlled agents' observations (Eq. 14)."""
        obs = self.stepper.observations()
        return {a: obs[a].astype(float).tolist() for a in self.control}

    def state(self) -> dict[str, Any]:
        """Agents, spaces and the controlled agents' observations."""
        static = self.stepper.static
        space = self.stepper.core.observation_space(self.stepper.agents[0])
        low, high = space.low, space.high
        return {
            "agents": list(self.stepper.agents),
            "control": list(self.control),
            "step": int(self.stepper.frame.step),
            "done": self.done,
            "observations": self.observations(),
            "spaces": {
                "observation": {"low": low.tolist(), "high": high.tolist(), "shape": [int(low.size)]},
                "action": {a.name: _action_space(a) for a in static.agents},
            },
        }

    def static(self) -> dict[str, Any]:
        """The frames' static part."""
        return static_dict(self.stepper.static)

    def frame(self) -> dict[str, Any]:
        """The current frame."""
        data: dict[str, Any] = self.stepper.frame.to_dict()
        return data

    def frame_due(self) -> dict[str, Any] | None:
        """The current frame if live views are due one (``spec.event_hz``, and the last), else None."""
        now = time.perf_counter()
        if self.done or now >= self._next_frame:
            self._next_frame = now + (1.0 / self.spec.event_hz if self.spec.event_hz > 0 else math.inf)
            return self.frame()
        return None

    def progress(self) -> dict[str, Any]:
        """Steps out of the limit, simulated and wall time."""
        f = self.stepper.frame
        return _progress(f.step, self.stepper.static.max_steps, f.time, self.started)

    def step(self, actions: dict[str, Any]) -> dict[str, Any]:
        """One step with the controlled agents' ``[v, omega]``.

        Every active controlled agent without a fallback policy must act; one with a fallback
        that ``actions`` leaves out follows its policy in this step.

        Raises:
            ValueError: An agent not controlled by the client, a missing, malformed or
                non-finite action (the message names ``actions.<agent>``).
        """
        for agent in actions:
            if agent not in self.control:
                raise ValueError(
                    f"actions.{agent}: not an agent you control; you control {list(self.control)}"
                )
        frame = self.stepper.frame
        active = {a.name for a in frame.agents if a.active}
        missing = [a for a in self._must_act if a in active and a not in actions]
        if missing:
            shape = "[v, omega, w_z]" if self.stepper.game == "3d" else "[v, omega]"
            raise ValueError(
                f"actions.{missing[0]}: missing; give {shape} for every controlled agent that has "
                "no policy (policies.<agent>)"
            )
        try:
            frame = self.stepper.step({a: v for a, v in actions.items() if a in active})
        except ValueError as exc:
            raise ValueError(f"actions: {exc}") from None
        states = {a.name: a for a in frame.agents}
        return {
            "step": frame.step,
            "t": frame.time,
            "observations": self.observations(),
            "rewards": {a: states[a].reward for a in self.control},
            "terminated": {a: states[a].terminated for a in self.control},
            "truncated": {a: states[a].truncated for a in self.control},
            "infos": {
                a: {
                    "distance": states[a].distance,
                    "min_range": states[a].min_range,
                    "captured": frame.captured,
                    "collision": states[a].collision,
                    "out_of_site": states[a].out_of_site,
                    "reached": states[a].reached,
                    "active": states[a].active,
                }
                for a in self.control
            },
            "done": self.done,
        }

    def finish(self, *, cancel: bool = False, error: str | None = None) -> dict[str, Any]:
        """End the episode (cancelling it if it still runs) and write its files.

        Returns:
            What ``result.json`` holds.
        """
        if cancel and not self.stepper.done:
            self.stepper.cancel()
        result = self.stepper.result()
        self.stepper.close()
        return write_outputs(Path(self.spec.out_dir), result, error=error)
