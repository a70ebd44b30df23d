"""Robust updates in a Monte Carlo report: each filter's rejected, applied and downweighted samples per sensor.

A folder whose filters include one with ``--filter-option NAME.robust=gate|huber`` holds, per run and
sensor, ``rejected_<sensor>`` (samples the χ² gate refused), ``applied_<sensor>`` (samples applied) and
``downweighted_<sensor>`` (applied with a Huber-inflated R) in ``metrics.parquet``
(:func:`nespm_cli.experiments.metrics.sensor_rejections`; docs/results-schema.md). :func:`rejection_table`
sums them over the runs of every track; :func:`rejection_md` is the report's short table ("" without the
columns: no filter of the folder had a robust update).
"""
from __future__ import annotations

import re

import pandas as pd

from nespm_cli.reports.markdown import md_table
from nespm_cli.reports.results import filters_in_order, smoother_label

__all__ = ["rejection_md", "rejection_sensors", "rejection_table"]

REJECTED_RE = re.compile(r"^rejected_(.+)$")


def rejection_sensors(metrics: pd.DataFrame) -> list[str]:
    """The sensors with ``rejected_<sensor>`` and ``applied_<sensor>`` columns, in column order."""
    return [m.group(1) for c in metrics.columns for m in [REJECTED_RE.match(c)]
            if m and f"applied_{m.group(1)}" in metrics.columns]


def rejection_table(metrics: pd.DataFrame) -> pd.DataFrame:
    """One row per (filter, sensor): ``runs``, ``rejected``, ``applied``, ``downweighted`` (sums over every run
    of every track; ``downweighted`` 0 without the column) and ``rejected_share`` = rejected / (rejected +
    applied), the share of the samples the filter was offered that it refused. Empty without the columns."""
    cols = ["filter", "sensor", "runs", "rejected", "applied", "downweighted", "rejected_share"]
    rows = []
    for s in rejection_sensors(metrics):
        down = f"downweighted_{s}"
        for f in filters_in_order(metrics):
            d = metrics[metrics["filter"] == f]
            rej, app = int(d[f"rejected_{s}"].sum()), int(d[f"applied_{s}"].sum())
            rows.append({"filter": f, "sensor": s, "runs": int(len(d)), "rejected": rej, "applied": app,
                         "downweighted": int(d[down].sum()) if down in d.columns else 0,
                         "rejected_share": rej / (rej + app) if rej + app else float("nan")})
    return pd.DataFrame(rows, columns=cols)


def rejection_md(metrics: pd.DataFrame, manifest: dict | None = None) -> str:
    """The report's section body: per filter and sensor the samples rejected, applied (accepted) and
    downweighted over all runs, with the sensor's outlier scenario from the manifest when it has one; ""
    when the folder has no rejection columns."""
    t = rejection_table(metrics)
    if t.empty:
        return ""
    cells = {}
    for c in ((manifest or {}).get("sensors") or {}).values():
        if isinstance(c, dict):
            cells.update({n: o for n, o in c.items() if isinstance(o, dict)})
    scen = {s: (cells.get(s) or {}).get("outliers") or "none" for s in t["sensor"].unique()}
    rows = [[smoother_label(r.filter), f"{r.sensor} (outliers: {scen[r.sensor]})", str(r.runs), str(r.rejected),
             str(r.applied), str(r.downweighted),
             f"{100 * r.rejected_share:.2f} %" if r.rejected_share == r.rejected_share else "—"]
            for r in t.itertuples(index=False)]
    return ("Robust updates (`--filter-option NAME.robust=gate|huber`, docs/filters.md \"Robust updates\"): per "
            "filter and sensor, the samples the χ² gate rejected, those applied (accepted) and those applied with a "
            "Huber-inflated R, summed over every run (lost ones included); a filter without a robust update rejects "
            "none. A consistent gated filter also rejects 1 − `gate_prob` of good samples (0.1 % by default).\n\n"
            + md_table(["Method", "sensor", "runs", "rejected", "applied", "downweighted", "rejected share"], rows))
