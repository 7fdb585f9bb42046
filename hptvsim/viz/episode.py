"""The episode runner: one episode of a scenario with a policy per agent, as frames.

* :func:`run_episode`: play a whole episode (deterministic for a seed, cancellable between steps),
  stream its frames to a callback, write its rerun recording, and return an
  :class:`EpisodeResult` (summary with metrics, trajectories, the recording's path);
* :class:`EpisodeStepper`: the same, one step at a time, with actions given from outside for
  some agents and policies for the rest (the service's interactive stepping and ``RemoteEnv``).

Both only need plain, picklable arguments (a scenario name or dict, policy specs as strings, a
seed), so a service calls them in a worker process; frames reach the parent through
``on_frame`` (e.g. put on a queue) and ``cancel`` may be a ``multiprocessing.Event``.

The scenario's ``simulation.game`` decides the game: ``planar`` (:class:`~hptvsim.envs.core.GameCore`,
actions ``[v, omega]``) or ``3d`` (:class:`~hptvsim.envs.game3d.Game3DCore`, actions
``[v, omega, w_z]``, frames with depth and attitude); both give frames of the one schema
(:mod:`hptvsim.viz.frames`).

Policies are zoo specs (:func:`hptvsim.zoo.load_policy`): ``scripted:pure_pursuit``, a shipped
trained policy's name, ... An agent without a spec follows its role's default
(:func:`hptvsim.zoo.default_policy`: the shipped trained policy of its role where there is one,
else pursuers ``scripted:pure_pursuit``, evaders ``scripted:potential_field``; in the goto task
every agent ``scripted:pure_pursuit``). The spec :data:`EXTERNAL` marks an agent whose actions
must come with every :meth:`EpisodeStepper.step`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, Protocol

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi2 import FmuError
from hptvsim.cosim.orchestrator import SimulationFailedError
from hptvsim.envs.core import Backend, GameCore, StepResult
from hptvsim.envs.game3d import Game3DCore, Step3D
from hptvsim.envs.metrics import EpisodeMetrics
from hptvsim.viz.frames import (
    AgentInfo,
    AgentState,
    EpisodeStatic,
    EpisodeSummary,
    Frame,
    FrameOptions,
    Outcome,
    Point,
    SiteInfo,
    Trajectories,
    agent_color,
    append_state,
    beam_directions,
    empty_columns,
    obstacle_summary,
    terrain_mesh,
    trajectory_of,
)
from hptvsim.world.scenario import Scenario, ScenarioError, list_scenarios, load_scenario, scenario_dir

__all__ = [
    "EXTERNAL",
    "EpisodeResult",
    "EpisodeStepper",
    "SimulationError",
    "build_static",
    "default_policy",
    "resolve_scenario",
    "run_episode",
]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]


class SimulationError(RuntimeError):
    """The simulation failed (a vehicle's state became non-finite, an FMU failed): it cannot go on.

    The message names the step and the agent; it is safe to show to a client. Raised by
    :func:`run_episode`, :attr:`partial` holds what ran before the failure (summary status
    ``cancelled``, trajectories up to the last good step), so its files can still be written.
    """

    partial: EpisodeResult | None = None


EXTERNAL: Final = "external"
"""Policy spec of an agent whose actions come from outside (:meth:`EpisodeStepper.step`)."""

HIT_FRACTION: Final = 0.98
"""A beam counts as a hit when its measured range is below this fraction of the maximum range
(measured ranges carry noise, so a beam that hits nothing reads about the maximum)."""


class _EventLike(Protocol):
    def is_set(self) -> bool: ...


CancelLike = Callable[[], bool] | _EventLike
"""What stops an episode between steps: a callable returning True, or an Event that is set."""

ScenarioLike = str | Scenario | Mapping[str, Any]
"""A shipped scenario's name, a :class:`~hptvsim.world.scenario.Scenario`, or scenario data."""


def resolve_scenario(scenario: ScenarioLike, *, allow_paths: bool = False) -> Scenario:
    """Turn a scenario name, object or dict into a validated :class:`Scenario`.

    Args:
        scenario: A shipped scenario's name, a scenario object, or scenario data (as a parsed
            TOML file; validated by the scenario schema).
        allow_paths: Also accept a path to a TOML file, and terrain files anywhere. Off by
            default: a service must never load a path a client sends (scenario data may only
            name terrain files shipped with the scenarios).

    Raises:
        ScenarioError: Unknown name, a path while paths are not allowed, or invalid data.
    """
    if isinstance(scenario, Scenario):
        sc = scenario
    elif isinstance(scenario, str):
        if not allow_paths and scenario not in list_scenarios():
            raise ScenarioError(
                f"no shipped scenario of that name; shipped scenarios: {', '.join(list_scenarios())}",
                file=scenario,
            )
        sc = load_scenario(scenario)
    elif isinstance(scenario, Mapping):
        sc = Scenario.from_dict(scenario, source="<request>")
    else:
        raise TypeError(
            f"scenario must be a shipped scenario's name, a Scenario or scenario data; got {scenario!r}"
        )
    if not allow_paths:
        path = sc.terrain_path()
        root = scenario_dir().resolve()
        if path is not None and not path.resolve().is_relative_to(root):
            raise ScenarioError(
                f"terrain.path {sc.terrain.path!r} lies outside the shipped scenarios folder; "  # type: ignore[union-attr]  # file terrain has a path
                "only shipped terrain files can be named here",
                file=sc.source,
            )
    return sc


AnyCore = GameCore | Game3DCore
"""The core of either game."""


def game_of(core: AnyCore) -> Literal["planar", "3d"]:
    """Which game ``core`` plays."""
    return "3d" if isinstance(core, Game3DCore) else "planar"


def default_policy(core: AnyCore, agent: str) -> str:
    """The zoo spec an agent follows when none is given (:func:`hptvsim.zoo.default_policy`)."""
    from hptvsim.zoo import default_policy as zoo_default

    role = "pursuer" if core.pursuer[core.agents.index(agent)] else "evader"
    return zoo_default(role, "goto" if core.goto else "pursuit", game_of(core))


def _policy_specs(core: AnyCore, policies: Mapping[str, str] | None) -> dict[str, str]:
    given = dict(policies or {})
    unknown = sorted(set(given) - set(core.agents))
    if unknown:
        raise ValueError(f"policies given for unknown agent(s) {unknown}; agents: {', '.join(core.agents)}")
    for agent, spec in given.items():
        if not isinstance(spec, str) or not spec:
            raise ValueError(f"the policy of {agent} must be a zoo spec (a non-empty string); got {spec!r}")
    return {a: given.get(a, default_policy(core, a)) for a in core.agents}


def build_static(
    core: AnyCore,
    policies: Mapping[str, str],
    *,
    options: FrameOptions | None = None,
    seed: int | None = None,
) -> EpisodeStatic:
    """The static part of the frames of an episode of ``core`` (terrain mesh, obstacles, agents)."""
    opts = options if options is not None else FrameOptions()
    sc = core.scenario
    hm = core.world.heightmap
    obstacles = core.world.obstacles
    counters: dict[str, int] = {}
    agents: list[AgentInfo] = []
    three_d = isinstance(core, Game3DCore)
    if isinstance(core, Game3DCore):
        state_goals, limits = core.goals, core.limits
        beams, elevations = core.layout.azimuth, core.layout.elevation
        max_range, fence, radii = core.layout.max_range, False, core.radii
    else:
        state_goals, limits = core.state.goals, core.robots.limits
        beams, elevations = core.robots.beam_angles, None
        max_range, fence, radii = core.robots.max_range, core.fence, core.robots.radii
    for i, spec in enumerate(sc.agents):
        k = counters.get(spec.role, 0)
        counters[spec.role] = k + 1
        v_min, v_max, om = (float(v) for v in limits[i, :3])
        goal: Point | None = None
        goal_radius = None
        if core.goto and state_goals is not None:
            g = [float(v) for v in state_goals[0, i]]
            goal = (g[0], g[1], g[2]) if three_d else (g[0], g[1])
            goal_radius = float(core.goal_radius[i])
        agents.append(
            AgentInfo(
                name=spec.name,
                role="pursuer" if spec.role == "pursuer" else "evader",
                vehicle_type=spec.vehicle_type,
                policy=policies[spec.name],
                color=agent_color(spec.role, k),
                radius=float(radii[i]),
                v_min=v_min,
                v_max=v_max,
                omega_max=om,
                beam_angles=tuple(float(a) for a in beams),
                max_range=float(max_range),
                goal=goal,
                goal_radius=goal_radius,
                w_z_max=float(limits[i, 3]) if three_d else None,
                beam_elevations=tuple(float(e) for e in elevations) if elevations is not None else None,
            )
        )
    return EpisodeStatic(
        scenario=sc.name,
        description=sc.description,
        task="goto" if core.goto else "pursuit",
        seed=int(core.seed if seed is None else seed),
        dt=float(core.dt),
        max_steps=int(core.max_steps),
        backend=core.backend,
        sensor_fidelity=sc.sensors.sonar.fidelity,
        capture_distance=float(sc.task.target_distance),
        safe_distance=float(sc.task.safe_distance),
        site=SiteInfo(
            size=(float(sc.site.size[0]), float(sc.site.size[1])),
            origin=(float(sc.site.origin[0]), float(sc.site.origin[1])),
            operating_depth=float(sc.site.operating_depth),
        ),
        terrain=terrain_mesh(hm.depth, hm.geometry.extent, max_cells=opts.terrain_cells),
        obstacles=obstacle_summary(
            # the 3-D game has no obstacle map: the seabed (the terrain mesh) is what vehicles hit
            np.zeros_like(obstacles.occupied) if three_d else obstacles.occupied,
            resolution=obstacles.geometry.resolution,
            extent=obstacles.geometry.extent,
            fence=fence,
            max_cells=opts.obstacle_cells,
        ),
        agents=tuple(agents),
        options=opts,
        game=game_of(core),
    )


@dataclass(frozen=True, kw_only=True)
class EpisodeResult:
    """What an episode produced.

    Attributes:
        static: The static part of its frames.
        summary: How it ended, with its metrics and the recording's path.
        trajectories: Every agent at every step (step 0: after reset).
        final_frame: The last frame.
    """

    static: EpisodeStatic
    summary: EpisodeSummary
    trajectories: Trajectories
    final_frame: Frame

    @property
    def metrics(self) -> EpisodeMetrics:
        """The evaluation metrics."""
        return self.summary.metrics

    @property
    def status(self) -> str:
        """``finished`` or ``cancelled``."""
        return self.summary.status

    @property
    def outcome(self) -> Outcome:
        """Why the episode ended."""
        return self.summary.outcome

    @property
    def recording_path(self) -> Path | None:
        """The rerun recording, if one was written."""
        return Path(self.summary.recording) if self.summary.recording else None

    def to_dict(self) -> dict[str, Any]:
        """``{"static", "summary", "trajectories"}`` as plain JSON-ready data."""
        return {
            "static": self.static.to_dict(),
            "summary": self.summary.to_dict(),
            "trajectories": self.trajectories.to_dict(),
        }


class _Columns:
    """Trajectory columns and metric accumulators, filled frame by frame."""

    def __init__(self, names: tuple[str, ...], pursuer: npt.NDArray[np.bool_]) -> None:
        self.names = names
        self.pursuer = pursuer
        self.step: list[int] = []
        self.time: list[float] = []
        self.cols: dict[str, dict[str, list[Any]]] = {n: empty_columns() for n in names}
        self.captured_at: int | None = None
        self.collision = False
        self.distances: list[float] = []
        self.success: dict[str, bool] = {}

    def add(self, frame: Frame, goto: bool) -> None:
        self.step.append(frame.step)
        self.time.append(frame.time)
        for a in frame.agents:
            append_state(self.cols[a.name], a)
        if frame.step == 0:
            return
        # the evaluation's definitions (hptvsim.train.evaluate.run_episode)
        if self.captured_at is None and frame.captured:
            self.captured_at = frame.step
        self.collision = self.collision or any(a.collision for a in frame.agents)
        d = [a.distance for a, p in zip(frame.agents, self.pursuer, strict=True) if p]
        if not d:
            d = [a.distance for a in frame.agents]
        self.distances.append(min(d))
        if goto:
            for a in frame.agents:
                if (a.terminated or a.truncated) and a.name not in self.success:
                    self.success[a.name] = a.reached

    def trajectories(self) -> Trajectories:
        return Trajectories(
            step=tuple(self.step),
            time=tuple(self.time),
            agents=tuple(trajectory_of(n, self.cols[n]) for n in self.names),
        )

    def metrics(self, seed: int, length: int, dt: float, returns: dict[str, float]) -> EpisodeMetrics:
        return EpisodeMetrics(
            seed=seed,
            length=length,
            captured=self.captured_at is not None,
            time_to_capture_steps=self.captured_at,
            time_to_capture_s=self.captured_at * dt if self.captured_at is not None else None,
            collision=self.collision,
            min_distance=min(self.distances) if self.distances else None,
            final_distance=self.distances[-1] if self.distances else None,
            success_rate=float(np.mean(list(self.success.values()))) if self.success else None,
            returns=returns,
        )


def _cancelled(cancel: CancelLike | None) -> bool:
    if cancel is None:
        return False
    is_set = getattr(cancel, "is_set", None)
    if callable(is_set):
        return bool(is_set())
    return bool(cancel())  # type: ignore[operator]  # a callable, the other variant


class EpisodeStepper:
    """One episode, one step at a time: reset, then step with given actions and policies.

    Args:
        scenario: A shipped scenario's name, a :class:`~hptvsim.world.scenario.Scenario` or
            scenario data (see :func:`resolve_scenario`).
        policies: ``{agent: zoo spec}``; agents left out follow their role's default;
            :data:`EXTERNAL` marks agents whose actions every :meth:`step` must give.
        seed: Seed of spawn poses, sensor noise and stochastic policies (default: the scenario's).
        max_steps: Step limit (default: the scenario's).
        sensor_fidelity: ``geometric`` or ``signal`` (default: the scenario's).
        backend: ``batched`` or ``fmu``.
        options: What frames carry (:class:`~hptvsim.viz.frames.FrameOptions`).
        recording_path: Write a rerun recording (``.rrd``) here as the episode runs.
        recording_options: What the recording holds (:class:`~hptvsim.viz.recording.RecordingOptions`).
        allow_paths: Accept scenario file paths (see :func:`resolve_scenario`) and checkpoint
            files as policies (``sb3:PATH``, ``dt:PATH``; see :func:`hptvsim.zoo.load_policy`).
            Only for a local user's own commands: a service never turns it on.

    The episode starts at construction (as after :meth:`reset`); :attr:`frame` is the current frame.

    Raises:
        ValueError: Unknown agents or policies, bad settings (the message names them).
        ScenarioError: An unknown or invalid scenario.
    """

    def __init__(
        self,
        scenario: ScenarioLike,
        policies: Mapping[str, str] | None = None,
        *,
        seed: int | None = None,
        max_steps: int | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        backend: Backend = "batched",
        options: FrameOptions | None = None,
        recording_path: str | Path | None = None,
        recording_options: Any = None,
        allow_paths: bool = False,
    ) -> None:
        sc = resolve_scenario(scenario, allow_paths=allow_paths)
        if seed is not None and (not isinstance(seed, int) or seed < 0):
            raise ValueError(f"seed = {seed!r} is invalid; valid: an integer >= 0")
        self.core: AnyCore
        if sc.simulation.game == "3d":
            if sensor_fidelity not in (None, "geometric"):
                raise ValueError(
                    f"sensor_fidelity = {sensor_fidelity!r} is invalid in the 3-D game; valid: 'geometric'"
                )
            self.core = Game3DCore(sc, num_envs=1, backend=backend, max_steps=max_steps, seed=seed, threads=1)
        else:
            self.core = GameCore(
                sc,
                num_envs=1,
                backend=backend,
                sensor_fidelity=sensor_fidelity,
                max_steps=max_steps,
                seed=seed,
                threads=1,
            )
        self.game = game_of(self.core)
        self.action_size = 3 if self.game == "3d" else 2
        self.seed = int(self.core.seed)
        self.options = options if options is not None else FrameOptions()
        self.policy_specs = _policy_specs(self.core, policies)
        self.allow_paths = allow_paths
        self._policies: dict[str, Any] = {}
        self._load_policies(self.seed)
        self.static = build_static(self.core, self.policy_specs, options=self.options, seed=self.seed)
        self._index = {a: i for i, a in enumerate(self.core.agents)}
        self._recording_path = Path(recording_path) if recording_path is not None else None
        self._recording_options = recording_options
        self._recorder: Any = None
        self._started = 0.0
        self._frame: Frame | None = None
        self._columns: _Columns | None = None
        self._outcome: Outcome = "running"
        self._cancelled = False
        self._episode_start = True
        self.reset()

    def _load_policies(self, seed: int) -> None:
        from hptvsim.zoo import load_policy

        for i, agent in enumerate(self.core.agents):
            spec = self.policy_specs[agent]
            if spec != EXTERNAL:
                self._policies[agent] = load_policy(
                    spec, self.core, agent, seed=seed + i, allow_paths=self.allow_paths
                )

    # -- state -----------------------------------------------------------------------------------

    @property
    def agents(self) -> tuple[str, ...]:
        """Agent names, in frame order."""
        return self.core.agents

    @property
    def frame(self) -> Frame:
        """The current frame."""
        assert self._frame is not None
        return self._frame

    @property
    def done(self) -> bool:
        """Whether the episode is over (ended, truncated or cancelled)."""
        return self.frame.done or self._cancelled

    @property
    def outcome(self) -> Outcome:
        """Why the episode ended (``running`` until it does)."""
        return "cancelled" if self._cancelled else self._outcome

    def _obs(self) -> F32:
        core = self.core
        obs: F32 = core.obs[0] if isinstance(core, Game3DCore) else core.state.obs[0]
        return obs

    def _active(self) -> npt.NDArray[np.bool_]:
        core = self.core
        active: npt.NDArray[np.bool_] = (
            core.active[0] if isinstance(core, Game3DCore) else core.state.active[0]
        )
        return active

    def _returns(self) -> F64:
        core = self.core
        ret: F64 = core.episode_return[0] if isinstance(core, Game3DCore) else core.state.episode_return[0]
        return ret

    def observations(self) -> dict[str, F32]:
        """Each agent's current observation (Eq. 14; 3-D game: :class:`~hptvsim.envs.game3d.Obs3DLayout`)."""
        obs = self._obs()
        return {a: obs[i].copy() for a, i in self._index.items()}

    # -- driving ---------------------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> Frame:
        """Start a new episode (a new recording file replaces the old one) and return its first frame.

        Args:
            seed: A new seed (default: the stepper's seed, so a reset replays the same episode).
        """
        if seed is not None:
            if not isinstance(seed, int) or seed < 0:
                raise ValueError(f"seed = {seed!r} is invalid; valid: an integer >= 0")
            self.seed = seed
            if self.static.seed != seed:
                self.static = build_static(self.core, self.policy_specs, options=self.options, seed=seed)
            self._load_policies(seed)
        self._close_recorder(None)
        self.core.reset(seed=self.seed)
        core = self.core
        if isinstance(core, Game3DCore) and any(lo < hi for lo, hi in core.goal_depth_ranges):
            # goal depths are drawn at every reset: the static part names this episode's
            self.static = build_static(core, self.policy_specs, options=self.options, seed=self.seed)
        self._started = time.perf_counter()
        self._outcome = "running"
        self._cancelled = False
        self._episode_start = True
        self._columns = _Columns(self.core.agents, self.core.pursuer)
        zeros = np.zeros((self.core.num_agents, self.action_size))
        frame = self._make_frame(None, zeros)
        if self._recording_path is not None:
            from hptvsim.viz.recording import RecordingWriter

            self._recorder = RecordingWriter(
                self._recording_path, self.static, options=self._recording_options
            )
        self._emit(frame)
        return frame

    def policy_actions(self) -> dict[str, F64]:
        """What each agent's policy would do now (agents with :data:`EXTERNAL` left out)."""
        obs = self._obs()
        start = np.array([self._episode_start])
        k = self.action_size
        return {
            agent: np.asarray(pol.act(obs[self._index[agent]][None], start), dtype=np.float64).reshape(k)
            for agent, pol in self._policies.items()
        }

    def step(self, actions: Mapping[str, npt.ArrayLike] | None = None) -> Frame:
        """Advance one control step and return its frame.

        Args:
            actions: ``{agent: [v, omega]}`` [m/s, rad/s] (3-D game: ``[v, omega, w_z]`` [m/s,
                rad/s, m/s]) for some agents (clipped to their limits, Eq. 15); the others follow
                their policies. Actions of agents that are already done are ignored.

        Raises:
            RuntimeError: The episode is over (call :meth:`reset`).
            ValueError: An unknown agent, a wrong shape, a non-finite value, or a missing action
                of an :data:`EXTERNAL` agent.
        """
        if self.done:
            raise RuntimeError(f"the episode is over ({self.outcome}); call reset() before step()")
        given = dict(actions or {})
        unknown = sorted(set(given) - set(self._index))
        if unknown:
            raise ValueError(
                f"actions given for unknown agent(s) {unknown}; agents: {', '.join(self.agents)}"
            )
        active = self._active()
        k = self.action_size
        shape = "[v, omega, w_z]" if k == 3 else "[v, omega]"
        act = np.zeros((1, self.core.num_agents, k))
        missing = [
            a for a in self.agents if a not in given and a not in self._policies and active[self._index[a]]
        ]
        if missing:
            raise ValueError(f"no action given for {', '.join(missing)} (policy {EXTERNAL!r})")
        from_policy = self.policy_actions()
        for agent, i in self._index.items():
            if agent in given:
                arr = np.asarray(given[agent], dtype=np.float64)
                if arr.shape != (k,):
                    raise ValueError(
                        f"the action of {agent} must be {shape} (shape ({k},)); got shape {arr.shape}"
                    )
                if not np.isfinite(arr).all():
                    raise ValueError(f"the action of {agent} is not finite: {arr.tolist()}")
                act[0, i] = arr
            elif agent in from_policy:
                act[0, i] = from_policy[agent]
        self._episode_start = False
        core = self.core
        result: StepResult | Step3D
        try:
            if isinstance(core, Game3DCore):
                normalised = core.normalised(act)
                applied = core.commands(normalised)[0]
                applied[~active] = 0.0
                result = core.step(normalised)
            else:
                applied = core.robots.clip(act)[0]
                applied[~active] = 0.0
                result = core.step(act)
        except (SimulationFailedError, FmuError) as exc:  # it cannot go on: end it, keep what ran
            self._cancelled = True
            self._close_recorder(self.summary())  # the recording says how far it got
            reason = str(exc).split("; reset", 1)[0]
            raise SimulationError(
                f"the simulation failed at step {self.frame.step + 1}: {reason} "
                "(look at the scenario's currents, vehicle parameters and h_max)"
            ) from None
        frame = self._make_frame(result, applied)
        self._emit(frame)
        return frame

    def cancel(self) -> None:
        """End the episode now (outcome ``cancelled``)."""
        if not self.done:
            self._cancelled = True
            self._close_recorder(self.summary())

    # -- results ---------------------------------------------------------------------------------

    def summary(self) -> EpisodeSummary:
        """The summary so far: status ``finished`` once the episode ended, ``cancelled`` before."""
        assert self._columns is not None
        ret = self._returns()
        returns = {a: float(ret[i]) for a, i in self._index.items()}
        frame = self.frame
        metrics = self._columns.metrics(self.seed, frame.step, self.core.dt, returns)
        return EpisodeSummary(
            status="cancelled" if self._cancelled or not frame.done else "finished",
            outcome=self.outcome,
            steps=frame.step,
            sim_time=frame.time,
            wall_time=time.perf_counter() - self._started,
            metrics=metrics,
            recording=str(self._recording_path) if self._recording_path is not None else None,
        )

    def trajectories(self) -> Trajectories:
        """Every agent at every step of the episode so far."""
        assert self._columns is not None
        return self._columns.trajectories()

    def result(self) -> EpisodeResult:
        """Summary, trajectories and the last frame of the episode so far."""
        return EpisodeResult(
            static=self.static,
            summary=self.summary(),
            trajectories=self.trajectories(),
            final_frame=self.frame,
        )

    def close(self) -> None:
        """Finish the recording and release the simulation."""
        if self._recorder is not None:
            self._close_recorder(self.summary())
        self.core.close()

    def __enter__(self) -> EpisodeStepper:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------------

    def _emit(self, frame: Frame) -> None:
        self._frame = frame
        assert self._columns is not None
        self._columns.add(frame, self.core.goto)
        if self._recorder is not None:
            self._recorder.add(frame)
            if frame.done:
                self._close_recorder(self.summary())

    def _close_recorder(self, summary: EpisodeSummary | None) -> None:
        if self._recorder is not None:
            rec, self._recorder = self._recorder, None
            paths = None
            if self._columns is not None:
                cols = self._columns.cols
                keys = ("x", "y", "z") if self.game == "3d" else ("x", "y")
                paths = {a: np.column_stack([cols[a][c] for c in keys]) for a in self.agents}
            rec.close(summary, paths=paths)

    def _make_frame(self, result: StepResult | Step3D | None, applied: F64) -> Frame:
        core = self.core
        n = core.num_agents
        none: list[float | None] = [None] * n
        z, phi, theta, w, alt = none, none, none, none, none
        hits: list[tuple[Point, ...] | None] = [None] * n
        if isinstance(core, Game3DCore):
            step = int(core.steps[0])
            pose = core.poses[0]
            nu = core.velocity[0]
            pos = pose[:, 0:2].tolist()
            yaw = pose[:, 5].tolist()
            vel = nu[:, [0, 1, 5]].tolist()
            z, phi, theta = pose[:, 2].tolist(), pose[:, 3].tolist(), pose[:, 4].tolist()
            w, alt = nu[:, 2].tolist(), core.altitude[0].tolist()
            dist = core.distance[0].tolist()
            ranges = core.ranges[0]
            ret = core.episode_return[0].tolist()
            active = core.active[0].tolist()
        else:
            s = core.state
            step = int(s.steps[0])
            pos = s.positions[0].tolist()
            yaw = s.yaw[0].tolist()
            vel = s.velocity[0].tolist()
            dist = s.distance[0].tolist()
            ranges = s.ranges[0]
            ret = s.episode_return[0].tolist()
            active = s.active[0].tolist()
        min_range = ranges.min(axis=1).tolist()
        act = applied.tolist()
        sonar = self.options.sonar_at(step)
        if result is None:
            reward = [0.0] * n
            r_C = r_E1 = r_E2 = reward
            falses = [False] * n
            terminated = truncated = collision = out_of_site = reached = falses
            captured = trunc_all = done = False
        else:
            f = result.flags
            reward = result.reward[0].tolist()
            r_C = result.terms.r_C[0].tolist()
            r_E1 = result.terms.r_E1[0].tolist()
            r_E2 = result.terms.r_E2[0].tolist()
            terminated = result.terminated[0].tolist()
            truncated = result.truncated[0].tolist()
            collision = f.collision[0].tolist()
            out_of_site = f.out_of_site[0].tolist()
            reached = f.reached[0].tolist()
            captured = bool(f.captured[0])
            trunc_all = bool(f.truncated[0])
            done = bool(result.done[0])
            if done:
                self._outcome = _outcome(captured, collision, out_of_site, reached, trunc_all)
        if sonar and self.options.hits:
            if isinstance(core, Game3DCore):
                body = beam_directions(self.static.agents[0])  # one beam layout for every agent
                hits = _hit_points_3d(core.poses[0], ranges, body, core.layout.max_range)
            else:
                hits = _hit_points(
                    core.state.positions[0],
                    core.state.yaw[0],
                    ranges,
                    core.robots.beam_angles,
                    core.robots.max_range,
                )
        obs = self._obs().tolist() if self.options.obs else None
        agents = tuple(
            AgentState(
                name=name,
                x=pos[i][0],
                y=pos[i][1],
                psi=yaw[i],
                u=vel[i][0],
                v=vel[i][1],
                r=vel[i][2],
                action=(act[i][0], act[i][1], act[i][2]) if self.action_size == 3 else (act[i][0], act[i][1]),
                reward=reward[i],
                episode_return=ret[i],
                r_C=r_C[i],
                r_E1=r_E1[i],
                r_E2=r_E2[i],
                distance=dist[i],
                min_range=min_range[i],
                ranges=tuple(ranges[i].tolist()) if sonar else None,
                hits=hits[i],
                obs=tuple(obs[i]) if obs is not None else None,
                active=active[i],
                terminated=terminated[i],
                truncated=truncated[i],
                collision=collision[i],
                out_of_site=out_of_site[i],
                reached=reached[i],
                z=z[i],
                phi=phi[i],
                theta=theta[i],
                w=w[i],
                altitude=alt[i],
            )
            for i, name in enumerate(core.agents)
        )
        return Frame(
            step=step,
            time=step * core.dt,
            agents=agents,
            captured=captured,
            truncated=trunc_all,
            done=done,
            outcome=self._outcome,
        )


def _outcome(
    captured: bool, collision: list[bool], out_of_site: list[bool], reached: list[bool], truncated: bool
) -> Outcome:
    if captured:
        return "captured"
    if any(collision):
        return "collision"
    if any(out_of_site):
        return "out_of_site"
    if truncated:
        return "truncated"
    if any(reached):
        return "reached"
    return "truncated"


def _hit_points(
    positions: F64, yaw: F64, ranges: F64, beam_angles: F64, max_range: float
) -> list[tuple[Point, ...] | None]:
    """Points where each agent's beams returned an echo, ``(x, y)`` [m]."""
    ang = yaw[:, None] + beam_angles[None, :]
    hx = positions[:, 0:1] + ranges * np.cos(ang)
    hy = positions[:, 1:2] + ranges * np.sin(ang)
    hit = ranges < HIT_FRACTION * max_range
    out: list[tuple[Point, ...] | None] = []
    for i in range(positions.shape[0]):
        m = hit[i]
        out.append(tuple(zip(hx[i, m].tolist(), hy[i, m].tolist(), strict=True)))
    return out


def _hit_points_3d(poses: F64, ranges: F64, body: F64, max_range: float) -> list[tuple[Point, ...] | None]:
    """Points where each agent's 3-D beams returned an echo, ``(x, y, z)`` [m].

    The beams are those of :class:`~hptvsim.sensors.sonar3d.Sonar3d`: fixed in the body frame
    (``body``, :func:`~hptvsim.viz.frames.beam_directions`), turned into NED by the vehicle's
    roll, pitch and yaw.
    """
    from hptvsim.sensors.sonar3d import rotation_zyx

    rot = rotation_zyx(poses[:, 3], poses[:, 4], poses[:, 5])  # (N, 3, 3)
    out: list[tuple[Point, ...] | None] = []
    for i in range(poses.shape[0]):
        m = ranges[i] < HIT_FRACTION * max_range
        pts = poses[i, 0:3][None, :] + ranges[i, m, None] * (body[m] @ rot[i].T)
        out.append(tuple((q[0], q[1], q[2]) for q in pts.tolist()))
    return out


def run_episode(
    scenario: ScenarioLike,
    policies: Mapping[str, str] | None = None,
    seed: int | None = None,
    max_steps: int | None = None,
    sensor_fidelity: Literal["geometric", "signal"] | None = None,
    backend: Backend = "batched",
    *,
    on_static: Callable[[EpisodeStatic], None] | None = None,
    on_frame: Callable[[Frame], None] | None = None,
    cancel: CancelLike | None = None,
    recording_path: str | Path | None = None,
    options: FrameOptions | None = None,
    recording_options: Any = None,
    progress: bool = False,
    allow_paths: bool = False,
) -> EpisodeResult:
    """Play one episode and return its summary, metrics, trajectories and recording path.

    Deterministic: the same arguments give the same frames, bit for bit.

    Args:
        scenario: A shipped scenario's name, a Scenario or scenario data (:func:`resolve_scenario`).
        policies: ``{agent: zoo spec}``; agents left out follow their role's default.
        seed: Seed of spawn poses, sensor noise and stochastic policies (default: the scenario's).
        max_steps: Step limit (default: the scenario's).
        sensor_fidelity: ``geometric`` or ``signal`` (default: the scenario's).
        backend: ``batched`` or ``fmu``.
        on_static: Called once with the static part, before the first frame.
        on_frame: Called with every frame, from the reset frame (step 0) to the last.
        cancel: Checked before every step; when it reports True the episode stops with status
            ``cancelled``. A callable or anything with ``is_set()`` (threading/multiprocessing Event).
        recording_path: Write the rerun recording here (``.rrd``), as the episode runs.
        options: What frames carry (:class:`~hptvsim.viz.frames.FrameOptions`).
        recording_options: What the recording holds (:class:`~hptvsim.viz.recording.RecordingOptions`).
        progress: Show a progress bar.
        allow_paths: Accept scenario and checkpoint file paths (see :class:`EpisodeStepper`).

    Raises:
        ValueError: Unknown agents or policies, or bad settings (the message names them).
        ScenarioError: An unknown or invalid scenario.
        Exception: Whatever a callback raises (the recording is finished first).
    """
    if any(a == EXTERNAL for a in (policies or {}).values()):
        raise ValueError(f"run_episode needs a policy for every agent; {EXTERNAL!r} is for EpisodeStepper")
    stepper = EpisodeStepper(
        scenario,
        policies,
        seed=seed,
        max_steps=max_steps,
        sensor_fidelity=sensor_fidelity,
        backend=backend,
        options=options,
        recording_path=recording_path,
        recording_options=recording_options,
        allow_paths=allow_paths,
    )
    bar: Any = None
    try:
        if on_static is not None:
            on_static(stepper.static)
        if on_frame is not None:
            on_frame(stepper.frame)
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=stepper.static.max_steps, desc=f"episode {stepper.static.scenario}", unit="step")
        while not stepper.done:
            if _cancelled(cancel):
                stepper.cancel()
                break
            try:
                frame = stepper.step()
            except SimulationError as exc:
                exc.partial = stepper.result()  # what ran, for the caller to keep
                raise
            if bar is not None:
                bar.update(1)
            if on_frame is not None:
                on_frame(frame)
        return stepper.result()
    finally:
        if bar is not None:
            bar.close()
        stepper.close()
