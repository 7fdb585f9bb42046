"""The IoUT acoustic link: how the pursuers learn where the target is (paper section IV-A).

The paper's IoUT network (surface buoys and seabed sensor nodes) captures the target's position
and reports it to the UUVs by acoustic communication. :class:`AcousticLink` models that report
stream for ``B`` environments x ``P`` pursuers (the model is documented on
:class:`~hptvsim.world.sensor_config.AcousticLinkConfig`):

* every ``report_period`` seconds after a reset (``t_k = k * report_period``, ``k = 0, 1, ...``)
  one report is broadcast, stamped ``t_k``, carrying the target's position at ``t_k`` plus the
  network's localisation error (Gauss-Markov, Eq. 3, one process per environment and axis);
* pursuer ``p`` receives it at ``t_k + distance_p / sound_speed``, the distance being measured
  at ``t_k`` from the transmitter (the target itself, or a gateway buoy) to the pursuer (during
  the flight, at most 0.7 s over a 1 km link, a vehicle moves less than 2 m: ignored), unless the
  packet is lost (probability ``packet_loss``, independently per pursuer and report) or the
  pursuer is beyond ``max_range``;
* each pursuer keeps the newest report it has received (by time stamp): :attr:`position` and
  :attr:`age` (now minus the stamp, so the age includes the propagation delay).

Positions between control steps are interpolated linearly (reports may fall between steps).
With ``enabled = False`` the link is perfect: the pursuers know the target's current position,
with age 0.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from hptvsim.sensors.errors import GaussMarkov, as_generator
from hptvsim.world.sensor_config import AcousticLinkConfig

__all__ = ["MAX_REPORTS_PER_STEP", "AcousticLink", "queue_length", "reports_per_step"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

_EPS_T = 1e-9  # s, tolerance when comparing report times with step times

MAX_REPORTS_PER_STEP = 1000
"""Most reports one control step may send (``dt / report_period``): each is a loop iteration.

The scenario schema's :data:`~hptvsim.world.sensor_config.MIN_REPORT_PERIOD` (0.1 s) with its
largest ``dt`` (10 s) makes at most 100; this bounds the link built with other steps.
"""


def reports_per_step(config: AcousticLinkConfig, dt: float) -> int:
    """Most reports a control step of ``dt`` [s] sends (0 when the link is disabled)."""
    return math.ceil(dt / config.report_period - _EPS_T) if config.enabled else 0


def queue_length(config: AcousticLinkConfig, dt: float) -> int:
    """Reports a pursuer's queue holds: those in flight over the longest propagation delay and a step.

    The link's arrays are ``(envs, pursuers, queue_length)`` times 32 bytes (arrival time, position
    and stamp of each report).
    """
    max_delay = config.max_range / config.sound_speed  # s
    return math.ceil((max_delay + dt) / config.report_period) + 1


class AcousticLink:
    """Target position reports over the acoustic link, for ``B`` environments x ``P`` pursuers.

    Call :meth:`reset` when environments start, then :meth:`step` once per control step with
    the positions at the end of the step.

    Args:
        config: Link settings.
        num_envs: Environments ``B``.
        num_pursuers: Pursuers ``P`` per environment.
        dt: Control step [s] (the time :meth:`step` advances).
        rng: Generator or seed for losses and localisation errors.

    Raises:
        ValueError: Sizes or ``dt`` out of range, or a report period that would send more than
            :data:`MAX_REPORTS_PER_STEP` reports in a step.

    Attributes:
        position: ``(B, P, 2)`` [m], last received target position (NaN before the first).
        age: ``(B, P)`` [s], time since that position was measured (inf before the first).
        time: ``(B,)`` [s], time since each environment's reset.
        sent: ``(B, P)`` reports addressed to each pursuer since reset.
        received: ``(B, P)`` reports each pursuer received since reset.
    """

    def __init__(
        self,
        config: AcousticLinkConfig,
        *,
        num_envs: int,
        num_pursuers: int,
        dt: float,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        if num_envs < 1 or num_pursuers < 1:
            raise ValueError(f"num_envs and num_pursuers must be >= 1, got {num_envs} and {num_pursuers}")
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt = {dt!r} is invalid; valid: a control step > 0 s")
        if reports_per_step(config, dt) > MAX_REPORTS_PER_STEP:
            raise ValueError(
                f"report_period = {config.report_period:g} s would send {dt / config.report_period:.3g} "
                f"reports in every control step of {dt:g} s; valid: report_period >= dt / "
                f"{MAX_REPORTS_PER_STEP} = {dt / MAX_REPORTS_PER_STEP:g} s"
            )
        self.config = config
        self.num_envs, self.num_pursuers, self.dt = int(num_envs), int(num_pursuers), float(dt)
        self.rng = as_generator(rng)
        b, p = self.num_envs, self.num_pursuers
        self.queue_length = queue_length(config, self.dt)
        q = self.queue_length
        self.errors = GaussMarkov(config.position_error, (b, 2), rng=self.rng)
        self.position: F64 = np.full((b, p, 2), np.nan)
        self.stamp: F64 = np.full((b, p), -np.inf)  # s, measurement time of ``position``
        self.age: F64 = np.full((b, p), np.inf)
        self.time: F64 = np.zeros(b)
        self.sent: I64 = np.zeros((b, p), dtype=np.int64)
        self.received: I64 = np.zeros((b, p), dtype=np.int64)
        self._steps: I64 = np.zeros(b, dtype=np.int64)  # control steps since reset (exact time)
        self._next_report: I64 = np.zeros(b, dtype=np.int64)  # index k of the next report
        self._arrival: F64 = np.full((b, p, q), np.inf)  # s, arrival time of queued reports
        self._queued_pos: F64 = np.zeros((b, p, q, 2))
        self._queued_stamp: F64 = np.zeros((b, p, q))
        self._last_target: F64 = np.zeros((b, 2))
        self._last_pursuers: F64 = np.zeros((b, p, 2))
        # earliest report due and earliest arrival over all environments [s]: a step before both
        # has nothing to send or deliver, and skips that work
        self._due_min = 0.0
        self._arrival_min = math.inf
        self._env_index = np.arange(b)[:, None]  # index grids for picking a slot per (env, pursuer)
        self._pursuer_index = np.arange(p)[None, :]

    def _check(self, name: str, a: npt.ArrayLike, shape: tuple[int, ...]) -> F64:
        arr = np.asarray(a, dtype=np.float64)
        if arr.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} holds a non-finite value")
        return arr

    def reset(
        self,
        target_xy: npt.ArrayLike,
        pursuer_xy: npt.ArrayLike,
        index: npt.ArrayLike | None = None,
    ) -> None:
        """Start environments afresh at time 0.

        Args:
            target_xy: ``(B, 2)`` target positions [m] (rows outside ``index`` are ignored).
            pursuer_xy: ``(B, P, 2)`` pursuer positions [m].
            index: Boolean mask or indices of the environments to reset; ``None``: all.
        """
        b, p = self.num_envs, self.num_pursuers
        target = self._check("target_xy", target_xy, (b, 2))
        pursuers = self._check("pursuer_xy", pursuer_xy, (b, p, 2))
        envs = np.arange(b) if index is None else np.arange(b)[np.asarray(index)]
        self.errors.reset(envs)
        self.time[envs] = 0.0
        self._steps[envs] = 0
        self._next_report[envs] = 0
        self._arrival[envs] = np.inf
        self.sent[envs] = 0
        self.received[envs] = 0
        self._last_target[envs] = target[envs]
        self._last_pursuers[envs] = pursuers[envs]
        if not self.config.enabled or self.config.initial_fix:
            self.position[envs] = target[envs][:, None, :]
            self.stamp[envs] = 0.0
        else:
            self.position[envs] = np.nan
            self.stamp[envs] = -np.inf
        if self.config.enabled:
            self._send(envs, np.zeros(envs.size), target[envs], pursuers[envs])
            self._deliver()
        self.age[envs] = self.time[envs][:, None] - self.stamp[envs]
        self._refresh_horizon()

    def _refresh_horizon(self) -> None:
        self._due_min = float(self._next_report.min()) * self.config.report_period
        self._arrival_min = float(self._arrival.min())

    def step(self, target_xy: npt.ArrayLike, pursuer_xy: npt.ArrayLike, *, check: bool = True) -> None:
        """Advance every environment by ``dt``; positions are those at the end of the step.

        Args:
            target_xy: ``(B, 2)`` target positions [m].
            pursuer_xy: ``(B, P, 2)`` pursuer positions [m].
            check: Validate shapes and finiteness (callers that built the arrays may skip it).
        """
        b, p = self.num_envs, self.num_pursuers
        if check:
            target = self._check("target_xy", target_xy, (b, 2))
            pursuers = self._check("pursuer_xy", pursuer_xy, (b, p, 2))
        else:
            target = np.asarray(target_xy, dtype=np.float64)
            pursuers = np.asarray(pursuer_xy, dtype=np.float64)
        self._steps += 1
        np.multiply(self._steps, self.dt, out=self.time)
        if not self.config.enabled:
            self.position[...] = target[:, None, :]
            self.stamp[...] = self.time[:, None]
            self.age[...] = 0.0
            return
        t_max = float(np.maximum.reduce(self.time))  # (the ufunc: no wrapper)
        if t_max + _EPS_T >= self._due_min:
            period = self.config.report_period
            t_prev: F64 = np.multiply(self._steps - 1, self.dt, dtype=np.float64)  # the time before this step
            while True:
                t_k: F64 = self._next_report.astype(np.float64) * period
                due = np.flatnonzero(t_k <= self.time + _EPS_T)
                if due.size == 0:
                    break
                w = np.clip((t_k[due] - t_prev[due]) / self.dt, 0.0, 1.0)  # interpolation weight
                tgt = (1.0 - w)[:, None] * self._last_target[due] + w[:, None] * target[due]
                pur = (1.0 - w)[:, None, None] * self._last_pursuers[due] + w[:, None, None] * pursuers[due]
                self._send(due, t_k[due], tgt, pur)
            self._refresh_horizon()
        np.copyto(self._last_target, target)
        np.copyto(self._last_pursuers, pursuers)
        if t_max + _EPS_T >= self._arrival_min:
            self._deliver()
            self._arrival_min = float(self._arrival.min())
        np.subtract(self.time[:, None], self.stamp, out=self.age)

    def _send(self, envs: I64, t_k: F64, target: F64, pursuers: F64) -> None:
        """Broadcast report ``_next_report[envs]`` sent at ``t_k`` from ``target`` positions."""
        cfg = self.config
        every = envs.size == self.num_envs  # all environments report together (always at B = 1)
        k = self._next_report[envs]
        if every and k.min() > 0:
            self.errors.step(cfg.report_period)
        elif (k > 0).any():  # the bias evolves between consecutive reports (report 0 starts fresh)
            self.errors.step(cfg.report_period, envs[k > 0])
        reported = self.errors.apply(target) if every else self.errors.apply(target, index=envs)
        if cfg.transmitter == "target":
            rel = pursuers - target[:, None, :]
            dist = np.hypot(rel[..., 0], rel[..., 1])
        else:
            bx, by = cfg.buoy_position
            horizontal = np.hypot(pursuers[..., 0] - bx, pursuers[..., 1] - by)
            dist = np.hypot(horizontal, cfg.buoy_vertical_offset)
        lost = (self.rng.random(dist.shape) < cfg.packet_loss) | (dist > cfg.max_range)
        slot = k % self.queue_length
        arrival = np.where(lost, np.inf, t_k[:, None] + dist / cfg.sound_speed)
        self._arrival[envs, :, slot] = arrival
        self._queued_pos[envs, :, slot] = reported[:, None, :]
        self._queued_stamp[envs, :, slot] = t_k[:, None]
        if every:
            self.sent += 1
            self._next_report += 1
        else:
            self.sent[envs] += 1
            self._next_report[envs] += 1

    def _deliver(self) -> None:
        """Hand over every queued report that has arrived; keep the newest per pursuer."""
        arrived = self._arrival <= self.time[:, None, None] + _EPS_T
        if not arrived.any():
            return
        self.received += arrived.sum(axis=2)
        stamps = np.where(arrived, self._queued_stamp, -np.inf)
        best = np.argmax(stamps, axis=2)  # (B, P)
        e, q = self._env_index, self._pursuer_index
        best_stamp = stamps[e, q, best]
        newer = best_stamp > self.stamp
        best_pos = self._queued_pos[e, q, best]
        self.position[newer] = best_pos[newer]
        self.stamp[newer] = best_stamp[newer]
        self._arrival[arrived] = np.inf
