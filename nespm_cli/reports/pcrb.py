"""The report's section on the posterior Cramér–Rao bound: each filter's efficiency (docs/pcrb.md).

``epochs.parquet`` holds per epoch the bound's variances ``pcrb_<label>`` (the mean over the runs
of each run's bound, :mod:`nespm_cli.experiments.pcrb_table`) and the manifest's ``pcrb`` entry
says whether the bound was computed or why it is unknown (a recorded IMU or sensor).
:func:`pcrb_md` sets each filter's RMSE beside the root of the bound, block by block, over the epochs after
t = 0 (the bias blocks from ``CONVERGED_S`` on), with the sampling interval of the runs.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from nespm_cli.experiments.pcrb_table import CONVERGED_S, efficiency
from nespm_cli.reports.efficiency_runs import run_mse
from nespm_cli.reports.markdown import fmt, md_table

#: block -> (name, unit, factor from SI)
BLOCK_NAMES = {"vel": ("velocity", "m/s", 1.0), "att": ("attitude", "deg", 180.0 / math.pi),
               "hpos": ("horizontal position", "m", 1.0), "pos": ("position", "m", 1.0),
               "ba": ("accelerometer bias", "m/s²", 1.0), "bg": ("gyro bias", "deg/h", 180.0 / math.pi * 3600.0)}
SMOOTHED = "-rts"
SECTION = "## Efficiency against the posterior Cramér–Rao bound"


def efficiency_table(epochs: pd.DataFrame | None, metrics: pd.DataFrame | None = None,
                     series: Sequence[Path] = ()) -> pd.DataFrame:
    """:func:`nespm_cli.experiments.pcrb_table.efficiency` of a folder's epochs (empty without them), its
    sampling interval from ``metrics`` and the per-run ``series`` chunks
    (:func:`nespm_cli.reports.efficiency_runs.run_mse`; NaN without them)."""
    keys = sweep_keys(epochs)
    if epochs is None or epochs.empty or not any(c.startswith("pcrb_") for c in epochs.columns):
        return pd.DataFrame(columns=[*keys, "track", "filter", "block", "window", "epochs", "rmse", "rmse_3sigma",
                                     "root_pcrb", "efficiency", "efficiency_lo", "efficiency_hi"])
    return efficiency(epochs, keys, run_mse(metrics, series, keys))


def sweep_keys(epochs: pd.DataFrame | None) -> tuple[str, ...]:
    """A sweep's key columns (``param``, ``value``) where ``epochs`` has them, else ()."""
    return tuple(k for k in ("param", "value") if epochs is not None and k in epochs.columns)


def next_step(manifest: dict) -> str:
    """The options that make the bound computable: a synthetic IMU and synthetic sensors (the embedded
    tracks' DVL, source ``embedded``, is one draw every run shares: as a recorded one, it has no bound);
    "" when no source of the manifest is recorded or embedded."""
    opts = (manifest or {}).get("options") or {}
    steps = ["`--imu synthetic`"] if opts.get("imu") == "recorded" else []
    sensors = ((manifest or {}).get("sensors") or {}).get("all") or {}
    for name, o in sensors.items():
        if isinstance(o, dict) and o.get("source") in ("recorded", "embedded"):  # embedded: generated, one draw
            steps.append("`--dvl synthetic`" if name == "dvl" else f"`--sensor-option {name}.source=synthetic`")
    if not steps and not sensors and opts.get("dvl") == "recorded":  # an older manifest without its sensors
        steps.append("`--dvl synthetic`")
    return " ".join(steps)


def _unknown_md(info: dict, manifest: dict) -> str:
    """The "Unknown" line: the reason and the options that give a bound on the same tracks."""
    step = next_step(manifest)
    return (f"**Unknown**: {info.get('reason')}; no bound and no efficiency is given."
            + (f" For a bound, run the same study with {step} (the realizations' noise statistics are then "
               "known): the efficiency of the filters on synthetic measurements of the same tracks." if step else ""))


def _interval(r) -> str:
    """``eff [lo, hi]``: the efficiency with its ±3σ sampling interval (the interval "—" when unknown)."""
    eff = fmt(r.efficiency, ".3f")
    if np.isfinite(r.efficiency_lo):
        eff += f" [{r.efficiency_lo:.3f}, {r.efficiency_hi:.3f}]"
    if str(r.filter).endswith(SMOOTHED):
        eff += " (smoothed)"
    return eff


def pcrb_md(epochs: pd.DataFrame | None, manifest: dict, metrics: pd.DataFrame | None = None,
            series: Sequence[Path] = ()) -> str:
    """The section's markdown: what the bound is, why it is unknown when it is (and what gives one), and per
    track, filter and block the epochs averaged, the RMSE ± 3σ, √PCRB and their ratio (the efficiency) with its
    sampling interval (``metrics``, ``series``: :func:`efficiency_table`)."""
    info = (manifest or {}).get("pcrb")
    if info is None:
        return ("Not computed: this folder predates the bound (`nespm mc` with the same options adds it to "
                "`epochs.parquet` without recomputing a chunk).")
    intro = ("The posterior Cramér–Rao bound (PCRB; Tichavský, Muravchik & Nehorai 1998) of the error state "
             "from the truth and the realizations' true noise statistics, whatever the filters were told "
             "(docs/pcrb.md). Efficiency = RMSE / √PCRB over the runs not lost and the epochs of the window: "
             f"every epoch after t = 0 (docs/report.md, \"The t = 0 rule\"), and for the bias blocks from "
             f"{CONVERGED_S:g} s on (their bound falls by decades in the first seconds: an average over those is "
             "the prior's, not the filter's). 1 is the best any causal estimator can do on these realizations; "
             "below 1 only within sampling (a smoothed `-rts` result is not causal, and may lie below). "
             "± 3σ and [lo, hi]: the sampling interval over the runs (3 standard errors, from each run's own "
             "mean square error; — where the folder has no per-run errors of the block).")
    if info.get("status") == "unknown":
        return intro + "\n\n" + _unknown_md(info, manifest)
    table = efficiency_table(epochs, metrics, series)
    if table.empty:
        return intro + "\n\nNo epochs table: no efficiency."
    rows = []
    value = "value" in table.columns
    for r in table.itertuples(index=False):
        name, unit, k = BLOCK_NAMES.get(r.block, (r.block, "SI", 1.0))
        if not np.isfinite(r.rmse):
            continue
        known = np.isfinite(r.root_pcrb)
        err = fmt(r.rmse * k) + (f" ± {fmt(r.rmse_3sigma * k, '.2g')}" if np.isfinite(r.rmse_3sigma) else "")
        rows.append(([fmt(r.value, "g")] if value else [])
                    + [str(r.track), str(r.filter), f"{name} [{unit}]", f"{r.window} ({r.epochs})", err,
                       fmt(r.root_pcrb * k) if known else "not in the state", _interval(r) if known else "—"])
    return intro + "\n\n" + md_table((["value"] if value else []) + ["track", "filter", "block", "epochs",
                                                                    "RMSE ± 3σ", "√PCRB", "efficiency [± 3σ]"], rows)


__all__ = ["SECTION", "efficiency_table", "next_step", "pcrb_md", "sweep_keys"]
