"""A sweep results folder (``nespm sweep``): loading and checking its metrics, the swept parameter
and values, the baseline filter, the protocol in words.

A sweep folder has the schema of ``docs/results-schema.md`` plus two leading columns ``param``
(str) and ``value`` (float); the same run index is the same realization across filters and values.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.reports.results import (
    METRICS_COLUMNS,
    check_metrics,
    checked_filter,
    filters_in_order,
    is_smoother,
    read_results_folder,
    require_columns,
    scenario_of,
    unique_text,
)

__all__ = ["DEFAULT_BASELINE", "SWEEP_COLUMNS", "check_sweep_metrics", "default_baseline", "load_sweep",
           "param_label", "param_of", "protocol_text", "sweep_values"]

DEFAULT_BASELINE = "ekf"
SWEEP_COLUMNS: tuple[str, ...] = ("param", "value")


def check_sweep_metrics(metrics: pd.DataFrame, where: object = "metrics") -> None:
    """Validate a sweep metrics table: columns, one parameter, finite values and, per
    value, the (track, filter, run) uniqueness of :func:`results.check_metrics`."""
    require_columns(metrics, SWEEP_COLUMNS + METRICS_COLUMNS, where)
    if metrics.empty:
        raise NespmError(f"{where}: no rows")
    params = [str(p) for p in pd.unique(metrics["param"])]
    if len(params) != 1:
        raise NespmError(f"{where}: expected one swept parameter, found {', '.join(params)}")
    values = metrics["value"].to_numpy(dtype=float)
    if not np.all(np.isfinite(values)):
        raise NespmError(f"{where}: non-finite swept value")
    for v, sub in metrics.groupby("value", sort=True):
        check_metrics(sub, f"{where} (value {v:g})")


def load_sweep(out_dir: Path) -> tuple[pd.DataFrame, dict]:
    """Read and validate ``metrics.parquet`` and ``manifest.json`` (optional) of a sweep folder."""
    metrics, manifest = read_results_folder(Path(out_dir), "sweep")
    check_sweep_metrics(metrics, Path(out_dir) / "metrics.parquet")
    return metrics, manifest


def sweep_values(metrics: pd.DataFrame) -> list[float]:
    """The swept values, ascending."""
    return sorted(float(v) for v in pd.unique(metrics["value"]))


def param_of(metrics: pd.DataFrame) -> str:
    return str(metrics["param"].iloc[0])


def param_label(param: str) -> str:
    """Axis label with unit of a sweep parameter (a sensor's or filter's option too), else its name."""
    from nespm_cli.experiments.sweep import param_label as label

    return label(param)


def default_baseline(metrics: pd.DataFrame, baseline: str | None = None) -> str:
    """``baseline`` if given (must be a filter of the results, not an RTS-smoother floor), else
    ``ekf`` if present, else the first causal filter."""
    if baseline:
        return checked_filter(metrics, baseline, "baseline")
    names = filters_in_order(metrics)
    causal = [n for n in names if not is_smoother(n)] or names
    return DEFAULT_BASELINE if DEFAULT_BASELINE in names else causal[0]



def protocol_text(metrics: pd.DataFrame, manifest: dict) -> str:
    """``schedule …, scenario …, DVL …, IMU …`` from the metrics columns / manifest options."""
    options = manifest.get("options") or {}
    parts = []
    if "schedule" in metrics.columns:
        parts.append(f"schedule {unique_text(metrics['schedule'])}")
    elif options.get("schedule"):
        parts.append(f"schedule {options['schedule']}")
    scen = scenario_of(metrics, manifest)
    if scen:
        parts.append(f"scenario {scen}")
    if options.get("dvl"):
        parts.append(f"DVL {options['dvl']}")
    if options.get("imu"):
        parts.append(f"IMU {options['imu']}")
    return ", ".join(parts)


