"""The IoUT acoustic link: propagation delay, packet loss, localisation error, off mode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.sensors import AcousticLinkConfig, GaussMarkovConfig
from hptvsim.sensors.acoustic import AcousticLink

PERFECT_POS = GaussMarkovConfig(enabled=False)


def run_static(
    link: AcousticLink, target: np.ndarray, pursuers: np.ndarray, steps: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    history = []
    for _ in range(steps):
        link.step(target, pursuers)
        history.append((link.time.copy(), link.position.copy(), link.age.copy(), link.stamp.copy()))
    return history


def test_delay_is_range_over_sound_speed() -> None:
    cfg = AcousticLinkConfig(
        packet_loss=0.0, position_error=PERFECT_POS, report_period=1.0, initial_fix=False
    )
    link = AcousticLink(cfg, num_envs=1, num_pursuers=2, dt=0.25, rng=0)
    target = np.array([[0.0, 0.0]])
    pursuers = np.array([[[750.0, 0.0], [0.0, 300.0]]])  # 0.5 s and 0.2 s away
    link.reset(target, pursuers)
    assert np.isnan(link.position).all() and np.isinf(link.age).all()
    hist = run_static(link, target, pursuers, 12)
    times = [h[0][0] for h in hist]
    stamps = np.array([h[3][0] for h in hist])  # (steps, P)
    # the near pursuer hears report 0 (sent at t = 0) at 0.2 s, i.e. at the step ending 0.25 s
    assert stamps[0, 1] == 0.0 and stamps[0, 0] == -np.inf
    # the far one at 0.5 s
    assert times[1] == 0.5 and stamps[1, 0] == 0.0
    # report 1 (t = 1.0) reaches the far pursuer at 1.5 s: at t = 1.25 it still has report 0
    i125, i150 = times.index(1.25), times.index(1.5)
    assert stamps[i125, 0] == 0.0 and stamps[i150, 0] == 1.0
    assert hist[i150][2][0, 0] == pytest.approx(0.5)  # age = now - stamp = the propagation delay
    assert hist[i125][2][0, 0] == pytest.approx(1.25)
    np.testing.assert_array_equal(hist[-1][1][0], [[0.0, 0.0], [0.0, 0.0]])


def test_moving_target_reports_its_past_position() -> None:
    cfg = AcousticLinkConfig(packet_loss=0.0, position_error=PERFECT_POS, report_period=0.5)
    link = AcousticLink(cfg, num_envs=1, num_pursuers=1, dt=0.25, rng=0)
    pursuers = np.array([[[30.0, 0.0]]])  # 20 ms away
    link.reset(np.array([[0.0, 0.0]]), pursuers)
    for k in range(1, 9):
        link.step(np.array([[2.0 * 0.25 * k, 0.0]]), pursuers)  # 2 m/s north
    # at t = 2.0 the newest report is the one sent at 1.5 s (the one sent at 2.0 s arrives at 2.02 s)
    assert link.stamp[0, 0] == 1.5
    assert link.position[0, 0, 0] == pytest.approx(3.0)  # where the target was at 1.5 s
    assert link.age[0, 0] == pytest.approx(0.5)


def test_reports_between_steps_are_interpolated() -> None:
    cfg = AcousticLinkConfig(packet_loss=0.0, position_error=PERFECT_POS, report_period=0.3)
    link = AcousticLink(cfg, num_envs=1, num_pursuers=1, dt=1.0, rng=0)
    pursuers = np.zeros((1, 1, 2))
    link.reset(np.array([[0.0, 0.0]]), pursuers)
    link.step(np.array([[10.0, 0.0]]), pursuers)  # reports at 0.3, 0.6, 0.9 within the step
    assert link.sent[0, 0] == 4  # 0.0 at reset, then three
    assert link.stamp[0, 0] == pytest.approx(0.9)
    assert link.position[0, 0, 0] == pytest.approx(9.0, abs=1e-6)  # delays: microseconds at < 10 m


def test_loss_statistics() -> None:
    p_loss = 0.3
    cfg = AcousticLinkConfig(packet_loss=p_loss, position_error=PERFECT_POS, report_period=0.25)
    b, p, steps = 200, 3, 100
    link = AcousticLink(cfg, num_envs=b, num_pursuers=p, dt=0.25, rng=5)
    target = np.zeros((b, 2))
    pursuers = np.full((b, p, 2), 15.0)
    link.reset(target, pursuers)
    gaps = []
    last = link.stamp.copy()
    for _ in range(steps):
        link.step(target, pursuers)
        gaps.append(link.stamp - last)
        last = link.stamp.copy()
    sent, received = int(link.sent.sum()), int(link.received.sum())
    rate = 1.0 - received / sent
    assert rate == pytest.approx(p_loss, abs=5 * math.sqrt(p_loss * (1 - p_loss) / sent))
    # losses are independent: after a received report, the next is lost with probability p_loss,
    # so the number of periods until the next one is geometric with mean 1 / (1 - p_loss)
    stamps_gap = np.diff(np.stack([np.zeros((b, p))] + [g for g in np.cumsum(gaps, axis=0)]), axis=0)
    updates = stamps_gap[stamps_gap > 0] / 0.25
    assert updates.mean() == pytest.approx(1 / (1 - p_loss), rel=0.05)


def test_out_of_range_pursuers_hear_nothing() -> None:
    cfg = AcousticLinkConfig(packet_loss=0.0, max_range=100.0, initial_fix=False, position_error=PERFECT_POS)
    link = AcousticLink(cfg, num_envs=1, num_pursuers=2, dt=0.25, rng=0)
    target = np.zeros((1, 2))
    pursuers = np.array([[[50.0, 0.0], [150.0, 0.0]]])
    link.reset(target, pursuers)
    run_static(link, target, pursuers, 10)
    assert link.received[0].tolist() == [3, 0]
    assert np.isinf(link.age[0, 1]) and np.isnan(link.position[0, 1]).all()


def test_buoy_transmitter_uses_slant_range() -> None:
    cfg = AcousticLinkConfig(
        packet_loss=0.0,
        transmitter="buoy",
        buoy_position=(0.0, 0.0),
        buoy_vertical_offset=400.0,
        initial_fix=False,
        position_error=PERFECT_POS,
    )
    link = AcousticLink(cfg, num_envs=1, num_pursuers=1, dt=0.05, rng=0)
    target = np.array([[100.0, 100.0]])  # far from the pursuer; irrelevant to the delay
    pursuers = np.array([[[300.0, 0.0]]])  # slant range 500 m: 1/3 s
    link.reset(target, pursuers)
    hist = run_static(link, target, pursuers, 8)
    first = next(h[0][0] for h in hist if h[3][0, 0] == 0.0)
    assert first == pytest.approx(0.35)  # first step end after 0.333 s


def test_localisation_error_statistics_shared_by_pursuers() -> None:
    err = GaussMarkovConfig(bias_std=2.0, tau=30.0, noise_std=1.0)
    cfg = AcousticLinkConfig(packet_loss=0.0, position_error=err, report_period=1.0)
    b = 2000
    link = AcousticLink(cfg, num_envs=b, num_pursuers=2, dt=1.0, rng=3)
    target = np.zeros((b, 2))
    pursuers = np.full((b, 2, 2), 1.0)
    link.reset(target, pursuers)
    link.step(target, pursuers)  # report 1, sent at 1 s, is a millisecond away at 1.0 s
    assert (link.stamp == 0.0).all()  # still the exact initial fix
    assert (link.position == 0.0).all()
    link.step(target, pursuers)
    assert (link.stamp == 1.0).all()
    errors = link.position[:, 0, :]
    assert float(errors.std()) == pytest.approx(math.hypot(2.0, 1.0), rel=5 / math.sqrt(2 * 2 * b))
    np.testing.assert_array_equal(link.position[:, 0], link.position[:, 1])  # one broadcast


def test_off_mode_is_perfect_and_instantaneous() -> None:
    cfg = AcousticLinkConfig(enabled=False)
    link = AcousticLink(cfg, num_envs=2, num_pursuers=3, dt=0.25, rng=0)
    pursuers = np.zeros((2, 3, 2))
    link.reset(np.array([[1.0, 2.0], [3.0, 4.0]]), pursuers)
    assert (link.age == 0).all()
    for k in range(5):
        target = np.array([[k, -k], [2.0 * k, 7.0]], dtype=float)
        link.step(target, pursuers)
        np.testing.assert_array_equal(link.position, np.broadcast_to(target[:, None, :], (2, 3, 2)))
        assert (link.age == 0).all()


def test_reset_subset_and_determinism() -> None:
    cfg = AcousticLinkConfig(packet_loss=0.5)

    def run(seed: int) -> AcousticLink:
        link = AcousticLink(cfg, num_envs=4, num_pursuers=2, dt=0.25, rng=seed)
        target = np.zeros((4, 2))
        pursuers = np.full((4, 2, 2), 100.0)
        link.reset(target, pursuers)
        for k in range(20):
            if k == 10:
                link.reset(target, pursuers, index=np.array([False, True, False, False]))
            link.step(target + k, pursuers)
        return link

    a, b = run(9), run(9)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.age, b.age)
    assert a.time.tolist() == [5.0, 2.5, 5.0, 5.0]


def test_bad_inputs_are_named() -> None:
    link = AcousticLink(AcousticLinkConfig(), num_envs=2, num_pursuers=1, dt=0.25)
    with pytest.raises(ValueError, match=r"target_xy must have shape \(2, 2\)"):
        link.reset(np.zeros((3, 2)), np.zeros((2, 1, 2)))
    with pytest.raises(ValueError, match="pursuer_xy holds a non-finite value"):
        link.reset(np.zeros((2, 2)), np.full((2, 1, 2), np.nan))
    with pytest.raises(ValueError, match="dt"):
        AcousticLink(AcousticLinkConfig(), num_envs=1, num_pursuers=1, dt=0.0)
