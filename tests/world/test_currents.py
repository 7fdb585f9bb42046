"""Current fields: analytic values, composition, vectorised shapes, and the FMU's current inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hptvsim.world.currents import (
    M2_PERIOD,
    CurrentField,
    CurrentSum,
    ShearCurrent,
    TidalCurrent,
    UniformCurrent,
    VortexCurrent,
    still_water,
)


def test_uniform_is_speed_times_compass_direction() -> None:
    c = UniformCurrent(speed=0.5, direction=math.radians(60.0))
    v = c.sample(0.0, np.array([[0.0, 0.0], [100.0, -50.0]]))
    expected = (0.5 * math.cos(math.radians(60.0)), 0.5 * math.sin(math.radians(60.0)))
    np.testing.assert_allclose(v, [expected, expected], atol=1e-15)
    east = UniformCurrent(speed=1.0, direction=math.pi / 2).sample(3.0, [0.0, 0.0])
    np.testing.assert_allclose(east, [0.0, 1.0], atol=1e-15)  # 90 deg = towards east (NED)
    assert c.is_steady and c.is_uniform


def test_shear_speed_changes_linearly_to_the_right_of_the_flow() -> None:
    c = ShearCurrent(speed=0.2, direction=0.0, shear_rate=0.01, reference=(10.0, 20.0))  # flows north
    pts = np.array([[10.0, 20.0], [500.0, 20.0], [10.0, 30.0], [10.0, 0.0]])
    v = c.sample(0.0, pts)
    # to the right of a northward flow is east: +10 m east adds 0.1 m/s, -20 m removes 0.2 m/s
    np.testing.assert_allclose(v, [[0.2, 0.0], [0.2, 0.0], [0.3, 0.0], [0.0, 0.0]], atol=1e-15)
    diagonal = ShearCurrent(speed=0.0, direction=math.pi / 4, shear_rate=0.1)
    d = diagonal.sample(0.0, [-1.0, 1.0])  # right of a north-east flow is south-east
    across = math.sqrt(2.0)
    np.testing.assert_allclose(
        d, [0.1 * across * math.cos(math.pi / 4), 0.1 * across * math.sin(math.pi / 4)]
    )
    assert not c.is_uniform and ShearCurrent(speed=1.0, direction=0.0, shear_rate=0.0).is_uniform


def test_vortex_matches_lamb_oseen_profile_and_sense() -> None:
    rc, vmax = 20.0, 0.8
    c = VortexCurrent(centre=(100.0, 50.0), speed=vmax, core_radius=rc, clockwise=True)
    r = np.array([1e-9, 0.5, 5.0, 1.1209181 * rc, 40.0, 200.0, 2000.0])
    pts = np.column_stack([100.0 + r, np.full_like(r, 50.0)])  # due north of the centre
    v = c.sample(0.0, pts)
    gamma = c.circulation
    expected = gamma / (2.0 * math.pi * r) * -np.expm1(-(r**2) / rc**2)
    np.testing.assert_allclose(v[:, 0], 0.0, atol=1e-15)  # purely tangential
    np.testing.assert_allclose(v[:, 1], expected, rtol=1e-9, atol=1e-12)
    assert v[3, 1] == pytest.approx(vmax, rel=1e-6)  # the peak is the stated speed
    assert v[3, 1] >= v[:, 1].max() - 1e-12
    assert v[-1, 1] == pytest.approx(gamma / (2.0 * math.pi * 2000.0), rel=1e-9)  # 1/r far field
    assert v[1, 1] > 0.0  # north of the centre the water flows east: clockwise seen from above
    ccw = VortexCurrent(centre=(100.0, 50.0), speed=vmax, core_radius=rc, clockwise=False)
    np.testing.assert_allclose(ccw.sample(0.0, pts), -v)
    np.testing.assert_allclose(c.sample(0.0, [100.0, 50.0]), [0.0, 0.0], atol=1e-15)  # still at the centre
    # the speed depends on the distance alone
    a = np.linspace(-math.pi, math.pi, 16)
    ring = np.column_stack([100.0 + 30.0 * np.cos(a), 50.0 + 30.0 * np.sin(a)])
    speeds = np.hypot(*c.sample(0.0, ring).T)
    np.testing.assert_allclose(speeds, speeds[0], rtol=1e-12)


def test_tidal_oscillates_with_its_period() -> None:
    c = TidalCurrent(amplitude=0.4, direction=math.pi / 2, period=600.0, mean=0.1)

    def east(t: float) -> float:
        return float(c.sample(t, [0.0, 0.0])[1])

    assert east(0.0) == pytest.approx(0.5)  # peak flood
    assert east(150.0) == pytest.approx(0.1)  # slack around the mean
    assert east(300.0) == pytest.approx(-0.3)  # peak ebb
    assert east(600.0) == pytest.approx(0.5)
    assert float(c.sample(123.0, [0.0, 0.0])[0]) == pytest.approx(0.0, abs=1e-15)
    assert not c.is_steady and c.is_uniform
    assert TidalCurrent(amplitude=0.1, direction=0.0).period == M2_PERIOD
    shifted = TidalCurrent(amplitude=0.4, direction=0.0, period=600.0, phase=math.pi)
    assert float(shifted.sample(0.0, [0.0, 0.0])[0]) == pytest.approx(-0.4)


def test_sum_superposes_and_flattens() -> None:
    a = UniformCurrent(speed=0.2, direction=0.0)
    b = VortexCurrent(centre=(0.0, 0.0), speed=0.5, core_radius=10.0)
    c = TidalCurrent(amplitude=0.1, direction=1.0, period=100.0)
    total = a + b + c
    assert isinstance(total, CurrentSum) and len(total.components) == 3
    pts = np.random.default_rng(0).uniform(-50.0, 50.0, size=(7, 2))
    np.testing.assert_allclose(
        total.sample(12.0, pts), a.sample(12.0, pts) + b.sample(12.0, pts) + c.sample(12.0, pts), atol=1e-15
    )
    assert not total.is_steady and not total.is_uniform
    np.testing.assert_array_equal(still_water().sample(5.0, pts), np.zeros_like(pts))
    assert still_water().is_steady and still_water().is_uniform


@pytest.mark.parametrize(
    "field",
    [
        UniformCurrent(speed=0.3, direction=0.4),
        ShearCurrent(speed=0.3, direction=0.4, shear_rate=0.002),
        VortexCurrent(centre=(50.0, 50.0), speed=0.6, core_radius=15.0),
        TidalCurrent(amplitude=0.2, direction=2.0, period=300.0),
        UniformCurrent(speed=0.3, direction=0.4)
        + VortexCurrent(centre=(0.0, 0.0), speed=0.6, core_radius=15.0),
    ],
    ids=["uniform", "shear", "vortex", "tidal", "sum"],
)
def test_sampling_is_vectorised_over_any_leading_shape(field: CurrentField) -> None:
    rng = np.random.default_rng(1)
    batch = rng.uniform(0.0, 100.0, size=(16, 4, 2))  # environments x agents
    v = field.sample(7.0, batch)
    assert v.shape == (16, 4, 2) and v.dtype == np.float64
    one_by_one = np.array([[field.sample(7.0, batch[e, a]) for a in range(4)] for e in range(16)])
    np.testing.assert_allclose(v, one_by_one, atol=1e-15)
    out = np.full((16, 4, 2), np.nan)
    assert field.sample(7.0, batch, out=out) is out  # written in place, no new array returned
    np.testing.assert_array_equal(out, v)
    assert field.sample(7.0, [1.0, 2.0]).shape == (2,)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        field.sample(0.0, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="out has shape"):
        field.sample(0.0, batch, out=np.zeros((4, 2)))


def test_invalid_parameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="out of range"):
        UniformCurrent(speed=-1.0, direction=0.0)
    with pytest.raises(ValueError, match="out of range"):
        VortexCurrent(centre=(0.0, 0.0), speed=1.0, core_radius=0.0)
    with pytest.raises(ValueError, match="out of range"):
        TidalCurrent(amplitude=0.1, direction=0.0, period=-5.0)


@pytest.mark.parametrize("psi_0", [0.0, math.pi / 2], ids=["heading-north", "heading-east"])
def test_fmu_drifts_with_the_current_in_ned(psi_0: float) -> None:
    """The FMU inputs current_x/current_y are {n} components: an unpowered sphere drifts due
    east with an eastward current whatever its heading (a body-frame reading would send the
    east-headed one south), as the quadratic drag of the relative velocity (nu_r = nu - nu_c)
    predicts: v_r(t) = v_c / (1 + k v_c t)."""
    from hptvsim.cosim import FmuModel
    from hptvsim.dynamics import SPHERICAL_UUV
    from hptvsim.fmu import fmu_path

    p = SPHERICAL_UUV
    current = UniformCurrent(speed=0.3, direction=math.pi / 2)
    inst = FmuModel(fmu_path("spherical")).instantiate("drift")
    inst.initialize({"x_0": 0.0, "y_0": 0.0, "psi_0": psi_0, "h_max": 0.05, "control_mode": 1})
    inputs = inst.bind_inputs(["current_x", "current_y"])
    outputs = inst.bind_outputs(["x", "y"])
    dt, steps = 0.25, 960  # 240 s
    for k in range(steps):
        inputs[:] = current.sample(k * dt, outputs)
        inst.step(dt)
    t = steps * dt
    vc = 0.3
    k_drag = -p.X_uu / (p.m - p.X_udot)  # 1/m, quadratic drag per unit (rigid + added) mass
    y_expected = vc * t - math.log1p(k_drag * vc * t) / k_drag  # m, integral of vc - v_r(t)
    assert abs(outputs[0]) < 0.01  # no north-south drift
    assert outputs[1] == pytest.approx(y_expected, rel=0.01)  # the tiny Stokes term slows it a little
