"""The Gauss-Markov error model (Eq. 3): stationary statistics match theory, exact discretisation.

Tolerances are stated from sampling theory: for an AR(1) sequence with coefficient ``phi`` and
``N`` samples, the sample variance has relative standard deviation ``sqrt(2 / N_eff)``,
``N_eff = N (1 - phi^2) / (1 + phi^2)``, and the lag-1 autocorrelation estimate has standard
deviation ``sqrt((1 - phi^2) / N)`` (Bartlett). Each check allows 5 of those standard deviations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.sensors import GaussMarkovConfig
from hptvsim.sensors.errors import GaussMarkov

CHAINS, STEPS, DT = 400, 4000, 0.5  # s


def simulate(config: GaussMarkovConfig, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    gm = GaussMarkov(config, (CHAINS,), rng=seed)
    bias = np.empty((STEPS, CHAINS))
    meas = np.empty((STEPS, CHAINS))
    for k in range(STEPS):
        gm.step(DT)
        bias[k] = gm.bias
        meas[k] = gm.apply(np.zeros(CHAINS))
    return bias, meas


def test_stationary_variance_and_correlation_time_match_theory() -> None:
    cfg = GaussMarkovConfig(bias_std=2.0, tau=5.0, noise_std=0.7)
    bias, meas = simulate(cfg)
    phi = math.exp(-DT / cfg.tau)
    n = bias.size
    n_eff = n * (1 - phi**2) / (1 + phi**2)

    var = float(np.mean(bias**2))  # mean zero by construction
    assert var == pytest.approx(cfg.bias_std**2, rel=5 * math.sqrt(2 / n_eff))

    rho1 = float(np.sum(bias[1:] * bias[:-1]) / np.sum(bias[:-1] ** 2))
    rho_tol = 5 * math.sqrt((1 - phi**2) / n)
    assert rho1 == pytest.approx(phi, abs=rho_tol)
    tau_hat = -DT / math.log(rho1)
    tau_tol = DT / (phi * math.log(phi) ** 2) * rho_tol  # delta method
    assert tau_hat == pytest.approx(cfg.tau, abs=tau_tol)
    assert tau_tol < 0.05 * cfg.tau  # the test is sharp: a 5 % error in tau would fail

    # the autocorrelation one correlation time apart is 1/e
    lag = round(cfg.tau / DT)
    rho_tau = float(np.sum(bias[lag:] * bias[:-lag]) / np.sum(bias[:-lag] ** 2))
    p2k = phi ** (2 * lag)
    bartlett = ((1 + phi**2) * (1 - p2k) / (1 - phi**2) - 2 * lag * p2k) / n
    assert rho_tau == pytest.approx(math.exp(-1.0), abs=5 * math.sqrt(bartlett))

    # the measurement adds independent white noise: total variance bias^2 + noise^2
    white = meas - bias
    assert float(np.std(white)) == pytest.approx(cfg.noise_std, rel=5 * math.sqrt(1 / (2 * n)))
    assert abs(float(np.mean(white[1:] * white[:-1]))) / cfg.noise_std**2 < 5 / math.sqrt(n)


@pytest.mark.parametrize("dt", [0.01, 1.0, 30.0])
def test_transition_is_exact_for_any_step(dt: float) -> None:
    """From a known bias, one step of any length gives mean phi n0 and variance s^2 (1 - phi^2)."""
    cfg = GaussMarkovConfig(bias_std=1.5, tau=4.0, noise_std=0.0)
    m = 200_000
    gm = GaussMarkov(cfg, (m,), rng=1)
    gm.bias[:] = 3.0
    gm.step(dt)
    phi = math.exp(-dt / cfg.tau)
    want_var = cfg.bias_std**2 * (1 - phi**2)
    assert float(gm.bias.mean()) == pytest.approx(3.0 * phi, abs=5 * math.sqrt(want_var / m) + 1e-12)
    assert float(gm.bias.var()) == pytest.approx(want_var, rel=5 * math.sqrt(2 / m))


def test_seeded_vectorised_and_resettable() -> None:
    cfg = GaussMarkovConfig(bias_std=1.0, tau=2.0, noise_std=0.5)
    a = GaussMarkov(cfg, (3, 4, 5), rng=42)
    b = GaussMarkov(cfg, (3, 4, 5), rng=np.random.default_rng(42))
    y = np.arange(60.0).reshape(3, 4, 5)
    for _ in range(5):
        np.testing.assert_array_equal(a.measure(y, 0.25), b.measure(y, 0.25))
    before = a.bias.copy()
    a.reset(np.array([False, True, False]))
    assert np.array_equal(a.bias[0], before[0]) and np.array_equal(a.bias[2], before[2])
    assert not np.array_equal(a.bias[1], before[1])
    a.step(0.5, index=[2])
    assert np.array_equal(a.bias[0], before[0]) and not np.array_equal(a.bias[2], before[2])
    part = a.apply(np.zeros((1, 4, 5)), index=[0])
    assert part.shape == (1, 4, 5)
    out = np.zeros((3, 4, 5))
    assert a.apply(y, out=out) is out


def test_disabled_or_zero_is_perfect_and_draws_nothing() -> None:
    y = np.linspace(0, 1, 10)
    for cfg in (GaussMarkovConfig(enabled=False), GaussMarkovConfig(bias_std=0.0, noise_std=0.0)):
        rng = np.random.default_rng(0)
        gm = GaussMarkov(cfg, (10,), rng=rng)
        state = rng.bit_generator.state
        np.testing.assert_array_equal(gm.measure(y, 1.0), y)
        assert rng.bit_generator.state == state


def test_bad_step_is_named() -> None:
    gm = GaussMarkov(GaussMarkovConfig(), (2,), rng=0)
    with pytest.raises(ValueError, match=r"dt = -1\.0 is invalid"):
        gm.step(-1.0)
