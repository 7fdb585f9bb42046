"""Intervals over seeds (hptvsim.experiments.stats) against SciPy's own tests and hand computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as st

from hptvsim.experiments.reproduce import metric_range
from hptvsim.experiments.stats import difference, mean_interval, slope, verdict


def test_mean_interval_is_the_student_t_interval() -> None:
    x = [1.0, 2.0, 4.0, 7.0]
    iv = mean_interval(x)
    lo, hi = st.t.interval(0.95, len(x) - 1, loc=np.mean(x), scale=st.sem(x))
    assert iv.value == pytest.approx(3.5)
    assert [iv.low, iv.high] == pytest.approx([lo, hi])
    assert iv.n == 4 and iv.resolved


def test_one_value_has_no_interval_and_nan_values_are_dropped() -> None:
    iv = mean_interval([2.0, math.nan])
    assert iv.value == 2.0 and iv.n == 1 and not iv.resolved
    assert "no interval" in iv.format()
    assert mean_interval([]).format() == "n/a"


def test_difference_matches_welch() -> None:
    a, b = [5.0, 6.0, 7.5], [1.0, 3.0, 2.0, 2.5]
    iv = difference(a, b)
    res = st.ttest_ind(a, b, equal_var=False)
    lo, hi = res.confidence_interval(0.95)
    assert iv.value == pytest.approx(np.mean(a) - np.mean(b))
    assert [iv.low, iv.high] == pytest.approx([lo, hi])


def test_slope_matches_linregress() -> None:
    x = [0.1, 0.1, 0.2, 0.2, 0.3, 0.3, 0.4, 0.4]
    y = [10.0, 9.0, 8.5, 7.0, 6.0, 6.5, 4.0, 5.0]
    iv = slope(x, y)
    r = st.linregress(x, y)
    half = st.t.ppf(0.975, len(x) - 2) * r.stderr
    assert iv.value == pytest.approx(r.slope)
    assert [iv.low, iv.high] == pytest.approx([r.slope - half, r.slope + half])
    assert verdict(iv, "less") == "holds" and verdict(iv, "greater") == "does not hold"


def test_verdicts_need_the_whole_interval_on_one_side() -> None:
    overlapping = difference([1.0, 3.0, 2.0], [1.5, 2.5, 2.2])
    assert verdict(overlapping, "greater") == "not resolved"
    assert verdict(difference([1.0], [0.0]), "greater") == "not resolved"  # one seed: no interval
    assert verdict(difference([10.0, 11.0, 10.5], [1.0, 1.2, 0.9]), "greater") == "holds"


def test_an_interval_is_cut_to_the_range_of_its_quantity() -> None:
    rates = [1.0, 0.5]  # a capture rate's t interval with 2 seeds reaches far past 1
    raw = mean_interval(rates)
    assert raw.low < 0.0 and raw.high > 1.0
    cut = raw.within(*metric_range("eval.vs_scripted_evader.capture_rate"))
    assert (cut.value, cut.low, cut.high, cut.n) == (0.75, 0.0, 1.0, 2)
    assert mean_interval([3.0]).within(0.0, 1.0).format() == "3 (n = 1, no interval)"
    assert metric_range("eval.self.collision_rate", difference_of=True) == (-1.0, 1.0)
    assert metric_range("train_var.evader") == (0.0, math.inf)
    assert metric_range("eval.self.time_to_capture_s") == (0.0, math.inf)
    for unbounded in ("train_final.pursuer", "train_mean.evader", "eval.self.return_pursuer"):
        assert metric_range(unbounded) == (-math.inf, math.inf)
    assert metric_range("train_var.pursuer", difference_of=True) == (-math.inf, math.inf)
    # a verdict is the same before and after the cut: 0 stays inside or outside [-1, 1]
    d = difference([1.0, 0.9, 1.0], [0.0, 0.1, 0.2])
    assert verdict(d, "greater") == verdict(d.within(-1.0, 1.0), "greater")
