"""Documented statistics against a run of today's machine: agreement within the statistic's interval.

A closed loop of hundreds of steps amplifies last-bit differences between CPUs' floating-point
paths (on x86-64, MKL's single-precision GEMM behind the policies' torch layers takes another
kernel on an AVX-512 Intel CPU than on an AMD EPYC), so an episode can end a step earlier or later
and a rate over 100 episodes can move by an episode or two. Tests compare a documented rate with
a new measurement of the same episodes within the documented rate's 95 % interval, never to the
last digit (README, "Numbers and CPUs").
"""

from __future__ import annotations

import math


def rate_tolerance(documented: float, episodes: int) -> float:
    """Half-width allowed between a documented rate and a new measurement over the same episodes.

    The normal approximation's 95 % half-width of a rate over ``episodes`` Bernoulli trials, plus
    one episode (so a rate of 0 or 1 may still move by one episode).

    Args:
        documented: The documented rate, in [0, 1].
        episodes: The number of episodes it was measured over.

    Returns:
        The largest difference that agrees.
    """
    if not 0.0 <= documented <= 1.0 or episodes < 1:
        raise ValueError(f"a rate in [0, 1] over at least one episode, not {documented} over {episodes}")
    return 1.96 * math.sqrt(documented * (1.0 - documented) / episodes) + 1.0 / episodes


def agrees(measured: float, documented: float, episodes: int) -> bool:
    """Whether ``measured`` is within :func:`rate_tolerance` of ``documented``."""
    return abs(measured - documented) <= rate_tolerance(documented, episodes) + 1e-12
