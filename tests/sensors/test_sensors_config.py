"""Sensor settings: defaults, units metadata, strict validation naming the field."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest

from hptvsim.sensors import AcousticLinkConfig, GaussMarkovConfig, SonarConfig


def test_defaults_are_valid_and_sensible() -> None:
    s = SonarConfig()
    assert s.beams >= 16
    assert s.fov == pytest.approx(2.0 * math.pi)
    assert s.max_range > 15.0 * 3  # well beyond the 15 m safe distance
    assert s.fidelity == "geometric"
    assert s.pulse_samples == 160
    assert s.record_samples == math.ceil(2 * 50.0 / 1500.0 * 80e3) + 160
    assert s.array_spacing <= s.wavelength / 2 + 1e-12  # no grating lobes
    AcousticLinkConfig()
    GaussMarkovConfig()


@pytest.mark.parametrize("cls", [SonarConfig, GaussMarkovConfig, AcousticLinkConfig])
def test_frozen_keyword_only_all_defaulted(cls: type[Any]) -> None:
    for f in dataclasses.fields(cls):
        assert f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING, f.name
    obj = cls()
    with pytest.raises(dataclasses.FrozenInstanceError):
        obj.enabled = False  # (SonarConfig has no 'enabled': still frozen)
    with pytest.raises(TypeError):
        cls(1)  # keyword-only


def test_angle_fields_carry_radian_metadata() -> None:
    units = {f.name: f.metadata.get("unit") for f in dataclasses.fields(SonarConfig)}
    assert units["fov"] == "rad"
    assert all(u is None for n, u in units.items() if n != "fov")


@pytest.mark.parametrize(
    ("cls", "kwargs", "field"),
    [
        (SonarConfig, {"beams": 0}, "beams"),
        (SonarConfig, {"beams": 2.5}, "beams"),
        (SonarConfig, {"beams": True}, "beams"),
        (SonarConfig, {"fov": 0.0}, "fov"),
        (SonarConfig, {"fov": 7.0}, "fov"),
        (SonarConfig, {"max_range": -1.0}, "max_range"),
        (SonarConfig, {"max_range": float("nan")}, "max_range"),
        (SonarConfig, {"fidelity": "exact"}, "fidelity"),
        (SonarConfig, {"pulse": "hfm"}, "pulse"),
        (SonarConfig, {"bandwidth": 50e3}, "bandwidth"),
        (SonarConfig, {"sampling_rate": 40e3}, "sampling_rate"),
        (SonarConfig, {"pulse_length": 1e-6}, "pulse_length"),
        (SonarConfig, {"snr_db": float("inf")}, "snr_db"),
        (SonarConfig, {"false_alarm_probability": 1.0}, "false_alarm_probability"),
        (SonarConfig, {"array_elements": 1}, "array_elements"),
        (SonarConfig, {"array_spacing": 0.0}, "array_spacing"),
        (SonarConfig, {"errors": {"tau": 1.0}}, "errors"),
        (SonarConfig, {"detect_vehicles": "yes"}, "detect_vehicles"),
        (GaussMarkovConfig, {"tau": 0.0}, "tau"),
        (GaussMarkovConfig, {"bias_std": -0.1}, "bias_std"),
        (GaussMarkovConfig, {"noise_std": float("nan")}, "noise_std"),
        (AcousticLinkConfig, {"packet_loss": 1.0}, "packet_loss"),
        (AcousticLinkConfig, {"packet_loss": -0.1}, "packet_loss"),
        (AcousticLinkConfig, {"report_period": 0.0}, "report_period"),
        (AcousticLinkConfig, {"transmitter": "satellite"}, "transmitter"),
        (AcousticLinkConfig, {"buoy_position": (1.0,)}, "buoy_position"),
        (AcousticLinkConfig, {"sound_speed": 0.0}, "sound_speed"),
        (AcousticLinkConfig, {"max_range": 0.0}, "max_range"),
    ],
)
def test_bad_values_name_the_field_and_what_is_valid(
    cls: type[Any], kwargs: dict[str, Any], field: str
) -> None:
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{field} = .* valid: "):
        cls(**kwargs)


def test_buoy_position_normalised_to_float_tuple() -> None:
    c = AcousticLinkConfig(buoy_position=[10, 20])  # type: ignore[arg-type]  # lists come from TOML
    assert c.buoy_position == (10.0, 20.0)


def test_cw_pulse_ignores_bandwidth_for_nyquist() -> None:
    c = SonarConfig(pulse="cw", bandwidth=0.0, sampling_rate=45e3)
    assert c.pulse == "cw"


def test_gauss_markov_active() -> None:
    assert GaussMarkovConfig().active
    assert not GaussMarkovConfig(enabled=False).active
    assert not GaussMarkovConfig(bias_std=0.0, noise_std=0.0).active
