r"""Signal-level sonar: echo synthesis, the matched filter of Eq. 1 and the spatial periodogram of Eq. 2.

**Ranging (Eq. 1).** A beam transmits the real pulse ``S[n]`` (:func:`transmit_pulse`: an LFM
chirp or a tone burst, ``M`` samples at ``fs``). The received record ``X[n]``, ``N`` samples long
(echoes from up to ``max_range``), is the pulse delayed by the two-way travel time
``tau = 2 r / c`` plus white Gaussian noise (:func:`synthesize_echoes`; the delayed pulse is
evaluated at ``n / fs - tau`` exactly, so delays need not be whole samples). The correlator

.. math::  J[D] = \sum_{n=D}^{D+M-1} X[n] S[n-D], \quad 0 \le D \le N - M \qquad (1a)

is evaluated for all lags at once with FFTs (:func:`matched_filter`; the direct sum
:func:`matched_filter_direct` is the same number and the tests compare them), and
``D^ = argmax J[D]`` (1b) gives the range ``r^ = c D^ / (2 fs)``.

**SNR.** ``snr_db`` is the echo's mean power over the pulse divided by the noise power per
sample. The matched filter gains the pulse's sample count: its output SNR is
``snr + 10 log10(sum S^2 / mean S^2)``. At high SNR the estimate is within one sample of the
truth (the integer argmax quantises to ``1/sqrt(12)`` sample RMS); as the output SNR falls
towards ``2 ln(N - M)`` noise peaks anywhere in the record start to beat the echo's peak and
the estimate jumps to random lags (the threshold effect of nonlinear estimators; Van Trees,
*Detection, Estimation and Modulation Theory I*, ch. 4): :func:`snr_sweep` and the plot of
``hptvsim sonar snr-plot`` show both regimes against the Cramér-Rao bound.

**Detection.** A sonar must also say when there is no echo: the noise-only correlator output is
Gaussian with standard deviation ``sigma sqrt(sum S^2)``, so a peak below
``z sigma sqrt(sum S^2)``, ``z = Phi^-1(1 - p_fa / (N - M + 1))`` (Bonferroni over the lags),
is reported as "nothing within ``max_range``" with a false-alarm probability of at most
``false_alarm_probability`` per record.

**Azimuth (Eq. 2).** A uniform linear array of ``M`` hydrophones spaced ``d`` apart receives a
narrowband plane wave at ``F0``; element ``n`` sees ``A exp(j (2 pi F0 d cos(beta) n / c + phi))``
plus complex white noise, ``beta`` being the angle between the array axis and the direction to
the source. The spatial periodogram

.. math::  P_s(\beta) = \frac{1}{M} \Big| \sum_{n=0}^{M-1} X[n]
           e^{-j 2 \pi F_0 \frac{d}{c} \cos\beta \, n} \Big|^2 \qquad (2a)

is maximised over ``beta`` in ``[0, pi]`` (2b). The array's resolution (Rayleigh) is
``Delta cos(beta) = c / (F0 M d)``, i.e. ``Delta beta ~ c / (F0 M d sin beta)``. On a vehicle the
array lies along the body's starboard axis, so ``beta = pi/2 - theta`` for a source at relative
bearing ``theta`` (clockwise from the bow): the forward half-plane is resolved unambiguously and
a source astern appears at its mirror image ahead (a line array's cone ambiguity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy import fft as sp_fft
from scipy import special

from hptvsim.sensors.errors import as_generator
from hptvsim.sensors.sonar import GeometricSonar
from hptvsim.world.grid import OccupancyGrid
from hptvsim.world.sensor_config import SonarConfig

__all__ = [
    "SignalSonar",
    "SnrSweep",
    "array_resolution",
    "array_snapshots",
    "delay_crlb",
    "detection_threshold",
    "estimate_azimuth",
    "estimate_delay",
    "matched_filter",
    "matched_filter_direct",
    "noise_std",
    "outlier_threshold",
    "plot_snr_sweep",
    "snr_sweep",
    "spatial_periodogram",
    "synthesize_echoes",
    "transmit_pulse",
]

F64 = npt.NDArray[np.float64]
C128 = npt.NDArray[np.complex128]
I64 = npt.NDArray[np.int64]

_CHUNK_SAMPLES = 2_000_000  # samples per block of records (about 16 MB of float64)


# --- the pulse and the echoes ---------------------------------------------------------------------


def _pulse_at(t: F64, config: SonarConfig) -> F64:
    """The transmitted pulse ``S(t)`` at times ``t`` [s] (zero outside ``[0, pulse_length)``)."""
    T = config.pulse_length  # s
    inside = (t >= 0.0) & (t < T)
    if config.pulse == "lfm":
        f_start = config.center_frequency - 0.5 * config.bandwidth  # Hz
        k = config.bandwidth / T  # Hz/s, chirp rate
        phase = 2.0 * math.pi * (f_start * t + 0.5 * k * t * t)
    else:
        phase = 2.0 * math.pi * config.center_frequency * t
    result: F64 = np.where(inside, np.cos(phase), 0.0)
    return result


def _pulse_rate_at(t: F64, config: SonarConfig) -> F64:
    """``dS/dt`` [1/s] inside the pulse (for the Cramér-Rao bound)."""
    T = config.pulse_length
    inside = (t >= 0.0) & (t < T)
    if config.pulse == "lfm":
        f_start = config.center_frequency - 0.5 * config.bandwidth
        k = config.bandwidth / T
        phase = 2.0 * math.pi * (f_start * t + 0.5 * k * t * t)
        rate = 2.0 * math.pi * (f_start + k * t)
    else:
        phase = 2.0 * math.pi * config.center_frequency * t
        rate = np.full_like(t, 2.0 * math.pi * config.center_frequency)
    result: F64 = np.where(inside, -rate * np.sin(phase), 0.0)
    return result


def transmit_pulse(config: SonarConfig) -> F64:
    """The sampled pulse ``S[n]``, ``n = 0 .. M - 1`` (``M = config.pulse_samples``)."""
    n = np.arange(config.pulse_samples, dtype=np.float64)
    return _pulse_at(n / config.sampling_rate, config)


def noise_std(config: SonarConfig, snr_db: float | None = None) -> float:
    """Noise standard deviation per sample for a unit-amplitude echo at ``snr_db`` (default: config)."""
    snr = config.snr_db if snr_db is None else snr_db
    power = float(np.mean(transmit_pulse(config) ** 2))
    return math.sqrt(power / 10.0 ** (snr / 10.0))


def synthesize_echoes(
    ranges: npt.ArrayLike,
    config: SonarConfig,
    rng: np.random.Generator | int | None,
    *,
    snr_db: float | None = None,
    present: npt.ArrayLike | None = None,
) -> F64:
    """Received records ``X[n]`` ``(R, N)`` for true ranges ``(R,)`` [m].

    Args:
        ranges: Distance to each echo's reflector [m].
        config: Pulse, sampling and sound speed.
        rng: Generator or seed for the noise.
        snr_db: Echo SNR [dB] (default ``config.snr_db``).
        present: ``(R,)`` booleans; False: the record holds noise only (nothing hit).
    """
    r = np.atleast_1d(np.asarray(ranges, dtype=np.float64))
    gen = as_generator(rng)
    n_samples = config.record_samples
    t = np.arange(n_samples, dtype=np.float64) / config.sampling_rate  # s
    tau = 2.0 * r / config.sound_speed  # s, two-way travel time
    x = _pulse_at(t[None, :] - tau[:, None], config)
    if present is not None:
        x *= np.asarray(present, dtype=np.bool_).reshape(-1, 1)
    x += noise_std(config, snr_db) * gen.standard_normal(x.shape)
    return x


# --- Eq. 1: the matched filter --------------------------------------------------------------------


def matched_filter_direct(x: npt.ArrayLike, s: npt.ArrayLike) -> F64:
    """Eq. 1a as written: ``J[D] = sum_{n=D}^{D+M-1} X[n] S[n - D]`` for ``D = 0 .. N - M``."""
    xa = np.atleast_2d(np.asarray(x, dtype=np.float64))
    sa = np.asarray(s, dtype=np.float64)
    m = sa.shape[0]
    lags = xa.shape[1] - m + 1
    j = np.empty((xa.shape[0], lags))
    for d in range(lags):
        j[:, d] = xa[:, d : d + m] @ sa
    return j


def matched_filter(x: npt.ArrayLike, s: npt.ArrayLike) -> F64:
    """Eq. 1a for all lags at once: the correlation ``J[D]`` ``(R, N - M + 1)`` by FFT."""
    xa = np.atleast_2d(np.asarray(x, dtype=np.float64))
    sa = np.asarray(s, dtype=np.float64)
    n, m = xa.shape[1], sa.shape[0]
    if m > n:
        raise ValueError(f"the record ({n} samples) is shorter than the pulse ({m} samples)")
    nfft = sp_fft.next_fast_len(n, real=True)  # no wrap-around: lags D <= N - M, D + M - 1 < nfft
    spec = sp_fft.rfft(xa, nfft, axis=1) * np.conj(sp_fft.rfft(sa, nfft))
    j: F64 = sp_fft.irfft(spec, nfft, axis=1)[:, : n - m + 1]
    return j


def estimate_delay(x: npt.ArrayLike, s: npt.ArrayLike) -> tuple[I64, F64]:
    """Eq. 1b: ``D^ = argmax J[D]`` per record; returns ``(D^, J[D^])``."""
    j = matched_filter(x, s)
    d = np.argmax(j, axis=1)
    return d.astype(np.int64), j[np.arange(j.shape[0]), d]


def detection_threshold(config: SonarConfig, sigma: float) -> float:
    """Correlator level that noise alone exceeds with probability <= ``false_alarm_probability``."""
    s = transmit_pulse(config)
    lags = config.record_samples - config.pulse_samples + 1
    z = math.sqrt(2.0) * float(special.erfcinv(2.0 * config.false_alarm_probability / lags))
    return z * sigma * math.sqrt(float(s @ s))


def delay_crlb(config: SonarConfig, snr_db: float) -> float:
    """Cramér-Rao bound on the delay's standard deviation [samples] at ``snr_db``.

    For a known real signal in white noise of variance ``sigma^2``,
    ``var(D^) >= sigma^2 / sum_n (dS/dn)^2`` (Kay, *Fundamentals of Statistical Signal
    Processing I*, Eq. 3.14 applied to the delay).
    """
    n = np.arange(config.pulse_samples, dtype=np.float64)
    ds_dn = _pulse_rate_at(n / config.sampling_rate, config) / config.sampling_rate
    return noise_std(config, snr_db) / math.sqrt(float(ds_dn @ ds_dn))


def outlier_threshold(config: SonarConfig) -> float:
    """Range error [m] beyond which an estimate has left the correlation peak's main lobe.

    Half the main lobe of the pulse's autocorrelation: ``c / (2 B)`` for a chirp, ``c T / 2``
    for a tone burst.
    """
    if config.pulse == "lfm":
        return config.sound_speed / (2.0 * config.bandwidth)
    return config.sound_speed * config.pulse_length / 2.0


# --- Eq. 2: the spatial periodogram ---------------------------------------------------------------


def array_snapshots(
    beta: npt.ArrayLike,
    config: SonarConfig,
    rng: np.random.Generator | int | None,
    *,
    snr_db: float | None = None,
) -> C128:
    """One narrowband snapshot ``X[n]`` ``(R, M)`` of the array per source angle ``beta`` [rad].

    Unit amplitude, a random phase per snapshot, complex white noise at ``snr_db`` per element.
    """
    b = np.atleast_1d(np.asarray(beta, dtype=np.float64))
    gen = as_generator(rng)
    m = config.array_elements
    n = np.arange(m, dtype=np.float64)
    k = 2.0 * math.pi * config.center_frequency * config.array_spacing / config.sound_speed  # rad per element
    phase = gen.uniform(0.0, 2.0 * math.pi, size=b.shape)
    x: C128 = np.exp(1j * (k * np.cos(b)[:, None] * n[None, :] + phase[:, None]))
    snr = config.snr_db if snr_db is None else snr_db
    sigma = math.sqrt(0.5 / 10.0 ** (snr / 10.0))  # per real and imaginary part
    x += sigma * (gen.standard_normal(x.shape) + 1j * gen.standard_normal(x.shape))
    return x


def spatial_periodogram(x: npt.ArrayLike, betas: npt.ArrayLike, config: SonarConfig) -> F64:
    """Eq. 2a: ``P_s(beta)`` ``(R, G)`` for snapshots ``(R, M)`` at angles ``betas`` ``(G,)`` [rad]."""
    xa = np.atleast_2d(np.asarray(x, dtype=np.complex128))
    b = np.asarray(betas, dtype=np.float64)
    m = xa.shape[1]
    n = np.arange(m, dtype=np.float64)
    k = 2.0 * math.pi * config.center_frequency * config.array_spacing / config.sound_speed
    steering = np.exp(-1j * k * np.cos(b)[None, :] * n[:, None])  # (M, G)
    p: F64 = np.abs(xa @ steering) ** 2 / m
    return p


def estimate_azimuth(x: npt.ArrayLike, config: SonarConfig, *, grid_points: int = 1801) -> F64:
    """Eq. 2b: ``beta^ = argmax P_s(beta)`` over ``grid_points`` angles in ``[0, pi]`` [rad]."""
    betas = np.linspace(0.0, math.pi, grid_points)
    p = spatial_periodogram(x, betas, config)
    result: F64 = betas[np.argmax(p, axis=1)]
    return result


def array_resolution(config: SonarConfig, beta: float = 0.5 * math.pi) -> float:
    """Rayleigh resolution [rad] of the array at angle ``beta`` (first null of the beam pattern)."""
    du = config.sound_speed / (config.center_frequency * config.array_elements * config.array_spacing)
    s = max(math.sin(beta), 1e-9)
    return du / s


# --- the signal-level sonar -----------------------------------------------------------------------


class SignalSonar:
    """Signal-level fidelity: each beam's range comes from a synthesised echo and Eq. 1.

    The geometric ray cast (:class:`~hptvsim.sensors.sonar.GeometricSonar`) gives each beam's
    true range; the echo of that range is synthesised at ``config.snr_db`` and the matched filter
    estimates the delay; a correlator peak below :func:`detection_threshold` means no echo, and
    the beam reports ``max_range``. :meth:`bearings` estimates the relative bearing of given
    targets with the array and Eq. 2.

    Args:
        config: Sonar settings (``fidelity`` may be either; this class is the signal level).
        grid: Obstacle map, or ``None``.
        rng: Generator or seed for all noise.
        backend: Ray-cast backend (``"c"`` or ``"numpy"``).
        threads: Ray-cast threads.
    """

    def __init__(
        self,
        config: SonarConfig,
        grid: OccupancyGrid | None = None,
        *,
        rng: np.random.Generator | int | None = None,
        backend: Literal["c", "numpy"] = "c",
        threads: int | None = None,
    ) -> None:
        self.config = config
        self.rng = as_generator(rng)
        self.geometric = GeometricSonar(config, grid, backend=backend, threads=threads)
        self.pulse = transmit_pulse(config)
        self.sigma = noise_std(config)
        self.threshold = detection_threshold(config, self.sigma)

    def estimate_ranges(self, true_ranges: npt.ArrayLike) -> F64:
        """Range estimates (same shape) for true ranges [m]; ``>= max_range`` means no reflector."""
        r = np.asarray(true_ranges, dtype=np.float64)
        flat = r.ravel()
        out = np.empty_like(flat)
        cfg = self.config
        per_block = max(1, _CHUNK_SAMPLES // cfg.record_samples)
        for a in range(0, flat.size, per_block):
            block = flat[a : a + per_block]
            present = block < cfg.max_range
            x = synthesize_echoes(np.where(present, block, 0.0), cfg, self.rng, present=present)
            d, peak = estimate_delay(x, self.pulse)
            est = cfg.sound_speed * d / (2.0 * cfg.sampling_rate)
            out[a : a + per_block] = np.where(
                peak >= self.threshold, np.minimum(est, cfg.max_range), cfg.max_range
            )
        return out.reshape(r.shape)

    def ranges(
        self,
        poses: npt.ArrayLike,
        radii: npt.ArrayLike | None = None,
        *,
        sensing: npt.ArrayLike | None = None,
        active: npt.ArrayLike | None = None,
    ) -> F64:
        """Estimated ranges ``(B, S, K)`` [m] for poses ``(B, N, 3)`` (see ``GeometricSonar.ranges``)."""
        return self.estimate_ranges(self.geometric.ranges(poses, radii, sensing=sensing, active=active))

    def bearings(self, poses: npt.ArrayLike, targets: npt.ArrayLike) -> F64:
        """Relative bearings [rad] of targets estimated with the array (Eq. 2).

        Args:
            poses: ``(..., 3)`` [x, y, psi] of the listening vehicles.
            targets: ``(..., 2)`` [x, y] of the sources, broadcast against ``poses``.

        Returns:
            ``(...)`` bearing from the bow, clockwise, in ``[-pi/2, pi/2]`` (a source astern is
            reported at its mirror image ahead).
        """
        p = np.asarray(poses, dtype=np.float64)
        q = np.asarray(targets, dtype=np.float64)
        theta = np.arctan2(q[..., 1] - p[..., 1], q[..., 0] - p[..., 0]) - p[..., 2]
        beta = np.arccos(np.clip(np.sin(theta), -1.0, 1.0))  # angle from the starboard axis
        x = array_snapshots(beta.ravel(), self.config, self.rng)
        est: F64 = (0.5 * math.pi - estimate_azimuth(x, self.config)).reshape(beta.shape)
        return est


# --- error against SNR ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SnrSweep:
    """Monte Carlo of the matched filter's range error against SNR (:func:`snr_sweep`).

    Attributes:
        snr_db: ``(S,)`` echo SNRs [dB].
        rms_error: ``(S,)`` RMS range error [m] over all trials.
        rms_inlier: ``(S,)`` RMS range error [m] of the non-outliers (NaN when none).
        outlier_rate: ``(S,)`` fraction of errors beyond :func:`outlier_threshold`.
        within_one_sample: ``(S,)`` fraction of delay estimates within one sample of the truth.
        detection_rate: ``(S,)`` fraction of peaks above :func:`detection_threshold`.
        crlb: ``(S,)`` Cramér-Rao bound on the range's standard deviation [m].
        quantisation: RMS range error [m] of rounding to whole samples, ``c / (2 fs sqrt 12)``.
        trials: Records per SNR.
        config: The sonar settings used.
    """

    snr_db: F64
    rms_error: F64
    rms_inlier: F64
    outlier_rate: F64
    within_one_sample: F64
    detection_rate: F64
    crlb: F64
    quantisation: float
    trials: int
    config: SonarConfig


def snr_sweep(
    config: SonarConfig,
    snr_db: npt.ArrayLike,
    *,
    trials: int = 200,
    seed: int = 0,
    min_range: float = 5.0,
    progress: bool = False,
) -> SnrSweep:
    """Monte Carlo of the Eq. 1 estimator at each SNR, ranges uniform in ``[min_range, max_range - 1)``.

    Args:
        config: Sonar settings (pulse, sampling, sound speed, maximum range).
        snr_db: Echo SNRs [dB].
        trials: Records per SNR.
        seed: Random seed (the same seed gives the same numbers).
        min_range: Shortest true range [m].
        progress: Show a progress bar.
    """
    snrs = np.atleast_1d(np.asarray(snr_db, dtype=np.float64))
    rng = np.random.default_rng(seed)
    s = transmit_pulse(config)
    metres_per_sample = config.sound_speed / (2.0 * config.sampling_rate)
    limit = outlier_threshold(config)
    keys = ("rms", "inl", "out", "one", "det", "crlb")
    stats: dict[str, list[float]] = {k: [] for k in keys}
    from hptvsim._output import progress_bar

    for snr in progress_bar(snrs, desc="SNR sweep", unit="SNR", disable=not progress, leave=False):
        true_r = rng.uniform(min_range, config.max_range - 1.0, size=trials)
        x = synthesize_echoes(true_r, config, rng, snr_db=float(snr))
        d, peak = estimate_delay(x, s)
        true_d = 2.0 * true_r / config.sound_speed * config.sampling_rate
        err = d * metres_per_sample - true_r
        outlier = np.abs(err) > limit
        stats["rms"].append(float(np.sqrt(np.mean(err**2))))
        stats["inl"].append(float(np.sqrt(np.mean(err[~outlier] ** 2))) if (~outlier).any() else float("nan"))
        stats["out"].append(float(np.mean(outlier)))
        stats["one"].append(float(np.mean(np.abs(d - true_d) <= 1.0)))
        stats["det"].append(
            float(np.mean(peak >= detection_threshold(config, noise_std(config, float(snr)))))
        )
        stats["crlb"].append(delay_crlb(config, float(snr)) * metres_per_sample)
    arr = {k: np.array(v) for k, v in stats.items()}
    return SnrSweep(
        snr_db=snrs,
        rms_error=arr["rms"],
        rms_inlier=arr["inl"],
        outlier_rate=arr["out"],
        within_one_sample=arr["one"],
        detection_rate=arr["det"],
        crlb=arr["crlb"],
        quantisation=metres_per_sample / math.sqrt(12.0),
        trials=trials,
        config=config,
    )


def plot_snr_sweep(sweep: SnrSweep, path: str) -> None:
    """Write the plot of a :class:`SnrSweep` (RMS error and outlier rate against SNR) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = sweep.config
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7.5, 7.5), sharex=True, constrained_layout=True)
    ax1.semilogy(sweep.snr_db, sweep.rms_error, "o-", label="RMS error, all estimates")
    ax1.semilogy(sweep.snr_db, sweep.rms_inlier, "s--", label="RMS error, main-lobe estimates")
    ax1.semilogy(sweep.snr_db, sweep.crlb, "k-", lw=1, label="Cramér-Rao bound")
    ax1.axhline(sweep.quantisation, color="grey", ls=":", label="whole-sample quantisation")
    ax1.set_ylabel("range error [m]")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(loc="upper right", fontsize=8)
    pulse = f"LFM {cfg.bandwidth / 1e3:g} kHz" if cfg.pulse == "lfm" else "CW"
    ax1.set_title(
        f"Matched filter (Eq. 1): {pulse} at {cfg.center_frequency / 1e3:g} kHz, "
        f"{cfg.pulse_length * 1e3:g} ms, "
        f"fs {cfg.sampling_rate / 1e3:g} kHz, {sweep.trials} trials per SNR",
        fontsize=9,
    )
    ax2.plot(
        sweep.snr_db, sweep.outlier_rate, "o-", label=f"outliers (|error| > {outlier_threshold(cfg):.3g} m)"
    )
    ax2.plot(sweep.snr_db, 1.0 - sweep.within_one_sample, "s--", label="more than one sample off")
    ax2.plot(
        sweep.snr_db, sweep.detection_rate, "^-", label=f"detected (p_fa {cfg.false_alarm_probability:g})"
    )
    ax2.set_xlabel("echo SNR per sample [dB]")
    ax2.set_ylabel("fraction")
    ax2.set_ylim(-0.02, 1.02)
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="center right", fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)
