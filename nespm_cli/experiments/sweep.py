"""Error-regime sweeps: one paired Monte Carlo experiment per value of one parameter.

Every value reuses the same seeds, so run ``r`` of track ``N`` draws the same standard
normals at every value and for every filter: a sweep of an error std scales one fixed
set of draws, and the curves of different filters and values are paired.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import Cell, run_cells
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.spec import Spec, couple_filter, validate


@dataclass(frozen=True)
class Param:
    label: str  # axis label, with unit
    apply: Callable[[Spec, float], Spec]
    positive: bool = True  # values must be > 0 (a std of 0 makes P0 singular)


def _corr(**fields):
    """Change the corruption protocol and keep the filter told the truth (P0, Q)."""
    def apply(spec: Spec, v: float) -> Spec:
        corr = dataclasses.replace(spec.corruption, **{k: (v if f is None else f(v)) for k, f in fields.items()})
        return dataclasses.replace(spec, corruption=corr, filter_config=couple_filter(spec.filter_config, corr))
    return apply


def _dvl_noise(spec: Spec, v: float) -> Spec:
    if spec.dvl != "synthetic":
        raise NespmError("--param dvl-noise needs --dvl synthetic (the recorded DVL's noise is what it is)")
    corr = dataclasses.replace(spec.corruption, dvl_noise=v)
    return dataclasses.replace(spec, corruption=corr, dvl_r_std=v)


def _outage(spec: Spec, v: float) -> Spec:
    return dataclasses.replace(spec, scenario="outage", outage_length=v)


def _alpha(spec: Spec, v: float) -> Spec:
    return dataclasses.replace(spec, filter_config=dataclasses.replace(spec.filter_config, alpha=v))


def sensor_param(sensor: str, key: str) -> Callable[[Spec, float], Spec]:
    """Set the option ``key`` of ``sensor`` (``--sensor-option SENSOR.KEY=value``, over any given one);
    the sensor must be in ``--sensors``. Its draws come from its own seed stream, so the values are
    paired: a std scales the same normals, an interval takes the same stream's first draws."""
    def apply(spec: Spec, v: float) -> Spec:
        if sensor not in spec.sensors:
            raise NespmError(f"--param {sensor}.{key}: {sensor} is not in --sensors ({', '.join(spec.sensors)})")
        text = v if isinstance(v, str) else f"{v!r}"
        opts = tuple(o for o in spec.sensor_options if (o[0], o[1]) != (sensor, key)) + ((sensor, key, text),)
        return dataclasses.replace(spec, sensor_options=opts)
    return apply


def beam_loss_length(spec: Spec, v: float) -> Spec:
    """The length [s] of the DVL-beam loss: the first window of ``dvl-beams.beam_outage`` (its beams
    and start kept; default beams 1, 2 from 180 s) ends ``v`` s after it starts."""
    from nespm_cli.sensors.dvl_beams import parse_beam_outage

    if "dvl-beams" not in spec.sensors:
        raise NespmError(f"--param beam-loss-length: dvl-beams is not in --sensors ({', '.join(spec.sensors)})")
    given = [o[2] for o in spec.sensor_options if o[:2] == ("dvl-beams", "beam_outage")]
    entries = parse_beam_outage(given[-1] if given else "1,2@180:240", "--sensor-option dvl-beams.beam_outage")
    beams, windows = entries[0] if entries else ((1, 2), [(180.0, 240.0)])
    start = windows[0][0]
    text = f"{','.join(map(str, beams))}@{start:g}:{start + v:g}"
    return sensor_param("dvl-beams", "beam_outage")(spec, text)


#: named sensor parameters (any ``SENSOR.KEY`` of a numeric option is a parameter too)
SENSOR_PARAMS: dict[str, Param] = {
    "fix-interval": Param("position fix interval [s]", sensor_param("fix", "interval")),
    "fix-std": Param("position fix std [m]", sensor_param("fix", "std")),
    "depth-std": Param("depth sensor std [m]", sensor_param("depth", "std")),
    "heading-std": Param("heading sensor std [deg]", sensor_param("heading", "std")),
    "beam-loss-length": Param("length of the DVL-beam loss [s]", beam_loss_length),
}


def filter_param(filt: str, key: str) -> Callable[[Spec, float], Spec]:
    """Set the option ``key`` of filter ``filt`` (``--filter-option FILTER.KEY=value``, over any given
    one): a plugin's own option or a tunable field (``ukf.alpha``); checked by ``validate``."""
    def apply(spec: Spec, v: float) -> Spec:
        opts = tuple(o for o in spec.filter_options if (o[0], o[1]) != (filt, key)) + ((filt, key, f"{v!r}"),)
        return dataclasses.replace(spec, filter_options=opts)
    return apply


def option_param_of(param: str, filters: tuple = ()) -> Param | None:
    """The :class:`Param` of a sensor or filter option: a name of :data:`SENSOR_PARAMS`, or ``NAME.KEY``
    (a filter's option when ``NAME`` is in ``filters``, else a sensor's)."""
    if param in SENSOR_PARAMS:
        return SENSOR_PARAMS[param]
    if "." in param:
        name, key = param.split(".", 1)
        if name and key.isidentifier():
            make = filter_param if name in filters else sensor_param
            return Param(f"{name} {key}", make(name, key), positive=False)
    return None


PARAMS: dict[str, Param] = {
    "misalignment-deg": Param("initial misalignment std per axis [deg]", _corr(misalignment_deg=None)),
    "heading-deg": Param("initial heading misalignment std [deg]", _corr(heading_deg=None)),
    "vel-std": Param("initial horizontal velocity error std [m/s]", _corr(vel_h_std=None)),
    "acc-bias": Param("accelerometer bias std [m/s²]", _corr(acc_bias=None)),
    "gyro-bias": Param("gyro bias std [rad/s]", _corr(gyro_bias=None)),
    "acc-noise": Param("accelerometer noise std per sample [m/s²]", _corr(acc_noise=None)),
    "gyro-noise": Param("gyro noise std per sample [rad/s]", _corr(gyro_noise=None)),
    "dvl-noise": Param("DVL noise std [m/s]", _dvl_noise),
    "outage-length": Param("DVL outage length [s]", _outage),
    "alpha": Param("UKF sigma-point spread alpha", _alpha),
}


def param_label(param: str) -> str:
    """The axis label (with unit) of a sweep parameter; the name itself when it has none."""
    p = PARAMS.get(param) or option_param_of(param)
    return p.label if p is not None else param


def parse_values(text: str) -> list[float]:
    try:
        vals = [float(x) for x in text.replace(" ", "").split(",") if x]
    except ValueError:
        raise NespmError(f"--values: expected comma-separated numbers like 0.01,0.1,1, got {text!r}") from None
    if not vals:
        raise NespmError("--values: give at least one value")
    if len(set(vals)) != len(vals):
        raise NespmError("--values: each value once")
    if not all(np.isfinite(vals)):
        raise NespmError("--values: values must be finite")
    return vals


def sweep_cells(spec: Spec, param: str, values: list[float]) -> list[Cell]:
    """One validated cell per value; chunk files are tagged ``v00-``, ``v01-``, ..."""
    p = PARAMS.get(param) or option_param_of(param, tuple(spec.filters))
    if p is None:
        raise NespmError(f"--param: unknown parameter {param!r}; choose from {', '.join([*PARAMS, *SENSOR_PARAMS])} "
                         "or an option SENSOR.KEY or FILTER.KEY (e.g. fix.interval, ukf.alpha)")
    if p.positive and min(values) <= 0:
        raise NespmError(f"--values: {param} values must be positive, got {min(values):g}")
    return [Cell(validate(p.apply(spec, v)), tag=f"v{i:02d}-", columns=(("param", param), ("value", float(v))))
            for i, v in enumerate(values)]


def run_sweep(spec: Spec, param: str, values: list[float], out_dir: str | Path, execution: Execution | None = None,
              *, jobs: int | None = None, progress: bool | None = None, argv=None, backend: str | None = None,
              scheduler: str | None = None) -> pd.DataFrame:
    """Run (or resume) the sweep into ``out_dir``; metrics gain the columns ``param``, ``value``.
    ``execution``: where the chunks run (the keyword arguments are its fields, as :func:`run_mc`)."""
    ex = Execution.of(execution, jobs=jobs, progress=progress, argv=argv, backend=backend, scheduler=scheduler)
    cells = sweep_cells(spec, param, values)
    options = {**validate(spec).as_dict(), "sweep": {"param": param, "values": list(values)}}
    return run_cells(cells, options, out_dir, ex, label="sweep")
