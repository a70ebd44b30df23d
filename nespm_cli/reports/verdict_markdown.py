"""The markdown of a verdict (:func:`verdict.verdict_table`): one row per metric (and per swept value
in a sweep) with the best filter, what it is compared with, the paired improvement [95 % CI], whether
it is statistically and practically meaningful, the pairs, the verdict in words; the same over the
common survivors when some run was lost; the RTS-smoother floor when there is one."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.reports.block_consistency import CONSISTENT_SHARE, share_text
from nespm_cli.reports.markdown import DASH, fmt, fmt_imprv, md_table
from nespm_cli.reports.stats import MIN_PAIRED_RUNS, interval_mark, nees_check
from nespm_cli.reports.verdict import VERDICT_METRICS
from nespm_cli.reports.wording import SHORT_VERDICT, verdict_headline

__all__ = ["PAIRWISE_NAMES", "pairwise_md", "sweep_verdict_frame", "verdict_intro", "verdict_md"]


def _absent(name: Any) -> bool:
    """A filter cell that holds no filter (None, or NaN after the frames of a sweep were stacked)."""
    return name is None or (isinstance(name, float) and np.isnan(name))


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def _stat_cell(significant: bool, excludes_0: bool, pairs_min: int, imprv: float, min_pairs: int) -> str:
    """Statistically meaningful: ``yes`` (the interval excludes 0, enough pairs), ``no``, or
    ``not assessed †`` (too few pairs on some track, whatever the interval)."""
    if not np.isfinite(imprv):
        return DASH
    if pairs_min < min_pairs:
        return "not assessed †"
    return _yes(significant and excludes_0)


def _pairs_cell(pairs: int, pairs_min: int, tracks: int) -> str:
    return str(pairs) if tracks <= 1 or pairs == pairs_min else f"{pairs} (≥ {pairs_min} per track)"


def _comparison_cells(r: Any, prefix: str, min_pairs: int, tracks: int) -> list[str]:
    """Improvement [CI] mark, statistically, practically, pairs of one verdict row (``prefix`` ``""`` or ``s_``)."""
    g = lambda k: getattr(r, prefix + k)  # noqa: E731
    imprv = g("imprv")
    if not np.isfinite(imprv):
        return [DASH, DASH, DASH, str(g("pairs")) if g("pairs") else DASH]
    mark = interval_mark(g("significant"), g("pairs_min"), min_pairs)
    return [fmt_imprv(imprv, g("ci_lo"), g("ci_hi"), mark),
            _stat_cell(g("significant"), g("excludes_0"), g("pairs_min"), imprv, min_pairs),
            _yes(g("practical")), _pairs_cell(g("pairs"), g("pairs_min"), tracks)]


def _lost_cell(r: Any) -> str:
    """``best lost / runs, runner-up lost / runs``: each filter's own lost runs (— without the filter)."""
    runs = int(r.runs) if np.isfinite(r.runs) else 0
    parts = [f"{int(n)} / {runs}" for n in (r.best_lost, r.other_lost) if np.isfinite(n) and n >= 0]
    return ", ".join(parts) or DASH


def _consistency_cells(r: Any, with_survivors: bool, with_floor: bool, role: str,
                       share: float = CONSISTENT_SHARE) -> list[str]:
    """The consistency row: best and runner-up with the share of epochs inside the bounds of their worst block
    or sensor (printed on the side of ``share``, the least share for *consistent*, where it lies:
    :func:`block_consistency.share_text`), the rule, the epochs judged, the best filter's words."""
    name = "consistency (worst block or sensor: share of epochs inside)"
    if _absent(r.best):
        cells = [name, DASH, DASH, DASH, DASH, DASH, DASH, "undefined (no filter has a covariance)", DASH]
        return cells + ([DASH] * 4 if with_survivors else []) + ([DASH] if with_floor else [])
    pct = lambda v: share_text(v, share)  # noqa: E731
    other = DASH
    if not _absent(r.other):
        ref = f" ({role})" if r.other_is_reference else ""
        other = f"`{r.other}`{ref} {r.other_item} {pct(r.other_value)}"
    cells = [name, f"`{r.best}` {r.best_item} {pct(r.best_value)}", other, DASH, DASH, DASH, DASH, r.verdict,
             _lost_cell(r)]
    return cells + ([DASH] * 4 if with_survivors else []) + ([DASH] if with_floor else [])


def _anees_cells(r: Any, with_survivors: bool, with_floor: bool, role: str) -> list[str]:
    """The ANEES row (a folder without per-epoch block NEES): best and runner-up with their mean NEES, the
    95 % band, the words."""
    if _absent(r.best):
        cells = ["ANEES (6 dof)", DASH, DASH, DASH, DASH, DASH, DASH, "undefined (no filter has a covariance)", DASH]
        return cells + ([DASH] * 4 if with_survivors else []) + ([DASH] if with_floor else [])
    lo, hi, word = nees_check(r.best_value, int(r.pairs))
    other = DASH
    if not _absent(r.other):
        other_word = nees_check(r.other_value, int(r.pairs))[2]
        other = f"`{r.other}`{f' ({role})' if r.other_is_reference else ''} {fmt(r.other_value, '.2f')}: {other_word}"
    cells = ["ANEES (6 dof)", f"`{r.best}` {fmt(r.best_value, '.2f')}", other,
             DASH, DASH, DASH, str(int(r.pairs)),
             f"closest to 6: {word}" + (f" (band [{lo:.2f}, {hi:.2f}])" if np.isfinite(lo) else ""), _lost_cell(r)]
    if with_survivors:
        cells += [f"`{r.best}` {fmt(r.s_best_value, '.2f')}, `{r.other}` {fmt(r.s_other_value, '.2f')}"
                  if not _absent(r.other) else fmt(r.s_best_value, ".2f"), DASH, DASH, str(int(r.s_pairs))]
    return cells + ([DASH] if with_floor else [])


def verdict_md(vt: pd.DataFrame, comps: pd.DataFrame, tracks: int = 1, value_col: str | None = None,
               role: str = "reference") -> str:
    """The verdict table in markdown. ``vt``: :func:`verdict.verdict_table` (in a sweep: its rows of
    every value, with a ``value`` column, ``value_col`` its header); ``comps``: the
    :func:`comparisons.compare_filters` rows it came from (a ``value`` column in a sweep), for the
    verdict in words; ``tracks``: the tracks of the study (pairs per track are shown with several);
    ``role``: the word for the filter compared with (``reference``, a sweep's ``baseline``)."""
    min_pairs = vt.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    p = f"{vt.attrs.get('practical_pct', 1.0):g} %"
    with_surv = bool(vt.attrs.get("any_lost", False))
    with_floor = bool(vt["floor"].map(lambda f: isinstance(f, str)).any())
    headers = ([value_col] if value_col else []) + [
        "Metric", "Best filter", "runner-up", "Improvement over the runner-up [95 % CI]",
        "statistically (excludes 0)", f"practically (≥ {p})", "pairs", "verdict", "lost: best, runner-up"]
    if with_surv:
        headers += ["Common survivors: improvement [95 % CI]", "statistically", "practically", "runs"]
    if with_floor:
        headers.append("RTS smoother floor")
    rows = []
    order = {k: i for i, k in enumerate(VERDICT_METRICS)}
    sort_cols = ["_o"] + (["value"] if value_col else [])
    vt = vt.assign(_o=vt["metric"].map(order)).sort_values(sort_cols, kind="stable")
    for r in vt.itertuples(index=False):
        lead = [f"{r.value:g}"] if value_col else []
        if r.metric in ("anees", "consistency"):
            rows.append(lead + (_anees_cells(r, with_surv, with_floor, role) if r.metric == "anees" else
                                _consistency_cells(r, with_surv, with_floor, role,
                                                   vt.attrs.get("consistent_share", CONSISTENT_SHARE))))
            continue
        name, unit = VERDICT_METRICS[r.metric]
        c = comps[comps["metric"] == r.metric]
        if value_col:
            c = c[c["value"] == r.value]
        if _absent(r.best):
            words = "undefined (every run lost on some track)"
        elif _absent(r.other):
            words = "only filter"
        elif r.verdict == "undefined":
            words = "undefined (no run kept by both on some track)"
        else:
            words = verdict_headline(c)
        best = DASH if _absent(r.best) else f"`{r.best}` {fmt(r.best_value)}"
        other = DASH if _absent(r.other) else f"`{r.other}` {fmt(r.other_value)}" + (
            f" ({role})" if r.other_is_reference else "")
        cells = lead + [f"{name} [{unit}]", best, other, *_comparison_cells(r, "", min_pairs, tracks), words,
                        _lost_cell(r)]
        if with_surv:
            cells += _comparison_cells(r, "s_", min_pairs, tracks)
        if with_floor:
            cells.append(f"`{r.floor}` {fmt(r.floor_value)}" if isinstance(r.floor, str) else DASH)
        rows.append(cells)
    return md_table(headers, rows)


#: the verdict's note on the t = 0 rule: with the posterior sums, and for a folder without them
POSTERIOR_NOTE = {
    True: ("Errors are posterior: every RMS here is over the epochs after t = 0, where each filter has had its "
           "first update (the tables keep the papers' definition over every epoch; docs/report.md, "
           "\"The t = 0 rule\")."),
    False: ("This folder has no posterior error sums (`sse_vel_post`, ...; written by an older nespm), so these "
            "RMS values and improvements include the t = 0 error, which no filter changes, and are diluted "
            "towards 0 (docs/report.md, \"The t = 0 rule\"); re-run `nespm mc` into a new folder to get them."),
}


def verdict_intro(reference: str, n_boot: int, seed: int, practical_pct: float, any_lost: bool,
                  role: str = "reference", posterior: bool | None = None, consistency: float | None = None) -> str:
    """The lines above the verdict table: reference, practical threshold, bootstrap, and (``posterior``
    not None) which epochs the errors are over (:data:`POSTERIOR_NOTE`, said once); ``consistency``: the share
    of epochs of the consistency row's rule, when the verdict has that row."""
    surv = "" if any_lost else " No run was lost, so all runs are the common survivors."
    note = "" if posterior is None else " " + POSTERIOR_NOTE[bool(posterior)]
    note += (f" Consistency row: each filter's worst state block or sensor, its share of the epochs whose ANEES (ANIS) "
             f"lies inside the 95 % bounds; consistent when every block and sensor has at least "
             f"{100 * consistency:g} %." if consistency else "")
    return (f"{role.capitalize()} `{reference}`. Improvement of the best filter = 100 · (runner-up − best) / "
            f"runner-up over the runs both kept (over every other filter in the pairwise comparisons), paired "
            f"bootstrap 95 % interval ({n_boot} resamples, seed {seed}); "
            f"practical threshold {practical_pct:g} %.{surv}{note}")


def sweep_verdict_frame(parts: Sequence[tuple[float, pd.DataFrame]]) -> pd.DataFrame:
    """The verdict tables of the swept values stacked with a ``value`` column (attrs of the first;
    ``any_lost`` if some value lost a run)."""
    out = pd.concat([vt.assign(value=v) for v, vt in parts], ignore_index=True)
    out.attrs.update(parts[0][1].attrs)
    out.attrs["any_lost"] = any(vt.attrs.get("any_lost", False) for _, vt in parts)
    return out


#: short metric names of the pairwise table
PAIRWISE_NAMES = {"vrmse": "VRMSE", "mrmse": "MRMSE", "hpe_final": "final HPE", "hpe": "RMS HPE"}


def pairwise_md(comps: pd.DataFrame, min_pairs: int = MIN_PAIRED_RUNS) -> str:
    """Every comparison of :func:`comparisons.compare_filters` (per swept value when ``comps`` has a
    ``value`` column): per metric the verdict in words, the best filter and its paired improvement
    [95 % CI] over each other filter with the word of that comparison."""
    groups = comps.groupby("value", sort=True) if "value" in comps.columns else [(None, comps)]
    rows = []
    for v, cv in groups:
        lead = [] if v is None else [f"{v:g}"]
        for key in pd.unique(cv["metric"]):
            c = cv[cv["metric"] == key]
            first = c.iloc[0]
            if first["best"] is None:
                rows.append(lead + [PAIRWISE_NAMES[key], "undefined (every run diverged on some track)", DASH])
                continue
            if first["verdict"] == "only filter":
                rows.append(lead + [PAIRWISE_NAMES[key], f"only `{first['best']}`", DASH])
                continue
            cells = []
            for r in c.itertuples(index=False):
                mark = interval_mark(r.significant, r.pairs_min, min_pairs)
                cells.append(f"vs `{r.other}` {fmt_imprv(r.imprv, r.ci_lo, r.ci_hi, mark)} {SHORT_VERDICT[r.verdict]}")
            rows.append(lead + [PAIRWISE_NAMES[key], verdict_headline(c), "; ".join(cells)])
    headers = (["value"] if "value" in comps.columns else []) + ["metric", "verdict", "best vs each other filter"]
    return md_table(headers, rows)
