r"""The first-order Gauss-Markov sensor error model shared by all sensors (paper Eq. 3).

A sensor reports

.. math::  s = y + n + G_s \qquad (3a) \qquad\qquad \dot n = -n / \tau + G_b \qquad (3b)

(the paper prints Eq. 3b as ``-1/tau``; the bias ``n`` is what decays). ``G_s`` is white
measurement noise of standard deviation ``noise_std`` and ``G_b`` white noise whose intensity
``q = 2 bias_std^2 / tau`` makes ``bias_std`` the stationary standard deviation of ``n``.

**Exact discretisation.** Over a step ``dt`` the bias evolves as the AR(1) process

.. math::  n_{k+1} = \phi n_k + w_k, \quad \phi = e^{-dt/\tau}, \quad
           w_k \sim N(0, \sigma_b^2 (1 - \phi^2)),

which is the exact transition of Eq. 3b (no Euler error, any ``dt``); its stationary variance is
``sigma_b^2`` and its autocorrelation ``exp(-|lag| / tau)``. Every bias starts from the
stationary distribution, so the statistics do not depend on how long a process has run.

:class:`GaussMarkov` holds one independent process per element of an array of any shape
(environments x agents x beams for the sonar, environments x axes for the acoustic link), seeded
by a :class:`numpy.random.Generator`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from hptvsim.world.sensor_config import GaussMarkovConfig

__all__ = ["GaussMarkov", "as_generator"]

F64 = npt.NDArray[np.float64]


def as_generator(seed: np.random.Generator | int | None) -> np.random.Generator:
    """A numpy Generator from a seed (``None``: fresh entropy) or the Generator itself."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


class GaussMarkov:
    """Independent Gauss-Markov error processes (Eq. 3), one per element of ``shape``.

    Args:
        config: Model parameters; when ``config.active`` is False the sensor is perfect and no
            random numbers are drawn.
        shape: Shape of the measured array, e.g. ``(B, N, K)``.
        rng: Generator or seed; all draws come from it, so one seed gives one sequence.

    Attributes:
        bias: The current bias ``n``, an array of ``shape`` [unit of the signal].
    """

    def __init__(
        self,
        config: GaussMarkovConfig,
        shape: tuple[int, ...],
        *,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        self.config = config
        self.shape = tuple(int(s) for s in shape)
        self.rng = as_generator(rng)
        self.bias: F64 = np.zeros(self.shape)
        self._noise: F64 = np.empty(self.shape)
        self.reset()

    def reset(self, index: npt.ArrayLike | slice | None = None) -> None:
        """Draw fresh biases from the stationary distribution.

        Args:
            index: Which entries along the first axis (e.g. the environments that reset): a
                boolean mask, integer indices or a slice; ``None`` resets all.
        """
        if not self.config.active or self.config.bias_std == 0.0:
            return
        sel: slice | npt.NDArray[np.intp] | npt.NDArray[np.bool_] = (
            slice(None) if index is None else index if isinstance(index, slice) else np.asarray(index)
        )
        target = self.bias[sel]
        self.bias[sel] = self.config.bias_std * self.rng.standard_normal(target.shape)

    def step(self, dt: float, index: npt.ArrayLike | slice | None = None) -> None:
        """Advance the biases by ``dt`` [s] with the exact AR(1) transition of Eq. 3b.

        Args:
            dt: Time step [s], >= 0.
            index: Which entries along the first axis to advance (as in :meth:`reset`);
                ``None``: all.
        """
        if not self.config.active or self.config.bias_std == 0.0:
            return
        if not (dt >= 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt = {dt!r} is invalid; valid: a finite time step >= 0 s")
        phi = math.exp(-dt / self.config.tau)
        w_std = self.config.bias_std * math.sqrt(-math.expm1(-2.0 * dt / self.config.tau))
        if index is None:
            self.bias *= phi
            self.rng.standard_normal(out=self._noise)
            self._noise *= w_std
            self.bias += self._noise
            return
        sel = index if isinstance(index, slice) else np.asarray(index)
        part = self.bias[sel]
        self.bias[sel] = phi * part + w_std * self.rng.standard_normal(part.shape)

    def apply(
        self,
        y: npt.ArrayLike,
        *,
        index: npt.ArrayLike | slice | None = None,
        out: F64 | None = None,
    ) -> F64:
        """Return the measurement ``s = y + n + G_s`` (Eq. 3a) of the true values ``y``.

        Args:
            y: True values, broadcastable to ``shape`` (or to ``bias[index].shape``).
            index: Measure only these entries along the first axis (as in :meth:`reset`).
            out: Optional array to write into (may be ``y`` itself).
        """
        bias = (
            self.bias
            if index is None
            else self.bias[index if isinstance(index, slice) else np.asarray(index)]
        )
        result: F64 = np.add(y, 0.0, out=out) if out is not None else np.array(y, dtype=np.float64)
        if result.shape != bias.shape:
            result = np.broadcast_to(result, bias.shape).copy()
        if not self.config.active:
            return result
        if self.config.bias_std > 0.0:
            result += bias
        if self.config.noise_std > 0.0:
            if index is None:
                self.rng.standard_normal(out=self._noise)
                self._noise *= self.config.noise_std
                result += self._noise
            else:
                result += self.config.noise_std * self.rng.standard_normal(result.shape)
        return result

    def measure(self, y: npt.ArrayLike, dt: float, *, out: F64 | None = None) -> F64:
        """Advance the biases by ``dt`` [s], then return ``s = y + n + G_s`` for ``y``."""
        self.step(dt)
        return self.apply(y, out=out)
