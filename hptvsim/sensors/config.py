"""Sensor settings: the sonar, the shared Gauss-Markov error model (Eq. 3) and the IoUT link.

Every class here is a frozen, keyword-only dataclass whose fields all have defaults, so a
scenario file only names what it changes. Units are SI inside (metres, seconds, hertz,
radians); angle fields carry ``metadata={"unit": "rad"}`` so that file loaders may accept them
as ``<field>_deg`` in degrees. Each ``__post_init__`` raises :class:`ValueError` naming the
field and what would be valid.

The scenario schema (``hptvsim.world``) maps TOML tables onto these classes through
:func:`dataclasses.fields`; a nested dataclass field (``SonarConfig.errors``) is a nested table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

__all__ = [
    "PULSE_KINDS",
    "SONAR_FIDELITIES",
    "TRANSMITTERS",
    "AcousticLinkConfig",
    "GaussMarkovConfig",
    "SonarConfig",
]

SONAR_FIDELITIES: tuple[str, ...] = ("geometric", "signal")
"""``geometric``: exact ray casts (training); ``signal``: echoes and the estimators of Eqs. 1-2."""

PULSE_KINDS: tuple[str, ...] = ("lfm", "cw")
"""``lfm``: linear frequency-modulated chirp; ``cw``: constant-frequency tone burst."""

TRANSMITTERS: tuple[str, ...] = ("target", "buoy")
"""Who sends the target's position reports over the acoustic link (see :class:`AcousticLinkConfig`)."""


def _fail(cls: str, name: str, value: Any, valid: str) -> ValueError:
    return ValueError(f"{cls}.{name} = {value!r} is invalid; valid: {valid}")


def _finite(
    cls: str, name: str, value: float, *, lower: float | None = None, open_lower: bool = False
) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and lower is not None:
        ok = value > lower if open_lower else value >= lower
    if not ok:
        bound = "" if lower is None else (f" > {lower:g}" if open_lower else f" >= {lower:g}")
        raise _fail(cls, name, value, f"a finite number{bound}")


def _integer(cls: str, name: str, value: int, *, lower: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < lower:
        raise _fail(cls, name, value, f"an integer >= {lower}")


def _boolean(cls: str, name: str, value: bool) -> None:
    if not isinstance(value, bool):
        raise _fail(cls, name, value, "true or false")


@dataclass(frozen=True, kw_only=True)
class GaussMarkovConfig:
    """The first-order Gauss-Markov error model shared by all sensors (paper Eq. 3).

    A sensor reports ``s = y + n + G_s`` (Eq. 3a): the true value ``y``, a slowly drifting bias
    ``n`` and white noise ``G_s ~ N(0, noise_std^2)``. The bias obeys ``n_dot = -n / tau + G_b``
    (Eq. 3b), driven by white noise ``G_b`` whose intensity is chosen so that the stationary
    standard deviation of ``n`` is ``bias_std``; its autocorrelation is
    ``bias_std^2 exp(-|lag| / tau)``. Units of ``bias_std`` and ``noise_std`` are those of the
    measured quantity (metres for ranges and positions).

    Attributes:
        enabled: False: the sensor is perfect (``s = y``).
        bias_std: Stationary standard deviation of the bias ``n`` [unit of the signal], >= 0.
        tau: Correlation time ``tau`` of the bias [s], > 0.
        noise_std: Standard deviation of the white noise ``G_s`` [unit of the signal], >= 0.
    """

    enabled: bool = True
    bias_std: float = 0.05  # m for ranges: a slowly drifting calibration / sound-speed error
    tau: float = 10.0  # s
    noise_std: float = 0.1  # m for ranges: per-ping jitter

    def __post_init__(self) -> None:
        c = type(self).__name__
        _boolean(c, "enabled", self.enabled)
        _finite(c, "bias_std", self.bias_std, lower=0.0)
        _finite(c, "tau", self.tau, lower=0.0, open_lower=True)
        _finite(c, "noise_std", self.noise_std, lower=0.0)

    @property
    def active(self) -> bool:
        """Whether the model adds anything (enabled and some standard deviation is non-zero)."""
        return self.enabled and (self.bias_std > 0.0 or self.noise_std > 0.0)


@dataclass(frozen=True, kw_only=True)
class SonarConfig:
    """A multi-beam range sonar, with its signal-level settings and error model.

    **Beams.** ``beams`` rays spread evenly over ``fov``, centred on the heading and numbered from
    port to starboard (angles measured clockwise from the bow, like ``psi`` in NED). With a full
    circle (``fov = 2 pi``) beam ``k`` points at ``(k - beams // 2) * 2 pi / beams``, so beam
    ``beams // 2`` looks straight ahead and beam 0 astern; with a sector the two edge beams lie
    on its edges (``-fov/2 .. +fov/2``).

    **Defaults and why.** 16 beams over a full circle with a 50 m maximum range:

    * the environments' observation (paper Eq. 14) holds ``l_i(t)``, "the distance detected by
      the sonar in the surroundings", and the collision penalty (Eq. 17) fires on
      ``min(l_i) < l_min`` whichever side the obstacle or the other vehicle is on, so the sonar
      must see all around (another vehicle closing from astern matters as much as a ridge ahead);
      16 beams give 22.5 degrees between beams;
    * 50 m is more than three times the 15 m safe distance and twice the 25 m target distance:
      two UUVs closing head-on at 2 x 3 m/s (Table II) still see each other about 6 s (23
      control steps of 0.25 s) before the safe distance is breached. Ranges much longer than
      that would, on the 400 m x 300 m site, mostly measure the far side of the site, make
      every ray longer to cast and add little to the decision; shorter ones leave too little
      warning at full speed.

    **Signal level** (``fidelity = "signal"``): each beam's echo is the transmitted pulse
    ``S[n]`` (an LFM chirp from ``center_frequency - bandwidth/2`` to ``+ bandwidth/2``, or a
    tone burst at ``center_frequency``) delayed by the two-way travel time, with white noise
    at ``snr_db``; the matched filter of Eq. 1 estimates the delay. A receiving uniform linear
    array of ``array_elements`` hydrophones spaced ``array_spacing`` apart estimates a target's
    azimuth with the spatial periodogram of Eq. 2. The defaults (20 kHz centre, 10 kHz band,
    2 ms pulse, 80 kHz sampling) give a time-bandwidth product of 20, a range resolution
    ``c / (2 B)`` of 7.5 cm and range bins of ``c / (2 fs)`` = 9.4 mm; half-wavelength spacing
    at 20 kHz (3.75 cm) with 16 elements gives a 60 cm array with a broadside beam width of
    about 7 degrees.

    Attributes:
        beams: Number of beams ``K`` (>= 1).
        fov: Angular width covered by the beams [rad], in (0, 2 pi]; 2 pi is a full circle.
        max_range: Maximum range [m], > 0; a beam that hits nothing reports it.
        fidelity: ``"geometric"`` (exact ray casts, for training) or ``"signal"`` (echo
            synthesis and the estimators of Eqs. 1-2).
        detect_vehicles: Whether beams hit other vehicles (circles of
            ``hptvsim.dynamics.VEHICLE_RADIUS``) as well as terrain.
        pulse: Transmitted pulse, ``"lfm"`` or ``"cw"``.
        center_frequency: Centre frequency ``F0`` [Hz].
        bandwidth: Swept bandwidth of the LFM chirp [Hz] (ignored by ``"cw"``).
        pulse_length: Pulse duration [s].
        sampling_rate: Sampling rate ``fs`` [Hz]; must exceed twice the highest frequency.
        sound_speed: Speed of sound ``c`` [m/s].
        snr_db: Echo signal-to-noise ratio [dB]: mean power of the echo over the pulse divided by
            the noise power per sample (matched-filter output SNR adds ``10 log10(pulse samples)``).
        false_alarm_probability: Probability that a noise-only record crosses the detection
            threshold somewhere (the signal-level sonar reports ``max_range`` below threshold).
        array_elements: Hydrophones ``M`` of the receiving uniform linear array (>= 2).
        array_spacing: Element spacing ``d`` [m]; ``d <= c / (2 F0)`` avoids grating lobes.
        errors: Gauss-Markov error model (Eq. 3) added to the reported ranges [m].
    """

    beams: int = 16
    fov: float = field(default=2.0 * math.pi, metadata={"unit": "rad"})  # rad
    max_range: float = 50.0  # m
    fidelity: Literal["geometric", "signal"] = "geometric"
    detect_vehicles: bool = True
    pulse: Literal["lfm", "cw"] = "lfm"
    center_frequency: float = 20e3  # Hz
    bandwidth: float = 10e3  # Hz
    pulse_length: float = 2e-3  # s
    sampling_rate: float = 80e3  # Hz
    sound_speed: float = 1500.0  # m/s
    snr_db: float = 0.0  # dB
    false_alarm_probability: float = 1e-3  # per record
    array_elements: int = 16
    array_spacing: float = 0.0375  # m, half a wavelength at 20 kHz and 1500 m/s
    errors: GaussMarkovConfig = field(default_factory=GaussMarkovConfig)

    def __post_init__(self) -> None:
        c = type(self).__name__
        _integer(c, "beams", self.beams, lower=1)
        _finite(c, "fov", self.fov, lower=0.0, open_lower=True)
        if self.fov > 2.0 * math.pi * (1.0 + 1e-12):
            raise _fail(c, "fov", self.fov, "an angle in (0, 2 pi] rad (files: fov_deg in (0, 360])")
        _finite(c, "max_range", self.max_range, lower=0.0, open_lower=True)
        if self.fidelity not in SONAR_FIDELITIES:
            raise _fail(c, "fidelity", self.fidelity, " or ".join(repr(f) for f in SONAR_FIDELITIES))
        _boolean(c, "detect_vehicles", self.detect_vehicles)
        if self.pulse not in PULSE_KINDS:
            raise _fail(c, "pulse", self.pulse, " or ".join(repr(p) for p in PULSE_KINDS))
        _finite(c, "center_frequency", self.center_frequency, lower=0.0, open_lower=True)
        _finite(c, "bandwidth", self.bandwidth, lower=0.0)
        if self.pulse == "lfm" and not 0.0 < self.bandwidth < 2.0 * self.center_frequency:
            raise _fail(
                c,
                "bandwidth",
                self.bandwidth,
                f"in (0, 2 * center_frequency = {2 * self.center_frequency:g}) Hz",
            )
        _finite(c, "pulse_length", self.pulse_length, lower=0.0, open_lower=True)
        _finite(c, "sampling_rate", self.sampling_rate, lower=0.0, open_lower=True)
        _finite(c, "sound_speed", self.sound_speed, lower=0.0, open_lower=True)
        f_high = self.center_frequency + (0.5 * self.bandwidth if self.pulse == "lfm" else 0.0)
        if self.sampling_rate <= 2.0 * f_high:
            raise _fail(
                c,
                "sampling_rate",
                self.sampling_rate,
                f"> {2.0 * f_high:g} Hz (twice the pulse's highest frequency)",
            )
        if self.pulse_samples < 2:
            raise _fail(
                c, "pulse_length", self.pulse_length, f">= 2 samples, i.e. >= {2.0 / self.sampling_rate:g} s"
            )
        _finite(c, "snr_db", self.snr_db)
        _finite(c, "false_alarm_probability", self.false_alarm_probability, lower=0.0, open_lower=True)
        if self.false_alarm_probability >= 1.0:
            raise _fail(c, "false_alarm_probability", self.false_alarm_probability, "a probability in (0, 1)")
        _integer(c, "array_elements", self.array_elements, lower=2)
        _finite(c, "array_spacing", self.array_spacing, lower=0.0, open_lower=True)
        if not isinstance(self.errors, GaussMarkovConfig):
            raise _fail(
                c,
                "errors",
                self.errors,
                "a GaussMarkovConfig (a table with enabled, bias_std, tau, noise_std)",
            )

    @property
    def pulse_samples(self) -> int:
        """Samples in the transmitted pulse, ``M`` of Eq. 1."""
        return round(self.pulse_length * self.sampling_rate)

    @property
    def record_samples(self) -> int:
        """Samples in one received record, ``N`` of Eq. 1: echoes from up to ``max_range``."""
        return math.ceil(2.0 * self.max_range / self.sound_speed * self.sampling_rate) + self.pulse_samples

    @property
    def wavelength(self) -> float:
        """Wavelength at the centre frequency [m]."""
        return self.sound_speed / self.center_frequency


@dataclass(frozen=True, kw_only=True)
class AcousticLinkConfig:
    """How the target's position reaches the pursuers through the IoUT network (section IV-A).

    The paper's IoUT network (surface buoys and seabed sensor nodes) captures the target's
    position and reports it to the UUVs by acoustic communication. Modelled here: every
    ``report_period`` seconds a position report is sent; it carries the target's position at
    that instant with the localisation error of ``position_error`` (Eq. 3, one bias per
    environment and axis, shared by all pursuers because one broadcast reaches them all). Each
    pursuer receives it after the acoustic propagation delay ``distance / sound_speed``, unless
    the packet is lost (independently per pursuer with probability ``packet_loss``) or the
    pursuer is farther than ``max_range`` from the transmitter.

    Who transmits (``transmitter``):

    * ``"target"`` (default): the sensor node that detects the target is close to it, so the
      report starts from the target's position;
    * ``"buoy"``: a gateway buoy at ``buoy_position`` relays every report; the distance is the
      slant range including ``buoy_vertical_offset`` (e.g. the operating depth).

    Attributes:
        enabled: False: perfect, instantaneous knowledge of the target's position.
        sound_speed: Speed of sound [m/s].
        report_period: Time between reports [s], > 0.
        packet_loss: Probability that a pursuer misses a report, in [0, 1).
        max_range: Farthest a report reaches [m], > 0 (acoustic modem range).
        transmitter: ``"target"`` or ``"buoy"``.
        buoy_position: ``(x, y)`` of the gateway buoy [m] (NED, used with ``"buoy"``).
        buoy_vertical_offset: Vertical distance between buoy and plane of motion [m], >= 0.
        initial_fix: Whether pursuers know the target's exact position at reset (briefing);
            otherwise they know nothing (NaN position, infinite age) until the first report.
        position_error: Localisation error of the reported position, per axis [m].
    """

    enabled: bool = True
    sound_speed: float = 1500.0  # m/s
    report_period: float = 1.0  # s
    packet_loss: float = 0.1  # probability per pursuer and report
    max_range: float = 1000.0  # m
    transmitter: Literal["target", "buoy"] = "target"
    buoy_position: tuple[float, float] = (200.0, 150.0)  # m, centre of a 400 m x 300 m site at (0, 0)
    buoy_vertical_offset: float = 0.0  # m
    initial_fix: bool = True
    position_error: GaussMarkovConfig = field(
        default_factory=lambda: GaussMarkovConfig(bias_std=1.0, tau=30.0, noise_std=0.5)
    )

    def __post_init__(self) -> None:
        c = type(self).__name__
        _boolean(c, "enabled", self.enabled)
        _finite(c, "sound_speed", self.sound_speed, lower=0.0, open_lower=True)
        _finite(c, "report_period", self.report_period, lower=0.0, open_lower=True)
        _finite(c, "packet_loss", self.packet_loss, lower=0.0)
        if self.packet_loss >= 1.0:
            raise _fail(c, "packet_loss", self.packet_loss, "a probability in [0, 1)")
        _finite(c, "max_range", self.max_range, lower=0.0, open_lower=True)
        if self.transmitter not in TRANSMITTERS:
            raise _fail(c, "transmitter", self.transmitter, " or ".join(repr(t) for t in TRANSMITTERS))
        pos = tuple(self.buoy_position) if isinstance(self.buoy_position, (tuple, list)) else ()
        if len(pos) != 2 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pos
        ):
            raise _fail(c, "buoy_position", self.buoy_position, "two finite numbers (x, y) in metres")
        object.__setattr__(self, "buoy_position", (float(pos[0]), float(pos[1])))
        _finite(c, "buoy_vertical_offset", self.buoy_vertical_offset, lower=0.0)
        _boolean(c, "initial_fix", self.initial_fix)
        if not isinstance(self.position_error, GaussMarkovConfig):
            raise _fail(c, "position_error", self.position_error, "a GaussMarkovConfig table")
