"""The tables of a sweep report, per swept value: each filter's track-averaged VRMSE / MRMSE / mean
NEES with bootstrap intervals and its divergence rate with a Wilson interval (:func:`sweep_table`);
each filter's paired improvement over the baseline (:func:`improvement_table`, the one source of
the improvement table and figure); head-to-head comparisons per value (:func:`summary_rows`).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.reports.comparisons import compare_filters
from nespm_cli.reports.markdown import SIG_MARK, SMALL_MARK
from nespm_cli.reports.results import filters_in_order
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    PRACTICAL_PCT,
    ci_marks,
    lost_by_any,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    posterior_view,
    resample_counts,
    rmse,
    track_average,
    track_rng,
    wilson_interval,
)
from nespm_cli.reports.sweep_data import check_sweep_metrics, default_baseline, sweep_values
from nespm_cli.reports.tables import filter_table, horizontal_table
from nespm_cli.reports.verdict import verdict_table
from nespm_cli.reports.verdict_markdown import sweep_verdict_frame

__all__ = ["filter_bootstrap", "improvement_points", "improvement_table", "nees_runs", "summary_rows",
           "sweep_horizontal", "sweep_table", "sweep_verdict"]

def filter_bootstrap(
    metrics: pd.DataFrame, filt: str, n_boot: int = 2000, seed: int = 0
) -> dict[str, np.ndarray]:
    """Bootstrap replicates of one filter's track-averaged VRMSE, MRMSE and mean NEES.

    ``metrics`` holds one swept value. Per track, the non-diverged runs of ``filt`` are
    resampled with replacement (vectorized multiplicities, as in
    :func:`stats.paired_bootstrap`, with the same ``(seed, track)`` streams); eqs 50-52
    are recomputed per track and averaged over tracks (eq 51); the NEES is the mean over the
    resampled runs of all tracks. VRMSE/MRMSE replicates are NaN when some track has no
    non-diverged run; NEES replicates are NaN when no run has a finite NEES (``ins``).
    """
    keys = list(METRICS) + ["nees"]
    out = {k: np.full(max(n_boot, 0), np.nan) for k in keys}
    metrics = posterior_view(metrics)  # the t = 0 rule, as the table's point
    d = metrics[(metrics["filter"] == filt) & ~lost_by_any(metrics)]  # the runs no filter lost
    if d.empty or n_boot < 1:
        return out
    per_track: dict[str, list[np.ndarray]] = {k: [] for k in METRICS}
    complete = True
    nees_sum = np.zeros(n_boot)
    nees_cnt = np.zeros(n_boot)
    for track in sorted(pd.unique(d["track"])):
        t = d[d["track"] == track].sort_values("run")
        if len(t) == 0:
            complete = False
            continue
        counts = resample_counts(len(t), n_boot, track_rng(seed, track))
        for key, (sse_col, _, _) in METRICS.items():
            per_track[key].append(rmse(t[sse_col], t["n_samples"], counts))
        nees = t["nees"].to_numpy(float)
        fin = np.isfinite(nees)
        nees_sum += counts[:, fin] @ nees[fin]
        nees_cnt += counts[:, fin].sum(axis=1)
    if complete:
        for key in METRICS:
            out[key] = track_average(per_track[key])
    with np.errstate(divide="ignore", invalid="ignore"):
        out["nees"] = np.where(nees_cnt > 0, nees_sum / np.where(nees_cnt > 0, nees_cnt, 1), np.nan)
    return out


def sweep_table(metrics: pd.DataFrame, n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """One row per (value, filter), values ascending, filters in order of appearance.

    Columns: ``value``, ``filter``; ``vrmse``, ``mrmse`` (track average, eqs 50-52, over the
    non-diverged runs and the epochs after t = 0, as :func:`tables.filter_table`) and ``nees`` (mean per-run NEES of the
    non-diverged runs), each with ``<key>_lo`` / ``<key>_hi`` (95 % bootstrap percentile
    interval, :func:`filter_bootstrap`); ``diverged``, ``runs``, ``div_rate`` =
    diverged / runs with its 95 % Wilson interval ``div_rate_lo`` / ``div_rate_hi``.
    A filter absent at a value gets NaN metrics and 0 runs.
    """
    check_sweep_metrics(metrics)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    filters = filters_in_order(metrics)
    rows = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v]
        ft = filter_table(sub, None, n_boot=0, seed=seed).set_index("filter")
        for f in filters:
            row: dict[str, Any] = {"value": v, "filter": f}
            if f in ft.index:
                r = ft.loc[f]
                boot = filter_bootstrap(sub, f, n_boot=n_boot, seed=seed)
                for key in ("vrmse", "mrmse", "nees"):
                    row[key] = float(r[key])
                    row[f"{key}_lo"], row[f"{key}_hi"] = percentile_ci(boot[key])
                k, n = int(r["diverged"]), int(r["runs"])
            else:
                for key in ("vrmse", "mrmse", "nees"):
                    row[key] = row[f"{key}_lo"] = row[f"{key}_hi"] = math.nan
                k, n = 0, 0
            row["diverged"], row["runs"] = k, n
            row["div_rate"] = k / n if n else math.nan
            row["div_rate_lo"], row["div_rate_hi"] = wilson_interval(k, n)
            rows.append(row)
    return pd.DataFrame(rows)


def improvement_table(
    metrics: pd.DataFrame,
    baseline: str | None = None,
    n_boot: int = 2000,
    seed: int = 0,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> pd.DataFrame:
    """Improvement of each non-baseline filter over the baseline, per value, percent.

    ``100 · (metric_baseline − metric_filter) / metric_baseline`` (positive = the filter is
    better) for VRMSE and MRMSE over the runs that diverged in neither filter (so a filter
    is not credited for the runs its baseline lost); ``<key>_ci_lo`` / ``<key>_ci_hi`` is the 95 % paired
    bootstrap interval of :func:`stats.paired_bootstrap` (runs diverged in neither filter,
    the same resample for both) and ``<key>_ci_excludes_0`` flags an interval without 0;
    ``pairs_min`` is the fewest paired runs on a track and ``<key>_significant`` = excludes 0
    and ``pairs_min >= min_pairs``. ``attrs["baseline"]`` names the baseline. This table is
    the only source of the improvements of the sweep report's table and figure. Errors after t = 0
    (:func:`stats.posterior_view`, the t = 0 rule of docs/report.md).
    """
    metrics = posterior_view(metrics)
    base = default_baseline(metrics, baseline)
    rows = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v]
        for f in filters_in_order(metrics):
            if f == base:
                continue
            row: dict[str, Any] = {"value": v, "filter": f}
            boot = paired_bootstrap(sub, base, f, n_boot=n_boot, seed=seed)
            paired = paired_improvement(sub, base, f)  # on the runs diverged in neither, as the interval
            counts = paired_run_counts(sub, base, f)
            row["pairs_min"] = min(counts.values()) if counts else 0
            for key in METRICS:
                row[f"{key}_imprv"] = paired[key]
                lo, hi = percentile_ci(boot[key])
                row[f"{key}_ci_lo"], row[f"{key}_ci_hi"] = lo, hi
                excludes, significant, _ = ci_marks(lo, hi, row["pairs_min"], min_pairs)
                row[f"{key}_ci_excludes_0"] = excludes
                row[f"{key}_significant"] = significant
            rows.append(row)
    cols = ["value", "filter", "pairs_min"] + [
        f"{k}_{s}" for k in METRICS for s in ("imprv", "ci_lo", "ci_hi", "ci_excludes_0", "significant")
    ]
    out = pd.DataFrame(rows, columns=cols)
    out.attrs["baseline"] = base
    out.attrs["min_pairs"] = int(min_pairs)
    return out


def improvement_points(imp: pd.DataFrame, key: str, filt: str) -> pd.DataFrame:
    """The points of one filter's improvement curve, values ascending: ``value``, ``imprv``,
    ``ci_lo``, ``ci_hi``, ``significant``, ``mark`` (``*``, ``†`` or ``""``). Both the
    improvement table and the improvement figure are drawn from this (one run set: the pairs)."""
    min_pairs = imp.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    d = imp[imp["filter"] == filt].sort_values("value")
    small = d["pairs_min"].to_numpy(int) < min_pairs if "pairs_min" in d else np.zeros(len(d), bool)
    sig = (d[f"{key}_significant"] if f"{key}_significant" in d else d[f"{key}_ci_excludes_0"]).to_numpy(bool)
    return pd.DataFrame({
        "value": d["value"].to_numpy(float),
        "imprv": d[f"{key}_imprv"].to_numpy(float),
        "ci_lo": d[f"{key}_ci_lo"].to_numpy(float),
        "ci_hi": d[f"{key}_ci_hi"].to_numpy(float),
        "significant": sig,
        "mark": np.where(small, SMALL_MARK, np.where(sig, SIG_MARK, "")),
    })


def summary_rows(
    metrics: pd.DataFrame, n_boot: int = 2000, seed: int = 0, practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> pd.DataFrame:
    """:func:`comparisons.compare_filters` per swept value (column ``value`` first): the rows of the
    verdict and of the pairwise comparisons of a sweep."""
    parts = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v].drop(columns=["param", "value"])
        c = compare_filters(sub, n_boot=n_boot, seed=seed, practical_pct=practical_pct, min_pairs=min_pairs)
        parts.append(c.assign(value=v)[["value"] + list(c.columns)])
    return pd.concat(parts, ignore_index=True)


def nees_runs(metrics: pd.DataFrame) -> int:
    """Realizations per value, i.e. distinct (track, run) pairs (the largest over values)."""
    n = metrics.groupby("value")[["track", "run"]].apply(lambda d: len(d.drop_duplicates()))
    return int(n.max())


def sweep_verdict(metrics: pd.DataFrame, baseline: str, n_boot: int = 2000, seed: int = 0,
                  practical_pct: float = PRACTICAL_PCT, min_pairs: int = MIN_PAIRED_RUNS,
                  comps: pd.DataFrame | None = None) -> pd.DataFrame:
    """The sweep report's verdict: :func:`verdict.verdict_table` of each swept value against ``baseline``,
    stacked with a ``value`` column (the report's rows, the horizontal position error ones included);
    ``comps``: :func:`summary_rows` (computed here when not given)."""
    if comps is None:
        comps = summary_rows(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct, min_pairs=min_pairs)
    return sweep_verdict_frame([
        (v, verdict_table(metrics[metrics["value"] == v].drop(columns=["param", "value"]), baseline, n_boot=n_boot,
                          seed=seed, practical_pct=practical_pct, min_pairs=min_pairs,
                          comps=comps[comps["value"] == v].drop(columns="value").reset_index(drop=True)))
        for v in sweep_values(metrics)])


def sweep_horizontal(metrics: pd.DataFrame) -> pd.DataFrame | None:
    """:func:`tables.horizontal_table` of each swept value (``value`` first: per filter the track averages
    of the final and RMS horizontal position error [m], CEP50, R95, then per track); None when the
    metrics lack the horizontal-error columns (a folder written before them)."""
    parts = []
    for v in sweep_values(metrics):
        h = horizontal_table(metrics[metrics["value"] == v].drop(columns=["param", "value"]))
        if h is None:
            return None
        parts.append(h.assign(value=v)[["value"] + list(h.columns)])
    return pd.concat(parts, ignore_index=True)
