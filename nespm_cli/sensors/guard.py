"""Calls into a sensor plugin's code, checked: every failure is one line naming the sensor and its file.

A plugin sensor (one not defined under ``nespm_cli.``) is called through this module wherever
nespm calls it — its construction (:func:`make_sensor`), ``true_values`` / ``synthesize``
(:func:`sensor_call`, :func:`checked_values`) and every method of its
:class:`~nespm_cli.sensors.measurement.Measurement` (:class:`CheckedMeasurement`, which the engine
hands to the filter in place of the plugin's object). The rules (docs/sensors.md, "Errors"):

* an exception — ``SystemExit`` too — becomes ``sensor NAME (FILE): METHOD raised TYPE: text``
  (``NESPM_DEBUG=1`` re-raises it with its traceback); a :class:`NespmError` the plugin raises
  keeps its text, prefixed with ``sensor NAME (FILE):``;
* shapes: ``dim`` a positive int with ``dim`` ``labels``; ``true_values`` (K, dim),
  ``synthesize`` (R, K, dim), ``z`` / ``predict`` / ``innovation`` (R, m), ``h`` (R, S, m),
  ``H`` and ``H_invariant`` (R, m, n), ``R`` (m, m) or (R, m, m);
* values: ``R`` finite, symmetric to :data:`SYM_TOL` of its largest element (then symmetrized,
  ``(R + Rᵀ)/2``; more asymmetry is refused) and positive definite; ``true_values``, ``H``, ``predict``
  and ``innovation`` finite wherever the solution is finite (NaN there is the sensor's, not a
  filter's divergence);
* randomness: a call that moves numpy's global random state (``np.random.normal`` ...) is refused,
  since its numbers would depend on ``--jobs`` and ``--chunk-size``; a sensor draws from
  ``self.rng(seed, track, run)``.

Built-in sensors are called directly (they are tested; the checks would cost time, not change numbers).
"""
from __future__ import annotations

import dataclasses
import math
import os

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.state import BLOCKS, NavState
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.registry import SENSOR_REGISTRY
from nespm_cli.sensors.source import Sensor, SensorOptions

#: largest |R − Rᵀ| accepted, relative to max |R| (round-off); it is then symmetrized
SYM_TOL = 1e-9


def is_plugin(sensor: Sensor | type) -> bool:
    """Whether ``sensor`` (an instance or class) is a plugin's (not defined under ``nespm_cli.``)."""
    cls = sensor if isinstance(sensor, type) else type(sensor)
    return not cls.__module__.startswith("nespm_cli.")


def where(sensor: Sensor | type) -> str:
    """``sensor NAME (FILE)``: the words that start every message about a sensor's code."""
    cls = sensor if isinstance(sensor, type) else type(sensor)
    return f"sensor {cls.name} ({SENSOR_REGISTRY.source_of(cls)})"


def global_rng_state() -> tuple:
    """A cheap fingerprint of numpy's global (legacy) random state."""
    st = np.random.get_state(legacy=False)
    return st["state"]["pos"], st["has_gauss"], st["state"]["key"][:8].tobytes(), st["state"]["key"][-8:].tobytes()


def sensor_call(sensor: Sensor | type, method: str, fn, *args):
    """``fn(*args)`` for a plugin's ``method``, every failure one line (module docstring);
    a built-in's is called as it is."""
    if not is_plugin(sensor):
        return fn(*args)
    before = global_rng_state()
    try:
        out = fn(*args)
    except NespmError as e:
        text = " ".join(str(e).split())
        raise NespmError(text if text.startswith(where(sensor)) else f"{where(sensor)}: {text}") from None
    except (Exception, SystemExit) as e:
        if os.environ.get("NESPM_DEBUG"):
            raise
        text = " ".join(str(e).split())[:160]
        if isinstance(e, SystemExit):
            raise NespmError(f"{where(sensor)}: {method} called sys.exit({e.code!r}); a sensor raises "
                             "nespm_cli.errors.NespmError to stop with a message") from None
        raise NespmError(f"{where(sensor)}: {method} raised {type(e).__name__}: {text} "
                         "(NESPM_DEBUG=1 shows the traceback)") from None
    if global_rng_state() != before:
        raise NespmError(f"{where(sensor)}: {method} drew from numpy's global random generator (np.random.*), "
                         "so its numbers would depend on --jobs and --chunk-size; draw from "
                         "self.rng(seed, track, run) (docs/sensors.md)")
    return out


def check_class(cls: type) -> None:
    """A plugin's class attributes: ``observes`` blocks of the error state, ``dim`` a positive int,
    ``labels`` ``dim`` names (one line)."""
    unknown = [b for b in tuple(cls.observes or ()) if b not in BLOCKS]
    if unknown:
        raise NespmError(f"{where(cls)}: observes {unknown[0]!r}, not a block of the error state "
                         f"(choose from {', '.join(BLOCKS)})")
    dim = cls.dim
    if isinstance(dim, property):
        return  # a dimension that follows the options (the fix's) is checked on the instance
    check_dim(cls, dim, cls.labels)


def check_dim(sensor, dim, labels) -> None:
    """``dim`` a positive int and ``labels`` as many names (one line naming the sensor)."""
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise NespmError(f"{where(sensor)}: dim = {dim!r}; a sensor measures dim >= 1 values (an int)")
    if labels and len(labels) < dim:
        raise NespmError(f"{where(sensor)}: labels has {len(labels)} names for dim = {dim}")


def make_sensor(cls: type, options: SensorOptions) -> Sensor:
    """``cls(options)``, a plugin's ``__init__`` failure and a bad ``dim`` one line naming it."""
    if not is_plugin(cls):
        return cls(options)
    check_class(cls)
    for f in dataclasses.fields(options):  # a plugin's own options: NaN is no value (built-ins check theirs)
        v = getattr(options, f.name)
        if any(isinstance(x, float) and math.isnan(x) for x in (v if isinstance(v, tuple) else (v,))):
            raise NespmError(f"--sensor-option {cls.name}.{f.name}=nan: is NaN; give a number")
    sensor = sensor_call(cls, "__init__", cls, options)
    check_dim(sensor, sensor.dim, sensor.labels)
    return sensor


def with_lever(sensor: Sensor, lever) -> Sensor:
    """A copy of ``sensor`` whose options put it at ``lever`` (3,) [m, body]: the sensor one filter's
    measurement model assumes (``--filter-option NAME.lever_arm_x_SENSOR``); its values are unchanged."""
    return make_sensor(type(sensor), dataclasses.replace(sensor.opt, lever_arm=tuple(float(x) for x in lever)))


def checked_values(sensor: Sensor, method: str, values, shape: tuple, finite: bool = True) -> np.ndarray:
    """``values`` as a float array of ``shape`` (NaN refused when ``finite``), else one line."""
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as e:
        raise NespmError(f"{where(sensor)}: {method} returned {type(values).__name__}, not an array "
                         f"of numbers ({type(e).__name__})") from None
    if arr.shape != tuple(shape):
        raise NespmError(f"{where(sensor)}: {method} returned shape {arr.shape}, expected {tuple(shape)}"
                         f" (m = dim = {sensor.dim})")
    if finite and not np.isfinite(arr).all():
        raise NespmError(f"{where(sensor)}: {method} returned NaN or inf ({int((~np.isfinite(arr)).sum())} "
                         f"of {arr.size} values)")
    return arr


def checked_R(sensor: Sensor, R, runs: int, m: int) -> np.ndarray:
    """A measurement's ``R`` checked (module docstring) and symmetrized."""
    R = np.asarray(R, dtype=float)
    if R.shape not in ((m, m), (runs, m, m)):
        raise NespmError(f"{where(sensor)}: measurement R has shape {R.shape}, expected ({m}, {m}) or "
                         f"({runs}, {m}, {m})")
    if not np.isfinite(R).all():
        raise NespmError(f"{where(sensor)}: measurement R holds NaN or inf")
    Rt = np.swapaxes(R, -1, -2)
    asym = float(np.abs(R - Rt).max())
    if asym > SYM_TOL * float(np.abs(R).max()):
        raise NespmError(f"{where(sensor)}: measurement R is not symmetric (max |R - R^T| = {asym:.3g}, more than "
                         f"{SYM_TOL:g} of max |R|)")
    if asym:
        R = 0.5 * (R + Rt)
    try:
        np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        raise NespmError(f"{where(sensor)}: measurement R is not positive definite "
                         f"(smallest eigenvalue {float(np.linalg.eigvalsh(R).min()):.3g})") from None
    return R


def finite_runs(nav: NavState) -> np.ndarray:
    """(R,) runs whose solution is finite (elsewhere a NaN is the filter's divergence)."""
    return (np.isfinite(nav.pos).all(-1) & np.isfinite(nav.v_n).all(-1)
            & np.isfinite(nav.C_bn).all(axis=(-2, -1)))


class CheckedMeasurement(Measurement):
    """A plugin's measurement with every call checked (module docstring); other attributes are the
    plugin object's."""

    def __init__(self, inner: Measurement, sensor: Sensor, runs: int, n: int):
        self.inner, self.sensor, self.runs, self.n = inner, sensor, runs, n
        m = int(sensor.dim)
        self.z = checked_values(sensor, "measurement's z", getattr(inner, "z", None), (runs, m), finite=False)
        self.R = checked_R(sensor, sensor_call(sensor, "R", lambda: inner.R), runs, m)
        self.layout = getattr(inner, "layout", None)
        if self.layout is None or getattr(self.layout, "n", None) != n:
            raise NespmError(f"{where(sensor)}: the measurement's layout is {self.layout!r}; set it to the "
                             "layout measurement() was given")

    def __getattr__(self, name):
        inner = self.__dict__.get("inner")
        if inner is None:
            raise AttributeError(name)
        return getattr(inner, name)

    def _call(self, method: str, nav: NavState, shape: tuple, *args, out=None):
        if out is None:
            out = sensor_call(self.sensor, method, getattr(self.inner, method), *args)
        arr = checked_values(self.sensor, method, out, shape, finite=False)
        ok = finite_runs(nav)
        if not np.isfinite(arr[ok]).all():
            raise NespmError(f"{where(self.sensor)}: {method} returned NaN or inf where the solution is finite "
                             f"({int((~np.isfinite(arr[ok])).any(axis=tuple(range(1, arr.ndim))).sum())} runs)")
        return arr

    def predict(self, nav: NavState) -> np.ndarray:
        return self._call("predict", nav, (self.runs, self.dim), nav)

    def innovation(self, nav: NavState) -> np.ndarray:
        """The plugin's own ``innovation``; where it keeps the base class's (``z - predict``), that is
        computed here from the checked :meth:`predict`, so that a failure or a wrong shape is reported as
        ``predict``'s, with the shape ``predict`` returned (not the one ``z - predict`` broadcast to)."""
        if getattr(type(self.inner), "innovation", None) is Measurement.innovation:
            return self._call("innovation", nav, (self.runs, self.dim), out=self.z - self.predict(nav))
        return self._call("innovation", nav, (self.runs, self.dim), nav)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        return self._call("h", nav, tuple(np.shape(X)[:-1]) + (self.dim,), X, nav)

    def H(self, nav: NavState) -> np.ndarray:
        return self._call("H", nav, (self.runs, self.dim, self.n), nav)

    def H_invariant(self, nav: NavState) -> np.ndarray | None:
        out = sensor_call(self.sensor, "H_invariant", self.inner.H_invariant, nav)
        return None if out is None else self._call("H_invariant", nav, (self.runs, self.dim, self.n), out=out)


def checked_measurement(sensor: Sensor, z, nav, ctx, layout) -> Measurement:
    """``sensor.measurement(z, nav, ctx, layout)``, a plugin's wrapped in :class:`CheckedMeasurement`."""
    if not is_plugin(sensor):
        return sensor.measurement(z, nav, ctx, layout)
    meas = sensor_call(sensor, "measurement", sensor.measurement, z, nav, ctx, layout)
    if not isinstance(meas, Measurement):
        raise NespmError(f"{where(sensor)}: measurement returned {type(meas).__name__}, not a "
                         "nespm_cli.sensors.Measurement")
    return CheckedMeasurement(meas, sensor, int(np.shape(z)[0]), layout.n)


__all__ = ["CheckedMeasurement", "SYM_TOL", "check_class", "check_dim", "checked_R", "checked_measurement",
           "checked_values", "global_rng_state", "is_plugin", "make_sensor", "sensor_call", "where", "with_lever"]
