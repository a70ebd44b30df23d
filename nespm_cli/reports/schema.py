"""The unit of every column of a results folder's tables: the one copy (docs/results-schema.md's unit
columns are checked against it by tests/test_export_meta.py).

``UNITS[table][column]`` for the tables ``metrics`` (``metrics.parquet``), ``epochs``
(``epochs.parquet``) and ``series`` (the chunks' per-run series, ``nespm export --series``). An empty
unit is a count, an index, a ratio or a text. A column name with ``<sensor>``, ``<label>``,
``<block>`` or ``<k>`` stands for a family (``nis_dvl``, ``rms_dpN``, ``nci_att``, ``cover2_vel``);
the unit ``SI`` of a state component's column is resolved from its label (:data:`AXIS_UNITS`).
:func:`unit_of` gives a concrete column's unit.
"""
from __future__ import annotations

import re

#: leading key columns of a sweep folder's tables (the swept parameter and its value, in that parameter's unit)
SWEEP_UNITS = {"param": "", "value": ""}

METRICS_UNITS = {
    "track": "", "filter": "", "run": "", "scenario": "", "schedule": "", "seed": "",
    "vrmse": "m/s", "mrmse": "rad", "sse_vel": "(m/s)²", "sse_att": "rad²", "n_samples": "",
    "max_vel_err": "m/s", "max_att_err": "rad", "nees": "", "diverged": "", "diverged_reason": "",
    "inconsistent": "", "seconds": "s", "kernels": "", "sse_hpe": "m²", "hpe_final": "m", "hpe_rms": "m",
    "hpe_max": "m", "distance": "m", "north_final": "m", "east_final": "m", "lost_at": "s",
    "vrmse_alive": "m/s", "mrmse_alive": "rad", "hpe_rms_alive": "m", "hpe_final_pct": "%",
    "drift_m_per_h": "m/h", "vert_rms": "m",
    "sse_vel_post": "(m/s)²", "sse_att_post": "rad²", "sse_hpe_post": "m²", "n_post": "", "nees_post": "", "vert_rms_post": "m",
    "rejected_<sensor>": "", "applied_<sensor>": "", "downweighted_<sensor>": "", "nis_<sensor>": "", "q_factor_acc": "", "q_factor_gyro": "", "noise_model_faults": "",
}

EPOCHS_UNITS = {
    "track": "", "filter": "", "epoch": "", "t": "s", "vel_err_mean": "m/s", "vel_err_std": "m/s",
    "att_err_mean": "rad", "att_err_std": "rad", "nees_mean": "", "north_err_mean": "m", "east_err_mean": "m",
    "hpe_mean": "m", "hpe_std": "m", "hpe_cep50": "m", "hpe_r95": "m",
    **{f"nees_{b}_mean": "" for b in ("vel", "att", "pos", "ba", "bg")},
    **{f"cover{k}_{b}_mean": "" for b in ("vel", "att", "pos", "ba", "bg") for k in (1, 2, 3)},
    "nis_<sensor>_mean": "", "nis_<sensor>_n": "", "north_true": "m", "east_true": "m", "dvl_used": "",
    "n_runs": "", "rms_<label>": "SI", "sig_<label>": "SI", "nci_<block>": "dB",
    "pcrb_<label>": "SI²",
}

SERIES_UNITS = {
    "track": "", "filter": "", "run": "", "epoch": "", "t": "s", "vel_err": "m/s", "att_err": "rad", "nees": "",
    "north_err": "m", "east_err": "m", "nees_<block>": "", "cover<k>_<block>": "", "nis_<sensor>": "",
    "dvl_used": "", "diverged": "", "e_<label>": "SI", "s_<label>": "SI",
}

UNITS = {"metrics": METRICS_UNITS, "epochs": EPOCHS_UNITS, "series": SERIES_UNITS}

#: the unit of a state component by its label's block prefix (``dpN`` m, ``dvE`` m/s, ``dpsiD`` rad, ...)
AXIS_UNITS = {"dp": "m", "dv": "m/s", "dpsi": "rad", "ba": "m/s²", "bg": "rad/s"}

_FAMILY = {"<sensor>": r"(?P<sensor>[A-Za-z0-9_-]+)", "<label>": r"(?P<label>[A-Za-z]+)",
           "<block>": r"(?P<block>vel|att|pos|ba|bg)", "<k>": r"(?P<k>[123])"}


def _pattern(name: str) -> re.Pattern:
    text = re.escape(name)
    for key, rx in _FAMILY.items():
        text = text.replace(re.escape(key), rx)
    return re.compile(text + r"\Z")


def axis_unit(label: str) -> str | None:
    """The unit of state component ``label`` (``dpsiN`` -> rad), None for an unknown label."""
    m = re.fullmatch(r"(dpsi|dp|dv|ba|bg)[NEDXYZ]", label)
    return AXIS_UNITS[m.group(1)] if m else None


def unit_of(table: str, column: str) -> str | None:
    """The unit of ``column`` of ``table`` (``metrics``, ``epochs``, ``series``); ``""`` for a count,
    ratio or text; None for a column the schema does not define (a plugin's own)."""
    units = {**SWEEP_UNITS, **UNITS[table]}
    if column in units:
        return units[column]
    for name, unit in units.items():
        if "<" in name:
            m = _pattern(name).match(column)
            if m:
                if unit in ("SI", "SI²") and "label" in m.groupdict():  # a state component's unit (squared)
                    base = axis_unit(m.group("label"))
                    return base if unit == "SI" or base is None else (f"({base})²" if "/" in base else f"{base}²")
                return unit
    return None


__all__ = ["AXIS_UNITS", "EPOCHS_UNITS", "METRICS_UNITS", "SERIES_UNITS", "SWEEP_UNITS", "UNITS", "axis_unit",
           "unit_of"]
