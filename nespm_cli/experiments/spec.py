"""The Monte Carlo experiment's specification: every option that determines its numbers, checked once.

:class:`Spec` is what ``mc``, ``sweep``, ``run``, ``corrupt`` and the Python API run; :func:`validate`
checks every option against its domain and the data before anything is written (one-line
:class:`~nespm_cli.errors.NespmError`), resolves paths, per-track corrections and the filter tuning
the filters will use. :func:`couple_filter` tells the filters the truth about the corruption (P0
and Q from the injected errors): it lives here, not in the CLI, so the API and the CLI give the
same numbers for the same options.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nespm_cli.data.corrections import IDENTITY_AXES, Corrections, resolve
from nespm_cli.data.corruption import CorruptionConfig, check_seed
from nespm_cli.data.track import Track
from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import DivergenceRule
from nespm_cli.filters import FilterConfig
from nespm_cli.filters.adaptive import BIAS_MODES
from nespm_cli.filters.options import check_filter_options, configure
from nespm_cli.filters.smoother import smoothed_name
from nespm_cli.nav.state import parse_layout
from nespm_cli.nav.synthesis import DEFAULT_IMU_RATE, ImuTruth

# The track readers, the filter and sensor registries and ProcessNet are imported in the functions
# that use them: the ``nespm`` command imports this module for its option defaults (``nespm
# --help`` stays fast), and they import every filter, sensor and data reader.

SCENARIOS = ("nominal", "outage")


#: what the per-run series chunks hold (docs/results-schema.md): error norms, block NEES and coverage,
#: NIS; ``axes`` adds every state component's error and std
SAVE_SERIES = ("norms", "axes")


@dataclass(frozen=True)
class Spec:
    """Everything that determines an experiment's numbers (``jobs`` does not)."""

    tracks: tuple = (5, 6)
    runs: int = 100
    filters: tuple = ("ekf", "ukf", "ukf-nespm")
    scenario: str = "nominal"
    seed: int = 0
    chunk_size: int | None = None  # runs per chunk; None: by runs and jobs, or the folder's (experiments/chunking.py)
    data_dir: str | None = None
    imu: str = "synthetic"
    dvl: str = "recorded"
    dvl_lever_arm: tuple = (0.0, 0.0, 0.0)
    dvl_r_std: float | None = None  # None: 0.02 synthetic, 0.1 recorded
    outage_start: float = 180.0
    outage_length: float = 20.0
    imu_axes: str = IDENTITY_AXES  # recorded IMU axis mapping (data/corrections.py)
    imu_time_offset: float = 0.0  # [s] recorded IMU stamp minus GT time
    imu_time_drift: float = 0.0  # [s/s] growth of that offset with GT time (a clock-rate error)
    dvl_time_offset: float = 0.0  # [s] DVL stamp minus GT time
    window: str | None = None  # "START:END" [s] of the GT file time to use
    corrections: str | None = None  # corrections.json (nespm check): per-track values of the four above
    track_corrections: tuple = ()  # resolved by validate: ((track, Corrections), ...), what the runs use
    divergence: DivergenceRule = field(default_factory=DivergenceRule)  # when a run counts as diverged
    weights: str | None = None  # ProcessNet file of the adaptive filters; None: the packaged default
    filter_plugins: tuple = ()  # user filter files or modules (docs/plugins.md), loaded before the filters run
    corruption: CorruptionConfig = field(default_factory=CorruptionConfig)
    filter_config: FilterConfig = field(default_factory=FilterConfig)  # its ``state``: the error-state layout
    sensors: tuple = ("dvl",)  # the measurement sources, in update order at equal times (docs/sensors.md)
    sensor_options: tuple = ()  # ((sensor, key, value), ...): --sensor-option NAME.KEY=VALUE, [sensors.NAME]
    sensor_plugins: tuple = ()  # user sensor files or modules, loaded before the sensors are built
    imu_rate: float = DEFAULT_IMU_RATE  # [Hz] the synthesized IMU's rate (--imu synthetic)
    tell_filter: bool = True  # P0 and Q's white noise from the corruption (couple_filter); False: as given
    filter_acc_noise: float | None = None  # [m/s² per sample] the filters' own Q white noise, over the coupling
    filter_gyro_noise: float | None = None  # [rad/s per sample]
    smooth: tuple = ()  # filters whose RTS-smoothed solution is reported too, as <filter>-rts (filters.smoother)
    filter_options: tuple = ()  # ((filter, key, value), ...): --filter-option NAME.KEY=VALUE, [filters.NAME]
    save_series: str = "norms"  # per-run series kept in the chunks: norms, or axes (+ every component's error and std)
    # run a track whose data contradict its declared conventions (a warning, recorded: experiments.accepted); False:
    # each track spec's gt.accept_residual decides (data.conventions)
    accept_residual: bool = False
    # options given explicitly (command line or config, e.g. "alpha"): checked for an effect (check_effective);
    # how an option was given is no part of the experiment: not compared, not recorded
    given: tuple = field(default=(), compare=False)

    @property
    def outputs(self) -> tuple:
        """``((result name, filter), ...)``: each filter's own results, then each smoothed one's
        (``<filter>-rts``, computed in the same pass as its filter)."""
        return tuple((f, f) for f in self.filters) + tuple((smoothed_name(f), f) for f in self.smooth)

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["tracks"] = list(self.tracks)
        d["filters"] = list(self.filters)
        d["sensors"] = list(self.sensors)
        # absent at their defaults: folders made before these options keep their identity
        if self.smooth:
            d["smooth"] = list(self.smooth)
        else:
            d.pop("smooth")
        if self.save_series == "norms":
            d.pop("save_series")
        if not self.accept_residual:
            d.pop("accept_residual")
        if self.filter_options:
            d["filter_options"] = [list(o) for o in self.filter_options]
        else:
            d.pop("filter_options")
        if not self.filter_config.options:
            d["filter_config"].pop("options")
        d.pop("given")  # how the options were given is no part of the experiment
        if not self.filter_config.r_scale:
            d["filter_config"].pop("r_scale")
        if not self.filter_config.levers:
            d["filter_config"].pop("levers")
        return json.loads(json.dumps(d, default=list))


def validate(spec: Spec) -> Spec:
    """Check every option against the data; return the spec with ``data_dir`` resolved."""
    from nespm_cli.data.tracks import available_tracks, load_track, resolve_data_dir
    from nespm_cli.experiments.suite import check_suite, load_sensors
    from nespm_cli.filters.registry import filter_names, get_filter
    from nespm_cli.learn.noise_model import WINDOW
    from nespm_cli.learn.noise_models import load_noise_model, typed_option
    from nespm_cli.sensors.registry import get_sensor, sensor_names

    check_domains(spec)
    if spec.chunk_size is not None and spec.chunk_size < 1:
        raise NespmError(f"--chunk-size must be at least 1, got {spec.chunk_size}")
    spec = load_sensors(load_filters(spec))
    for f in spec.filters:
        if f not in filter_names():
            raise NespmError(f"--filters: unknown filter {f!r}; choose from {', '.join(filter_names())}")
    if not spec.filters:
        raise NespmError("--filters: give at least one filter")
    if len(set(spec.filters)) != len(spec.filters):
        dup = next(f for f in spec.filters if spec.filters.count(f) > 1)
        raise NespmError(f"--filters: {dup} is given {spec.filters.count(dup)} times ({','.join(spec.filters)}); "
                         "give each filter once")
    layout = parse_layout(spec.filter_config.state)
    levered = tuple(n for n in spec.sensors if n in sensor_names() and get_sensor(n).has_lever)
    spec = dataclasses.replace(spec, filter_options=check_filter_options(spec.filter_options, spec.filters,
                                                                         get_filter, spec.sensors, levered))
    for f in spec.smooth:
        if f not in spec.filters:
            raise NespmError(f"--smooth {f}: not in --filters ({', '.join(spec.filters)}); the smoother runs on a "
                             "filter of the study")
        if not getattr(get_filter(f), "smoothable", False):
            able = [n for n in spec.filters if getattr(get_filter(n), "smoothable", False)]
            raise NespmError(f"--smooth {f}: this filter has no RTS smoother (of --filters, these have one: "
                             f"{', '.join(able) or 'none'}; docs/filters.md)")
    check_alpha_options(spec)
    check_sigma_options(spec, layout.n)
    check_effective(spec)
    if spec.save_series not in SAVE_SERIES:
        raise NespmError(f"--save-series: choose {' or '.join(SAVE_SERIES)}, got {spec.save_series!r}")
    if len(set(spec.smooth)) != len(spec.smooth):
        raise NespmError("--smooth: give each filter once")
    for f in spec.filters:
        if not get_filter(f).supports(layout):
            raise NespmError(f"--filters {f}: serves --state {' or '.join(get_filter(f).layouts)}, not {layout.name} "
                             "(docs/sensors.md)")
    if spec.imu == "recorded" and spec.imu_rate != DEFAULT_IMU_RATE:
        raise NespmError("--imu-rate sets the synthesized IMU's rate; --imu recorded keeps the file's own rate")
    if spec.scenario not in SCENARIOS:
        raise NespmError(f"--scenario: unknown scenario {spec.scenario!r}; choose from {', '.join(SCENARIOS)}")
    if spec.imu not in ("synthetic", "recorded"):
        raise NespmError(f"--imu: choose synthetic or recorded, got {spec.imu!r}")
    if spec.dvl not in ("synthetic", "recorded"):
        raise NespmError(f"--dvl: choose synthetic or recorded, got {spec.dvl!r}")
    if spec.filter_config.time_update not in ("dvl", "imu"):
        raise NespmError(f"--time-update: choose dvl or imu, got {spec.filter_config.time_update!r}")
    fc = spec.filter_config
    if fc.adaptive_bias not in BIAS_MODES:
        raise NespmError(f"--adaptive-bias: choose {' or '.join(BIAS_MODES)}, got {fc.adaptive_bias!r}")
    for flag, v in (("--tau", fc.tau), ("--tau-a", fc.tau_a), ("--tau-g", fc.tau_g)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise NespmError(f"{flag} must be a positive number of seconds, got {v:g}")
    lo, hi = fc.q_clip
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= 1 <= hi):
        raise NespmError(f"--q-clip must satisfy 0 < low <= 1 <= high, got {lo:g} {hi:g}")
    adaptive = any(needs_noise_std(f) for f in spec.filters)
    window = WINDOW
    if adaptive:  # a missing or foreign file or model fails now, in one line
        window = load_noise_model(spec.weights, typed_option(spec.given)).window
    elif spec.weights:
        raise NespmError(f"--noise-model/--weights {spec.weights}: only the adaptive filters (anekf, anukf, "
                         "anukf-nespm) use a noise model, and none is in --filters; drop it or add one")
    d = resolve_data_dir(spec.data_dir)
    have = available_tracks(d)
    for n in spec.tracks:
        if n not in have:
            where = d if d is not None else "the embedded default"
            raise NespmError(f"--tracks: no track {n} in {where}; available: {', '.join(map(str, have))}")
    for n in spec.tracks:
        load_track(n, d, accept_residual=accept_of(spec))  # validates every file up front
    spec = dataclasses.replace(spec, data_dir=str(Path(d).resolve()) if d is not None else None,
                               corrections=str(Path(spec.corrections).expanduser().resolve()) if spec.corrections else None,
                               weights=(str(Path(spec.weights).expanduser().resolve())
                                        if spec.weights and Path(spec.weights).expanduser().is_file() else spec.weights))
    spec = dataclasses.replace(spec, track_corrections=resolve_corrections(spec))
    durations = {n: track_inputs(spec, n)[0].duration
                 for n in spec.tracks}
    check_filter_domains(spec, min(durations.values()))
    check_suite(spec, layout, {n: track_inputs(spec, n)[0] for n in spec.tracks},
                {n: track_inputs(spec, n)[1] for n in spec.tracks})
    if adaptive and spec.imu == "recorded":  # one network window per DVL interval
        for n in spec.tracks:
            steps = np.diff(track_inputs(spec, n)[1].epoch_index)
            if not np.all(steps >= window):
                raise NespmError(f"--imu recorded: track {n} has {int(steps.min())}-{int(steps.max())} IMU steps "
                                 f"per DVL interval; the adaptive filters' noise model needs at least {window}")
    if spec.scenario == "outage":
        if spec.outage_length <= 0 or spec.outage_start <= 0:
            raise NespmError("--outage-start and --outage-length must be positive")
        for n in spec.tracks:
            dur = durations[n]
            if spec.outage_start + spec.outage_length > dur:
                raise NespmError(
                    f"--outage-start {spec.outage_start:g} + --outage-length {spec.outage_length:g} s "
                    f"ends past track {n}'s end ({dur:.1f} s)"
                )
    return dataclasses.replace(spec, filter_config=filter_config(spec))  # what the filters use, recorded as such


MAX_TRACK = 2**63 - 1  # the largest track number the tables' int64 column holds
MAX_LEVER_ARM = 100.0  # [m] a DVL farther than this from the INS is a units or sign mistake


def check_domains(spec: Spec) -> None:
    """Every option's domain, before anything is read or written (one-line NespmError)."""
    def finite(x) -> bool:
        return x is not None and np.isfinite(x)

    if spec.runs < 1:
        raise NespmError(f"--runs must be at least 1, got {spec.runs}")
    if not (finite(spec.imu_rate) and 1.0 <= spec.imu_rate <= 10000.0):
        raise NespmError(f"--imu-rate must be a rate from 1 to 10000 Hz, got {spec.imu_rate:g}")
    for flag, v in (("--filter-acc-noise", spec.filter_acc_noise), ("--filter-gyro-noise", spec.filter_gyro_noise)):
        if v is not None and not (finite(v) and v > 0):
            raise NespmError(f"{flag} must be a positive number, got {v:g}")
    check_filter_values(spec)
    check_seed(spec.seed)
    if len(set(spec.tracks)) != len(spec.tracks):
        dup = next(n for n in spec.tracks if list(spec.tracks).count(n) > 1)
        raise NespmError(f"--tracks: track {dup} is given more than once")
    if any(n < 1 for n in spec.tracks):
        raise NespmError(f"--tracks: track numbers are positive, got {min(spec.tracks)}")
    if any(n > MAX_TRACK for n in spec.tracks):
        raise NespmError(f"--tracks: track {max(spec.tracks)} is beyond {MAX_TRACK} (2^63-1: the tables store "
                         "track numbers as int64); rename its folder to a smaller number")
    fc = spec.filter_config
    check_alpha(fc.alpha, "--alpha")
    if spec.dvl_r_std is not None and not (finite(spec.dvl_r_std) and spec.dvl_r_std > 0):
        raise NespmError(f"--dvl-r-std must be a positive std [m/s], got {spec.dvl_r_std:g}")
    for flag, v in (("--acc-bias-rw", fc.acc_bias_rw), ("--gyro-bias-rw", fc.gyro_bias_rw)):
        if not (finite(v) and v >= 0):
            raise NespmError(f"{flag} must be a finite random walk >= 0, got {v:g}")
    lever = np.asarray(spec.dvl_lever_arm, dtype=float)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)) or np.abs(lever).max() > MAX_LEVER_ARM:
        raise NespmError(f"--dvl-lever-arm must be three finite numbers within +-{MAX_LEVER_ARM:g} m, "
                         f"got {' '.join(f'{x:g}' for x in lever.ravel())}")
    for flag, v in (("--outage-start", spec.outage_start), ("--outage-length", spec.outage_length)):
        if not finite(v):
            raise NespmError(f"{flag} must be a finite number of seconds, got {v:g}")
    d = spec.divergence
    for flag, v in (("--diverge-att-deg", d.att_deg), ("--diverge-nees", d.nees), ("--diverge-window", d.window_s)):
        if not (finite(v) and v > 0):
            raise NespmError(f"{flag} must be a positive number, got {v:g}")
    if not (finite(d.after_s) and d.after_s >= 0):
        raise NespmError(f"--diverge-after must be a number of seconds >= 0, got {d.after_s:g}")


#: the largest filter noise value a study may give: (Spec path, flag, limit, unit); beyond is a units
#: mistake (an accelerometer white noise of 1 g per sample, a DVL std of 5 m/s), and every run is lost
FILTER_VALUE_LIMITS = (
    ("filter_acc_noise", "--filter-acc-noise", 10.0, "m/s^2 per sample"),
    ("filter_gyro_noise", "--filter-gyro-noise", 1.0, "rad/s per sample"),
    ("filter_config.acc_bias_rw", "--acc-bias-rw", 1.0, "m/s^2/sqrt(s)"),
    ("filter_config.gyro_bias_rw", "--gyro-bias-rw", 0.1, "rad/s/sqrt(s)"),
    ("dvl_r_std", "--dvl-r-std", 5.0, "m/s"),
)


def check_filter_values(spec: Spec) -> None:
    """The filters' own noise values within :data:`FILTER_VALUE_LIMITS` (one line naming the option)."""
    for path, flag, limit, unit in FILTER_VALUE_LIMITS:
        v = _value(spec, path)
        if v is not None and np.isfinite(v) and v > limit:
            raise NespmError(f"{flag} {v:g}: above {limit:g} {unit}, not a sensor's noise (a units mistake?)")


def check_sigma_options(spec: Spec, n: int) -> None:
    """``--filter-option NAME.kappa`` with ``n + kappa > 0`` (``n`` the error-state size): else the
    sigma points' spread is not a real square root and every run is lost (one line naming it)."""
    for name, key, value in spec.filter_options:
        if key == "kappa" and not float(value) > -n:
            raise NespmError(f"--filter-option {name}.kappa={float(value):g}: need n + kappa > 0 with the {n}-state "
                             f"error state (kappa > {-n})")


def check_alpha(alpha, flag: str) -> None:
    """The sigma-point spread's domain, 0 < alpha <= 1, for ``--alpha`` and ``--filter-option NAME.alpha``."""
    if not (alpha is not None and np.isfinite(alpha) and 0 < alpha <= 1):
        raise NespmError(f"{flag} must satisfy 0 < alpha <= 1 (the UKF's sigma-point spread), got {alpha:g}")


def check_alpha_options(spec: Spec) -> None:
    """``--filter-option NAME.alpha`` (checked, typed triples) within the same domain as ``--alpha``."""
    for name, key, value in spec.filter_options:
        if key == "alpha":
            check_alpha(value, f"--filter-option {name}.alpha")


#: options that act on some filters or sensors only: (Spec path, flag, what uses it); one given while no
#: chosen filter or sensor uses it is refused (:func:`check_effective`)
SCOPED = (
    ("filter_config.alpha", "--alpha", "sigma"), ("filter_config.tau", "--tau", "adaptive"),
    ("filter_config.tau_a", "--tau-a", "adaptive"), ("filter_config.tau_g", "--tau-g", "adaptive"),
    ("filter_config.adaptive_bias", "--adaptive-bias", "adaptive"), ("filter_config.q_clip", "--q-clip", "adaptive"),
    ("corruption.dvl_noise", "--dvl-noise", "dvl"), ("dvl_lever_arm", "--dvl-lever-arm", "dvl"),
    ("dvl_r_std", "--dvl-r-std", "dvl"), ("outage_start", "--outage-start", "outage"),
    ("outage_length", "--outage-length", "outage"),
)


def _value(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return tuple(obj) if isinstance(obj, (list, tuple)) else obj


def check_effective(spec: Spec) -> None:
    """Refuse, in one line naming it, an option that does nothing for the chosen filters and sensors:
    ``--alpha`` without a sigma-point filter, ``--tau`` (``--tau-a``, ``--tau-g``, ``--adaptive-bias``,
    ``--q-clip``) without an adaptive filter, the DVL flags (``--dvl-noise``, ``--dvl-lever-arm``,
    ``--dvl-r-std``) without the ``dvl`` sensor, ``--outage-start``/``--outage-length`` without
    ``--scenario outage``. An option counts as given when it is in ``spec.given`` (the command line or a
    config named it) or differs from its default (the API); one left at its default is never an error."""
    from nespm_cli.filters.registry import filter_names, get_filter

    base = Spec()
    sigma = [f for f in spec.filters if "alpha" in (getattr(get_filter(f), "tunable", ()) or ())]
    adaptive = [f for f in spec.filters if needs_noise_std(f)]
    uses = {"sigma": bool(sigma), "adaptive": bool(adaptive), "dvl": "dvl" in spec.sensors,
            "outage": spec.scenario == "outage"}
    given = {g.replace("-", "_") for g in spec.given}
    for path, flag, scope in SCOPED:
        if uses[scope] or not (path.split(".")[-1] in given or _value(spec, path) != _value(base, path)):
            continue
        chosen = ",".join(spec.filters)
        takes = {"sigma": [f for f in filter_names() if "alpha" in (getattr(get_filter(f), "tunable", ()) or ())],
                 "adaptive": [f for f in filter_names() if needs_noise_std(f)]}.get(scope, [])
        why = {"sigma": f"sets the sigma-point spread of the unscented filters ({', '.join(takes)}), "
                        f"and none is in --filters ({chosen})",
               "adaptive": f"tunes the adaptive filters' process noise ({', '.join(takes)}), and none is in "
                           f"--filters ({chosen})",
               "dvl": f"is an option of the dvl sensor, which is not in --sensors ({','.join(spec.sensors)}); give the "
                      "sensor's own --sensor-option NAME.KEY=VALUE instead",
               "outage": f"applies with --scenario outage only (the scenario is {spec.scenario})"}[scope]
        raise NespmError(f"{flag}: {why}; the option would change nothing: drop it")


def check_filter_domains(spec: Spec, span_s: float) -> None:
    """Each filter's own option domains before anything is written: a filter class may define
    ``check_options(name, options, given, span_s)`` (its option values, the keys set explicitly, the
    shortest track's span [s]) raising one line (e.g. an adaptive filter's window longer than a track)."""
    from nespm_cli.filters.options import check_window, option_values
    from nespm_cli.filters.registry import get_filter

    step = None
    for f in spec.filters:
        cls = get_filter(f)
        given = {k for n, k, _ in spec.filter_options if n == f}
        values = option_values(cls, configure(filter_config(spec), f, cls, spec.filter_options))
        if "window" in given:
            step = epoch_step(spec) if step is None else step
            check_window(f, cls, values, given, step)
        check = getattr(cls, "check_options", None)
        if check is not None:
            check(f, values, given, span_s)


def epoch_step(spec: Spec) -> float:
    """[s] the longest of the spec's tracks' median epoch steps (the measurement epochs a window spans)."""
    return max(float(np.median(np.diff(track_inputs(spec, n)[0].t))) for n in spec.tracks)


def load_filters(spec: Spec) -> Spec:
    """Import the spec's filter plugins and the installed ``nespm.filters`` entry points (in the
    parent and again in every worker; idempotent); return the spec with plugin files as
    absolute paths (module names stay as given)."""
    from nespm_cli.filters.registry import FILTER_REGISTRY

    return dataclasses.replace(spec, filter_plugins=FILTER_REGISTRY.load_plugins(spec.filter_plugins))


def needs_noise_std(name: str) -> bool:
    """Whether filter ``name`` takes the ProcessNet noise std (the adaptive filters)."""
    from nespm_cli.filters.registry import get_filter

    return bool(get_filter(name).needs_noise_std)


def resolve_corrections(spec: Spec) -> tuple:
    """``((track, Corrections), ...)`` for every track of ``spec`` (:func:`corrections.resolve`)."""
    per = resolve(spec.tracks, spec.imu, spec.corrections, spec.imu_axes, spec.imu_time_offset,
                  spec.dvl_time_offset, spec.window, spec.imu_time_drift)
    return tuple(per.items())


def corrections_for(spec: Spec, number: int) -> Corrections:
    """The corrections track ``number`` runs with (resolved by :func:`validate`)."""
    if spec.track_corrections:
        return dict(spec.track_corrections)[number]
    return dict(resolve_corrections(dataclasses.replace(spec, tracks=(number,))))[number]


def track_inputs(spec: Spec, number: int) -> tuple[Track, ImuTruth]:
    """Track ``number`` as ``spec`` runs it (its corrections applied) and its IMU-rate truth and
    IMU (:func:`nespm_cli.experiments.inputs.prepared`: read once per process)."""
    from nespm_cli.experiments.inputs import prepared

    return prepared(number, spec.data_dir, spec.imu, corrections_for(spec, number), spec.imu_rate, accept_of(spec))


def accept_of(spec: Spec) -> bool | None:
    """``load_track``'s ``accept_residual`` of ``spec``: True with ``--accept-residual``, else None (each track
    spec's ``gt.accept_residual`` decides; a key set true stays true)."""
    return True if spec.accept_residual else None


#: what a study on tracks without ground truth reports, in one line (docs/data.md)
NO_TRUTH = "no ground truth: innovation statistics only"


def has_truth(spec: Spec, tracks: tuple | None = None) -> bool:
    """Whether every track of ``spec`` (``tracks``: these) has a ground truth (``ImuTruth.known``); a track
    spec without ``[gt]`` gives tracks without one (docs/data.md): their runs have innovations, no errors."""
    return all(track_inputs(spec, n)[1].known for n in (spec.tracks if tracks is None else tracks))


def filter_config(spec: Spec) -> FilterConfig:
    """The tuning the filters run with: ``spec.filter_config`` told the truth about the corruption
    (:func:`couple_filter`, unless ``tell_filter`` is False), the filters' own white noise
    (``filter_acc_noise``, ``filter_gyro_noise``) over it, and the DVL's filter std and lever arm as
    the DVL sensor resolves them (:func:`nespm_cli.experiments.suite.dvl_of`; recorded in the manifest)."""
    from nespm_cli.experiments.suite import dvl_of

    fc = couple_filter(spec.filter_config, spec.corruption) if spec.tell_filter else spec.filter_config
    own = {k: float(v) for k, v in (("acc_noise", spec.filter_acc_noise), ("gyro_noise", spec.filter_gyro_noise))
           if v is not None}
    dvl = dvl_of(spec)
    if dvl is not None:
        own.update(dvl_std=dvl.r_std(), lever_arm=tuple(dvl.opt.lever_arm))
    return dataclasses.replace(fc, **own)


def filter_config_of(spec: Spec, name: str, cfg: FilterConfig | None = None) -> FilterConfig:
    """The FilterConfig filter ``name`` runs with: the study's (``cfg``, default
    :func:`filter_config`) with its ``--filter-option`` values (:func:`nespm_cli.filters.options.configure`)."""
    from nespm_cli.filters.registry import get_filter

    return configure(cfg if cfg is not None else filter_config(spec), name, get_filter(name), spec.filter_options)


def couple_filter(fcfg: FilterConfig, corr: CorruptionConfig) -> FilterConfig:
    """The filter told the truth about the corruption: P0 from the initial-error and bias
    std (position: at least ``model.POS_STD_FLOOR``), Q's white noise from the injected
    per-sample noise (docs/filters.md)."""
    att = [corr.misalignment_deg] * 3
    if corr.heading_deg is not None:
        att[2] = corr.heading_deg
    return dataclasses.replace(
        fcfg, p0_vel=(corr.vel_h_std, corr.vel_h_std, corr.vel_v_std), p0_att_deg=tuple(att),
        p0_acc_bias=corr.acc_bias, p0_gyro_bias=corr.gyro_bias, acc_noise=corr.acc_noise,
        gyro_noise=corr.gyro_noise, p0_pos=(corr.pos_h_std, corr.pos_h_std, corr.pos_v_std))
