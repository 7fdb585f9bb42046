"""Intervals over training seeds: the statistics behind every reported number.

A training seed is the unit of replication: each run gives one value of a metric, and a
setting's number is the mean over its seeds with a 95 % Student-t interval
(mean ± t(0.975, n-1) · s / √n). Two settings are compared by the Welch interval of the
difference of their means (unequal variances, Welch-Satterthwaite degrees of freedom); a trend
over a numeric setting (the entropy coefficient) by the ordinary least-squares slope over every
(setting, seed) value with its t interval (n - 2 degrees of freedom).

A mean that cannot leave a range (a rate in [0, 1], a variance or a time >= 0) has its interval
cut to that range (:meth:`Interval.within`): the true mean lies in the range, so the cut interval
covers it whenever the t interval does, and a reader is not shown a capture rate of 1.4.

A claim that one thing is larger than another *holds* when the whole interval of the difference
lies on the claimed side of zero, *does not hold* when it lies wholly on the other side, and is
*not resolved* otherwise (or with fewer than two seeds per side).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from scipy import stats as _st

__all__ = ["Interval", "Verdict", "difference", "mean_interval", "slope", "verdict"]

Verdict = Literal["holds", "does not hold", "not resolved"]
LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    """An estimate with its 95 % interval.

    Attributes:
        value: The estimate (a mean, a difference of means, a slope).
        low: Lower end of the interval (``nan`` with too few values).
        high: Upper end.
        n: Number of values behind it (seeds; for a difference, the smaller side).
    """

    value: float
    low: float
    high: float
    n: int

    @property
    def resolved(self) -> bool:
        """Whether the interval exists (enough values)."""
        return math.isfinite(self.low) and math.isfinite(self.high)

    def within(self, low: float = -math.inf, high: float = math.inf) -> Interval:
        """This interval cut to the range ``[low, high]`` the estimated quantity cannot leave.

        Args:
            low: Smallest possible value (0 for a rate, a variance or a time).
            high: Largest possible value (1 for a rate).

        Returns:
            The same estimate with ``max(self.low, low)`` and ``min(self.high, high)`` as its ends
            (an interval without ends stays without).
        """
        if not self.resolved:
            return self
        return Interval(self.value, max(self.low, low), min(self.high, high), self.n)

    def format(self, digits: int = 3) -> str:
        """``value [low, high]`` (or ``value (n = 1, no interval)``)."""
        if not math.isfinite(self.value):
            return "n/a"
        v = f"{self.value:.{digits}g}"
        if not self.resolved:
            return f"{v} (n = {self.n}, no interval)"
        return f"{v} [{self.low:.{digits}g}, {self.high:.{digits}g}]"


def _clean(values: Sequence[float]) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(float(v))]


def mean_interval(values: Sequence[float]) -> Interval:
    """Mean and 95 % t interval of ``values`` (one per seed)."""
    x = _clean(values)
    n = len(x)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    m = sum(x) / n
    if n < 2:
        return Interval(m, math.nan, math.nan, n)
    s = math.sqrt(sum((v - m) ** 2 for v in x) / (n - 1))
    half = float(_st.t.ppf(0.5 + LEVEL / 2, n - 1)) * s / math.sqrt(n)
    return Interval(m, m - half, m + half, n)


def difference(a: Sequence[float], b: Sequence[float]) -> Interval:
    """Mean of ``a`` minus mean of ``b`` with its Welch 95 % interval."""
    xa, xb = _clean(a), _clean(b)
    na, nb = len(xa), len(xb)
    if na == 0 or nb == 0:
        return Interval(math.nan, math.nan, math.nan, min(na, nb))
    ma, mb = sum(xa) / na, sum(xb) / nb
    d = ma - mb
    if na < 2 or nb < 2:
        return Interval(d, math.nan, math.nan, min(na, nb))
    va = sum((v - ma) ** 2 for v in xa) / (na - 1) / na
    vb = sum((v - mb) ** 2 for v in xb) / (nb - 1) / nb
    se = math.sqrt(va + vb)
    if se == 0.0:
        return Interval(d, d, d, min(na, nb))
    df = (va + vb) ** 2 / (va**2 / (na - 1) + vb**2 / (nb - 1))
    half = float(_st.t.ppf(0.5 + LEVEL / 2, df)) * se
    return Interval(d, d - half, d + half, min(na, nb))


def slope(x: Sequence[float], y: Sequence[float]) -> Interval:
    """Least-squares slope of ``y`` on ``x`` with its 95 % t interval; ``n`` is the point count."""
    pts = [
        (float(a), float(b)) for a, b in zip(x, y, strict=True) if b is not None and math.isfinite(float(b))
    ]
    n = len(pts)
    xs = [p[0] for p in pts]
    if n < 2 or len(set(xs)) < 2:
        return Interval(math.nan, math.nan, math.nan, n)
    mx = sum(xs) / n
    my = sum(p[1] for p in pts) / n
    sxx = sum((a - mx) ** 2 for a in xs)
    b = sum((a - mx) * (c - my) for a, c in pts) / sxx
    if n < 3:
        return Interval(b, math.nan, math.nan, n)
    resid = sum((c - (my + b * (a - mx))) ** 2 for a, c in pts)
    se = math.sqrt(resid / (n - 2) / sxx)
    half = float(_st.t.ppf(0.5 + LEVEL / 2, n - 2)) * se
    return Interval(b, b - half, b + half, n)


def verdict(interval: Interval, direction: Literal["greater", "less"]) -> Verdict:
    """Whether an interval says a difference or slope is > 0 (``greater``) or < 0 (``less``)."""
    if not interval.resolved:
        return "not resolved"
    if direction == "greater":
        if interval.low > 0:
            return "holds"
        if interval.high < 0:
            return "does not hold"
    else:
        if interval.high < 0:
            return "holds"
        if interval.low > 0:
            return "does not hold"
    return "not resolved"
