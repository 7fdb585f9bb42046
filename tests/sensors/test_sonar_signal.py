"""Signal-level sonar: the matched filter (Eq. 1) and the spatial periodogram (Eq. 2)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
from click.testing import CliRunner

from hptvsim.sensors import GaussMarkovConfig, SonarConfig
from hptvsim.sensors import signal as sig
from hptvsim.sensors.measured import Sonar
from hptvsim.sensors.sonar import GeometricSonar
from hptvsim.world.grid import GridGeometry, OccupancyGrid


@pytest.mark.parametrize("pulse", ["lfm", "cw"])
def test_pulse(pulse: Literal["lfm", "cw"]) -> None:
    cfg = SonarConfig(pulse=pulse)
    s = sig.transmit_pulse(cfg)
    assert s.shape == (cfg.pulse_samples,)
    assert np.abs(s).max() <= 1.0
    assert np.mean(s**2) == pytest.approx(0.5, rel=0.05)
    spectrum = np.abs(np.fft.rfft(s, 8192))
    f = np.fft.rfftfreq(8192, 1 / cfg.sampling_rate)
    peak = f[np.argmax(spectrum)]
    lo, hi = (15e3, 25e3) if pulse == "lfm" else (19.5e3, 20.5e3)
    assert lo <= peak <= hi


def test_fft_matched_filter_is_eq_1a() -> None:
    cfg = SonarConfig(max_range=5.0)
    s = sig.transmit_pulse(cfg)
    x = sig.synthesize_echoes([1.0, 2.5, 4.2], cfg, 0)
    np.testing.assert_allclose(sig.matched_filter(x, s), sig.matched_filter_direct(x, s), atol=1e-9)
    assert sig.matched_filter(x, s).shape == (3, cfg.record_samples - cfg.pulse_samples + 1)


@pytest.mark.parametrize("snr_db", [5.0, 20.0])
def test_high_snr_delay_within_one_sample(snr_db: float) -> None:
    cfg = SonarConfig(pulse="lfm")
    rng = np.random.default_rng(1)
    r = rng.uniform(2.0, 49.0, 300)  # fractional delays in samples
    x = sig.synthesize_echoes(r, cfg, rng, snr_db=snr_db)
    d, _ = sig.estimate_delay(x, sig.transmit_pulse(cfg))
    true_d = 2 * r / cfg.sound_speed * cfg.sampling_rate
    assert np.abs(d - true_d).max() <= 1.0
    est = cfg.sound_speed * d / (2 * cfg.sampling_rate)
    assert np.abs(est - r).max() <= cfg.sound_speed / (2 * cfg.sampling_rate)  # one range bin, 9.4 mm


@pytest.mark.parametrize("snr_db", [15.0, 40.0])
def test_cw_stays_in_the_main_lobe_but_slips_carrier_cycles(snr_db: float) -> None:
    """A tone burst's correlation has carrier peaks every 4 samples (20 kHz at 80 kHz) that differ
    from the main one by a sample or two of overlap: even at high SNR the estimate lands on
    any peak near the top of the triangular main lobe. That is why sonars range with chirps."""
    cfg = SonarConfig(pulse="cw")
    rng = np.random.default_rng(2)
    r = rng.uniform(2.0, 49.0, 300)
    d, _ = sig.estimate_delay(sig.synthesize_echoes(r, cfg, rng, snr_db=snr_db), sig.transmit_pulse(cfg))
    err = d - 2 * r / cfg.sound_speed * cfg.sampling_rate
    assert np.abs(err).max() < cfg.pulse_samples / 4  # near the top of the main lobe
    assert (np.abs(err) > 2).mean() > 0.05  # but whole carrier cycles off, often


def test_low_snr_breaks_down_with_outliers() -> None:
    """Below the threshold noise peaks win: errors spread over the record, as theory expects."""
    cfg = SonarConfig()
    sweep = sig.snr_sweep(cfg, [-25.0, -10.0, 10.0], trials=150, seed=3)
    low, mid, high = 0, 1, 2
    assert sweep.outlier_rate[low] > 0.9
    assert sweep.rms_error[low] > 10.0  # m: uniform over a 50 m record gives ~20 m
    assert sweep.within_one_sample[low] < 0.1
    assert 0.05 < sweep.outlier_rate[mid] < 0.95  # the threshold region
    assert sweep.outlier_rate[high] == 0.0
    assert sweep.within_one_sample[high] == 1.0
    # at high SNR the error is the whole-sample quantisation, far above the Cramér-Rao bound
    assert sweep.rms_error[high] == pytest.approx(sweep.quantisation, rel=0.25)
    assert sweep.crlb[high] < sweep.quantisation
    # the bound falls 10x per 20 dB
    assert sweep.crlb[low] / sweep.crlb[high] == pytest.approx(10 ** (35 / 20), rel=1e-9)


def test_sweep_is_seeded() -> None:
    cfg = SonarConfig()
    a = sig.snr_sweep(cfg, [-10.0], trials=40, seed=7)
    b = sig.snr_sweep(cfg, [-10.0], trials=40, seed=7)
    np.testing.assert_array_equal(a.rms_error, b.rms_error)


def test_detection_threshold_false_alarms() -> None:
    cfg = SonarConfig(max_range=10.0, false_alarm_probability=0.1)
    sigma = sig.noise_std(cfg)
    eta = sig.detection_threshold(cfg, sigma)
    x = sig.synthesize_echoes(np.zeros(1500), cfg, 4, present=np.zeros(1500, bool))
    _, peak = sig.estimate_delay(x, sig.transmit_pulse(cfg))
    rate = np.mean(peak >= eta)
    assert rate <= 0.1 + 3 * math.sqrt(0.1 * 0.9 / 1500)  # Bonferroni: at most p_fa
    assert rate > 0.01  # but not absurdly conservative for this record length


def test_periodogram_azimuth_within_resolution_at_high_snr() -> None:
    cfg = SonarConfig()
    beta = np.radians(np.linspace(15, 165, 61))
    x = sig.array_snapshots(beta, cfg, 0, snr_db=20.0)
    est = sig.estimate_azimuth(x, cfg)
    res = np.array([sig.array_resolution(cfg, b) for b in beta])
    assert np.all(np.abs(est - beta) <= res / 2)
    # at broadside the default array resolves 2 / M rad = 7.2 degrees
    assert math.degrees(sig.array_resolution(cfg)) == pytest.approx(math.degrees(2 / 16))
    p = sig.spatial_periodogram(x[:1], np.linspace(0, math.pi, 181), cfg)
    assert p.shape == (1, 181) and (p >= 0).all()


def test_periodogram_peak_is_eq_2a() -> None:
    cfg = SonarConfig(array_elements=8)
    x = sig.array_snapshots([1.0], cfg, 2, snr_db=30.0)
    k = 2 * math.pi * cfg.center_frequency * cfg.array_spacing / cfg.sound_speed
    b = 1.3
    direct = abs(sum(x[0, n] * np.exp(-1j * k * math.cos(b) * n) for n in range(8))) ** 2 / 8
    assert sig.spatial_periodogram(x, [b], cfg)[0, 0] == pytest.approx(direct)


def test_signal_sonar_ranges_and_bearings() -> None:
    geom = GridGeometry(origin=(0.5, 0.5), resolution=1.0, shape=(80, 60))
    occ = np.zeros(geom.shape, bool)
    occ[50:, :] = True  # a wall north at x = 50 m
    grid = OccupancyGrid(geometry=geom, occupied=occ)
    cfg = SonarConfig(fidelity="signal", snr_db=10.0, beams=8)
    poses = np.array([[[20.0, 30.0, 0.0], [30.0, 20.0, 0.5]]])
    son = sig.SignalSonar(cfg, grid, rng=0)
    truth = GeometricSonar(cfg, grid).ranges(poses)
    est = son.ranges(poses)
    hit = truth < cfg.max_range
    assert hit.any() and (~hit).any()
    assert np.abs(est[hit] - truth[hit]).max() <= 2 * cfg.sound_speed / (2 * cfg.sampling_rate)
    assert (est[~hit] == cfg.max_range).all()  # no echo, no detection
    # through the full sensor, errors disabled: the same estimator
    quiet = dataclasses.replace(cfg, errors=GaussMarkovConfig(enabled=False))
    full = Sonar(quiet, grid, num_envs=1, num_agents=2, rng=0)
    assert np.abs(full.measure(poses, 0.25)[hit] - truth[hit]).max() < 0.05
    # bearings of a target ahead-left and ahead-right, within the array's resolution
    targets = np.array([[[40.0, 20.0], [40.0, 40.0]]])
    listen = np.array([[[20.0, 30.0, 0.0], [20.0, 30.0, 0.0]]])
    theta = np.arctan2(targets[..., 1] - 30.0, targets[..., 0] - 20.0)
    got = son.bearings(listen, targets)
    assert np.abs(got - theta).max() <= sig.array_resolution(cfg) / 2


def test_snr_plot_command_writes_png(tmp_path: Path) -> None:
    from hptvsim.cli import main

    out = tmp_path / "snr.png"
    res = CliRunner().invoke(
        main,
        ["sonar", "snr-plot", "--out", str(out), "--trials", "20", "--snr-min", "-20", "--snr-step", "10"],
    )
    assert res.exit_code == 0, res.output
    assert out.stat().st_size > 10_000
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(out.resolve()) in res.output
    bad = CliRunner().invoke(main, ["sonar", "snr-plot", "--out", str(out), "--snr-step", "0"])
    assert bad.exit_code != 0 and "--snr-step" in bad.output
