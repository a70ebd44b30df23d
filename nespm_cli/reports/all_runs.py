"""Every run counted: the comparison of filters over *all* runs, a lost run ranked the worst.

The tables and the verdict's pooled RMS (eq 50) are over runs the filters kept: an RMS cannot hold
a run whose estimate is lost. Alone, that would let a filter look better for losing its hard runs.
So beside them the report gives, over every run of every track (``--all-runs median``, the
default; docs/report.md):

* per filter, the **median** of its per-run error with a lost run counted as +∞ (the worst of all),
  and its loss rate: the median stays finite while the filter keeps more than half its runs, and a
  filter that loses runs can only move its median up;
* per filter against the reference, the **median of the paired per-run improvement**
  ``100 (e_ref − e_f) / e_ref`` over every run: −∞ where only the filter lost the run, +∞ where
  only the reference did, 0 where both did; its 95 % interval from a bootstrap of the runs
  (resampled within each track, the same resamples for every filter).

Why a median with lost runs ranked worst rather than capping a lost run's error at a stated value:
a cap makes every number depend on an arbitrary constant, while the rank needs none. The price is
that it is a median, not the papers' eq 50 RMS, so it is shown beside those, not instead.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from nespm_cli.reports.results import causal_only, filters_in_order
from nespm_cli.reports.stats import has_posterior, track_rng

#: per-run error columns of metrics.parquet: key -> (column, name, unit)
RUN_METRICS = {"vrmse": ("vrmse", "velocity RMSE", "m/s"), "mrmse": ("mrmse", "attitude RMSE", "rad"),
               "hpe": ("hpe_rms", "horizontal position error, RMS", "m")}
ALL_RUNS = ("median", "none")
#: the posterior sum of each per-run error (:data:`nespm_cli.experiments.metrics.POSTERIOR_COLUMNS`)
POSTERIOR_SSE = {"vrmse": "sse_vel_post", "mrmse": "sse_att_post", "hpe": "sse_hpe_post"}


def run_errors(metrics: pd.DataFrame, key: str) -> pd.DataFrame:
    """(track, run) x filter: each causal filter's per-run error ``key``, +∞ for a lost run; posterior (the RMS
    over the epochs after t = 0, ``sqrt(sse_*_post / n_post)``, the t = 0 rule) where the folder has those sums,
    as the verdict's, else the papers' every-epoch column."""
    col = RUN_METRICS[key][0]
    m = causal_only(metrics)
    if has_posterior(m):
        with np.errstate(all="ignore"):
            x = np.sqrt(m[POSTERIOR_SSE[key]].to_numpy(float) / m["n_post"].to_numpy(float))
    else:
        x = m[col].to_numpy(float)
    v = np.where(m["diverged"].astype(bool), np.inf, x)
    t = pd.DataFrame({"track": m["track"], "run": m["run"], "filter": m["filter"], "v": v})
    return t.pivot_table(index=["track", "run"], columns="filter", values="v", aggfunc="first")[
        [f for f in filters_in_order(m)]]


def paired_change(e_f: np.ndarray, e_ref: np.ndarray) -> np.ndarray:
    """Per-run improvement [%] of filter f over the reference, ``100 (e_ref − e_f) / e_ref``, lost runs
    (+∞ errors) ranked: −∞ where only f lost, +∞ where only the reference lost, 0 where both did."""
    with np.errstate(all="ignore"):
        d = 100.0 * (e_ref - e_f) / e_ref
    d = np.where(np.isinf(e_f) & ~np.isinf(e_ref), -np.inf, d)
    d = np.where(np.isinf(e_ref) & ~np.isinf(e_f), np.inf, d)
    return np.where(np.isinf(e_f) & np.isinf(e_ref), 0.0, d)


def _median_ci(x: np.ndarray, tracks: np.ndarray, n_boot: int, seed: int) -> tuple[float, float]:
    """2.5 / 97.5 percentiles of the median of ``x`` over bootstrap resamples of its runs, drawn within
    each track (generator per track as the other intervals: :func:`stats.track_rng`)."""
    if n_boot < 1 or not x.size:
        return math.nan, math.nan
    idx = []
    for tr in np.unique(tracks):
        rows = np.flatnonzero(tracks == tr)
        idx.append(rows[track_rng(seed, tr).integers(0, rows.size, (n_boot, rows.size))])
    samples = x[np.concatenate(idx, axis=1)]
    med = np.median(samples, axis=1)
    return float(np.percentile(med, 2.5, method="lower")), float(np.percentile(med, 97.5, method="higher"))


def all_runs_table(metrics: pd.DataFrame, reference: str, n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """One row per (metric, causal filter): ``median`` over all runs (lost = +∞), ``lost``, ``runs``;
    ``imprv``, ``ci_lo``, ``ci_hi``: the median paired improvement over ``reference`` [%] and its
    bootstrap interval (NaN on the reference's row)."""
    rows = []
    for key, (_, name, unit) in RUN_METRICS.items():
        if RUN_METRICS[key][0] not in metrics.columns:
            continue
        E = run_errors(metrics, key)
        tracks = E.index.get_level_values("track").to_numpy()
        for f in E.columns:
            e = E[f].to_numpy(float)
            row = {"metric": key, "name": name, "unit": unit, "filter": f, "median": float(np.median(e)),
                   "lost": int(np.isinf(e).sum()), "runs": int(e.size), "imprv": math.nan, "ci_lo": math.nan,
                   "ci_hi": math.nan}
            if f != reference and reference in E.columns:
                d = paired_change(e, E[reference].to_numpy(float))
                row["imprv"] = float(np.median(d))
                row["ci_lo"], row["ci_hi"] = _median_ci(d, tracks, n_boot, seed)
            rows.append(row)
    return pd.DataFrame(rows)


def all_runs_md(table: pd.DataFrame, reference: str) -> str:
    """The all-runs section: a line per metric and filter."""
    from nespm_cli.reports.markdown import fmt, fmt_imprv, md_table

    def cell(x: float) -> str:
        return "lost (≥ half the runs)" if np.isinf(x) and x > 0 else fmt(x)

    rows = [[r["name"] + f" [{r['unit']}]", f"`{r['filter']}`" + (" (reference)" if r["filter"] == reference else ""),
             cell(r["median"]), f"{r['lost']} / {r['runs']}",
             "—" if r["filter"] == reference else _imprv(r, fmt_imprv)] for _, r in table.iterrows()]
    return md_table(["Metric", "filter", "median over all runs (lost = worst)", "lost",
                     f"median paired improvement over `{reference}` [95 % CI]"], rows)


def all_runs_section(metrics: pd.DataFrame, reference: str, n_boot: int, seed: int, value_label: str = "") -> str:
    """The report section "Every run counted" (a sweep: one table per value, ``value_label`` its axis)."""
    intro = ("Some runs were lost, and the tables above are over the runs kept. Here every run counts: the "
             "median of each filter's per-run error with a lost run ranked the worst (+∞), its losses, and "
             f"the median paired improvement over `{reference}` with a bootstrap 95 % interval; per-run errors "
             "over the same epochs as the verdict's (docs/report.md, "
             "\"Every run counted\"; `--all-runs none` leaves this out).")
    if "value" not in metrics.columns:
        return "## Every run counted\n\n" + intro + "\n\n" + all_runs_md(all_runs_table(metrics, reference, n_boot,
                                                                                           seed), reference)
    parts = []
    for v in sorted(metrics["value"].unique()):
        sub = metrics[metrics["value"] == v].drop(columns=["param", "value"], errors="ignore")
        if sub["diverged"].any():
            parts.append(f"**{value_label or 'value'} = {v:g}**\n\n"
                         + all_runs_md(all_runs_table(sub, reference, n_boot, seed), reference))
    return "## Every run counted\n\n" + intro + " Values with a lost run.\n\n" + "\n\n".join(parts)


def _imprv(r, fmt_imprv) -> str:
    vals = (r["imprv"], r["ci_lo"], r["ci_hi"])
    if any(np.isinf(v) for v in vals):
        show = ["−∞" if v == -np.inf else "+∞" if v == np.inf else f"{v:.3g}" for v in vals]
        return f"{show[0]} % [{show[1]}, {show[2]}]"
    return fmt_imprv(*vals)


__all__ = ["ALL_RUNS", "RUN_METRICS", "all_runs_md", "all_runs_section", "all_runs_table", "paired_change", "run_errors"]
