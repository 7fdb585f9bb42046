"""Sensor settings: the sonar, the shared Gauss-Markov error model (Eq. 3) and the IoUT link.

A scenario states what its vehicles carry (``[sonar]``, ``[acoustic]``), so these settings are
part of the scenario schema and live in the world layer; :mod:`hptvsim.sensors`, one layer up,
implements them over the world's maps (and re-exports the classes).

Every class here is a frozen, keyword-only dataclass whose fields all have defaults, so a
scenario file only names what it changes. Units are SI inside (metres, seconds, hertz,
radians). Fields are declared with :func:`hptvsim.world._schema.spec`: their docs, and the
limits (bounds) every number has, are metadata that the scenario schema, its JSON Schema and the
checks here share. Angle fields carry ``unit = "rad"`` so that file loaders may accept them as
``<field>_deg`` in degrees; the other units are stated in the docs. Each ``__post_init__``
raises :class:`ValueError` naming the field and what would be valid
(``SonarConfig.beams = 0 is invalid; valid: an integer in [1, 1024]``).

The scenario schema (:mod:`hptvsim.world.scenario`) maps TOML tables onto these classes through
:func:`dataclasses.fields`; a nested dataclass field (``SonarConfig.errors``) is a nested table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Literal

from hptvsim.world._schema import describe_bounds, show, spec, within_bounds

__all__ = [
    "MIN_REPORT_PERIOD",
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

MIN_REPORT_PERIOD = 0.1
"""Shortest time between two reports of the acoustic link [s]: 10 reports a second.

Physically, a position report is a packet of tens of bytes that an acoustic modem sends in tens of
milliseconds at a few kbit/s (plus its preamble and guard time), on a channel every node shares;
IoUT and USBL position fixes come at about 1 Hz, at best some 10 Hz. It also bounds the link's
work: at most ``dt / 0.1`` = 100 reports in a control step (``dt`` <= 10 s), and a queue of at
most ``(max_range / sound_speed + dt) / 0.1 + 1`` reports per pursuer
(:func:`~hptvsim.sensors.acoustic.queue_length`), instead of the ~1e9 slots (29 GB) that a
period of 1e-9 s asked for.
"""


def _fail(cls: str, name: str, value: Any, valid: str) -> ValueError:
    return ValueError(f"{cls}.{name} = {show(value)} is invalid; valid: {valid}")


def _meta(obj: Any, name: str) -> Any:
    return next(f.metadata for f in fields(obj) if f.name == name)


def _finite(obj: Any, name: str) -> None:
    """Check a number field: finite and within the bounds of its metadata."""
    value = getattr(obj, name)
    meta = _meta(obj, name)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and within_bounds(value, meta)
    if not ok:
        raise _fail(type(obj).__name__, name, value, f"a finite number {describe_bounds(meta)}")


def _integer(obj: Any, name: str) -> None:
    """Check an integer field against the bounds of its metadata."""
    value = getattr(obj, name)
    meta = _meta(obj, name)
    if isinstance(value, bool) or not isinstance(value, int) or not within_bounds(value, meta):
        raise _fail(type(obj).__name__, name, value, f"an integer {describe_bounds(meta)}")


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
        bias_std: Stationary standard deviation of the bias ``n`` [unit of the signal], in [0, 100].
        tau: Correlation time ``tau`` of the bias [s], in (0, 1e6].
        noise_std: Standard deviation of the white noise ``G_s`` [unit of the signal], in [0, 100].
    """

    enabled: bool = spec(True, doc="false: the sensor is perfect")
    bias_std: float = spec(
        0.05,  # m for ranges: a slowly drifting calibration / sound-speed error
        doc="stationary standard deviation of the bias n [unit of the signal: m for ranges]",
        ge=0.0,
        le=100.0,
    )
    tau: float = spec(10.0, doc="correlation time of the bias [s]", gt=0.0, le=1e6)
    noise_std: float = spec(
        0.1,  # m for ranges: per-ping jitter
        doc="standard deviation of the white noise G_s [unit of the signal: m for ranges]",
        ge=0.0,
        le=100.0,
    )

    def __post_init__(self) -> None:
        _boolean(type(self).__name__, "enabled", self.enabled)
        for name in ("bias_std", "tau", "noise_std"):
            _finite(self, name)

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
        beams: Number of beams ``K``, in [1, 1024].
        fov: Angular width covered by the beams [rad], in (0, 2 pi]; 2 pi is a full circle.
        max_range: Maximum range [m], in (0, 10000]; a beam that hits nothing reports it.
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
        array_elements: Hydrophones ``M`` of the receiving uniform linear array, in [2, 256].
        array_spacing: Element spacing ``d`` [m]; ``d <= c / (2 F0)`` avoids grating lobes.
        errors: Gauss-Markov error model (Eq. 3) added to the reported ranges [m].
    """

    # Units are stated in the docs, not as "unit" metadata: only angles carry that (fov).
    beams: int = spec(16, doc="number of beams K", ge=1, le=1024)
    fov: float = spec(
        2.0 * math.pi,
        doc="angular width covered by the beams (2 pi: a full circle)",
        unit="rad",
        gt=0.0,
        le=2.0 * math.pi,
    )
    max_range: float = spec(
        50.0, doc="maximum range; a beam that hits nothing reports it [m]", gt=0.0, le=1e4
    )
    fidelity: Literal["geometric", "signal"] = spec(
        "geometric", doc="'geometric' (exact ray casts, training) or 'signal' (echoes, Eqs. 1-2)"
    )
    detect_vehicles: bool = spec(True, doc="whether beams hit other vehicles as well as terrain")
    pulse: Literal["lfm", "cw"] = spec("lfm", doc="transmitted pulse: 'lfm' chirp or 'cw' tone burst")
    center_frequency: float = spec(20e3, doc="centre frequency F0 [Hz]", gt=0.0, le=1e7)
    bandwidth: float = spec(
        10e3, doc="swept bandwidth of the LFM chirp, below 2 F0 (ignored by 'cw') [Hz]", ge=0.0, le=1e7
    )
    pulse_length: float = spec(2e-3, doc="pulse duration, at least 2 samples [s]", gt=0.0, le=1.0)
    sampling_rate: float = spec(
        80e3, doc="sampling rate fs, above twice the pulse's highest frequency [Hz]", gt=0.0, le=1e7
    )
    sound_speed: float = spec(1500.0, doc="speed of sound c [m/s]", ge=1000.0, le=2000.0)
    snr_db: float = spec(0.0, doc="echo signal-to-noise ratio [dB]", ge=-100.0, le=100.0)
    false_alarm_probability: float = spec(
        1e-3, doc="probability that a noise-only record crosses the detection threshold", gt=0.0, lt=1.0
    )
    array_elements: int = spec(16, doc="hydrophones M of the receiving uniform linear array", ge=2, le=256)
    array_spacing: float = spec(
        0.0375,  # m, half a wavelength at 20 kHz and 1500 m/s
        doc="element spacing d; d <= c / (2 F0) avoids grating lobes [m]",
        gt=0.0,
        le=100.0,
    )
    errors: GaussMarkovConfig = spec(
        default_factory=GaussMarkovConfig, doc="Gauss-Markov error model (Eq. 3) of the reported ranges [m]"
    )

    def __post_init__(self) -> None:
        c = type(self).__name__
        _integer(self, "beams")
        _finite(self, "fov")
        _finite(self, "max_range")
        if self.fidelity not in SONAR_FIDELITIES:
            raise _fail(c, "fidelity", self.fidelity, " or ".join(repr(f) for f in SONAR_FIDELITIES))
        _boolean(c, "detect_vehicles", self.detect_vehicles)
        if self.pulse not in PULSE_KINDS:
            raise _fail(c, "pulse", self.pulse, " or ".join(repr(p) for p in PULSE_KINDS))
        _finite(self, "center_frequency")
        _finite(self, "bandwidth")
        if self.pulse == "lfm" and not 0.0 < self.bandwidth < 2.0 * self.center_frequency:
            raise _fail(
                c,
                "bandwidth",
                self.bandwidth,
                f"in (0, 2 * center_frequency = {2 * self.center_frequency:g}) Hz",
            )
        _finite(self, "pulse_length")
        _finite(self, "sampling_rate")
        _finite(self, "sound_speed")
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
        _finite(self, "snr_db")
        _finite(self, "false_alarm_probability")
        _integer(self, "array_elements")
        _finite(self, "array_spacing")
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
        report_period: Time between reports [s], in [0.1, 3600] (:data:`MIN_REPORT_PERIOD`: an
            acoustic modem sends a position report in tens of milliseconds and shares the
            channel, so an IoUT network reports a target at most about ten times a second).
        packet_loss: Probability that a pursuer misses a report, in [0, 1).
        max_range: Farthest a report reaches [m], in (0, 1e6] (acoustic modem range).
        transmitter: ``"target"`` or ``"buoy"``.
        buoy_position: ``(x, y)`` of the gateway buoy [m] (NED, used with ``"buoy"``).
        buoy_vertical_offset: Vertical distance between buoy and plane of motion [m], in [0, 11000].
        initial_fix: Whether pursuers know the target's exact position at reset (briefing);
            otherwise they know nothing (NaN position, infinite age) until the first report.
        position_error: Localisation error of the reported position, per axis [m].
    """

    enabled: bool = spec(True, doc="false: perfect, instantaneous knowledge of the target's position")
    sound_speed: float = spec(1500.0, doc="speed of sound [m/s]", ge=1000.0, le=2000.0)
    report_period: float = spec(1.0, doc="time between reports [s]", ge=MIN_REPORT_PERIOD, le=3600.0)
    packet_loss: float = spec(0.1, doc="probability that a pursuer misses a report", ge=0.0, lt=1.0)
    max_range: float = spec(
        1000.0, doc="farthest a report reaches (acoustic modem range) [m]", gt=0.0, le=1e6
    )
    transmitter: Literal["target", "buoy"] = spec("target", doc="who sends the reports: 'target' or 'buoy'")
    buoy_position: tuple[float, float] = spec(
        (200.0, 150.0),  # m, centre of a 400 m x 300 m site at (0, 0)
        doc="(x north, y east) of the gateway buoy, used with transmitter = 'buoy' [m]",
        ge=-1e7,
        le=1e7,
    )
    buoy_vertical_offset: float = spec(
        0.0, doc="vertical distance between buoy and plane of motion [m]", ge=0.0, le=11000.0
    )
    initial_fix: bool = spec(True, doc="whether pursuers know the target's exact position at reset")
    position_error: GaussMarkovConfig = spec(
        default_factory=lambda: GaussMarkovConfig(bias_std=1.0, tau=30.0, noise_std=0.5),
        doc="localisation error of the reported position, per axis [m]",
    )

    def __post_init__(self) -> None:
        c = type(self).__name__
        _boolean(c, "enabled", self.enabled)
        _finite(self, "sound_speed")
        _finite(self, "report_period")
        _finite(self, "packet_loss")
        _finite(self, "max_range")
        if self.transmitter not in TRANSMITTERS:
            raise _fail(c, "transmitter", self.transmitter, " or ".join(repr(t) for t in TRANSMITTERS))
        meta = _meta(self, "buoy_position")
        pos = tuple(self.buoy_position) if isinstance(self.buoy_position, (tuple, list)) else ()
        if len(pos) != 2 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and within_bounds(v, meta) for v in pos
        ):
            raise _fail(
                c,
                "buoy_position",
                self.buoy_position,
                f"two finite numbers (x, y) in metres, each {describe_bounds(meta)}",
            )
        object.__setattr__(self, "buoy_position", (float(pos[0]), float(pos[1])))
        _finite(self, "buoy_vertical_offset")
        _boolean(c, "initial_fix", self.initial_fix)
        if not isinstance(self.position_error, GaussMarkovConfig):
            raise _fail(c, "position_error", self.position_error, "a GaussMarkovConfig table")
