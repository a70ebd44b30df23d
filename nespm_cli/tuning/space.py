"""The search space of ``nespm tune``: which noise parameters of a filter are searched, over what range.

A parameter is a filter option (``--filter-option NAME.KEY``, :mod:`nespm_cli.filters.options`), so
a tuned value is written as the option and ``mc``, ``sweep`` and ``compare`` take it unchanged.
The default space of a filter with a covariance (docs/tuning.md):

* its Q: ``acc_noise_scale``, ``gyro_noise_scale`` (white noise) and, where the layout holds the
  bias blocks, ``acc_bias_rw_scale``, ``gyro_bias_rw_scale`` (random walks);
* its R: ``r_scale_<sensor>`` for every sensor of ``--sensors``;
* its P0: ``p0_<block>_scale`` for every block of the layout;

each a factor on a std over [0.1, 10] (the bias random walks over [0.001, 10]: :data:`BIAS_RW_RANGE`),
searched on a log scale (a factor 2 too large and a factor 2 too small are equally far from 1); the
sigma-point spread ``alpha`` over [1e-3, 1] (log) where the filter has one (``tunable``); a plugin's own options where the class declares a range in
``tune_ranges = {"key": (low, high)}`` (or ``(low, high, "linear")``; log by default).

``--tune-range NAME.KEY=LOW:HIGH`` (``NAME`` may be ``*``: every filter that has ``KEY``) or a
``[tune]`` config table (``"ekf.acc_noise_scale" = [0.5, 2]``) narrows or widens a range;
``=off`` drops a parameter from the search (it keeps its default). A noise scale's range (Q, R, P0) stays
within :data:`nespm_cli.filters.options.SCALE_LIMITS` (1e-3 to 1e3), the limits ``--filter-option`` puts on
the value a trial would write (:func:`check_scale_range`). Every mistake is one line.

Off by default, on with a range (:func:`optional_space`): a sensor's lever arm in the filter's model,
``lever_arm_<axis>_<sensor>`` [m, body, linear], from the sensor's ``lever_arm``. Not a noise
parameter but a model one, which the truth fixes and the filter may not know (the embedded DVL sits
1.6 m aft of the IMU): a researcher calibrates it on training tracks rather than hide the error in Q
and R. ``--tune-range '*.lever_arm_x_dvl=-3:3'`` searches the DVL's fore-aft offset for every filter.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from nespm_cli.errors import NespmError
from nespm_cli.filters.options import AXES, SCALE_LIMITS, lever_key, noise_scales, r_scale_key
from nespm_cli.nav.state import StateLayout

SCALE_RANGE = (0.1, 10.0)  # a std factor: two decades around the study's value
# A bias random walk's factor reaches three decades down: a walk the truth may not have (the synthetic IMU's
# biases are constant) must be able to vanish inside the range. At 0.1 every search of make tune-main's setup
# ended on that bound, and the others then traded against it along the level's direction (docs/tuning.md).
BIAS_RW_RANGE = (1e-3, 10.0)
ALPHA_RANGE = (1e-3, 1.0)  # the sigma-point spread (0 < alpha <= 1)
P0_KEYS = {"pos": "p0_pos_scale", "vel": "p0_vel_scale", "att": "p0_att_scale", "ba": "p0_acc_bias_scale",
           "bg": "p0_gyro_bias_scale"}


@dataclass(frozen=True)
class Param:
    """One searched parameter: the option ``filter.key`` over ``[low, high]`` (``log``: on a log
    scale); ``default`` is its value when the option is not given; ``kind`` says what it acts on
    (``Q``, ``R``, ``P0``, ``alpha`` or ``plugin``)."""

    filter: str
    key: str
    low: float
    high: float
    log: bool = True
    default: float = 1.0
    kind: str = "Q"  # Q, R, P0, alpha, plugin or model (a lever arm)

    @property
    def name(self) -> str:
        return f"{self.filter}.{self.key}"

    def record(self) -> dict:
        return asdict(self)


def default_space(name: str, cls: type, layout: StateLayout, sensors: tuple, alpha: float) -> list[Param]:
    """The default parameters of filter ``name`` (class ``cls``) for ``layout`` and ``sensors``;
    ``alpha``: the study's sigma-point spread (the default of the ``alpha`` parameter)."""
    if not noise_scales(cls, sensors):
        return []
    lo, hi = SCALE_RANGE
    out = [Param(name, "acc_noise_scale", lo, hi), Param(name, "gyro_noise_scale", lo, hi)]
    if layout.has("ba"):
        out.append(Param(name, "acc_bias_rw_scale", *BIAS_RW_RANGE))
    if layout.has("bg"):
        out.append(Param(name, "gyro_bias_rw_scale", *BIAS_RW_RANGE))
    out += [Param(name, r_scale_key(s), lo, hi, kind="R") for s in sensors]
    out += [Param(name, P0_KEYS[b], lo, hi, kind="P0") for b in layout.blocks if b in P0_KEYS]
    if "alpha" in (getattr(cls, "tunable", ()) or ()):
        out.append(Param(name, "alpha", *ALPHA_RANGE, default=float(alpha), kind="alpha"))
    defaults = dict(getattr(cls, "option_defaults", {}) or {})
    for key, rng in (getattr(cls, "tune_ranges", {}) or {}).items():
        if key not in defaults:
            raise NespmError(f"filter {name}: tune_ranges names {key!r}, which is not in its option_defaults")
        low, high = float(rng[0]), float(rng[1])
        log = len(rng) < 3 or rng[2] != "linear"
        out.append(Param(name, key, low, high, log, float(defaults[key]), "plugin"))
    for p in out:
        check_range(p.name, p.low, p.high, p.log)
    return out


def optional_space(name: str, cls: type, levers: dict) -> list[Param]:
    """The parameters of filter ``name`` (class ``cls``) a ``--tune-range`` turns on: the lever-arm
    coordinates of every sensor of ``levers`` (``{sensor: (x, y, z)}`` [m, body], the sensor's
    ``lever_arm``, each coordinate's default), linear over +-3 m around it until a range is given."""
    if not noise_scales(cls, tuple(levers)):
        return []
    return [Param(name, lever_key(s, a), float(lever[i]) - 3.0, float(lever[i]) + 3.0, False, float(lever[i]), "model")
            for s, lever in levers.items() for i, a in enumerate(AXES)]


def check_range(where: str, low: float, high: float, log: bool) -> None:
    """Refuse a non-finite, empty or inverted range, or a log range reaching 0 (one line)."""
    if not (math.isfinite(low) and math.isfinite(high)):
        raise NespmError(f"--tune-range {where}: the range must be finite, got {low:g}:{high:g}")
    if not low < high:
        raise NespmError(f"--tune-range {where}: empty or inverted range {low:g}:{high:g} (LOW < HIGH; "
                         "=off drops the parameter)")
    if log and low <= 0:
        raise NespmError(f"--tune-range {where}: a log-scale range needs LOW > 0, got {low:g}")


#: the kinds of :class:`Param` that are noise scales (a factor on a std of Q, R or P0)
SCALE_KINDS = ("Q", "R", "P0")


def check_scale_range(where: str, low: float, high: float) -> None:
    """Refuse a noise scale's range reaching outside :data:`~nespm_cli.filters.options.SCALE_LIMITS` (one line
    naming ``--tune-range``, the parameter ``where`` (NAME.KEY), the range and the limits): a trial there would
    run a factor ``--filter-option`` refuses (more than three decades from the study's std is a units
    mistake, not a tuning)."""
    lo, hi = SCALE_LIMITS
    if low < lo or high > hi:
        raise NespmError(f"--tune-range {where}={low:g}:{high:g}: outside the limits of a noise scale, {lo:g} to "
                         f"{hi:g} (a factor on the study's std, filters.options.SCALE_LIMITS; beyond is a units "
                         "mistake, not a tuning)")


def parse_range(text: str) -> tuple[str, str, float | None, float | None]:
    """``NAME.KEY=LOW:HIGH`` or ``NAME.KEY=off`` -> ``(NAME, KEY, LOW, HIGH)`` (None, None: off)."""
    head, eq, value = str(text).partition("=")
    name, dot, key = head.strip().partition(".")
    if not (eq and dot and name and key):
        raise NespmError(f"--tune-range {text!r}: expected NAME.KEY=LOW:HIGH or NAME.KEY=off, "
                         "e.g. ekf.acc_noise_scale=0.5:2")
    value = value.strip()
    if value.lower() == "off":
        return name.strip(), key.strip(), None, None
    try:
        low, high = (float(x) for x in value.replace(",", ":").split(":"))
    except ValueError:
        raise NespmError(f"--tune-range {head.strip()}: expected LOW:HIGH or off, got {value!r}") from None
    return name.strip(), key.strip(), low, high


def apply_ranges(space: dict[str, list[Param]], ranges, optional: dict | None = None) -> dict[str, list[Param]]:
    """``space`` ({filter: [Param]}) with ``ranges`` (``(NAME, KEY, LOW, HIGH)``, in order, the last
    winning; NAME ``*`` for every filter that has KEY) applied; a range on a parameter of
    ``optional`` ({filter: [Param]}, :func:`optional_space`) adds it. An unknown filter or
    parameter, an empty or inverted range, a noise scale's range outside ``SCALE_LIMITS``
    (:func:`check_scale_range`), or a space left empty is one line."""
    out = {f: {p.key: p for p in ps} for f, ps in space.items()}
    space = {f: list(ps) + list((optional or {}).get(f, ())) for f, ps in space.items()}
    for name, key, low, high in ranges:
        where = f"{name}.{key}"
        targets = [f for f in out if name in ("*", f)]
        if name != "*" and name not in out:
            raise NespmError(f"--tune-range {where}: {name} is not in --filters ({', '.join(out)})")
        hits = [f for f in targets if key in out[f] or key in {p.key for p in space[f]}]
        if not hits:
            known = sorted({p.key for f in targets for p in space[f]})
            raise NespmError(f"--tune-range {where}: unknown parameter; the space has {', '.join(known) or 'none'}")
        for f in hits:
            p = next(q for q in space[f] if q.key == key)
            if low is None:
                out[f].pop(key, None)
                continue
            check_range(where, low, high, p.log)
            if p.kind in SCALE_KINDS:
                check_scale_range(where, low, high)
            out[f][key] = Param(f, key, float(low), float(high), p.log, p.default, p.kind)
    result = {f: list(ps.values()) for f, ps in out.items()}
    for f, ps in result.items():
        if not ps:
            raise NespmError(f"--tune-range: nothing left to tune for {f} (every parameter is off)")
    return result


__all__ = ["ALPHA_RANGE", "BIAS_RW_RANGE", "P0_KEYS", "Param", "SCALE_KINDS", "SCALE_RANGE", "apply_ranges", "check_range",
           "check_scale_range", "default_space", "optional_space", "parse_range"]
