"""The per-filter tables of a Monte Carlo results folder (anukf.md eqs 50-53): per (track, filter),
per filter (track averages with the paired improvement over a reference), horizontal position
error, NEES consistency.

Every error number is over the runs no filter lost (:func:`stats.lost_by_any`): per track
``VRMSE = sqrt(sum(sse_vel) / sum(n_samples))`` (eq 50), MRMSE likewise with ``sse_att`` (eq 52),
the RMS horizontal position error with ``sse_hpe``; the track average is eq 51. The sums are the
posterior ones, over the epochs after t = 0 (:func:`stats.posterior_view`; docs/report.md, "The t = 0
rule"), unless ``with_t0`` asks for the papers' every-epoch sums (the published tables only). Improvements and
their intervals are over the runs the pair kept (:func:`stats.paired_improvement`,
:func:`stats.paired_bootstrap`). docs/report.md defines every column.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import cep
from nespm_cli.reports.results import check_metrics, checked_filter, filters_in_order, has_hpe, is_smoother
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    lost_by_any,
    nees_check,
    posterior_view,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    rmse,
    track_average,
)

__all__ = ["DEFAULT_REFERENCE", "default_reference", "filter_table", "horizontal_table", "nees_consistency",
           "rule_view", "track_table"]

DEFAULT_REFERENCE = "ukf-nespm"




def default_reference(metrics: pd.DataFrame, reference: str | None = None) -> str:
    """The reference filter: ``reference`` if given, else ``ukf-nespm`` if present, else the
    last filter that is neither the free-inertial ``ins`` nor an RTS-smoother floor.

    Raises NespmError if ``reference`` is not one of the filters in ``metrics`` or is a smoother
    floor (hindsight is no reference for a causal filter).
    """
    if reference:
        return checked_filter(metrics, reference, "reference")
    names = filters_in_order(metrics)
    causal = [n for n in names if not is_smoother(n)]
    if DEFAULT_REFERENCE in names:
        return DEFAULT_REFERENCE
    aided = [n for n in causal if n != "ins"]
    return aided[-1] if aided else (causal or names)[-1]


def _sums(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per (track, filter): error sums over the runs no filter lost (:func:`stats.lost_by_any`),
    NEES mean over those runs, and run counts (``diverged``: this filter's lost runs)."""
    df = metrics.assign(
        diverged=metrics["diverged"].astype(bool),
        ok=~lost_by_any(metrics),
    )
    ok = df[df["ok"]]
    grouped = ok.groupby(["track", "filter"], sort=False)
    sums = grouped[["sse_vel", "sse_att", "n_samples"]].sum()
    sums["nees"] = grouped["nees"].mean()
    sums["nees_n"] = grouped["nees"].count()
    if has_hpe(metrics):
        sums["sse_hpe"] = grouped["sse_hpe"].sum()
        sums["hpe_final"] = grouped["hpe_final"].mean()
        sums["hpe_final_pct"] = grouped["hpe_final_pct"].mean()
    counts = df.groupby(["track", "filter"], sort=False).agg(
        runs=("run", "size"), diverged=("diverged", "sum")
    )
    if has_hpe(metrics):
        counts["distance"] = df.groupby(["track", "filter"], sort=False)["distance"].mean()
    out = counts.join(sums, how="left")
    out["n_samples"] = out["n_samples"].fillna(0.0)
    out["nees_n"] = out["nees_n"].fillna(0).astype(int)
    return out


def _track_rmse(sums: pd.DataFrame, col: str) -> np.ndarray:
    """Eq 50 per (track, filter) row of :func:`_sums` from its error sums (NaN: every run diverged)."""
    return np.array([rmse([e], [n]) for e, n in zip(sums[col], sums["n_samples"])], dtype=float)


def rule_view(metrics: pd.DataFrame, with_t0: bool = False) -> pd.DataFrame:
    """``metrics`` as the tables read them: :func:`stats.posterior_view` (the t = 0 rule), or with ``with_t0``
    the papers' every-epoch sums (``attrs["posterior"]`` False), for a number set beside a published one."""
    if with_t0:
        out = metrics.copy(deep=False)
        out.attrs["posterior"] = False
        return out
    return posterior_view(metrics)


def track_table(metrics: pd.DataFrame, with_t0: bool = False) -> pd.DataFrame:
    """Per (track, filter): VRMSE, MRMSE (eqs 50, 52), mean NEES, diverged count and runs; the errors over
    the epochs after t = 0 (:func:`rule_view`; ``with_t0``: every epoch, the papers' definition).

    Rows are sorted by track, filters in order of appearance; the NEES is the mean of the
    per-run ``nees`` over the non-diverged runs (each run's mean over the epochs after t = 0, ``nees_post``,
    where the folder has it: :func:`rule_view`), ``nees_n`` the number of those runs with a
    finite NEES, ``nees_lo`` / ``nees_hi`` its 95 % band (:func:`metrics.nees_band`) and
    ``consistency`` the word for where the mean lies. With the horizontal-position columns
    (:data:`HPE_COLUMNS`): ``hpe_rms`` (eq 50 with ``sse_hpe``), ``hpe_final`` and
    ``hpe_final_pct`` (means over the non-diverged runs) and ``distance``; NaN otherwise.
    """
    check_metrics(metrics)
    metrics = rule_view(metrics, with_t0)
    s = _sums(metrics).reset_index()
    order = {f: i for i, f in enumerate(filters_in_order(metrics))}
    s = s.assign(_o=s["filter"].map(order)).sort_values(["track", "_o"]).drop(columns="_o")
    nan = np.full(len(s), np.nan)
    hpe = has_hpe(metrics)
    out = pd.DataFrame(
        {
            "track": s["track"].to_numpy(),
            "filter": s["filter"].astype(str).to_numpy(),
            "vrmse": _track_rmse(s, "sse_vel"),
            "mrmse": _track_rmse(s, "sse_att"),
            "nees": s["nees"].to_numpy(dtype=float),
            "diverged": s["diverged"].to_numpy(dtype=int),
            "runs": s["runs"].to_numpy(dtype=int),
            "nees_n": s["nees_n"].to_numpy(dtype=int),
            "hpe_rms": _track_rmse(s, "sse_hpe") if hpe else nan,
            "hpe_final": s["hpe_final"].to_numpy(dtype=float) if hpe else nan,
            "hpe_final_pct": s["hpe_final_pct"].to_numpy(dtype=float) if hpe else nan,
            "distance": s["distance"].to_numpy(dtype=float) if hpe else nan,
        }
    )
    bands = [nees_check(m, n) for m, n in zip(out["nees"], out["nees_n"])]
    out["nees_lo"] = [b[0] for b in bands]
    out["nees_hi"] = [b[1] for b in bands]
    out["consistency"] = [b[2] for b in bands]
    out = out.reset_index(drop=True)
    out.attrs["posterior"] = bool(metrics.attrs["posterior"])
    return out


def filter_table(
    metrics: pd.DataFrame, reference: str | None, n_boot: int = 2000, seed: int = 0,
    min_pairs: int = MIN_PAIRED_RUNS, with_t0: bool = False,
) -> pd.DataFrame:
    """One row per filter (order of appearance): track-averaged metrics and improvements.

    Columns: ``filter``, ``vrmse``, ``vrmse_imprv``, ``vrmse_ci_lo``, ``vrmse_ci_hi``,
    ``vrmse_ci_excludes_0``, ``vrmse_significant`` and the same for ``mrmse``; ``nees`` (mean
    per-run NEES over the non-diverged runs of all tracks, after t = 0 as the errors) with ``nees_n`` (those runs with a
    finite NEES), its 95 % band ``nees_lo`` / ``nees_hi`` and ``consistency``; ``hpe_rms``
    (eq 51 over the per-track RMS HPE), ``hpe_final`` and ``hpe_final_pct`` (mean over tracks of
    the per-track means; NaN without the HPE columns); ``diverged``, ``runs``, ``tracks``,
    ``pairs_min`` (fewest paired runs with the reference on any track), ``is_reference``.
    Improvements are percent, point and interval over the runs that diverged in neither the
    row nor the reference, NaN on the reference row; the interval is the 2.5/97.5 percentile
    of :func:`paired_bootstrap`; ``_significant`` = excludes 0 and ``pairs_min >= min_pairs``.
    ``attrs["reference"]`` names the reference filter. The errors and improvements are over the epochs
    after t = 0 (:func:`rule_view`; ``attrs["posterior"]`` False for a folder without those sums, or with
    ``with_t0``: every epoch, the papers' definition, for the published tables).
    """
    check_metrics(metrics)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    metrics = rule_view(metrics, with_t0)
    ref = default_reference(metrics, reference)
    tt = track_table(metrics, with_t0)
    ok = metrics[~lost_by_any(metrics)]
    rows = []
    for name in filters_in_order(metrics):
        t = tt[tt["filter"] == name]
        nees = ok.loc[ok["filter"] == name, "nees"]
        lo, hi, word = nees_check(float(nees.mean()), int(nees.count()))
        rows.append(
            {
                "filter": name,
                "vrmse": track_average(t["vrmse"]),
                "mrmse": track_average(t["mrmse"]),
                "nees": float(nees.mean()),
                "nees_n": int(nees.count()),
                "nees_lo": lo,
                "nees_hi": hi,
                "consistency": word,
                "hpe_rms": track_average(t["hpe_rms"]),
                "hpe_final": float(np.mean(t["hpe_final"].to_numpy(float))) if len(t) else math.nan,
                "hpe_final_pct": float(np.mean(t["hpe_final_pct"].to_numpy(float))) if len(t) else math.nan,
                "diverged": int(t["diverged"].sum()),
                "runs": int(t["runs"].sum()),
                "tracks": int(len(t)),
                "pairs_min": 0,
                "is_reference": name == ref,
            }
        )
    table = pd.DataFrame(rows)
    for key in METRICS:
        table[f"{key}_imprv"] = np.nan
        table[f"{key}_ci_lo"] = np.nan
        table[f"{key}_ci_hi"] = np.nan
    for i, name in enumerate(table["filter"]):
        if name == ref:
            continue
        counts = paired_run_counts(metrics, name, ref)
        table.loc[i, "pairs_min"] = min(counts.values()) if counts else 0
        for key, v in paired_improvement(metrics, name, ref).items():  # the point of its paired interval
            table.loc[i, f"{key}_imprv"] = v
        boot = paired_bootstrap(metrics, name, ref, n_boot=n_boot, seed=seed)
        for key, reps in boot.items():
            lo, hi = percentile_ci(reps)
            if np.isfinite(lo):
                table.loc[i, [f"{key}_ci_lo", f"{key}_ci_hi"]] = [lo, hi]
    for key in METRICS:
        lo, hi = table[f"{key}_ci_lo"], table[f"{key}_ci_hi"]
        table[f"{key}_ci_excludes_0"] = ((lo > 0) | (hi < 0)).to_numpy(bool)
        table[f"{key}_significant"] = (table[f"{key}_ci_excludes_0"]
                                       & (table["pairs_min"] >= min_pairs)).to_numpy(bool)
    columns = ["filter"]
    for key in METRICS:
        columns += [key, f"{key}_imprv", f"{key}_ci_lo", f"{key}_ci_hi", f"{key}_ci_excludes_0",
                    f"{key}_significant"]
    columns += ["nees", "nees_n", "nees_lo", "nees_hi", "consistency", "hpe_rms", "hpe_final",
                "hpe_final_pct", "diverged", "runs", "tracks", "pairs_min", "is_reference"]
    table = table[columns]
    table.attrs["reference"] = ref
    table.attrs["min_pairs"] = int(min_pairs)
    table.attrs["posterior"] = bool(metrics.attrs["posterior"])
    return table


def horizontal_table(metrics: pd.DataFrame) -> pd.DataFrame | None:
    """Per filter, track averages of the horizontal position error, then per (track, filter):
    columns ``track`` (``None`` on the track-average rows), ``filter``, ``distance`` [m],
    ``hpe_final`` [m], ``hpe_rms`` [m], ``hpe_final_pct`` [%], ``diverged``, ``runs``.
    ``None`` when the metrics lack the HPE columns (a folder written before them). The RMS HPE is over the
    epochs after t = 0 (:func:`rule_view`); the final HPE is the last epoch's."""
    if not has_hpe(metrics):
        return None
    tt = track_table(metrics)
    kept = metrics[~lost_by_any(metrics)]
    for q, col in ((0.5, "cep50"), (0.95, "r95")):  # over the runs no filter lost, at the final epoch
        per = kept.groupby(["track", "filter"], sort=False)["hpe_final"].apply(lambda x, q=q: cep(x, q))
        tt[col] = [per.get((tr, f), math.nan) for tr, f in zip(tt["track"], tt["filter"])]
    cols = ["distance", "hpe_final", "hpe_rms", "hpe_final_pct", "cep50", "r95", "diverged", "runs"]
    rows = []
    for name in filters_in_order(metrics):
        t = tt[tt["filter"] == name]
        rows.append({"track": None, "filter": name, "distance": float(t["distance"].mean()),
                     "hpe_final": float(t["hpe_final"].mean(skipna=False)),
                     "hpe_rms": track_average(t["hpe_rms"]),
                     "hpe_final_pct": float(t["hpe_final_pct"].mean(skipna=False)),
                     "cep50": float(t["cep50"].mean(skipna=False)), "r95": float(t["r95"].mean(skipna=False)),
                     "diverged": int(t["diverged"].sum()), "runs": int(t["runs"].sum())})
    per_track = tt[["track", "filter"] + cols].to_dict("records")
    out = pd.DataFrame(rows + per_track, columns=["track", "filter"] + cols)
    out["track"] = pd.Series([r["track"] for r in rows + per_track], dtype=object)  # None = average
    return out



def nees_consistency(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per filter: ``filter``, mean NEES ``nees`` (after t = 0, :func:`rule_view`) over the non-diverged runs
    of all tracks, ``nees_n``,
    its two-sided 95 % band ``nees_lo`` / ``nees_hi`` (``metrics.nees_band(6, nees_n)``) and
    ``consistency``: ``consistent`` (inside), ``overconfident`` (above: covariance too small),
    ``conservative`` (below), ``—`` without a covariance (``ins``)."""
    t = filter_table(metrics, None, n_boot=0)
    return t[["filter", "nees", "nees_n", "nees_lo", "nees_hi", "consistency"]].reset_index(drop=True)

