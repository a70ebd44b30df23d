"""The report's section on the posterior Cramér–Rao bound: each filter's efficiency (docs/pcrb.md).

``epochs.parquet`` holds per epoch the bound's variances ``pcrb_<label>`` (the mean over the runs
of each run's bound, :mod:`nespm_cli.experiments.pcrb_table`) and the manifest's ``pcrb`` entry
says whether the bound was computed or why it is unknown (a recorded IMU or sensor).
:func:`pcrb_md` sets each filter's RMSE beside the root of the bound, block by block.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from nespm_cli.experiments.pcrb_table import efficiency
from nespm_cli.reports.markdown import fmt, md_table

#: block -> (name, unit, factor from SI)
BLOCK_NAMES = {"vel": ("velocity", "m/s", 1.0), "att": ("attitude", "deg", 180.0 / math.pi),
               "hpos": ("horizontal position", "m", 1.0), "pos": ("position", "m", 1.0),
               "ba": ("accelerometer bias", "m/s²", 1.0), "bg": ("gyro bias", "deg/h", 180.0 / math.pi * 3600.0)}
SMOOTHED = "-rts"
SECTION = "## Efficiency against the posterior Cramér–Rao bound"


def efficiency_table(epochs: pd.DataFrame | None) -> pd.DataFrame:
    """:func:`nespm_cli.experiments.pcrb_table.efficiency` of a folder's epochs (empty without them)."""
    keys = sweep_keys(epochs)
    if epochs is None or epochs.empty or not any(c.startswith("pcrb_") for c in epochs.columns):
        return pd.DataFrame(columns=[*keys, "track", "filter", "block", "rmse", "root_pcrb", "efficiency"])
    return efficiency(epochs, keys)


def sweep_keys(epochs: pd.DataFrame | None) -> tuple[str, ...]:
    """A sweep's key columns (``param``, ``value``) where ``epochs`` has them, else ()."""
    return tuple(k for k in ("param", "value") if epochs is not None and k in epochs.columns)


def pcrb_md(epochs: pd.DataFrame | None, manifest: dict) -> str:
    """The section's markdown: what the bound is, why it is unknown when it is, and per track, filter
    and block the RMSE, √PCRB and their ratio (the efficiency)."""
    info = (manifest or {}).get("pcrb")
    if info is None:
        return ("Not computed: this folder predates the bound (`nespm mc` with the same options adds it to "
                "`epochs.parquet` without recomputing a chunk).")
    intro = ("The posterior Cramér–Rao bound (PCRB; Tichavský, Muravchik & Nehorai 1998) of the error state "
             "from the truth and the realizations' true noise statistics, whatever the filters were told "
             "(docs/pcrb.md). Efficiency = RMSE / √PCRB over the runs and epochs: 1 is the best any causal "
             "estimator can do on these realizations; below 1 only within sampling (a smoothed `-rts` "
             "result is not causal, and may lie below).")
    if info.get("status") == "unknown":
        return intro + f"\n\n**Unknown**: {info.get('reason')}; no bound and no efficiency is given."
    table = efficiency_table(epochs)
    if table.empty:
        return intro + "\n\nNo epochs table: no efficiency."
    rows = []
    value = "value" in table.columns
    for r in table.itertuples(index=False):
        name, unit, k = BLOCK_NAMES.get(r.block, (r.block, "SI", 1.0))
        eff = "—" if not np.isfinite(r.root_pcrb) else fmt(r.efficiency, ".3f")
        if str(r.filter).endswith(SMOOTHED) and np.isfinite(r.efficiency):
            eff += " (smoothed)"
        if not np.isfinite(r.rmse):
            continue
        rows.append(([fmt(r.value, "g")] if value else [])
                    + [str(r.track), str(r.filter), f"{name} [{unit}]", fmt(r.rmse * k),
                       fmt(r.root_pcrb * k) if np.isfinite(r.root_pcrb) else "not in the state", eff])
    return intro + "\n\n" + md_table((["value"] if value else []) + ["track", "filter", "block", "RMSE", "√PCRB",
                                                                    "efficiency"], rows)


__all__ = ["SECTION", "efficiency_table", "pcrb_md", "sweep_keys"]
