"""The sonar as the environments use it: ranges at the configured fidelity, plus Eq. 3 errors.

:class:`Sonar` puts the pieces of this package together: the geometric ray casts
(:class:`~hptvsim.sensors.sonar.GeometricSonar`), or at signal level the matched filter over
them (:class:`~hptvsim.sensors.signal.SignalSonar`), then the Gauss-Markov errors
(:class:`~hptvsim.sensors.errors.GaussMarkov`), fused with the clip and the no-echo rule into one
C pass (``errors_kernel.c``) where the C backend is in use. It sits above both fidelities, so
neither imports the other's user.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

from hptvsim.native import load_library
from hptvsim.sensors.errors import GaussMarkov, as_generator
from hptvsim.sensors.sonar import _CFLAGS, GeometricSonar, named_pool
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.sensor_config import GaussMarkovConfig, SonarConfig

if TYPE_CHECKING:
    from hptvsim.sensors.signal import SignalSonar  # scipy: imported where the signal level is used

__all__ = ["FusedRangeErrors", "Sonar", "measure_into", "measure_rows"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]


OVERLAP_MIN_DRAWS = 65536
"""Normals per measurement from which :meth:`FusedRangeErrors.start_drawing` draws on a thread
(below it the hand-off costs more than it saves)."""


def _draw_pool() -> ThreadPoolExecutor:
    """One worker that draws the sonars' normals beside their ray casts (its own, not the casts')."""
    return named_pool("sonar-normals", 1)


def _declare(lib: ctypes.CDLL) -> None:
    f = lib.hptv_gm_ranges
    f.restype = None
    pointers, doubles, flags = [ctypes.c_void_p] * 3, [ctypes.c_double] * 4, [ctypes.c_int64] * 3
    f.argtypes = [ctypes.c_int64, *pointers, *doubles, *flags, ctypes.c_void_p]


def _errors_kernel() -> ctypes.CDLL:
    """The fused Gauss-Markov kernel (``errors_kernel.c``), compiled, loaded and typed once."""
    source = Path(__file__).with_name("errors_kernel.c")
    return load_library(source, flags=_CFLAGS, declare=_declare, what="the sonar error kernel")


class FusedRangeErrors:
    """Eq. 3's errors, the clip and the no-echo rule over a sonar's ranges in one C pass.

    The pass is ``errors_kernel.c``; it gives the numpy path's numbers, its normals drawn from
    the generator in the same order (bias drive, then white noise). Every sonar with the C
    backend (the planar :class:`Sonar`, the 3-D :class:`~hptvsim.sensors.sonar3d.Sonar3d`) runs
    it.

    Args:
        errors_config: The sonar's error settings (Eq. 3).
        max_range: The sonar's range [m]: measurements are clipped to ``[0, max_range]``, and a
            beam without an echo reads ``max_range``.
        errors: The sonar's error state (its biases are advanced in place).
        shape: The ranges' shape.
    """

    def __init__(
        self,
        errors_config: GaussMarkovConfig,
        max_range: float,
        errors: GaussMarkov,
        shape: tuple[int, ...],
    ) -> None:
        self.errors_config, self.max_range, self.shape = errors_config, max_range, shape
        self._gm = _errors_kernel().hptv_gm_ranges
        self._z: F64 = np.empty(0)  # the step's normals
        self._z_ptr = self._z.ctypes.data
        self._bias_ptr = errors.bias.ctypes.data  # GaussMarkov updates its bias in place
        self._out_ptr: tuple[F64 | None, int] = (None, 0)  # the last caller buffer and its address
        self._dt = math.nan
        self._coef = (1.0, 0.0)  # the AR(1) coefficients of the last dt
        self._pending: tuple[Future[F64], np.random.Generator, int, Mapping[str, Any]] | None = None

    def _draws(self, n: int) -> int:
        cfg = self.errors_config
        return (int(cfg.bias_std != 0.0) + int(cfg.noise_std > 0.0)) * n

    def start_drawing(self, n: int, rng: np.random.Generator) -> None:
        """Begin drawing the normals of the next measurement of ``n`` ranges on a worker thread.

        The caller casts its rays meanwhile (C code, the GIL released), and the next call then
        waits for the normals instead of drawing them: the same numbers from the same generator in
        the same order, with the draws (about 10 ns each) beside the ray casts rather than after
        them. Nothing else may draw from ``rng`` in between. Small batches draw in the call.

        Args:
            n: How many ranges the next call measures.
            rng: The generator it will be given.
        """
        draws = self._draws(n)
        if draws < OVERLAP_MIN_DRAWS or self._pending is not None:
            return
        if self._z.size != draws:
            self._z = np.empty(draws)
            self._z_ptr = self._z.ctypes.data
        state = rng.bit_generator.state  # for cancel_drawing
        self._pending = (_draw_pool().submit(rng.standard_normal, out=self._z), rng, draws, state)

    def cancel_drawing(self) -> None:
        """Undo :meth:`start_drawing` (the caller failed before measuring): the generator is put back."""
        pending, self._pending = self._pending, None
        if pending is not None:
            future, rng, _, state = pending
            future.result()
            rng.bit_generator.state = state

    def __call__(
        self,
        src_ptr: int,
        n: int,
        dt: float,
        rng: np.random.Generator,
        out: F64 | None,
        *,
        bias: F64 | None = None,
    ) -> F64:
        """The measured ranges of the ``n`` true ranges at address ``src_ptr`` (float64, C order).

        Args:
            src_ptr: Address of the true ranges.
            n: How many.
            dt: Time since the last measurement [s] (the biases advance by it).
            rng: The sonar's generator now (the one the numpy path would draw from; a reset with
                a seed replaces it).
            out: A C-contiguous float64 array of :attr:`shape` to write into (default: a new one);
                with ``bias``, one of ``n`` values (required).
            bias: Some rows' biases, ``n`` C-contiguous values advanced in place instead of the
                sonar's own (:func:`measure_rows`).

        Raises:
            ValueError: ``dt`` is negative or not finite.
        """
        cfg = self.errors_config
        if dt != self._dt:
            if not (dt >= 0.0 and math.isfinite(dt)):
                raise ValueError(f"dt = {dt!r} is invalid; valid: a finite time step >= 0 s")
            phi = math.exp(-dt / cfg.tau)
            w_std = cfg.bias_std * math.sqrt(-math.expm1(-2.0 * dt / cfg.tau))
            self._coef = (phi, w_std)
            self._dt = dt
        if bias is not None and (out is None or out.size != n or bias.size != n):
            raise ValueError(f"with bias, out and bias must hold the {n} ranges' values")
        step_bias = cfg.bias_std != 0.0
        add_noise = cfg.noise_std > 0.0
        draws = self._draws(n)
        pending, self._pending = self._pending, None
        if pending is not None:
            future, drawn_from, drawn, state = pending
            future.result()
            if drawn_from is not rng or drawn != draws:  # not the draws this call needs: undo them
                drawn_from.bit_generator.state = state
                pending = None
        if pending is None:
            if self._z.size != draws:
                self._z = np.empty(draws)
                self._z_ptr = self._z.ctypes.data
            if draws:
                rng.standard_normal(out=self._z)
        bias_ptr = self._bias_ptr if bias is None else bias.ctypes.data
        if bias is not None and out is not None:
            out_ptr = out.ctypes.data
        elif out is None:
            out = np.empty(self.shape)
            out_ptr = out.ctypes.data
        else:  # a caller's buffer, usually the same one every step: its address is remembered
            if self._out_ptr[0] is not out:
                self._out_ptr = (out, out.ctypes.data)
            out_ptr = self._out_ptr[1]
        phi, w_std = self._coef
        self._gm(
            n, src_ptr, bias_ptr, self._z_ptr, phi, w_std, cfg.noise_std, self.max_range,
            int(step_bias), int(cfg.bias_std > 0.0), int(add_noise), out_ptr,
        )  # fmt: skip
        return out


def measure_rows(
    truth: F64,
    dt: float,
    envs: npt.NDArray[np.intp],
    *,
    errors: GaussMarkov,
    fused: FusedRangeErrors | None,
    max_range: float,
) -> F64:
    """Eq. 3 over the true ranges of some environments only: their measured ranges.

    Only those environments' biases advance by ``dt`` and only their normals are drawn, in the
    order of a whole-batch measurement (the bias drive of every row, then the white noise), so
    the C pass and the numpy path agree here as they do for the whole batch. Resets use it: a
    game that restarts a few of its environments senses those, not all ``B``.

    Args:
        truth: ``(m, ...)`` true ranges [m] of the environments ``envs``, in their order.
        dt: Time since those environments' last measurement [s].
        envs: ``(m,)`` distinct environment indices (rows of ``errors.bias``).
        errors: The sonar's error state.
        fused: The sonar's fused C pass, or ``None`` (the numpy path).
        max_range: The sonar's range [m] (clip and no-echo rule).
    """
    if not errors.config.active:
        return truth.copy()
    if fused is not None:
        src = np.ascontiguousarray(truth, dtype=np.float64)
        bias = np.ascontiguousarray(errors.bias[envs])
        out = np.empty_like(src)
        fused(src.ctypes.data, src.size, dt, errors.rng, out, bias=bias)
        errors.bias[envs] = bias
        return out
    errors.step(dt, envs)
    noisy = errors.apply(truth, index=envs)
    np.clip(noisy, 0.0, max_range, out=noisy)
    result: F64 = np.where(truth < max_range, noisy, max_range)
    return result


def measure_into(
    out: F64 | None,
    dt: float,
    envs: npt.ArrayLike,
    truth: Callable[[npt.NDArray[np.intp], Bool | None], F64],
    *,
    active: npt.ArrayLike | None,
    shape: tuple[int, ...],
    errors: GaussMarkov,
    fused: FusedRangeErrors | None,
    max_range: float,
) -> F64:
    """A sonar's ``measure(..., envs=...)``: the rows ``envs`` of ``out`` measured, the rest kept.

    Args:
        out: The sonar's ``(B, ...)`` float64 output, or ``None`` (a new one, NaN outside ``envs``).
        dt: Time since those environments' last measurement [s].
        envs: Which environments (distinct indices, or a boolean mask).
        truth: The true ranges of the given environments, given their ``active`` rows.
        active: ``(B, N)`` booleans, or ``None``.
        shape: The sonar's output shape.
        errors: The sonar's error state.
        fused: The sonar's fused C pass, or ``None``.
        max_range: The sonar's range [m].

    Raises:
        ValueError: ``out`` has another shape or dtype.
    """
    which = np.asarray(envs)
    rows = np.arange(shape[0])[which if which.dtype == np.bool_ else which.astype(np.intp)]
    if out is None:
        out = np.full(shape, np.nan)
    elif out.shape != shape or out.dtype != np.float64:
        raise ValueError(f"out must be a float64 array of shape {shape}")
    if rows.size:
        act = None if active is None else np.asarray(active, dtype=bool)[rows]
        measured = measure_rows(truth(rows, act), dt, rows, errors=errors, fused=fused, max_range=max_range)
        out[rows] = measured
    return out


class Sonar:
    """The sonar as the environments use it: ranges at the configured fidelity, plus Eq. 3 errors.

    ``config.fidelity`` picks the ranges: ``"geometric"`` (exact ray casts) or ``"signal"``
    (:class:`~hptvsim.sensors.signal.SignalSonar`: echo synthesis and the matched filter). The
    Gauss-Markov model ``config.errors`` (one process per environment, sensing agent and beam)
    is then added to every beam that hit something, and the result clipped to
    ``[0, max_range]``; a beam that hit nothing keeps ``max_range`` (no echo, nothing to be
    wrong about).

    Args:
        config: Sonar settings.
        grid: Obstacle map, or ``None``.
        num_envs: Environments ``B``.
        num_agents: Vehicles ``N`` per environment.
        radii: ``(N,)`` radius [m] of every agent's circle
            (:func:`~hptvsim.sensors.sonar.vehicle_radii`), or ``None`` when vehicles are not
            detected.
        sensing: Indices of the agents that carry this sonar (``None``: all ``N``).
        rng: Generator or seed for all noise (errors and, at signal level, echoes).
        backend: Ray-cast backend, ``"c"`` or ``"numpy"``.
        threads: Ray-cast threads (``None``: up to 2).
    """

    def __init__(
        self,
        config: SonarConfig,
        grid: OccupancyGrid | None,
        *,
        num_envs: int,
        num_agents: int,
        radii: npt.ArrayLike | None = None,
        sensing: Sequence[int] | None = None,
        rng: np.random.Generator | int | None = None,
        backend: Literal["c", "numpy"] = "c",
        threads: int | None = None,
    ) -> None:
        self.config = config
        self.rng = as_generator(rng)
        self.radii: F64 | None = None if radii is None else np.asarray(radii, dtype=np.float64)
        self.sensing: I64 | None = None if sensing is None else np.asarray(sensing, dtype=np.int64)
        self.num_envs, self.num_agents = int(num_envs), int(num_agents)
        if self.radii is not None and self.radii.shape != (self.num_agents,):
            raise ValueError(
                f"radii must hold {self.num_agents} radii, one per agent; got {self.radii.shape}"
            )
        if self.sensing is not None and not ((self.sensing >= 0) & (self.sensing < self.num_agents)).all():
            raise ValueError(
                f"sensing must hold agent indices in [0, {self.num_agents}); got {self.sensing.tolist()}"
            )
        n_sensing = self.num_agents if self.sensing is None else self.sensing.size
        self.geometric = GeometricSonar(config, grid, backend=backend, threads=threads)
        self.signal: SignalSonar | None = None
        if config.fidelity == "signal":
            from hptvsim.sensors.signal import SignalSonar

            self.signal = SignalSonar(config, grid, rng=self.rng, backend=backend, threads=threads)
            self.signal.geometric = self.geometric
        self.shape = (self.num_envs, n_sensing, config.beams)
        self.errors = GaussMarkov(config.errors, self.shape, rng=self.rng)
        self._truth: F64 = np.empty(self.shape)
        self._truth_ptr = self._truth.ctypes.data
        self._fused = (
            FusedRangeErrors(config.errors, config.max_range, self.errors, self.shape)
            if backend == "c" and config.errors.active
            else None
        )

    def reset(self, index: npt.ArrayLike | None = None) -> None:
        """Draw fresh error biases for the environments in ``index`` (``None``: all)."""
        self.errors.reset(index)

    def truth(self, poses: npt.ArrayLike, *, active: npt.ArrayLike | None = None) -> F64:
        """Error-free geometric ranges ``(B, S, K)`` [m] (for rewards and tests)."""
        return self.geometric.ranges(poses, self.radii, sensing=self.sensing, active=active)

    def measure(
        self,
        poses: npt.ArrayLike,
        dt: float,
        *,
        active: npt.ArrayLike | None = None,
        out: F64 | None = None,
        envs: npt.ArrayLike | None = None,
    ) -> F64:
        """Measured ranges ``(B, S, K)`` [m] for poses ``(B, N, 3)``; the error biases advance ``dt`` [s].

        Args:
            poses: ``[x, y, psi]`` of every vehicle [m, m, rad].
            dt: Time since the last measurement [s].
            active: ``(B, N)`` booleans; inactive vehicles are not detected.
            out: A C-contiguous float64 ``(B, S, K)`` array to write into (default: a new array).
            envs: Measure only these environments (distinct indices): only their rows of
                ``out`` are written (a new array's others are NaN), only their biases advance,
                only their normals are drawn (:func:`measure_rows`). ``None``: all.
        """
        shape = np.shape(poses)
        if shape != (self.num_envs, self.num_agents, 3):
            raise ValueError(
                f"this sonar was built for poses of shape {(self.num_envs, self.num_agents, 3)}, got {shape}"
            )
        if envs is not None:
            return self._measure_rows(np.asarray(poses, dtype=np.float64), dt, active, out, envs)
        if self._fused is not None and self.signal is None and self.geometric.threads > 1:
            self._fused.start_drawing(self._truth.size, self.rng)  # beside the ray casts
        try:
            truth = self.geometric.ranges(
                poses, self.radii, sensing=self.sensing, active=active, out=self._truth
            )
        except BaseException:
            if self._fused is not None:
                self._fused.cancel_drawing()
            raise
        ranges = truth if self.signal is None else self.signal.estimate_ranges(truth)
        bad_out = out is not None and (out.shape != self.shape or out.dtype != np.float64)
        if bad_out or (out is not None and not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float64 array of shape {self.shape}")
        if not self.config.errors.active:
            result = ranges.copy() if ranges is self._truth else ranges
        elif self._fused is not None:
            src = ranges if ranges.flags.c_contiguous else np.ascontiguousarray(ranges)
            ptr = self._truth_ptr if src is self._truth else src.ctypes.data
            return self._fused(ptr, src.size, dt, self.rng, out)
        else:
            max_range = self.config.max_range
            noisy = self.errors.measure(ranges, dt)
            np.clip(noisy, 0.0, max_range, out=noisy)
            result = np.where(ranges < max_range, noisy, max_range)
        if out is None:
            return result
        np.copyto(out, result)
        return out

    def _measure_rows(
        self, poses: F64, dt: float, active: npt.ArrayLike | None, out: F64 | None, envs: npt.ArrayLike
    ) -> F64:
        def truth(rows: npt.NDArray[np.intp], act: Bool | None) -> F64:
            ranges = self.geometric.ranges(poses[rows], self.radii, sensing=self.sensing, active=act)
            return ranges if self.signal is None else self.signal.estimate_ranges(ranges)

        return measure_into(
            out, dt, envs, truth, active=active, shape=self.shape, errors=self.errors, fused=self._fused,
            max_range=self.config.max_range,
        )  # fmt: skip
