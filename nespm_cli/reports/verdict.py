"""The verdict of a comparison of filters: one row per metric (velocity RMSE, attitude RMSE, final and
RMS horizontal position error when present, ANEES) with the best causal filter, its paired
improvement over the reference and whether that is statistically and practically meaningful, over
all the runs each pair kept and over the common survivors (the runs no filter lost).

The error rows are rows of :func:`comparisons.compare_filters`: the best filter and the interval of
its improvement over the reference (over the runner-up when the best is the reference) are the ones
it computes. The common-survivor columns redo the same comparison on the runs no causal filter lost
(:func:`stats.lost_by_any`); without a lost run they are the same numbers. RTS-smoother floors
(``<filter>-rts``) are never the best or the reference: the lowest floor of a metric stands beside.
The ANEES row names the filter whose mean NEES is closest to its expected value (6 dof) on a log
scale; it has no interval. docs/report.md defines every column.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from nespm_cli.reports.block_consistency import consistency_words
from nespm_cli.reports.comparisons import OWN_COLUMN, compare_filters
from nespm_cli.reports.results import causal_only, check_metrics, filters_in_order, is_smoother
from nespm_cli.reports.stats import (
    MIN_PAIRED_RUNS,
    NEES_DOF,
    PRACTICAL_PCT,
    ci_marks,
    lost_by_any,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    nees_check,
    percentile_ci,
    posterior_view,
)
from nespm_cli.reports.tables import default_reference, filter_table
from nespm_cli.reports.wording import block_cause, mean_nees_place, mean_nees_words

__all__ = ["VERDICT_COLUMNS", "VERDICT_METRICS", "anees_row", "consistency_summary", "verdict_table"]

#: metric key -> (name, unit) in the verdict's order; "anees" is the consistency row
VERDICT_METRICS: dict[str, tuple[str, str]] = {
    "vrmse": ("velocity RMSE", "m/s"),
    "mrmse": ("attitude RMSE", "rad"),
    "hpe_final": ("horizontal position error, final", "m"),
    "hpe": ("horizontal position error, RMS", "m"),
    "anees": ("ANEES", "6 dof"),
    "consistency": ("consistency", "share of epochs inside"),
}

#: the columns of :func:`verdict_table`; ``s_``: the same over the common survivors
VERDICT_COLUMNS = (
    "metric", "best", "best_value", "other", "other_value", "other_is_reference", "imprv", "ci_lo", "ci_hi",
    "excludes_0", "significant", "practical", "pairs_min", "pairs", "verdict", "s_best_value", "s_other_value",
    "s_imprv", "s_ci_lo", "s_ci_hi", "s_excludes_0", "s_significant", "s_practical", "s_pairs_min", "s_pairs",
    "floor", "floor_value", "best_lost", "other_lost", "runs", "best_item", "other_item", "other_verdict", "epochs",
)


def _paired(metrics: pd.DataFrame, other: str, best: str, key: str, n_boot: int, seed: int,
            practical_pct: float, min_pairs: int) -> dict[str, Any]:
    """The improvement of ``best`` over ``other`` on ``metrics`` with its paired interval and flags."""
    imp = paired_improvement(metrics, other, best, [key])[key]
    lo, hi = percentile_ci(paired_bootstrap(metrics, other, best, n_boot=n_boot, seed=seed, keys=[key])[key])
    counts = paired_run_counts(metrics, other, best)
    pairs_min = min(counts.values()) if counts else 0
    excludes, significant, _ = ci_marks(lo, hi, pairs_min, min_pairs)
    return {"imprv": imp, "ci_lo": lo, "ci_hi": hi, "excludes_0": excludes, "significant": significant,
            "practical": bool(np.isfinite(imp) and abs(imp) >= practical_pct), "pairs_min": pairs_min,
            "pairs": int(sum(counts.values()))}


def _floor(own: pd.DataFrame, column: str) -> tuple[str | None, float]:
    """The RTS-smoother floor with the smallest finite ``column`` of :func:`filter_table` ``own``."""
    rows = own[own["filter"].map(is_smoother) & np.isfinite(own[column].to_numpy(float))]
    if rows.empty:
        return None, math.nan
    r = rows.loc[rows[column].idxmin()]
    return str(r["filter"]), float(r[column])


def _error_row(key: str, c: pd.DataFrame, causal: pd.DataFrame, survivors: pd.DataFrame | None, ref: str,
               own: pd.DataFrame, n_boot: int, seed: int, practical_pct: float, min_pairs: int) -> dict[str, Any]:
    """One error metric's verdict from its :func:`compare_filters` rows ``c``."""
    row: dict[str, Any] = dict.fromkeys(VERDICT_COLUMNS, math.nan)
    row.update(metric=key, other=None, other_is_reference=False, excludes_0=False, significant=False,
               practical=False, pairs_min=0, pairs=0, s_excludes_0=False, s_significant=False,
               s_practical=False, s_pairs_min=0, s_pairs=0)
    row["floor"], row["floor_value"] = _floor(own, OWN_COLUMN[key])
    first = c.iloc[0]
    row.update(best=first["best"], best_value=first["best_value"], verdict=first["verdict"])
    row["s_best_value"] = first["best_value"]  # the tables' own values are over the common survivors
    if first["best"] is None or first["other"] is None:
        return row
    best = first["best"]
    # always the closest competitor (the runner-up: the smallest improvement of a defined comparison),
    # whether or not it is the reference, so the column means one thing (the reference is in the tables)
    finite = c[np.isfinite(c["imprv"].to_numpy(float))]
    other = finite.loc[finite["imprv"].idxmin(), "other"] if len(finite) else c["other"].iloc[0]
    r = c[c["other"] == other].iloc[0]
    own_value = own[~own["filter"].map(is_smoother)].set_index("filter")[OWN_COLUMN[key]]
    row.update(other=other, other_is_reference=other == ref, other_value=float(own_value[other]),
               s_other_value=float(own_value[other]), verdict=r["verdict"])
    pairs = paired_run_counts(causal, other, best)
    row.update({k: r[k] for k in ("imprv", "ci_lo", "ci_hi", "excludes_0", "significant", "practical",
                                  "pairs_min")}, pairs=int(sum(pairs.values())))
    surv = (_paired(survivors, other, best, key, n_boot, seed, practical_pct, min_pairs) if survivors is not None
            else {k: row[k] for k in ("imprv", "ci_lo", "ci_hi", "excludes_0", "significant", "practical",
                                      "pairs_min", "pairs")})
    row.update({f"s_{k}": v for k, v in surv.items()})
    return row


def anees_row(causal: pd.DataFrame, survivors: pd.DataFrame, ref: str) -> dict[str, Any]:
    """The consistency row: the causal filter whose mean NEES over its own kept runs is closest to
    :data:`stats.NEES_DOF` on a log scale (``|ln(NEES / 6)|``), the runner-up (the next closest) beside it;
    ``pairs`` / ``s_pairs``: the runs averaged; no interval. Used for a folder without the per-block NEES
    (:func:`consistency_row` otherwise)."""
    row: dict[str, Any] = dict.fromkeys(VERDICT_COLUMNS, math.nan)
    row.update(metric="anees", best=None, other=None, other_is_reference=False, excludes_0=False,
               significant=False, practical=False, pairs_min=0, pairs=0, s_excludes_0=False,
               s_significant=False, s_practical=False, s_pairs_min=0, s_pairs=0, floor=None, verdict="undefined")
    kept = causal[~causal["diverged"].astype(bool)]
    all_runs = kept.groupby("filter", sort=False)["nees"].agg(["mean", "count"])
    surv = survivors.groupby("filter", sort=False)["nees"].agg(["mean", "count"])
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(np.log(all_runs["mean"] / NEES_DOF)).replace([np.inf], np.nan).dropna()
    if dist.empty:
        return row
    order = [f for f in filters_in_order(causal) if f in dist.index]
    ranked = sorted(order, key=lambda f: (dist[f], order.index(f)))
    best = ranked[0]
    other = ranked[1] if len(ranked) > 1 else None  # the runner-up, as in every row

    def value(table: pd.DataFrame, f: str | None, col: str = "mean") -> float:
        return float(table.loc[f, col]) if f is not None and f in table.index else math.nan

    row.update(best=best, other=other, other_is_reference=other == ref,
               verdict=nees_check(value(all_runs, best), int(value(all_runs, best, "count")))[2],
               best_value=value(all_runs, best), other_value=value(all_runs, other),
               s_best_value=value(surv, best), s_other_value=value(surv, other),
               pairs=int(value(all_runs, best, "count")), pairs_min=int(value(all_runs, best, "count")),
               s_pairs=int(np.nan_to_num(value(surv, best, "count"))),
               s_pairs_min=int(np.nan_to_num(value(surv, best, "count"))))
    return row


def consistency_summary(consistency: pd.DataFrame | None, metrics: pd.DataFrame, shares: bool = True) -> dict[str, str]:
    """Per filter the one wording of its consistency (the verdict, the tables and the tune report say the same):
    the per-block words (:func:`block_consistency.consistency_words` of the pooled table ``consistency``) and,
    when its mean 6-DOF NEES (over the runs no filter lost, after t = 0: :func:`stats.posterior_view`) lies
    outside its 95 % band, where it lies and the block that drives it (:func:`wording.block_cause`), e.g.
    ``mixed: velocity 31 %; conservative: attitude 12 %; mean NEES 9.5 above its band [3.84, 8.63], driven by
    velocity (mean ANEES 4.2 of 3; 23 % of its epochs above the bounds, 71 % below: ...)``. Without a block
    table (``None`` or empty): the mean NEES's band word (:func:`stats.nees_check`), the only judgement there."""
    m = posterior_view(metrics)
    kept = m[~lost_by_any(m)].groupby("filter", sort=False)["nees"].agg(["mean", "count"])
    bands = {f: nees_check(float(r["mean"]), int(r["count"])) for f, r in kept.iterrows()}
    if consistency is None or consistency.empty:
        return {f: b[2] for f, b in bands.items()}
    pooled = consistency[consistency["track"].isna()] if "track" in consistency.columns else consistency
    out = consistency_words(pooled, shares=shares)
    for f in list(out):
        if f not in bands:
            continue
        lo, hi, _ = bands[f]
        mean = float(kept.loc[f, "mean"])
        place = mean_nees_place(mean, lo, hi)
        if place in ("above", "below"):
            out[f] += "; " + mean_nees_words(mean, lo, hi, block_cause(pooled[pooled["filter"] == f], place))
    return out


def consistency_row(table: pd.DataFrame, order: list[str], metrics: pd.DataFrame | None = None) -> dict[str, Any]:
    """The consistency row from the per-block table ``table`` (:func:`block_consistency.block_consistency`,
    pooled over tracks): per causal filter its worst block or sensor (the smallest share of epochs inside the
    95 % bounds); ``best`` the filter whose worst share is largest, ``other`` the runner-up; ``best_value`` /
    ``other_value`` those shares, ``verdict`` the best filter's words (:func:`block_consistency.consistency_words`);
    ``best_item`` / ``other_item`` their worst items' names, ``other_verdict`` the runner-up's words, ``epochs``
    the epochs judged; no interval. With ``metrics``, the words are :func:`consistency_summary`'s: where the mean
    NEES lies outside its band, they say so and name the block that drives it."""
    row: dict[str, Any] = dict.fromkeys(VERDICT_COLUMNS, math.nan)
    row.update(metric="consistency", best=None, other=None, other_is_reference=False, excludes_0=False,
               significant=False, practical=False, pairs_min=0, pairs=0, s_excludes_0=False,
               s_significant=False, s_practical=False, s_pairs_min=0, s_pairs=0, floor=None, verdict="undefined",
               best_item=None, other_item=None, other_verdict=None)
    t = table[table["filter"].isin(order) & np.isfinite(table["inside"].to_numpy(float))]
    if t.empty:
        return row
    worst = t.loc[t.groupby("filter", sort=False)["inside"].idxmin()].set_index("filter")
    ranked = sorted(worst.index, key=lambda f: (-worst.loc[f, "inside"], order.index(f)))
    words = consistency_words(t) if metrics is None else {**consistency_words(t), **consistency_summary(t, metrics)}
    best = ranked[0]
    other = ranked[1] if len(ranked) > 1 else None
    row.update(best=best, best_value=float(worst.loc[best, "inside"]), verdict=words[best],
               best_item=str(worst.loc[best, "name"]), epochs=int(worst.loc[best, "epochs"]))
    if other is not None:
        row.update(other=other, other_value=float(worst.loc[other, "inside"]), other_item=str(worst.loc[other, "name"]),
                   other_verdict=words[other])
    return row


def verdict_table(
    metrics: pd.DataFrame,
    reference: str | None = None,
    n_boot: int = 2000,
    seed: int = 0,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
    comps: pd.DataFrame | None = None,
    consistency: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """One row per metric of :data:`VERDICT_METRICS` present (columns :data:`VERDICT_COLUMNS`).

    ``best`` / ``best_value``: the best causal filter of :func:`compare_filters` (``comps``, computed
    here with the same arguments when not given) and its own track average; ``other``: the filter its
    improvement is over (the reference, or the runner-up when the best is the reference;
    ``other_is_reference``); ``imprv`` [%], ``ci_lo``, ``ci_hi``, ``excludes_0``, ``significant``,
    ``practical``, ``pairs_min`` (fewest pairs on a track), ``verdict``: that row of ``comps``;
    ``pairs``: the pairs summed over tracks. ``s_*``: the same comparison over the common survivors.
    ``floor`` / ``floor_value``: the lowest RTS-smoother floor of the metric (None without one).
    ``best_lost`` / ``other_lost``: the runs each lost (−1: no filter), ``runs``: the best filter's runs.
    The error metrics are posterior (the t = 0 rule, :func:`stats.posterior_view`) where the folder has
    those sums (``attrs["posterior"]``). The last row is the consistency row: per block and sensor from
    the share of epochs inside the bounds (:func:`consistency_row` of ``consistency``, a
    :func:`block_consistency.block_consistency` table) or, without it, the mean-NEES row (:func:`anees_row`).
    ``attrs``: ``reference``, ``any_lost``, ``practical_pct``, ``min_pairs``, ``n_boot``, ``seed`` (and
    ``consistent_share``, the consistency table's least share inside for *consistent*, when it has one).
    """
    check_metrics(metrics)
    ref = default_reference(metrics, reference)
    metrics = posterior_view(metrics)
    if comps is None:
        comps = compare_filters(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct, min_pairs=min_pairs)
    causal = causal_only(metrics)
    lost = lost_by_any(causal)
    survivors = causal[~lost.to_numpy(bool)]
    any_lost = bool(lost.any())
    own = filter_table(metrics, ref, n_boot=0, min_pairs=min_pairs)
    rows = [_error_row(key, comps[comps["metric"] == key], causal, survivors if any_lost else None, ref, own,
                       n_boot, seed, practical_pct, min_pairs)
            for key in VERDICT_METRICS if key in set(comps["metric"])]
    rows.append(anees_row(causal, survivors, ref) if consistency is None or consistency.empty
                else consistency_row(consistency, filters_in_order(causal), causal))
    out = pd.DataFrame(rows, columns=list(VERDICT_COLUMNS))
    lost = causal.groupby("filter", sort=False)["diverged"].agg(["sum", "size"])
    count = lambda f: int(lost.loc[f, "sum"]) if isinstance(f, str) and f in lost.index else -1  # noqa: E731
    out["best_lost"] = out["best"].map(count)
    out["other_lost"] = out["other"].map(count)
    out["runs"] = out["best"].map(lambda f: int(lost.loc[f, "size"]) if isinstance(f, str) and f in lost.index
                                  else int(lost["size"].max()) if len(lost) else 0)
    out.attrs.update(reference=ref, any_lost=any_lost, practical_pct=float(practical_pct),
                     posterior=bool(metrics.attrs.get("posterior", False)),
                     min_pairs=int(min_pairs), n_boot=int(n_boot), seed=int(seed))
    if consistency is not None and "share" in consistency.attrs:
        out.attrs["consistent_share"] = float(consistency.attrs["share"])  # the consistency row's rule
    return out
