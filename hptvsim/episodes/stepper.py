"""One episode of a scenario, one step at a time, as frames: :class:`EpisodeStepper`.

The stepper plays any game (:class:`~hptvsim.envs.protocol.Game`, built by
:func:`hptvsim.envs.games.make_game` from the scenario's ``[simulation] game``) through the
protocol's members only: it resets and steps the game, asks the zoo for each agent's policy,
turns every step into a :class:`~hptvsim.episodes.frames.Frame`, collects the episode's
:class:`~hptvsim.episodes.frames.Trajectories` and metrics, and hands each frame to a recorder
when one is given (the rerun recording of :mod:`hptvsim.viz.recording`, passed in from above).

Actions from outside and from policies are commands in SI units (the game's
:attr:`~hptvsim.envs.protocol.Game.command_fields`: ``[v, omega]`` [m/s, rad/s], or ``[v, omega,
w_z]`` with the vertical speed [m/s]); the game turns them into its actions
(:meth:`~hptvsim.envs.protocol.Game.to_actions`) and the frames show the commands it applied
(:meth:`~hptvsim.envs.protocol.Game.commands`, clipped to the limits, Eq. 15).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, Protocol

import numpy as np
import numpy.typing as npt

from hptvsim.cosim import trajectory
from hptvsim.cosim.fmi2 import FmuError
from hptvsim.cosim.orchestrator import SimulationFailedError
from hptvsim.envs.games import game_options, make_game
from hptvsim.envs.metrics import EpisodeMetrics
from hptvsim.envs.protocol import Game, Scene, StepResult
from hptvsim.episodes.frames import (
    AgentState,
    AgentTrajectory,
    CollisionEvent,
    EpisodeStatic,
    EpisodeSummary,
    Frame,
    FrameOptions,
    Outcome,
    Point,
    Trajectories,
    TrajectoryBuilder,
    beam_directions,
)
from hptvsim.episodes.scenarios import ScenarioLike, resolve_scenario
from hptvsim.episodes.static import build_static, flavour, policy_specs
from hptvsim.sensors.sonar3d import rotation_zyx
from hptvsim.zoo import load_policy

__all__ = [
    "EXTERNAL",
    "HIT_FRACTION",
    "Backend",
    "EpisodeResult",
    "EpisodeStepper",
    "Recorder",
    "RecorderFactory",
    "SimulationError",
]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

EXTERNAL: Final = "external"
"""Policy spec of an agent whose actions come from outside (:meth:`EpisodeStepper.step`)."""

HIT_FRACTION: Final = 0.98
"""A beam counts as a hit when its measured range is below this fraction of the maximum range
(measured ranges carry noise, so a beam that hits nothing reads about the maximum)."""

Backend = Literal["batched", "fmu"]
"""The simulation backends of the shipped games (:func:`hptvsim.envs.games.make_game`)."""

INITIAL_STEPS: Final = 1024
"""Steps the trajectory arrays reserve at first (they double when full, up to the step limit)."""


class Recorder(Protocol):
    """Writes an episode's frames as they come (e.g. :class:`hptvsim.viz.recording.RecordingWriter`).

    Attributes:
        path: The file it writes (named in the episode's summary).
    """

    path: Path

    def add(self, frame: Frame) -> None:
        """Take the next frame."""
        ...

    def close(self, summary: EpisodeSummary | None = None, paths: dict[str, F64] | None = None) -> None:
        """Finish, with the summary (None: an episode a reset replaced) and every agent's path.

        Args:
            summary: How the episode ended.
            paths: ``{agent: (T, 2) [x, y] or (T, 3) [x, y, z]}`` [m].
        """
        ...


RecorderFactory = Callable[[EpisodeStatic], Recorder]
"""Opens a recorder for an episode, given its static part (called at every reset)."""


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
        """The recording, if one was written."""
        return Path(self.summary.recording) if self.summary.recording else None

    def to_dict(self) -> dict[str, Any]:
        """``{"static", "summary", "trajectories"}`` as plain JSON-ready data."""
        return {
            "static": self.static.to_dict(),
            "summary": self.summary.to_dict(),
            "trajectories": self.trajectories.to_dict(),
        }


class SimulationError(RuntimeError):
    """The simulation failed (a vehicle's state became non-finite, an FMU failed): it cannot go on.

    The message names the step and the agent; it is safe to show to a client. Raised by
    :func:`~hptvsim.episodes.runner.run_episode`, :attr:`partial` holds what ran before the
    failure (summary status ``cancelled``, trajectories up to the last good step), so its files
    can still be written.
    """

    partial: EpisodeResult | None = None


class _Meter:
    """The evaluation's metrics (:class:`~hptvsim.envs.metrics.EpisodeMetrics`), frame by frame.

    The definitions are the trainers' evaluation's (:func:`hptvsim.train.evaluate.run_episode`).
    """

    def __init__(self, pursuer: npt.NDArray[np.bool_], goto: bool) -> None:
        self.pursuer = pursuer
        self.goto = goto
        self.captured_at: int | None = None
        self.collision = False
        self.collisions: list[CollisionEvent] = []
        self._collided: set[str] = set()
        self.distances: list[float] = []
        self.success: dict[str, bool] = {}

    def add(self, frame: Frame) -> None:
        if frame.step == 0:
            return
        if self.captured_at is None and frame.captured:
            self.captured_at = frame.step
        for a in frame.agents:
            if a.collision and a.name not in self._collided:  # its first (it stays in contact)
                self.collision = True
                self._collided.add(a.name)
                self.collisions.append(
                    CollisionEvent(
                        agent=a.name,
                        collided_with=a.collided_with or "",
                        step=frame.step,
                        time=frame.time,
                        x=a.x,
                        y=a.y,
                        z=a.z,
                    )
                )
        d = [a.distance for a, p in zip(frame.agents, self.pursuer, strict=True) if p]
        if not d:
            d = [a.distance for a in frame.agents]
        self.distances.append(min(d))
        if self.goto:
            for a in frame.agents:
                if (a.terminated or a.truncated) and a.name not in self.success:
                    self.success[a.name] = a.reached

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


def _make_game(
    scenario: ScenarioLike,
    *,
    allow_paths: bool,
    backend: str,
    seed: int | None,
    max_steps: int | None,
    sensor_fidelity: str | None,
    game: str | None,
) -> Game:
    """One environment of the scenario's game, or of ``game`` (:func:`hptvsim.envs.games.make_game`)."""
    sc = resolve_scenario(scenario, allow_paths=allow_paths)
    if seed is not None and (not isinstance(seed, int) or seed < 0):
        raise ValueError(f"seed = {seed!r} is invalid; valid: an integer >= 0")
    kind = sc.simulation.game if game is None else game
    takes = game_options(kind)
    options: dict[str, Any] = {"max_steps": max_steps, "seed": seed}
    if sensor_fidelity is not None:
        if takes is None or "sensor_fidelity" in takes:
            options["sensor_fidelity"] = sensor_fidelity
        elif sensor_fidelity != "geometric":
            raise ValueError(
                f"sensor_fidelity = {sensor_fidelity!r} is invalid in the {kind} game; valid: 'geometric'"
            )
    return make_game(sc, num_envs=1, backend=backend, game=game, defaults={"threads": 1}, **options)


class EpisodeStepper:
    """One episode, one step at a time: reset, then step with given actions and policies.

    Args:
        scenario: A shipped scenario's name, a :class:`~hptvsim.world.scenario.Scenario` or
            scenario data (see :func:`~hptvsim.episodes.scenarios.resolve_scenario`); its
            ``[simulation] game`` is the game played.
        policies: ``{agent: zoo spec}``; agents left out follow their role's default
            (:func:`hptvsim.zoo.default_policy_of`); :data:`EXTERNAL` marks agents whose actions
            every :meth:`step` must give.
        seed: Seed of spawn poses, sensor noise and stochastic policies (default: the scenario's).
        max_steps: Step limit (default: the scenario's).
        sensor_fidelity: ``geometric`` or ``signal`` (default: the scenario's; a game without
            the option plays ``geometric`` only).
        backend: ``batched`` or ``fmu``.
        options: What frames carry (:class:`~hptvsim.episodes.frames.FrameOptions`).
        recorder: Opens a recorder at every reset (e.g. :func:`hptvsim.viz.recording.recorder`);
            each frame goes to it as the episode runs.
        allow_paths: Accept scenario file paths (see
            :func:`~hptvsim.episodes.scenarios.resolve_scenario`) and checkpoint files as
            policies (``sb3:PATH``, ``dt:PATH``; see :func:`hptvsim.zoo.load_policy`). Only for a
            local user's own commands: a service never turns it on.
        game: Play this game (a kind of :func:`hptvsim.envs.games.game_kinds`) instead of the
            scenario's ``[simulation] game``.

    The episode starts at construction (as after :meth:`reset`); :attr:`frame` is the current frame.

    Attributes:
        core: The game (:class:`~hptvsim.envs.protocol.Game`, one environment).
        game: The frame flavour, ``planar`` or ``3d`` (:attr:`EpisodeStatic.game`).
        action_size: Values of an agent's command (:attr:`~hptvsim.envs.protocol.Game.command_fields`).

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
        recorder: RecorderFactory | None = None,
        allow_paths: bool = False,
        game: str | None = None,
    ) -> None:
        self.core: Game = _make_game(
            scenario,
            allow_paths=allow_paths,
            backend=backend,
            seed=seed,
            max_steps=max_steps,
            sensor_fidelity=sensor_fidelity,
            game=game,
        )
        core = self.core
        self._scene: Scene = core.scene(0)
        self.game: Literal["planar", "3d"] = flavour(self._scene)
        self.action_size = len(core.command_fields)
        fields = core.command_fields
        self._command_slots = {  # commanded column -> its entry of the action
            col: fields.index(f) for col, f in trajectory.COMMAND_FIELDS.items() if f in fields
        }
        self._columns = tuple(
            c
            for c in AgentTrajectory.COLUMNS
            if (self._scene.vertical or c not in AgentTrajectory.COLUMNS_3D)
            and (c not in trajectory.COMMAND_FIELDS or c in self._command_slots)
        )
        self.seed = int(core.seed)
        self.options = options if options is not None else FrameOptions()
        self.policy_specs = policy_specs(core, policies)
        self.allow_paths = allow_paths
        self._policies: dict[str, Any] = {}
        self._load_policies(self.seed)
        self.static = build_static(
            core, self.policy_specs, options=self.options, seed=self.seed, scene=self._scene
        )
        self._index = {a: i for i, a in enumerate(core.agents)}
        self._recorder_factory = recorder
        self._recorder: Recorder | None = None
        self._recording_path: Path | None = None
        self._started = 0.0
        self._frame: Frame | None = None
        self._trajectory: TrajectoryBuilder | None = None
        self._meter: _Meter | None = None
        self._outcome: Outcome = "running"
        self._cancelled = False
        self._episode_start = True
        self.reset()

    def _load_policies(self, seed: int) -> None:
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

    def observations(self) -> dict[str, F32]:
        """Each agent's current observation (its game's observation layout; planar: Eq. 14)."""
        obs = self.core.obs[0]
        return {a: obs[i].copy() for a, i in self._index.items()}

    # -- driving ---------------------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> Frame:
        """Start a new episode (a new recording replaces the old one) and return its first frame.

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
        core = self.core
        core.reset(seed=self.seed)
        scene = core.scene(0)
        if not _same(scene.goals, self._scene.goals):
            # goals drawn at every reset (the 3-D game's goal depths): the static part names this episode's
            self.static = build_static(
                core, self.policy_specs, options=self.options, seed=self.seed, scene=scene
            )
        self._scene = scene
        self._started = time.perf_counter()
        self._outcome = "running"
        self._cancelled = False
        self._episode_start = True
        self._trajectory = TrajectoryBuilder(
            core.agents, columns=self._columns, capacity=min(INITIAL_STEPS, core.max_steps + 1)
        )
        self._meter = _Meter(core.pursuer, core.goto)
        frame = self._make_frame(None, np.zeros((len(core.agents), self.action_size)))
        if self._recorder_factory is not None:
            self._recorder = self._recorder_factory(self.static)
            self._recording_path = Path(self._recorder.path)
        self._emit(frame)
        return frame

    def policy_actions(self) -> dict[str, F64]:
        """What each agent's policy would command now (agents with :data:`EXTERNAL` left out)."""
        obs = self.core.obs[0]
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
                rad/s, m/s]; the game's :attr:`~hptvsim.envs.protocol.Game.command_fields`) for
                some agents (clipped to their limits, Eq. 15); the others follow their policies.
                Actions of agents that are already done are ignored.

        Raises:
            RuntimeError: The episode is over (call :meth:`reset`).
            ValueError: An unknown agent, a wrong shape, a non-finite value, or a missing action
                of an :data:`EXTERNAL` agent.
            SimulationError: The simulation failed; the episode ends (what ran is kept).
        """
        if self.done:
            raise RuntimeError(f"the episode is over ({self.outcome}); call reset() before step()")
        given = dict(actions or {})
        unknown = sorted(set(given) - set(self._index))
        if unknown:
            raise ValueError(
                f"actions given for unknown agent(s) {unknown}; agents: {', '.join(self.agents)}"
            )
        core = self.core
        active = core.active[0]
        k = self.action_size
        shape = f"[{', '.join(core.command_fields)}]"
        commands = np.zeros((1, len(core.agents), k))
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
                commands[0, i] = arr
            elif agent in from_policy:
                commands[0, i] = from_policy[agent]
        self._episode_start = False
        try:
            act = core.to_actions(commands)
            applied = core.commands(act)[0]
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
        assert self._meter is not None
        ret = self.core.episode_return[0]
        returns = {a: float(ret[i]) for a, i in self._index.items()}
        frame = self.frame
        metrics = self._meter.metrics(self.seed, frame.step, self.core.dt, returns)
        return EpisodeSummary(
            status="cancelled" if self._cancelled or not frame.done else "finished",
            outcome=self.outcome,
            steps=frame.step,
            sim_time=frame.time,
            wall_time=time.perf_counter() - self._started,
            metrics=metrics,
            recording=str(self._recording_path) if self._recording_path is not None else None,
            collisions=tuple(self._meter.collisions),
        )

    def trajectories(self) -> Trajectories:
        """Every agent at every step of the episode so far."""
        assert self._trajectory is not None
        return self._trajectory.build()

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
        assert self._meter is not None
        self._meter.add(frame)
        if self._recorder is not None:
            self._recorder.add(frame)
            if frame.done:
                self._close_recorder(self.summary())

    def _close_recorder(self, summary: EpisodeSummary | None) -> None:
        if self._recorder is not None:
            rec, self._recorder = self._recorder, None
            paths = None
            if self._trajectory is not None:
                traj = self._trajectory.build()
                paths = {
                    a.name: np.column_stack(
                        [np.asarray(a.x), np.asarray(a.y)] + ([np.asarray(a.z)] if a.z is not None else [])
                    )
                    for a in traj.agents
                }
            rec.close(summary, paths=paths)

    def _make_frame(self, result: StepResult | None, applied: F64) -> Frame:
        core = self.core
        n = len(core.agents)
        vertical = self._scene.vertical
        step = int(core.steps[0])
        pose = core.poses[0]
        nu = core.velocity[0]
        ranges = core.ranges[0]
        dist_a = core.distance[0]
        ret_a = core.episode_return[0]
        sonar = self.options.sonar_at(step)
        min_range_a = ranges.min(axis=1)
        columns: dict[str, Any] = {
            "x": pose[:, 0],
            "y": pose[:, 1],
            "psi": pose[:, 5],
            "u": nu[:, 0],
            "v": nu[:, 1],
            "r": nu[:, 5],
            **{col: applied[:, k] for col, k in self._command_slots.items()},
            "distance": dist_a,
            "min_range": min_range_a,
        }
        none: list[float | None] = [None] * n
        z, phi, theta, w, alt = none, none, none, none, none
        if vertical:
            alt_a = core.altitude[0]
            columns.update(
                z=pose[:, 2],
                phi=pose[:, 3],
                theta=pose[:, 4],
                w=nu[:, 2],
                altitude=alt_a,
            )
            z, phi, theta = pose[:, 2].tolist(), pose[:, 3].tolist(), pose[:, 4].tolist()
            w, alt = nu[:, 2].tolist(), alt_a.tolist()
        x, y, yaw = pose[:, 0].tolist(), pose[:, 1].tolist(), pose[:, 5].tolist()
        u, v, r = nu[:, 0].tolist(), nu[:, 1].tolist(), nu[:, 5].tolist()
        dist, ret, active = dist_a.tolist(), ret_a.tolist(), core.active[0].tolist()
        min_range = min_range_a.tolist()
        act = applied.tolist()
        if result is None:
            zeros = np.zeros(n)
            columns.update(reward=zeros, r_C=zeros, r_E1=zeros, r_E2=zeros)
            reward = [0.0] * n
            r_C = r_E1 = r_E2 = reward
            falses = [False] * n
            terminated = truncated = collision = out_of_site = reached = falses
            captured = trunc_all = done = False
            touched: list[str | None] = [None] * n
        else:
            f = result.flags
            columns.update(
                reward=result.reward[0],
                r_C=result.terms.r_C[0],
                r_E1=result.terms.r_E1[0],
                r_E2=result.terms.r_E2[0],
            )
            reward = result.reward[0].tolist()
            r_C = result.terms.r_C[0].tolist()
            r_E1 = result.terms.r_E1[0].tolist()
            r_E2 = result.terms.r_E2[0].tolist()
            terminated = result.terminated[0].tolist()
            truncated = result.truncated[0].tolist()
            collision = f.collision[0].tolist()
            touched = [h or None for h in core.collided_with(result, 0)] if True in collision else [None] * n
            out_of_site = f.out_of_site[0].tolist()
            reached = f.reached[0].tolist()
            captured = bool(f.captured[0])
            trunc_all = bool(f.truncated[0])
            done = bool(result.done[0])
            if done:
                self._outcome = _outcome(captured, collision, out_of_site, reached, trunc_all)
        hits: list[tuple[Point, ...] | None] = [None] * n
        if sonar and self.options.hits:
            scene = self._scene
            if vertical:
                body = beam_directions(self.static.agents[0])  # one beam layout for every agent
                hits = _hit_points_3d(pose, ranges, body, scene.max_range)
            else:
                hits = _hit_points(pose[:, 0:2], pose[:, 5], ranges, scene.beam_azimuth, scene.max_range)
        obs = core.obs[0].tolist() if self.options.obs else None
        assert self._trajectory is not None
        self._trajectory.add(step, step * core.dt, columns, ranges if sonar else None)
        agents = tuple(
            AgentState(
                name=name,
                x=x[i],
                y=y[i],
                psi=yaw[i],
                u=u[i],
                v=v[i],
                r=r[i],
                action=tuple(act[i]),  # two or three commands (command_fields)
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
                collided_with=touched[i],
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


def _same(a: F64 | None, b: F64 | None) -> bool:
    """Whether two optional arrays hold the same values."""
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


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
    (``body``, :func:`~hptvsim.episodes.frames.beam_directions`), turned into NED by the vehicle's
    roll, pitch and yaw.
    """
    rot = rotation_zyx(poses[:, 3], poses[:, 4], poses[:, 5])  # (N, 3, 3)
    out: list[tuple[Point, ...] | None] = []
    for i in range(poses.shape[0]):
        m = ranges[i] < HIT_FRACTION * max_range
        pts = poses[i, 0:3][None, :] + ranges[i, m, None] * (body[m] @ rot[i].T)
        out.append(tuple((q[0], q[1], q[2]) for q in pts.tolist()))
    return out
