"""A sensor as a source of measurements: its times, its synthesis from the truth, its recorded
data and its measurement model (docs/sensors.md).

A :class:`Sensor` subclass (a built-in or a plugin, registered by name in
:mod:`nespm_cli.sensors.registry`) answers, for one track:

* **when** it measures: :meth:`Sensor.schedule` gives the grid samples of a synthesized record
  (every ``interval`` seconds of the IMU grid, optionally jittered; the engine splits the IMU step
  that straddles an off-grid time) — a recorded file brings its own stamps;
* **what** it measures from the truth: :meth:`Sensor.true_values` (K, m), to which the
  synthesis adds the per-run errors of the common options (white noise ``std``, a constant
  ``bias``, a ``scale`` factor error) drawn from the sensor's own seed stream;
* **which** of those measurements exist in each run: :func:`availability` (``outage`` windows,
  random ``dropout``, and a sensor's own rule such as surface-only fixes);
* **how a filter uses one**: :meth:`Sensor.measurement` builds the
  :class:`~nespm_cli.sensors.measurement.Measurement` (``z, h, H, R``) at that time.

Its records for R runs travel as a :class:`Channel`. A seed stream per sensor (:meth:`Sensor.rng`:
``SeedSequence(seed, spawn_key=(track, run, stream))``, the stream a number of the sensor's
own) means that adding or removing a sensor never changes the IMU, the initial errors or any
other sensor's draws.
"""
from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.state import NavState, StateLayout
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.scenario import (OUTLIER_SUB, SCHEDULE_SUB, outlier_errors, parse_outliers, parse_schedule,
                                        schedule_factor)

SOURCES = ("synthetic", "recorded")
MIN_VARIANCE = float(np.finfo(float).tiny)  # a std whose square is below the smallest normal double is refused
TRACK_LEVEL = 2**31  # the run slot of a track-level draw (jittered stamps: one schedule for every run)


LEVER_LIMIT = 100.0  # [m]: the largest lever-arm coordinate a sensor (or a filter's model of it) takes


@dataclass(frozen=True)
class SensorOptions:
    """Options every sensor has (``--sensor-option NAME.KEY=VALUE``; ``[sensors.NAME]`` in a config).

    * ``source``: ``synthetic`` (made from the truth in every run) or ``recorded`` (the track's file);
    * ``std``: the synthetic white noise std per measurement, and the filter's R unless ``r_std``;
    * ``r_std``: the filter's noise std (None: ``std``, the filter told the truth);
    * ``interval`` [s]: time between synthetic measurements (None: the sensor's default), on the
      IMU grid; ``jitter`` [s]: std of a random offset of each stamp (one draw per track, the same
      for every run; off-grid stamps split an IMU step);
    * ``bias``: std of a constant bias per run and axis; ``scale``: std of a scale-factor error per
      run (relative); both synthetic, unknown to the filter;
    * ``outage``: windows ``START:END[,START:END]`` [s since the first epoch] with no measurement;
    * ``dropout``: probability that a measurement is lost, independently per run and time;
    * ``lever_arm``: ``X,Y,Z`` [m, body] of the sensor from the IMU;
    * ``noise_schedule``: factors on ``std`` in time (``step:T=F,...``, ``ramp:T=F,...``,
      ``dynamic:SEG:LO:HI``); ``outliers``: heavy-tailed extra errors on a fraction of samples
      (``FRACTION:SCALE``, ``t:NU:FRACTION[:SCALE]``, ``:burst=L``); both synthetic, unknown to
      the filter (:mod:`nespm_cli.sensors.scenario`).
    """

    source: str = "synthetic"
    std: float = 1.0
    r_std: float | None = None
    interval: float | None = None
    jitter: float = 0.0
    bias: float = 0.0
    scale: float = 0.0
    outage: str = ""
    dropout: float = 0.0
    lever_arm: tuple = (0.0, 0.0, 0.0)
    noise_schedule: str = ""
    outliers: str = ""


@dataclass(frozen=True)
class TrackInfo:
    """The track a sensor measures on (docs/conventions.md, "A track's origin and start"):
    ``number``; ``origin`` (3,) the true ``[lat rad, lon rad, h m]`` (WGS-84, h up) of the vehicle
    (the IMU) at the run's first GT epoch, t = 0; ``start`` [s] that epoch's time on the track
    files' clock (the ``Time [s]`` column), so a file time is ``start + t``. Both are the same in
    every run and chunk of the track (they follow ``--window``)."""

    number: int
    origin: np.ndarray
    start: float


@dataclass(frozen=True)
class Truth:
    """The truth at K measurement times: ``t`` (K,) [s since the first epoch], ``pos`` (K, 3)
    ``[lat, lon, h]``, ``v_n`` (K, 3) [m/s], ``C_bn`` (K, 3, 3), ``w_nb_b`` (K, 3) body rate
    relative to NED [rad/s] (the IMU step ending there); ``track`` the :class:`TrackInfo`."""

    t: np.ndarray
    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    w_nb_b: np.ndarray
    track: TrackInfo | None = None


@dataclass
class Channel:
    """One sensor's measurements in R runs, K times in increasing order: ``index`` (K,) the IMU
    sample at or before each time and ``frac`` (K,) how far into the step that follows it lies
    (0: on the sample; the engine splits the step there); ``t`` (K,) [s since the first epoch];
    ``z`` (R, K, m) the values; ``ok`` (R, K) whether the measurement exists in that run;
    ``track`` the :class:`TrackInfo` (None for a channel built outside an experiment)."""

    sensor: "Sensor"
    index: np.ndarray
    t: np.ndarray
    z: np.ndarray
    ok: np.ndarray
    frac: np.ndarray | None = None
    track: TrackInfo | None = None

    def __post_init__(self) -> None:
        self.index = np.asarray(self.index, dtype=np.int64)
        self.t = np.asarray(self.t, dtype=float)
        self.frac = np.zeros(len(self.index)) if self.frac is None else np.asarray(self.frac, dtype=float)


@dataclass(frozen=True)
class Context:
    """What a measurement may need besides the solution: the bias-compensated IMU of the step that
    ends at its time, ``f_b`` (R, 3) specific force [m/s², body FRD] and ``w_ib_b`` (R, 3) angular
    rate relative to inertial space [rad/s, body FRD]; ``track`` the :class:`TrackInfo` (origin,
    start; None outside an experiment)."""

    f_b: np.ndarray
    w_ib_b: np.ndarray
    track: TrackInfo | None = None


class Sensor:
    """Base class of every sensor. Class attributes: ``name`` (set by ``register``), ``dim`` m,
    ``labels`` (m component names), ``observes`` (state blocks its model needs), ``Options``
    (its options dataclass, a :class:`SensorOptions` subclass), ``stream`` (its seed stream; None:
    derived from the name), ``default_interval`` [s] (None: the GT epochs), ``files`` (the
    recorded file's name pattern and its value columns)."""

    name: str = ""
    dim: int = 0
    labels: tuple = ()
    observes: tuple = ()
    Options: type = SensorOptions
    stream: int | None = None
    default_interval: float | None = 1.0
    has_lever: bool = True  # its model reads ``opt.lever_arm`` (a heading's does not)

    def __init__(self, options: SensorOptions | None = None):
        self.opt = options if options is not None else self.Options()

    # --- identity and randomness --------------------------------------------------------------
    @property
    def stream_id(self) -> int:
        """The seed stream of this sensor's draws (fixed per name; the DVL keeps the papers' 3)."""
        if self.stream is not None:
            return int(self.stream)
        return 1000 + zlib.crc32(self.name.encode()) % 1_000_000

    def rng(self, seed: int, track: int, run: int, sub: int = 0) -> np.random.Generator:
        """The generator of this sensor's draws in ``run`` (``sub`` 1: availability draws)."""
        key = (track, run, self.stream_id) if sub == 0 else (track, run, self.stream_id, sub)
        return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=key)))

    # --- to be provided by a sensor -------------------------------------------------------------
    def true_values(self, truth: Truth) -> np.ndarray:
        """The error-free measurement (K, m) at the truth ``truth``."""
        raise NotImplementedError

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        """The measurement object of values ``z`` (R, m) for a filter with ``layout``."""
        raise NotImplementedError

    def recorded(self, track) -> tuple[np.ndarray, np.ndarray] | None:
        """``(t (K,) [s, file time], z (K, m))`` of the track's recorded file (NaN rows: none), or None."""
        channels = getattr(track, "channels", None) or {}
        return channels.get(self.name)

    def available_extra(self, truth: Truth) -> np.ndarray | None:
        """A sensor's own availability rule (K,) bool (e.g. fixes only at the surface), or None."""
        return None

    def lose_components(self, values: np.ndarray, t: np.ndarray, seed: int, track: int,
                        runs: np.ndarray) -> np.ndarray:
        """``values`` (R, K, m) with the components a sensor loses on its own set to NaN (e.g. a
        DVL's lost beams); ``t`` (K,) [s since the first epoch]. Default: unchanged."""
        return values

    def present(self, values: np.ndarray) -> np.ndarray:
        """(R, K) whether a row of ``values`` (R, K, m) is a measurement: every component finite
        (a sensor whose ``Measurement`` masks NaN components itself says: any)."""
        return np.isfinite(values).all(axis=-1)

    # --- common behaviour ----------------------------------------------------------------------
    def check(self, layout: StateLayout) -> None:
        """Refuse a layout that cannot see what this sensor measures (one line)."""
        missing = [b for b in self.observes if not layout.has(b)]
        if missing:
            raise NespmError(f"--sensors {self.name}: observes the {missing[0]} block, which --state {layout.name} "
                             f"does not hold; use --state 15 (or add {missing[0]})")

    def interval(self) -> float | None:
        """Seconds between synthetic measurements (None: at the GT epochs)."""
        return self.opt.interval if self.opt.interval is not None else self.default_interval

    def noise_std(self) -> float:
        """The synthetic white noise std."""
        return float(self.opt.std)

    def r_std(self) -> float:
        """The filter's noise std per component."""
        return float(self.opt.r_std if self.opt.r_std is not None else self.opt.std)

    def R(self) -> np.ndarray:
        """The filter's noise covariance (m, m)."""
        return np.eye(self.dim) * self.r_std() ** 2

    def noise_factor(self, t: np.ndarray, seed: int, track: int, runs: np.ndarray) -> np.ndarray | None:
        """(R, K) the ``noise_schedule`` factor on the white noise std at times ``t`` (K,) [s since
        the first epoch] (a dynamic one from each run's :data:`SCHEDULE_SUB` sub-stream), or None
        without a schedule."""
        sched = parse_schedule(self.opt.noise_schedule, f"--sensor-option {self.name}.noise_schedule")
        if sched is None:
            return None
        dynamic = sched.kind == "dynamic"  # only a dynamic schedule draws
        return schedule_factor(sched, t, [self.rng(seed, track, int(r), sub=SCHEDULE_SUB) if dynamic else None
                                          for r in runs])

    def true_std(self, t: np.ndarray, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """(R, K) the white noise std the synthesis draws with at times ``t`` (K,) [s since the first
        epoch]: ``noise_std() x`` the schedule's factor (what an oracle filter is told; outliers aside)."""
        f = self.noise_factor(t, seed, track, runs)
        return np.full((len(runs), len(t)), self.noise_std()) if f is None else self.noise_std() * f

    def outlier_draws(self, t: np.ndarray, seed: int, track: int, runs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(errors (R, K, m), mask (R, K))``: the ``outliers`` extra errors at times ``t`` (K,)
        and which samples carry one, from each run's :data:`OUTLIER_SUB` sub-stream (zeros, no
        draw, without outliers)."""
        model = parse_outliers(self.opt.outliers, f"--sensor-option {self.name}.outliers")
        gens = [self.rng(seed, track, int(r), sub=OUTLIER_SUB) if model is not None else None for r in runs]
        return outlier_errors(model, len(t), self.dim, self.noise_std(), gens)

    def synthesize(self, truth: Truth, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """Synthetic records (R, K, m): true values x (1 + scale error) + bias + white noise (its std
        times the ``noise_schedule`` factor) + ``outliers``, each run from its own stream (noise
        first, then bias and scale, so an option never moves the noise draws; the schedule and the
        outliers from their own sub-streams)."""
        clean = self.true_values(truth)
        K, m = clean.shape
        runs = np.asarray(runs, dtype=np.int64)
        factor = self.noise_factor(truth.t, seed, track, runs)
        out = np.empty((len(runs), K, m))
        for i, r in enumerate(runs):
            g = self.rng(seed, track, int(r))
            noise = g.standard_normal((K, m))
            std = self.noise_std() if factor is None else self.noise_std() * factor[i][:, None]
            out[i] = clean + std * noise
            if self.opt.bias or self.opt.scale:
                bias, scale = g.standard_normal(m) * self.opt.bias, g.standard_normal() * self.opt.scale
                out[i] = out[i] + clean * scale + bias
        if self.opt.outliers:
            out = out + self.outlier_draws(truth.t, seed, track, runs)[0]
        return out


def parse_windows(text: str, where: str) -> list[tuple[float, float]]:
    """``"180:240,300:310"`` -> ``[(180, 240), (300, 310)]`` [s] (one-line error naming ``where``)."""
    out = []
    for part in str(text or "").replace(";", ",").split(","):
        if not part.strip():
            continue
        try:
            a, b = (float(x) for x in part.split(":"))
        except ValueError:
            raise NespmError(f"{where}: expected windows START:END[,START:END] in seconds, got {text!r}") from None
        if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
            raise NespmError(f"{where}: a window needs 0 <= START < END, got {part.strip()!r}")
        out.append((a, b))
    return out


def availability(sensor: Sensor, t: np.ndarray, truth: Truth | None, seed: int, track: int,
                 runs: np.ndarray) -> np.ndarray:
    """(R, K) whether each measurement exists: never at t = 0 (the filter starts there), not in an
    ``outage`` window ``[start, end)``, not where the sensor's own rule says no, and not dropped
    (probability ``dropout``, per run from the sensor's availability stream)."""
    t = np.asarray(t, dtype=float)
    ok = t > 1e-9
    for a, b in parse_windows(sensor.opt.outage, f"{sensor.name}.outage"):
        ok &= ~((t >= a - 1e-9) & (t < b - 1e-9))
    extra = sensor.available_extra(truth) if truth is not None else None
    if extra is not None:
        ok &= np.asarray(extra, dtype=bool)
    out = np.broadcast_to(ok, (len(runs), len(t))).copy()
    if sensor.opt.dropout > 0:
        for i, r in enumerate(runs):
            out[i] &= sensor.rng(seed, track, int(r), sub=1).random(len(t)) >= sensor.opt.dropout
    return out


def jittered(sensor: Sensor, t: np.ndarray, seed: int, track: int) -> np.ndarray:
    """Nominal stamps ``t`` (K,) [s] moved by N(0, jitter²), one draw per track (every run the
    same), kept increasing and inside ``(t[0], t[-1])`` of the nominal schedule's span."""
    if not sensor.opt.jitter:
        return t
    d = sensor.rng(seed, track, TRACK_LEVEL).standard_normal(len(t)) * sensor.opt.jitter
    return np.asarray(t, dtype=float) + d


def options_of(sensor_cls: type, raw: dict) -> SensorOptions:
    """``sensor_cls.Options`` from ``{key: value}`` (strings from the command line are converted by
    the field's type); an unknown key or a bad value is a one-line error naming ``name.key``."""
    fields = {f.name: f for f in dataclasses.fields(sensor_cls.Options)}
    kw = {}
    for key, value in raw.items():
        where = f"--sensor-option {sensor_cls.name}.{key}"
        if key not in fields:
            raise NespmError(f"{where}: unknown option; {sensor_cls.name} takes {', '.join(sorted(fields))}")
        kw[key] = convert(value, fields[key], where)
    opt = sensor_cls.Options(**kw)
    check_options(sensor_cls.name, opt)
    own = sensor_cls.synthesize is not Sensor.synthesize and not getattr(sensor_cls, "noise_scenarios", False)
    for key in ("noise_schedule", "outliers"):
        if getattr(opt, key, "") and own:
            raise NespmError(f"--sensor-option {sensor_cls.name}.{key}: {sensor_cls.name} draws its noise its own way "
                             "and does not apply noise scenarios yet (sensors with the common synthesis do: dvl, depth)")
    return opt


def convert(value, f: dataclasses.Field, where: str):
    """``value`` (a string, or a TOML value) as the type of field ``f`` (float, int, bool, str, tuple)."""
    default = f.default
    text = str(value).strip()
    try:
        if isinstance(default, bool):
            if isinstance(value, bool):
                return value
            if text.lower() in ("true", "yes", "1", "on"):
                return True
            if text.lower() in ("false", "no", "0", "off"):
                return False
            raise ValueError
        if isinstance(default, tuple):
            items = value if isinstance(value, (list, tuple)) else text.replace(" ", ",").split(",")
            out = tuple(float(x) for x in items if str(x).strip())
            if len(out) != len(default):
                raise NespmError(f"{where}={value!r}: expected {len(default)} comma-separated numbers "
                                 f"(e.g. {','.join(f'{x:g}' for x in default)}), got {len(out)}")
            return out
        if isinstance(default, str):
            return text
        if isinstance(value, bool):
            raise ValueError
        if text.lower() in ("none", "") and (default is None or "None" in str(f.type)):
            return None
        if isinstance(default, int):
            return int(text)
        return float(text)
    except ValueError:
        kind = type(default).__name__ if default is not None else "number"
        raise NespmError(f"{where}={value!r}: expected a {kind}") from None


def check_options(name: str, opt: SensorOptions) -> None:
    """Domains of the common options (one line naming ``name.key``)."""
    def bad(key: str, what: str) -> NespmError:
        return NespmError(f"--sensor-option {name}.{key}={getattr(opt, key)!r}: {what}")

    if opt.source not in SOURCES:
        raise bad("source", f"choose {' or '.join(SOURCES)}")
    derived = opt.std is None and type(opt).__dataclass_fields__["std"].default is None  # a sensor's own default
    if not derived and not (isinstance(opt.std, (int, float)) and math.isfinite(opt.std) and opt.std > 0):
        raise bad("std", "must be a positive std")
    if opt.r_std is not None and not (math.isfinite(opt.r_std) and opt.r_std > 0):
        raise bad("r_std", "must be a positive std")
    for key in ("std", "r_std"):  # R = std²: a square that underflows is a singular R, not a precise sensor
        v = getattr(opt, key)
        if isinstance(v, (int, float)) and v**2 < MIN_VARIANCE:
            raise bad(key, f"is too small: its square underflows ({v**2:.3g}), so R would be singular; "
                           f"give a std of at least {math.sqrt(MIN_VARIANCE):.2g}")
    if opt.interval is not None and not (math.isfinite(opt.interval) and opt.interval > 0):
        raise bad("interval", "must be a positive number of seconds")
    for key in ("jitter", "bias", "scale"):
        v = getattr(opt, key)
        if not (math.isfinite(v) and v >= 0):
            raise bad(key, "must be a finite std >= 0")
    if not (0.0 <= opt.dropout < 1.0):
        raise bad("dropout", "must be a probability in [0, 1)")
    lever = np.asarray(opt.lever_arm, dtype=float)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)) or np.abs(lever).max() > LEVER_LIMIT:
        raise bad("lever_arm", f"must be three finite numbers within +-{LEVER_LIMIT:g} m")
    parse_windows(opt.outage, f"--sensor-option {name}.outage")
    schedule = parse_schedule(opt.noise_schedule, f"--sensor-option {name}.noise_schedule={opt.noise_schedule!r}")
    outliers = parse_outliers(opt.outliers, f"--sensor-option {name}.outliers={opt.outliers!r}")
    for key, given in (("noise_schedule", schedule), ("outliers", outliers)):
        if given is not None and opt.source != "synthetic":
            raise bad(key, f"applies to a synthetic {name} only (its source is {opt.source}); "
                           f"add --sensor-option {name}.source=synthetic" + (" or --dvl synthetic" if name == "dvl" else ""))


__all__ = ["Channel", "Context", "LEVER_LIMIT", "SOURCES", "Sensor", "SensorOptions", "TrackInfo", "Truth", "availability", "check_options",
           "convert", "jittered", "options_of", "parse_windows"]
