"""Per-filter options: ``--filter-option NAME.KEY=VALUE`` and ``[filters.NAME]`` config tables.

A filter takes two kinds of option:

* **its own** (a plugin's tuning): the class attribute ``option_defaults`` (``{"q_scale": 1.0}``)
  names them with their defaults, whose types (float, int, bool, str) convert the given text; the
  filter reads the values from ``cfg.options`` (:func:`option_values`);
* **a tuning field of** :class:`~nespm_cli.filters.model.FilterConfig` it declares in ``tunable``
  (the sigma-point filters: ``alpha``, ``beta``, ``kappa``): given for that filter alone, the
  filter runs with its own FilterConfig (:func:`configure`);
* **a noise scale** (every filter with a covariance, :data:`NOISE_SCALES`): a factor on a std of
  its Q (``acc_noise_scale``, ``gyro_noise_scale``, ``acc_bias_rw_scale``, ``gyro_bias_rw_scale``),
  of its P0 per block (``p0_pos_scale`` ... ``p0_gyro_bias_scale``) or of a sensor's R
  (``r_scale_<sensor>``, ``-`` in the name written ``_``: ``r_scale_dvl``, ``r_scale_dvl_beams``),
  over the study's value (the filter told the truth, ``--filter-acc-noise``, the sensor's
  ``r_std``); a variance scales by its square; from :data:`SCALE_LIMITS` (1e-3 to 1e3). ``nespm tune``
  searches these (docs/tuning.md);
* **a lever arm** (every filter with a covariance): ``lever_arm_<axis>_<sensor>`` (``lever_arm_x_dvl``)
  [m, body], one coordinate of the sensor's mounting point from the IMU in this filter's
  measurement model, in place of the sensor's ``lever_arm`` (which still makes the synthetic
  measurements): a filter that assumes another mounting point than the truth's, or that ``nespm
  tune`` calibrates on training tracks (``--tune-range '*.lever_arm_x_dvl=-3:3'``);
* **a robust update** (every filter with a covariance, :mod:`nespm_cli.filters.robust`):
  ``robust`` = ``none`` (default), ``gate`` (χ² gating at ``gate_prob``, default 0.999, lock-out guard
  after ``gate_streak`` consecutive rejections, default 3) or ``huber``;
  kept in ``cfg.options`` (read with :meth:`FilterConfig.robust_update`), applied by the engine;
* ``tuned_on``: where ``nespm tune`` tuned them (``seed=S;tracks=N,M;runs=A-B``): no effect on the
  numbers; ``mc`` on those realizations says that its numbers are training numbers.

The options are part of the experiment (``Spec.filter_options``): recorded in the manifest, in
the experiment's identity (a folder is never resumed with another value) and sweepable
(``sweep --param NAME.KEY``). An unknown filter, key or value is a one-line error.
"""
from __future__ import annotations

import dataclasses

from nespm_cli.errors import NespmError
from nespm_cli.filters.model import FilterConfig
from nespm_cli.filters.robust import ROBUST_OPTIONS, check_robust
from nespm_cli.sensors.source import LEVER_LIMIT


#: noise-scale option -> the FilterConfig field (a std, or a tuple of stds) it multiplies
NOISE_SCALES = {
    "acc_noise_scale": "acc_noise", "gyro_noise_scale": "gyro_noise", "acc_bias_rw_scale": "acc_bias_rw",
    "gyro_bias_rw_scale": "gyro_bias_rw", "p0_pos_scale": "p0_pos", "p0_vel_scale": "p0_vel",
    "p0_att_scale": "p0_att_deg", "p0_acc_bias_scale": "p0_acc_bias", "p0_gyro_bias_scale": "p0_gyro_bias",
}
#: the range of a noise scale: a factor on a std more than three decades from the study's value is a
#: units or typing mistake, not a tuning (``acc_noise_scale = 1e300`` loses every run)
SCALE_LIMITS = (1e-3, 1e3)
#: bounds of the built-in filters' own options beyond the filters' own checks: ``{key: (low, high, what)}``
OWN_LIMITS = {"iterations": (1, 100, "fixed-point iterations"), "beta": (0.0, 1e3, "the sigma-point weight beta")}
#: the fewest innovations a built-in filter's ``window`` [s] must hold (it must be longer than WINDOW_EPOCHS - 1
#: epoch steps): one innovation alone estimates nothing
WINDOW_EPOCHS = 2
R_SCALE = "r_scale_"  # + the sensor's name with '-' as '_': a factor on that sensor's R std for this filter
LEVER = "lever_arm_"  # + axis + '_' + the sensor's key: this filter's model lever arm coordinate [m, body]
AXES = "xyz"


TUNED_ON = "tuned_on"  # where a filter's options were tuned: "seed=S;tracks=1,2;runs=0-19" (nespm tune)


def tuned_on_text(seed: int, tracks, first: int, end: int) -> str:
    """The ``tuned_on`` value of tuning realizations: ``seed``, ``tracks``, runs ``first .. end-1``."""
    return f"seed={int(seed)};tracks={','.join(str(int(n)) for n in tracks)};runs={int(first)}-{int(end) - 1}"


def parse_tuned_on(text: str, where: str) -> tuple[int, tuple, int, int]:
    """``(seed, tracks, first run, last run)`` of a ``tuned_on`` value (one-line error naming ``where``)."""
    try:
        kv = dict(part.split("=", 1) for part in str(text).split(";"))
        first, last = (int(x) for x in kv["runs"].split("-"))
        return int(kv["seed"]), tuple(int(n) for n in kv["tracks"].split(",")), first, last
    except (KeyError, ValueError):
        raise NespmError(f"{where}: expected seed=S;tracks=N,M;runs=A-B (as nespm tune writes it), got "
                         f"{text!r}") from None


def training_overlap(filter_options, seed: int, tracks, runs: int) -> list[str]:
    """One line per filter whose ``tuned_on`` realizations are among those of a study (``seed``,
    ``tracks``, runs ``0 .. runs-1``): its numbers there are training numbers, not held-out ones."""
    lines = []
    for name, key, value in filter_options:
        if key != TUNED_ON:
            continue
        s, on_tracks, first, last = parse_tuned_on(value, f"--filter-option {name}.{key}")
        shared = sorted(set(on_tracks) & {int(n) for n in tracks})
        if s == int(seed) and shared and first < int(runs):
            lines.append(f"{name}: its settings were tuned on these realizations (seed {s}, track(s) "
                         f"{' '.join(map(str, shared))}, runs {first}-{min(last, int(runs) - 1)}): its numbers "
                         "there are training numbers, not held-out ones")
    return lines


def r_scale_key(sensor: str) -> str:
    """The option that scales ``sensor``'s R std for one filter: ``r_scale_dvl``, ``r_scale_dvl_beams``."""
    return R_SCALE + sensor.replace("-", "_")


def lever_key(sensor: str, axis: str) -> str:
    """The option that sets coordinate ``axis`` (x, y, z) of ``sensor``'s lever arm in one filter's
    model: ``lever_arm_x_dvl``, ``lever_arm_z_dvl_beams``."""
    return f"{LEVER}{axis}_{sensor.replace('-', '_')}"


def lever_keys(cls: type, sensors=None) -> dict:
    """``{key: 0.0}`` of the lever-arm options filter class ``cls`` takes for ``sensors`` (none without
    a covariance)."""
    if not getattr(cls, "has_covariance", True):
        return {}
    return {lever_key(s, a): 0.0 for s in (sensors or ()) for a in AXES}


def noise_scales(cls: type, sensors=None) -> dict:
    """``{key: 1.0}`` of the noise scales filter class ``cls`` takes (none without a covariance):
    :data:`NOISE_SCALES` and ``r_scale_<sensor>`` for each of ``sensors`` (None: no R scale)."""
    if not getattr(cls, "has_covariance", True):
        return {}
    return {**{k: 1.0 for k in NOISE_SCALES}, **{r_scale_key(s): 1.0 for s in (sensors or ())}}


def option_defaults(cls: type) -> dict:
    """``{key: default}`` of every option the filter class takes: its own, then its ``tunable``
    FilterConfig fields (with FilterConfig's defaults)."""
    own = dict(getattr(cls, "option_defaults", {}) or {})
    base = FilterConfig()
    return {**own, **{k: getattr(base, k) for k in getattr(cls, "tunable", ()) or ()}}


def typed(value, default, where: str):
    """``value`` (text from the command line, or a TOML value) as the type of ``default``."""
    text = str(value).strip()
    try:
        if isinstance(default, bool):
            if isinstance(value, bool):
                return value
            low = text.lower()
            if low in ("true", "yes", "1", "on"):
                return True
            if low in ("false", "no", "0", "off"):
                return False
            raise ValueError
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float) or default is None:
            v = float(text)
            if v != v or v in (float("inf"), float("-inf")):
                raise ValueError
            return v
        return text
    except ValueError:
        kind = type(default).__name__ if default is not None else "number"
        raise NespmError(f"{where}: expected a {kind}, got {text!r}") from None


def check_filter_options(pairs, filters, get_filter, sensors=(), lever_sensors=None) -> tuple:
    """Check ``(filter, key, value)`` triples against the study's ``filters`` (the classes from
    ``get_filter``), ``sensors`` (the R scales) and ``lever_sensors`` (those whose model has a lever
    arm; None: all of ``sensors``); return them with typed values, in the given order, the last of a
    repeated key winning. One-line errors naming ``--filter-option NAME.KEY``."""
    out: dict = {}
    for name, key, value in pairs:
        where = f"--filter-option {name}.{key}"
        if name not in filters:
            raise NespmError(f"{where}: {name} is not in --filters ({', '.join(filters)})")
        cls = get_filter(name)
        own = option_defaults(cls)
        scales = noise_scales(cls, sensors)
        levers = lever_keys(cls, sensors if lever_sensors is None else lever_sensors)
        if key in levers:
            v = typed(value, 0.0, where)
            if abs(v) > LEVER_LIMIT:
                raise NespmError(f"{where}: a lever-arm coordinate within +-{LEVER_LIMIT:g} m, got {value!r}")
            out[(name, key)] = v
            continue
        if key in ROBUST_OPTIONS and scales:
            out[(name, key)] = check_robust(key, value, where)
            continue
        if key == TUNED_ON and scales:
            parse_tuned_on(value, where)
            out[(name, key)] = str(value).strip()
            continue
        if key not in own and key not in scales:
            takes = ", ".join(sorted(own)) or "no options"
            extra = (f" (of its own; and the noise scales {', '.join(scales)}; lever_arm_X_SENSOR; robust, gate_prob, gate_streak)"
                     if scales
                     else "")
            if key.startswith(R_SCALE) and scales:
                extra += f"; {key} names no sensor of --sensors ({', '.join(sensors)})"
            if key.startswith(LEVER) and scales:
                with_lever = sensors if lever_sensors is None else lever_sensors
                extra += (f"; {key} names no axis x, y, z or no sensor of --sensors whose model has a lever arm "
                          f"({', '.join(with_lever) or 'none'})")
            raise NespmError(f"{where}: unknown option; {name} takes {takes}{extra}")
        default = own.get(key, scales.get(key))
        v = typed(value, default, where)
        if key in scales and not (isinstance(v, float) and v > 0):
            raise NespmError(f"{where}: a noise scale is a factor > 0, got {value!r}")
        if key in scales and not SCALE_LIMITS[0] <= v <= SCALE_LIMITS[1]:
            raise NespmError(f"{where}: a noise scale is a factor from {SCALE_LIMITS[0]:g} to {SCALE_LIMITS[1]:g} on the "
                             f"study's std (beyond is a units mistake, not a tuning), got {value!r}")
        if key in OWN_LIMITS and key in own and builtin(cls):
            lo, hi, what = OWN_LIMITS[key]
            if not lo <= v <= hi:
                raise NespmError(f"{where}: {what}, from {lo:g} to {hi:g}, got {value!r}")
        out[(name, key)] = v
    return tuple((n, k, v) for (n, k), v in out.items())


def builtin(cls: type) -> bool:
    """Whether filter class ``cls`` is one of nespm's own (defined in :mod:`nespm_cli.filters`)."""
    return str(getattr(cls, "__module__", "")).startswith("nespm_cli.filters.")


def check_window(name: str, cls: type, values: dict, given: set, step_s: float) -> None:
    """Built-in filter ``name``'s (class ``cls``) ``window`` [s] (``values``: its option values, ``given``: the keys set
    explicitly) holds at least :data:`WINDOW_EPOCHS` innovations: longer than ``WINDOW_EPOCHS - 1`` epoch
    steps ``step_s`` [s] (the tracks' longest median epoch step); a shorter window holds one innovation at a
    time and estimates nothing (``iae-ekf.window=1e-9`` failed mid-run). One line naming
    ``--filter-option NAME.window``."""
    if "window" not in given or "window" not in values or not builtin(cls):
        return
    window, step = float(values["window"]), float(step_s)
    if not window > (WINDOW_EPOCHS - 1) * step:
        raise NespmError(f"--filter-option {name}.window={window:g}: not longer than {WINDOW_EPOCHS - 1} measurement "
                         f"epoch ({(WINDOW_EPOCHS - 1) * step:g} s, the tracks' epoch step); a window must hold at least "
                         f"{WINDOW_EPOCHS} innovations")


def configure(cfg: FilterConfig, name: str, cls: type, pairs) -> FilterConfig:
    """The FilterConfig filter ``name`` runs with: its ``tunable`` fields of ``pairs`` (checked
    triples) set on ``cfg``, and its own options in ``cfg.options`` (``((key, value), ...)``)."""
    mine = [(k, v) for n, k, v in pairs if n == name]
    if not mine:
        return cfg
    tunable = set(getattr(cls, "tunable", ()) or ())
    fields = {k: v for k, v in mine if k in tunable}
    for k, v in mine:
        if k in NOISE_SCALES:
            old = getattr(cfg, NOISE_SCALES[k])
            fields[NOISE_SCALES[k]] = tuple(float(x) * v for x in old) if isinstance(old, tuple) else float(old) * v
    r_scale = tuple((k[len(R_SCALE):], float(v)) for k, v in mine if k.startswith(R_SCALE))
    if r_scale:
        fields["r_scale"] = r_scale
    levers = tuple((k[len(LEVER) + 2:], AXES.index(k[len(LEVER)]), float(v)) for k, v in mine if k.startswith(LEVER))
    if levers:
        fields["levers"] = levers
    own = tuple((k, v) for k, v in mine if k not in tunable and k not in NOISE_SCALES and not k.startswith(R_SCALE)
                and not k.startswith(LEVER) and k != TUNED_ON)
    return dataclasses.replace(cfg, **fields, options=own)


def option_values(cls: type, cfg: FilterConfig) -> dict:
    """``{key: value}`` of the filter's own options: its defaults, with those given in ``cfg.options``."""
    return {**dict(getattr(cls, "option_defaults", {}) or {}), **dict(cfg.options)}


__all__ = ["AXES", "LEVER", "NOISE_SCALES", "OWN_LIMITS", "R_SCALE", "SCALE_LIMITS", "TUNED_ON", "WINDOW_EPOCHS",
           "builtin", "check_filter_options", "check_window", "configure", "lever_key",
           "lever_keys", "noise_scales",
           "option_defaults", "option_values", "parse_tuned_on", "r_scale_key", "training_overlap", "tuned_on_text",
           "typed"]
