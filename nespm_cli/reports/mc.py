"""Report of a Monte Carlo results folder (``nespm mc``): summary in words, tables, paired bootstrap, figures.

Reads the files described in ``docs/results-schema.md`` (``metrics.parquet``, optionally
``epochs.parquet`` and ``manifest.json``) and writes ``report.md`` plus PNG figures.

Metric definitions (anukf.md eqs 50-53), repeated in the report text:

* per track and filter, ``VRMSE = sqrt(sum(sse_vel) / sum(n_samples))`` over the
  non-diverged runs (eq 50); ``MRMSE`` likewise with ``sse_att`` (eq 52); the RMS horizontal
  position error (HPE) likewise with ``sse_hpe``;
* track average: ``sqrt(mean over tracks of VRMSE_track**2)`` (eq 51);
* improvement of a row over the reference filter F: ``100 * (m_row - m_F) / m_row``
  (the papers' "ANUKF Imprv." column), point and interval over the runs that diverged in
  neither filter (pairs);
* 95 % interval of the improvement: paired bootstrap over run indices, resampled per track;
  an interval from fewer than :data:`MIN_PAIRED_RUNS` paired runs on some track is marked
  ``†`` and never called significant;
* an improvement is *practically* meaningful when ``|improvement| >= practical_pct``
  (default :data:`PRACTICAL_PCT` percent) and *statistically* when its interval excludes 0;
* mean NEES against its two-sided 95 % chi-square band (:func:`metrics.nees_band`).

The equations are those of :mod:`nespm_cli.reports.stats`, the tables' markdown that of
:mod:`nespm_cli.reports.markdown`; :func:`nespm_cli.reports.dispatch.write_report` picks this module
for an ordinary Monte Carlo folder.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import cep
from nespm_cli.reports.consistency import anees_figure
from nespm_cli.reports.figures import filter_colors, outage_spans, save_figure
from nespm_cli.reports.markdown import (
    DASH,
    SIG_MARK,
    SMALL_MARK,
    fmt,
    fmt_imprv,
    fmt_pct,
    header_line,
    imprv_cells,
    md_table,
)
from nespm_cli.reports.published import PUBLISHED, published_tables
from nespm_cli.reports.results import (
    check_metrics,
    filters_in_order,
    has_hpe,
    load_results,
    scenario_of,
)
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    PRACTICAL_PCT,
    check_practical_pct,
    ci_marks,
    lost_by_any,
    improvement,
    interval_mark,
    metric_keys,
    nees_check,
    paired_averages,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    rmse,
    track_average,
)

__all__ = [
    "DEFAULT_REFERENCE",
    "default_reference",
    "track_table",
    "filter_table",
    "horizontal_table",
    "compare_filters",
    "nees_consistency",
    "verdict_headline",
    "summary_md",
    "render_report",
    "plot_track_figures",
    "write_mc_report",
]

DEFAULT_REFERENCE = "ukf-nespm"




def default_reference(metrics: pd.DataFrame, reference: str | None = None) -> str:
    """The reference filter: ``reference`` if given, else ``ukf-nespm`` if present, else the
    last filter that is not the free-inertial ``ins``.

    Raises NespmError if ``reference`` is not one of the filters in ``metrics``.
    """
    names = filters_in_order(metrics)
    if reference:
        if reference not in names:
            raise NespmError(
                f"--baseline: unknown filter '{reference}': the results hold {', '.join(names)}"
            )
        return reference
    if DEFAULT_REFERENCE in names:
        return DEFAULT_REFERENCE
    aided = [n for n in names if n != "ins"]
    return aided[-1] if aided else names[-1]


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


def track_table(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per (track, filter): VRMSE, MRMSE (eqs 50, 52), mean NEES, diverged count and runs.

    Rows are sorted by track, filters in order of appearance; the NEES is the mean of the
    per-run ``nees`` over the non-diverged runs, ``nees_n`` the number of those runs with a
    finite NEES, ``nees_lo`` / ``nees_hi`` its 95 % band (:func:`metrics.nees_band`) and
    ``consistency`` the word for where the mean lies. With the horizontal-position columns
    (:data:`HPE_COLUMNS`): ``hpe_rms`` (eq 50 with ``sse_hpe``), ``hpe_final`` and
    ``hpe_final_pct`` (means over the non-diverged runs) and ``distance``; NaN otherwise.
    """
    check_metrics(metrics)
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
    return out.reset_index(drop=True)


def filter_table(
    metrics: pd.DataFrame, reference: str | None, n_boot: int = 2000, seed: int = 0,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> pd.DataFrame:
    """One row per filter (order of appearance): track-averaged metrics and improvements.

    Columns: ``filter``, ``vrmse``, ``vrmse_imprv``, ``vrmse_ci_lo``, ``vrmse_ci_hi``,
    ``vrmse_ci_excludes_0``, ``vrmse_significant`` and the same for ``mrmse``; ``nees`` (mean
    per-run NEES over the non-diverged runs of all tracks) with ``nees_n`` (those runs with a
    finite NEES), its 95 % band ``nees_lo`` / ``nees_hi`` and ``consistency``; ``hpe_rms``
    (eq 51 over the per-track RMS HPE), ``hpe_final`` and ``hpe_final_pct`` (mean over tracks of
    the per-track means; NaN without the HPE columns); ``diverged``, ``runs``, ``tracks``,
    ``pairs_min`` (fewest paired runs with the reference on any track), ``is_reference``.
    Improvements are percent, point and interval over the runs that diverged in neither the
    row nor the reference, NaN on the reference row; the interval is the 2.5/97.5 percentile
    of :func:`paired_bootstrap`; ``_significant`` = excludes 0 and ``pairs_min >= min_pairs``.
    ``attrs["reference"]`` names the reference filter.
    """
    check_metrics(metrics)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    ref = default_reference(metrics, reference)
    tt = track_table(metrics)
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
    return table


def horizontal_table(metrics: pd.DataFrame) -> pd.DataFrame | None:
    """Per filter, track averages of the horizontal position error, then per (track, filter):
    columns ``track`` (``None`` on the track-average rows), ``filter``, ``distance`` [m],
    ``hpe_final`` [m], ``hpe_rms`` [m], ``hpe_final_pct`` [%], ``diverged``, ``runs``.
    ``None`` when the metrics lack the HPE columns (a folder written before them)."""
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


_SUMMARY_NAMES: dict[str, str] = {
    "vrmse": "VRMSE",
    "mrmse": "MRMSE",
    "hpe": "Horizontal position error (RMS over the epochs)",
}


_OWN_COLUMN: dict[str, str] = {"vrmse": "vrmse", "mrmse": "mrmse", "hpe": "hpe_rms"}


def compare_filters(
    metrics: pd.DataFrame,
    n_boot: int = 2000,
    seed: int = 0,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
    keys: Sequence[str] | None = None,
) -> pd.DataFrame:
    """Per metric, the best filter and its paired improvement over every other filter.

    ``keys`` default to VRMSE, MRMSE and, when the HPE columns are present, ``hpe`` (RMS
    horizontal position error). The best filter is the one with the smaller paired track
    average (eq 51 over the runs both kept) against the most other filters, ties broken by
    the smaller track average over its own non-diverged runs; without divergences this is the
    filter with the smallest track average.

    One row per (metric, other filter): ``metric``, ``best``, ``other``, ``best_value`` (the
    best filter's own track average), ``imprv`` (improvement of ``best`` over ``other``,
    :func:`paired_improvement`: positive = ``best`` has the smaller error), ``ci_lo``,
    ``ci_hi`` (:func:`paired_bootstrap`), ``pairs_min`` (fewest paired runs on a track),
    ``excludes_0``, ``significant`` (excludes 0 and ``pairs_min >= min_pairs``), ``practical``
    (``|imprv| >= practical_pct``), ``ci_within`` (the interval lies inside ±``practical_pct``)
    and ``verdict``: ``better`` (significant and practical, positive), ``worse`` (the same,
    negative), ``no practical difference`` (``|imprv| < practical_pct``, significant or not),
    ``not significant`` (practical point, interval includes 0), ``too few runs``
    (``pairs_min < min_pairs``) or ``undefined`` (no paired point). A metric with a single
    usable filter gets one row with ``other`` None and verdict ``only filter``.
    """
    check_metrics(metrics)
    if keys is None:
        keys = list(METRICS) + (["hpe"] if has_hpe(metrics) else [])
    keys = metric_keys(metrics, keys)
    filters = filters_in_order(metrics)
    own_table = filter_table(metrics, None, n_boot=0, min_pairs=min_pairs).set_index("filter")
    pair_avg = {(a, b): paired_averages(metrics, a, b, keys)
                for i, a in enumerate(filters) for b in filters[i + 1:]}
    boot_cache: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    cols = ["metric", "best", "other", "best_value", "imprv", "ci_lo", "ci_hi", "pairs_min",
            "excludes_0", "significant", "practical", "ci_within", "verdict"]
    rows = []
    for key in keys:
        own = {f: float(own_table.loc[f, _OWN_COLUMN[key]]) for f in filters}
        cands = [f for f in filters if np.isfinite(own[f])]
        if not cands:
            rows.append(dict(zip(cols, [key, None, None, math.nan, math.nan, math.nan, math.nan, 0,
                                        False, False, False, False, "undefined"])))
            continue
        wins = {f: 0.0 for f in cands}
        for (a, b), av in pair_avg.items():
            if a in wins and b in wins and all(np.isfinite(av[key])):
                ma, mb = av[key]
                if ma < mb:
                    wins[a] += 1
                elif mb < ma:
                    wins[b] += 1
                else:
                    wins[a] += 0.5
                    wins[b] += 0.5
        best = max(cands, key=lambda f: (wins[f], -own[f]))
        others = [f for f in filters if f != best]
        if not others:
            rows.append(dict(zip(cols, [key, best, None, own[best], math.nan, math.nan, math.nan, 0,
                                        False, False, False, False, "only filter"])))
            continue
        for other in others:
            if (other, best) not in boot_cache:
                boot_cache[(other, best)] = paired_bootstrap(metrics, other, best, n_boot=n_boot,
                                                             seed=seed, keys=keys)
            imp = paired_improvement(metrics, other, best, [key])[key]
            lo, hi = percentile_ci(boot_cache[(other, best)][key])
            counts = paired_run_counts(metrics, other, best)
            pairs_min = min(counts.values()) if counts else 0
            excludes, significant, _ = ci_marks(lo, hi, pairs_min, min_pairs)
            practical = bool(np.isfinite(imp) and abs(imp) >= practical_pct)
            within = bool(np.isfinite(lo) and np.isfinite(hi) and lo > -practical_pct and hi < practical_pct)
            if not np.isfinite(imp):
                verdict = "undefined"
            elif pairs_min < min_pairs:
                verdict = "too few runs"
            elif not practical:
                verdict = "no practical difference"
            elif significant:
                verdict = "better" if imp > 0 else "worse"
            else:
                verdict = "not significant"
            rows.append(dict(zip(cols, [key, best, other, own[best], imp, lo, hi, pairs_min, excludes,
                                        significant, practical, within, verdict])))
    out = pd.DataFrame(rows, columns=cols)
    out.attrs.update(practical_pct=float(practical_pct), min_pairs=int(min_pairs))
    return out


def nees_consistency(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per filter: ``filter``, mean NEES ``nees`` over the non-diverged runs of all tracks, ``nees_n``,
    its two-sided 95 % band ``nees_lo`` / ``nees_hi`` (``metrics.nees_band(6, nees_n)``) and
    ``consistency``: ``consistent`` (inside), ``overconfident`` (above: covariance too small),
    ``conservative`` (below), ``—`` without a covariance (``ins``)."""
    t = filter_table(metrics, None, n_boot=0)
    return t[["filter", "nees", "nees_n", "nees_lo", "nees_hi", "consistency"]].reset_index(drop=True)


_CONSISTENCY_WORDS = {
    "consistent": "consistent (inside the band)",
    "overconfident": "overconfident (NEES above band: its covariance is too small)",
    "conservative": "conservative (NEES below band: its covariance is too large)",
}


def _comparison_words(r: Any, practical_pct: float, min_pairs: int) -> str:
    """One comparison of :func:`compare_filters` in words."""
    head = f"`{r.best}` vs `{r.other}`"
    if r.verdict == "undefined":
        return f"{head}: undefined (on some track no run was kept by both)"
    mark = interval_mark(r.significant, r.pairs_min, min_pairs)
    num = fmt_imprv(r.imprv, r.ci_lo, r.ci_hi, mark)
    side = "lower error" if r.imprv > 0 else "higher error" if r.imprv < 0 else "equal error"
    p = f"{practical_pct:g} %"
    if r.verdict == "too few runs":
        size = "below" if abs(r.imprv) < practical_pct else "above"
        why = (f"only {r.pairs_min} paired runs on some track (fewer than {min_pairs}): the percentile "
               f"bootstrap is unreliable, no significance claimed (the point is {size} the {p} threshold)")
    elif r.verdict in ("better", "worse"):
        why = f"statistically (interval excludes 0) and practically (≥ {p}) meaningful"
    elif r.verdict == "no practical difference":
        why = (f"statistically significant, but below the {p} practical threshold: **no practical difference**"
               if r.significant else
               f"interval includes 0 and below the {p} threshold: **no practical difference**")
        if not r.ci_within:
            why += f" (the interval reaches beyond ±{p}, so a practical difference is not ruled out)"
    else:  # not significant
        why = f"above the {p} threshold, but the interval includes 0: not statistically significant"
    return f"{head}: {num} {side}; {why}"


def verdict_headline(comps: pd.DataFrame) -> str:
    """The verdict of one metric's comparisons in a few words."""
    best = comps["best"].iloc[0]
    v = set(comps["verdict"])
    if "better" in v:
        tied = [o for o, w in zip(comps["other"], comps["verdict"]) if w == "no practical difference"]
        if tied:
            return (f"best: `{best}` and {', '.join(f'`{o}`' for o in tied)} "
                    "(no practical difference between them)")
        return f"`{best}` is best" + (" (meaningfully better than every other filter)" if v == {"better"} else "")
    if v == {"no practical difference"}:
        return "no practical difference between the filters"
    if "too few runs" in v and v <= {"too few runs", "no practical difference"}:
        return "not assessed (too few paired runs)"
    return "no clear winner"


def _small_sample_tracks(metrics: pd.DataFrame, min_pairs: int) -> dict[Any, int]:
    """Tracks where some pair of filters shares fewer than ``min_pairs`` kept runs: track -> fewest."""
    filters = filters_in_order(metrics)
    fewest: dict[Any, int] = {}
    for i, a in enumerate(filters):
        for b in filters[i + 1:]:
            for track, n in paired_run_counts(metrics, a, b).items():
                fewest[track] = min(n, fewest.get(track, n))
    return {t: n for t, n in sorted(fewest.items()) if 0 < n < min_pairs}  # 0: comparison undefined


def summary_md(
    metrics: pd.DataFrame,
    table: pd.DataFrame,
    comps: pd.DataFrame,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> str:
    """The report's "Summary" section body: per metric the best filter and, over every other
    filter, its paired improvement [95 % CI] with whether it is statistically and practically
    meaningful; NEES consistency per filter; a small-sample warning."""
    p = f"{practical_pct:g} %"
    lines = [
        f"Meaningful = the paired 95 % interval excludes 0 (statistically, with at least {min_pairs} "
        f"paired runs per track) **and** |improvement| ≥ {p} (practically; `practical_pct` = "
        f"{practical_pct:g}). Improvements are 100 · (other − best) / other over the runs that "
        "diverged in neither filter.",
        "",
    ]
    units = {"vrmse": "m/s", "mrmse": "rad", "hpe": "m"}
    for key in pd.unique(comps["metric"]):
        c = comps[comps["metric"] == key]
        name = _SUMMARY_NAMES[key]
        first = c.iloc[0]
        if first["best"] is None:
            lines.append(f"- **{name}**: undefined (every run diverged on some track).")
            continue
        value = f"`{first['best']}` {fmt(first['best_value'])} {units[key]}"
        if first["verdict"] == "only filter":
            lines.append(f"- **{name}**: only {value}; nothing to compare.")
            continue
        words = "; ".join(_comparison_words(r, practical_pct, min_pairs) for r in c.itertuples(index=False))
        lines.append(f"- **{name}** — {verdict_headline(c)}. Lowest: {value}. {words}.")
        if key == "hpe":
            finals = ", ".join(
                f"`{r.filter}` {fmt(r.hpe_final, '.3g')} m ({fmt(r.hpe_final_pct, '.3g')} % of distance)"
                if np.isfinite(r.hpe_final) else f"`{r.filter}` {DASH}"
                for r in table.itertuples(index=False))
            lines.append(f"  Final horizontal error (mean over runs, then tracks): {finals}.")
    cons = []
    for r in table.itertuples(index=False):
        if r.consistency == DASH:
            cons.append(f"`{r.filter}` no covariance ({DASH})")
        else:
            cons.append(f"`{r.filter}` {r.nees:.2f} vs [{r.nees_lo:.2f}, {r.nees_hi:.2f}] ({r.nees_n} runs): "
                        f"{_CONSISTENCY_WORDS[r.consistency]}")
    lines.append("- **Consistency** (mean NEES against its 95 % band for a consistent 6-DOF filter): "
                 + "; ".join(cons) + ".")
    small = _small_sample_tracks(metrics, min_pairs)
    if small:
        which = ", ".join(f"track {t}: {n}" for t, n in small.items())
        n = min(small.values())
        lines.append(
            f"- **Warning — small sample**: fewer than {min_pairs} runs kept by both filters of a pair "
            f"({which}). With n = {n} runs the bootstrap has only {math.comb(2 * n - 1, n)} distinct "
            f"resamples and its percentile interval is too narrow, so those intervals are marked "
            f"`{SMALL_MARK}` and no difference is called significant. Use more `--runs`."
        )
    return "\n".join(lines)


def _definitions(ref: str, n_boot: int, seed: int, practical_pct: float = PRACTICAL_PCT,
                 min_pairs: int = MIN_PAIRED_RUNS) -> str:
    """The report's definitions section (every number in the tables)."""
    p = f"{practical_pct:g} %"
    return f"""## Definitions

- **VRMSE** (anukf.md eq 50), per track and filter: `sqrt(sum(sse_vel) / sum(n_samples))` over
  the runs that did not diverge, where `sse_vel` is a run's sum over the ground-truth epochs of
  the squared velocity-error norm. **MRMSE** (eq 52) likewise with `sse_att`, the squared norm of
  the misalignment Euler angles of `C_b^n C_n^b,GT` (eq 53).
- **Track average** (eq 51), used in the main table: `sqrt(mean over tracks of VRMSE_track²)`,
  and the same for MRMSE and the RMS horizontal position error.
- **Horizontal position error (HPE)**: `hypot(north, east)` of estimate − truth [m] at each epoch.
  *RMS HPE*: eq 50 with `sse_hpe` (sum over the epochs of HPE²); *final HPE*: at the last epoch;
  *% of distance*: final HPE / horizontal distance the truth travelled over the track · 100. Final
  HPE and its % are means over the runs no filter lost (per track), then over tracks.
- **{ref} Imprv.**: improvement of the reference filter `{ref}` over each other row, as in the
  papers' "ANUKF Imprv." column: `100 · (metric_row − metric_{ref}) / metric_row`. Positive
  means `{ref}` has the smaller error; the reference row shows "{DASH}". **Every improvement, its
  point and its interval, in every table and in the Summary, is computed over the runs that
  diverged in neither filter of the pair** (the pairs), per track with eqs 50–51; the VRMSE and
  MRMSE columns use the runs that no filter lost (so every filter is judged on the same runs and
  none looks better for having lost its hard runs), which with losses can be fewer than a pair's.
- **95 % CI**: paired bootstrap percentile interval (2.5 %, 97.5 %) of that improvement. The same
  run index is the same realization for every filter, so per track the pairs are resampled with
  replacement (the same resample for both filters), eqs 50–51 are recomputed for both and the
  improvement taken; {n_boot} resamples, seed {seed}. Intervals and their points are printed with
  two significant digits of the interval width. `{SIG_MARK}` marks an interval that excludes 0
  (statistically significant). `{SMALL_MARK}` marks an interval from fewer than {min_pairs} paired runs
  on some track: the percentile bootstrap is unreliable there (with n runs it has only
  C(2n−1, n) distinct resamples, 3 for n = 2, and its interval is too narrow, about
  sqrt((n−1)/n) · 1.96 / t₀.₉₇₅,ₙ₋₁ of a t interval's width: 63 % at n = 5, 82 % at n = 10), so
  such an interval is never starred or called significant, whether or not it excludes 0.
- **Practically meaningful**: |improvement| ≥ {p} (`practical_pct`). The Summary calls a
  difference meaningful only when it is both statistically significant and practically
  meaningful, and says "no practical difference" below the threshold even when significant.
  The **best** filter of a metric is the one with the smaller paired track average against the
  most other filters (ties: the smaller track average over its own runs).
- **mean NEES**: mean over the runs no filter lost of each run's epoch-averaged 6-DOF NEES of
  `[δv, δψ]` (6 for a consistent filter; {DASH} for `ins`). **95 % NEES band**: the two-sided
  95 % band of the mean of n chi-square(6) values, `chi2.ppf([0.025, 0.975], 6 n) / n`
  (`metrics.nees_band(6, n)`), n = the runs averaged. Above the band the filter is
  *overconfident* (its covariance is too small), below *conservative*. The band is for one
  epoch's NEES averaged over n runs; each run's epoch average fluctuates less, so the band is a
  lenient test: a mean outside it is a clear inconsistency.
- **diverged** (lost): runs whose state or covariance became non-finite (or not positive
  definite), whose speed exceeded 50 m/s, or whose attitude error exceeded `--diverge-att-deg`
  (45 deg) after `--diverge-after` (60 s), out of all runs (the reason per run is
  `diverged_reason` in metrics.parquet); a run lost by any filter is left out of every filter's
  error numbers (a filter that lost every run of a track excepted). A run whose NEES averaged over
  `--diverge-window` (30 s) exceeded `--diverge-nees` (1000) is *inconsistent*
  (`inconsistent` in metrics.parquet), not lost: it keeps its errors in every number.
"""


def _nees_cells(nees: float, lo: float, hi: float, word: str) -> list[str]:
    band = DASH if not np.isfinite(lo) else f"[{lo:.2f}, {hi:.2f}]"
    return [fmt(nees, ".2f"), band, word]


def _main_table(table: pd.DataFrame) -> str:
    """Markdown of :func:`filter_table`."""
    ref = table.attrs["reference"]
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    headers = [
        "Method", "VRMSE [m/s]", f"{ref} Imprv.", "95 % CI [%]",
        "MRMSE [rad]", f"{ref} Imprv.", "95 % CI [%]", "mean NEES", "95 % NEES band", "consistency",
        "diverged",
    ]
    rows = []
    for r in table.itertuples(index=False):
        cells = [r.filter + (" (reference)" if r.is_reference else "")]
        for key in METRICS:
            mark = interval_mark(getattr(r, f"{key}_ci_excludes_0"), r.pairs_min, min_pairs)
            cells += [fmt(getattr(r, key)),
                      *imprv_cells(getattr(r, f"{key}_imprv"), getattr(r, f"{key}_ci_lo"),
                                    getattr(r, f"{key}_ci_hi"), mark)]
        cells += _nees_cells(r.nees, r.nees_lo, r.nees_hi, r.consistency)
        cells.append(f"{r.diverged} / {r.runs}")
        rows.append(cells)
    return md_table(headers, rows)


def _track_md(tt: pd.DataFrame) -> str:
    """Markdown of :func:`track_table`."""
    headers = ["Track", "Method", "VRMSE [m/s]", "MRMSE [rad]", "mean NEES", "95 % NEES band",
               "consistency", "diverged"]
    rows = [
        [str(r.track), r.filter, fmt(r.vrmse), fmt(r.mrmse),
         *_nees_cells(r.nees, r.nees_lo, r.nees_hi, r.consistency), f"{r.diverged} / {r.runs}"]
        for r in tt.itertuples(index=False)
    ]
    return md_table(headers, rows)


def _horizontal_md(metrics: pd.DataFrame) -> str:
    """Markdown of :func:`horizontal_table`, or a note for a folder without the HPE columns."""
    ht = horizontal_table(metrics)
    if ht is None:
        return ("No horizontal-position columns (`hpe_final`, `hpe_rms`, `hpe_final_pct`, ...) in "
                "`metrics.parquet`: the folder was written by an older nespm; re-run `nespm mc` into a "
                "new folder to get them.")
    headers = ["Track", "Method", "distance [m]", "final HPE [m]", "RMS HPE [m]",
               "final HPE [% of distance]", "CEP50 [m]", "R95 [m]", "diverged"]
    rows = [
        ["average" if r.track is None else str(r.track),
         r.filter, fmt(r.distance, ".1f"), fmt(r.hpe_final, ".4g"), fmt(r.hpe_rms, ".4g"),
         fmt(r.hpe_final_pct, ".3g"), fmt(r.cep50, ".3g"), fmt(r.r95, ".3g"), f"{r.diverged} / {r.runs}"]
        for r in ht.itertuples(index=False)
    ]
    return ("Final HPE and its % of distance: mean over the runs no filter lost (per track), then over "
            "tracks; RMS HPE: eq 50 with `sse_hpe` per track and eq 51 over tracks; CEP50 and R95: the "
            "radii holding 50 % and 95 % of those runs' final horizontal errors (per track; mean over "
            "tracks on the average rows); distance: the truth's horizontal distance travelled.\n\n"
            + md_table(headers, rows))


def _published_note(filters: Sequence[str], scenario: str | None, shown: Sequence[dict]) -> str:
    """One line naming the published tables not shown and the filters each needs."""
    missing = [e for e in PUBLISHED.values() if e not in shown]
    if not missing:
        return ""
    needs = "; ".join(f"{e['source']} [scenario `{e['scenario']}`] needs {', '.join(e['values'])}"
                      for e in missing)
    lead = ("No published table has rows for at least two of the filters run "
            if not shown else "Not shown (fewer than two of their filters run, or another scenario) ")
    return f"{lead}({', '.join(filters)}; scenario `{scenario}`): {needs}."


def _published_md(metrics: pd.DataFrame, table: pd.DataFrame, scenario: str | None, n_boot: int,
                  seed: int) -> str:
    """Each published table of the scenario with rows for at least two of the filters run,
    beside ours: the table's methods in its order, our track-averaged VRMSE/MRMSE, the
    improvement of the table's proposed method over each row (ours with its paired 95 %
    interval, and the published one); then one line on the tables not shown."""
    filters = list(table["filter"])
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    entries = published_tables(filters, scenario, min_filters=2)
    note = _published_note(filters, scenario, entries)
    if not entries:
        return note
    intro = (
        "The published numbers come from the real Snapir AUV data (test tracks 5 and 6) with the "
        "authors' recorded IMU and their trained networks; our values on other tracks or data, "
        "or with a synthesized IMU, are not expected to match them closely. Methods we did not "
        f"run show \"{DASH}\". Imprv. is the improvement of the table's proposed method over the "
        "row, 100 (row - proposed) / row, with our paired bootstrap 95 % interval "
        f"({SIG_MARK} = excludes 0, {SMALL_MARK} = too few paired runs to judge)."
    )
    parts = [intro]
    ours = {r.filter: r for r in table.itertuples(index=False)}
    for entry in entries:
        ref = entry["reference"]
        pub_ref = entry["values"][ref]
        rows = []
        for name, pub in entry["values"].items():
            r = ours.get(name)
            cells = [name]
            paired = r is not None and ref in ours and name != ref
            boot = paired_bootstrap(metrics, name, ref, n_boot=n_boot, seed=seed) if paired else None
            imp = paired_improvement(metrics, name, ref) if paired else None
            counts = paired_run_counts(metrics, name, ref) if paired else {}
            pairs_min = min(counts.values()) if counts else 0
            for key in METRICS:
                mine = getattr(r, key) if r is not None else None
                cells += [fmt(mine), fmt(pub[key])]
                if name == ref:
                    cells += [DASH, DASH]
                    continue
                if boot is not None:
                    lo, hi = percentile_ci(boot[key])
                    _, _, mark = ci_marks(lo, hi, pairs_min, min_pairs)
                    cells.append(fmt_imprv(imp[key], lo, hi, mark))
                else:
                    cells.append(DASH)
                cells.append(fmt_pct(float(improvement(pub[key], pub_ref[key]))))
            rows.append(cells)
        parts.append(
            f"**{entry['source']}** (scenario `{entry['scenario']}`; Imprv. of {ref})\n\n"
            + md_table(["Method", "VRMSE ours [m/s]", "VRMSE published [m/s]", "Imprv. ours [95 % CI]",
                         "Imprv. published", "MRMSE ours [rad]", "MRMSE published [rad]",
                         "Imprv. ours [95 % CI]", "Imprv. published"], rows)
        )
    if note:
        parts.append(note)
    return "\n\n".join(parts)


def folder_label(out_dir: Path, manifest: dict) -> str:
    """``name (imu ..., dvl ...)`` of a results folder, from its manifest options."""
    o = manifest.get("options", {})
    return f"{Path(out_dir).name} (imu {o.get('imu', '?')}, dvl {o.get('dvl', '?')})"


def beside_md(metrics: pd.DataFrame, label: str, others: Sequence[tuple[str, pd.DataFrame]],
              scenario: str | None = "nominal") -> str:
    """This folder's track-averaged VRMSE / MRMSE / mean NEES beside other folders' (same filter
    names) and the published values (the first published table with the filter).

    ``others``: ``(label, metrics)`` of each other folder. Only tracks in every folder count.
    """
    folders = [(label, metrics), *others]
    common = set(metrics["track"].unique())
    for _, m in others:
        common &= set(m["track"].unique())
    tracks = sorted(common)
    if not tracks:
        return "The folders share no track; nothing to set side by side."
    avgs = [filter_table(m[m["track"].isin(tracks)], None, n_boot=0).set_index("filter")
            for _, m in folders]  # the main table's numbers: eq 51 over the tracks, NEES over all runs
    headers = ["Method"]
    for lab, _ in folders:
        headers += [f"VRMSE [m/s] {lab}", f"MRMSE [rad] {lab}", f"NEES {lab}"]
    headers.append("published VRMSE / MRMSE")
    rows = []
    for f in filters_in_order(metrics):
        row = [f]
        for a in avgs:
            if f in a.index:
                row += [fmt(a.loc[f, "vrmse"]), fmt(a.loc[f, "mrmse"]), fmt(a.loc[f, "nees"], ".3g")]
            else:
                row += ["—", "—", "—"]
        pub = [e for e in PUBLISHED.values() if f in e["values"] and e["scenario"] == scenario]
        row.append(f"{pub[0]['values'][f]['vrmse']:.4g} / {pub[0]['values'][f]['mrmse']:.4g} ({pub[0]['source']})"
                   if pub else "—")
        rows.append(row)
    return (f"Track average (eq 51) over tracks {', '.join(map(str, tracks))}.\n\n" + md_table(headers, rows))


def render_report(
    metrics: pd.DataFrame,
    manifest: dict,
    table: pd.DataFrame,
    tt: pd.DataFrame,
    figures: Sequence[Path],
    out_dir: Path,
    n_boot: int,
    seed: int,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
    beside: str = "",
) -> str:
    """The full markdown text of ``report.md``: header, Summary (:func:`summary_md` of
    :func:`compare_filters` with ``practical_pct``), Definitions, tables, figures; ``beside``:
    the :func:`beside_md` section, if any."""
    scenario = scenario_of(metrics, manifest)
    ref = table.attrs["reference"]
    diverged = ", ".join(f"{r.filter} {r.diverged}" for r in table.itertuples(index=False))
    if "diverged_reason" in metrics.columns and metrics["diverged"].astype(bool).any():
        why = metrics[metrics["diverged"].astype(bool)].groupby(["filter", "diverged_reason"], sort=False).size()
        diverged += " (" + "; ".join(f"{f}: {n} {r}" for (f, r), n in why.items()) + "; the tests: README, " \
            "\"Divergence\")"
    comps = compare_filters(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                            min_pairs=min_pairs)
    fig_text = (
        "\n".join(f"![{p.stem}]({p.relative_to(out_dir).as_posix()})" for p in figures)
        if figures
        else "No figures: `epochs.parquet` is absent."
    )
    hpe_fig = ("; horizontal position error, mean ± 1 std across the non-diverged runs"
               if any(Path(p).stem.startswith("hpe_") for p in figures) else "")
    return "\n\n".join(
        [
            "# nespm Monte Carlo report",
            header_line(metrics, manifest),
            "## Summary\n\n" + summary_md(metrics, table, comps, practical_pct, min_pairs),
            _definitions(ref, n_boot, seed, practical_pct, min_pairs).rstrip(),
            "## Track-averaged results (eq 51)\n\n" + _main_table(table),
            f"Diverged runs per filter: {diverged}.",
            "## Per-track results (eqs 50, 52)\n\n" + _track_md(tt),
            "## Horizontal position error\n\n" + _horizontal_md(metrics),
            "## Comparison with the published tables\n\n" + _published_md(metrics, table, scenario, n_boot, seed),
            *(["## Beside other results folders\n\n" + beside] if beside else []),
            "## Figures\n\nPer track: velocity-error norm and misalignment norm, mean ± 1 std "
            f"across the non-diverged runs (band clipped at 0){hpe_fig}; grey = epochs without a DVL "
            "update (outage); and the true vs mean estimated horizontal track.\n\n" + fig_text,
        ]
    ) + "\n"


def _error_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], kind: str, title: str, path: Path
) -> Path:
    """Plot mean ± 1 std of an error norm over time per filter with outage shading."""
    import matplotlib.pyplot as plt

    col, label = {"vel": ("vel_err", "velocity error norm [m/s]"),
                  "att": ("att_err", "misalignment norm [rad]"),
                  "hpe": ("hpe", "horizontal position error [m]")}[kind]
    fig, ax = plt.subplots(figsize=(9, 4.8))
    for f in filters:
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        t = d["t"].to_numpy(float)
        m = d[f"{col}_mean"].to_numpy(float)
        s = d[f"{col}_std"].to_numpy(float)
        ax.plot(t, m, color=colors[f], lw=1.4, label=f)
        ax.fill_between(t, np.clip(m - s, 0.0, None), m + s, color=colors[f], alpha=0.2, lw=0)
    grid = ep.groupby("t", sort=True)["dvl_used"].any()
    for k, (lo, hi) in enumerate(outage_spans(grid.index.to_numpy(float), grid.to_numpy(bool))):
        ax.axvspan(lo, hi, color="0.6", alpha=0.3, lw=0, label="DVL outage" if k == 0 else None)
    ax.set_xlabel("time since first epoch [s]")
    ax.set_ylabel(label)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    return save_figure(fig, path)


def _track_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], title: str, path: Path
) -> Path:
    """True vs mean estimated horizontal track (east, north) per filter, equal aspect."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    first = ep[ep["filter"] == filters[0]].sort_values("t")
    ax.plot(first["east_true"], first["north_true"], color="k", lw=2.0, label="truth")
    for f in filters:
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        ax.plot(d["east_true"] + d["east_err_mean"], d["north_true"] + d["north_err_mean"],
                color=colors[f], lw=1.2, ls="--", label=f"{f} (mean estimate)")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return save_figure(fig, path)


def plot_track_figures(
    epochs: pd.DataFrame, metrics: pd.DataFrame, fig_dir: Path, scenario: str | None = None
) -> list[Path]:
    """Write three or four PNGs per track into ``fig_dir``; return their paths in track order.

    ``vel_track<N>.png`` and ``att_track<N>.png``: mean ± 1 std of the error norms over time
    per filter, shading epochs (t > 0) where no filter applied a DVL update;
    ``hpe_track<N>.png`` (only when ``epochs`` has ``hpe_mean`` and ``hpe_std``): the same for
    the horizontal position error; ``path_track<N>.png``: true and mean estimated horizontal track;
    ``anees_track<N>.png`` (folders with the per-block NEES): the ANEES of each block over time
    against its chi-square bounds (:mod:`nespm_cli.reports.consistency`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (after selecting the backend)

    fig_dir.mkdir(parents=True, exist_ok=True)
    order = filters_in_order(metrics)
    filters = order + [f for f in (str(x) for x in pd.unique(epochs["filter"])) if f not in order]
    colors = filter_colors(filters)
    runs = metrics.groupby("track")["run"].nunique()
    paths: list[Path] = []
    for track in sorted(pd.unique(epochs["track"])):
        ep = epochs[epochs["track"] == track]
        present = [f for f in filters if (ep["filter"] == f).any()]
        n = int(runs.get(track, 0))
        tail = f"track {track}, {n} runs, scenario {scenario or DASH}"
        paths.append(_error_figure(ep, present, colors, "vel",
                                   f"Velocity error, mean ± 1 std — {tail}",
                                   fig_dir / f"vel_track{track}.png"))
        paths.append(_error_figure(ep, present, colors, "att",
                                   f"Misalignment, mean ± 1 std — {tail}",
                                   fig_dir / f"att_track{track}.png"))
        if {"hpe_mean", "hpe_std"} <= set(ep.columns):
            paths.append(_error_figure(ep, present, colors, "hpe",
                                       f"Horizontal position error, mean ± 1 std — {tail}",
                                       fig_dir / f"hpe_track{track}.png"))
        paths.append(_track_figure(ep, present, colors,
                                   f"Horizontal track — {tail}",
                                   fig_dir / f"path_track{track}.png"))
        anees = anees_figure(ep, present, colors, f"ANEES per block against its 95 % chi-square bounds — {tail}",
                             fig_dir / f"anees_track{track}.png")
        if anees is not None:
            paths.append(anees)
    return paths


def write_mc_report(out_dir: Path, reference: str | None = None, n_boot: int = 2000,
                    practical_pct: float = PRACTICAL_PCT, beside: Sequence[Path] = ()) -> Path:
    """Write ``out_dir/report.md`` and ``out_dir/figures/*.png`` of a Monte Carlo folder; return the
    report path.

    Figures are skipped when ``epochs.parquet`` is absent. The bootstrap seed is 0.
    ``reference`` is the filter whose improvement over each row is shown (:func:`default_reference`);
    ``practical_pct`` [%] (default :data:`PRACTICAL_PCT`) is the smallest |improvement| the
    Summary calls practically meaningful. ``beside``: other Monte Carlo folders whose numbers
    are set beside this one's (:func:`beside_md`), e.g. the synthetic-IMU run of a recorded one.
    """
    check_practical_pct(practical_pct)
    out_dir = Path(out_dir)
    metrics, epochs, manifest = load_results(out_dir)
    others = []
    for b in beside:
        m_b, _, man_b = load_results(Path(b))
        others.append((folder_label(Path(b), man_b), m_b))
    beside_text = (beside_md(metrics, folder_label(out_dir, manifest), others, scenario_of(metrics, manifest))
                   if others else "")
    seed = 0
    table = filter_table(metrics, reference, n_boot=n_boot, seed=seed)
    tt = track_table(metrics)
    figures: list[Path] = []
    if epochs is not None and not epochs.empty:
        figures = plot_track_figures(epochs, metrics, out_dir / "figures", scenario_of(metrics, manifest))
    text = render_report(metrics, manifest, table, tt, figures, out_dir, n_boot, seed,
                         practical_pct=practical_pct, beside=beside_text)
    path = out_dir / "report.md"
    write_text_atomic(path, text)
    return path
