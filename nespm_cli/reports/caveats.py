"""The caveats of a report, each said once: what limits the numbers of the verdict and the tables
(too few paired runs for the bootstrap, lost runs, inconsistent runs, undefined comparisons,
RTS-smoother floors, tracks run with a convention residual accepted). Each function returns one sentence, or None when the caveat does not apply;
a sweep's metrics (column ``value``) are judged per swept value.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import pandas as pd

from nespm_cli.reports.comparisons import small_sample_tracks
from nespm_cli.reports.markdown import DASH, SMALL_MARK
from nespm_cli.reports.results import causal_only, filters_in_order, is_smoother
from nespm_cli.reports.stats import MIN_PAIRED_RUNS, lost_by_any

__all__ = ["caveats", "caveats_md", "inconsistent_caveat", "lost_caveat", "residual_caveats", "small_sample_caveat",
           "smoother_caveat", "undefined_caveat"]


def _per_value(metrics: pd.DataFrame) -> list[tuple[Any, pd.DataFrame]]:
    """``[(value or None, metrics of that value)]``: one group for a Monte Carlo folder."""
    if "value" not in metrics.columns:
        return [(None, metrics)]
    return [(v, d.drop(columns=[c for c in ("param", "value") if c in d.columns]))
            for v, d in metrics.groupby("value", sort=True)]


def small_sample_caveat(metrics: pd.DataFrame, min_pairs: int = MIN_PAIRED_RUNS) -> str | None:
    """``†``: tracks (of swept values) where some pair of causal filters shares fewer than ``min_pairs``
    kept runs; the percentile bootstrap is unreliable there, so no difference is called significant."""
    where, fewest = [], None
    for v, d in _per_value(metrics):
        small = small_sample_tracks(d, min_pairs)
        if small:
            tracks = ", ".join(f"track {t}: {n}" for t, n in small.items())
            where.append(tracks if v is None else f"value {v:g}, {tracks}")
            fewest = min(small.values()) if fewest is None else min(fewest, *small.values())
    if not where:
        return None
    return (f"`{SMALL_MARK}` marks an interval from fewer than {min_pairs} runs kept by both filters of a pair on "
            f"some track ({'; '.join(where)}). With n = {fewest} run{'s' if fewest > 1 else ''} the bootstrap has "
            f"only {math.comb(2 * fewest - 1, fewest)} distinct resample{'s' if fewest > 1 else ''} and its "
            "percentile interval is too narrow, "
            "so no such difference is called significant. Use more `--runs`.")


def lost_caveat(metrics: pd.DataFrame) -> str | None:
    """Lost (diverged) runs per filter with their reasons, and that the tables leave a run lost by any
    filter out of every filter's errors (the common survivors); None when no run was lost."""
    lost = metrics["diverged"].astype(bool)
    if not lost.any():
        return None
    per = lost.groupby(metrics["filter"], sort=False).sum()
    text = ", ".join(f"{f} {int(per[f])}" for f in filters_in_order(metrics))
    if "diverged_reason" in metrics.columns:
        why = metrics[lost].groupby(["filter", "diverged_reason"], sort=False).size()
        text += " (" + "; ".join(f"{f}: {n} {r}" for (f, r), n in why.items()) + "; the tests: README, \"Divergence\")"
    kept = sum(int((~lost_by_any(d)).sum()) for _, d in _per_value(metrics))
    return (f"Lost (diverged) runs per filter: {text}. A run lost by any filter is left out of every filter's "
            f"error numbers, so the filters are compared on the same runs (the common survivors: {kept} of "
            f"{len(metrics)} filter-runs); the verdict shows each comparison over all the runs its pair kept and "
            "over the common survivors.")


def inconsistent_caveat(metrics: pd.DataFrame) -> str | None:
    """Runs that failed the NEES test (``inconsistent``, not lost), per filter; None without any."""
    if "inconsistent" not in metrics.columns:
        return None
    bad = metrics["inconsistent"].fillna(False).astype(bool)
    if not bad.any():
        return None
    per = bad.groupby(metrics["filter"], sort=False).sum()
    text = ", ".join(f"{f} {int(n)}" for f, n in per.items() if n)
    return (f"Inconsistent runs (NEES test) per filter: {text}. They are not lost: they keep their errors in "
            "every average.")


def undefined_caveat(comps: pd.DataFrame) -> str | None:
    """A comparison without a paired point (``undefined``): on some track no run was kept by both."""
    if not (comps["verdict"] == "undefined").any():
        return None
    return (f"`{DASH}` in a comparison: on some track (of some value) no run was kept by both filters, so the "
            "comparison is undefined there.")


def smoother_caveat(filters: Iterable[str]) -> str | None:
    """The RTS-smoother floors among ``filters``: hindsight, shown beside, never best or reference."""
    floors = [f for f in filters if is_smoother(f)]
    if not floors:
        return None
    names = ", ".join(f"`{f}`" for f in floors)
    many = len(floors) > 1
    return (f"{names}: RTS-smoother floor{'s' if many else ''} (hindsight: each epoch also uses the later "
            f"measurements), not {'causal filters' if many else 'a causal filter'}: shown beside the filters for "
            "how far a filter is from hindsight, never the best of the verdict nor the reference.")


def residual_caveats(manifest: dict) -> list[str]:
    """One sentence per track run although its data contradict its declared conventions (the manifest's
    ``accepted_residuals``, ``{"<folder>#<track>": sentence}``: ``--accept-residual`` or the track spec's
    ``gt.accept_residual``): ``"track N: convention residual accepted: <sentence>"``; ``[]`` without any (or in a
    folder made before the key)."""
    found = manifest.get("accepted_residuals") or {}
    return [f"track {key.rsplit('#', 1)[-1]}: convention residual accepted: {text}" for key, text in found.items()]


def caveats(metrics: pd.DataFrame, comps: pd.DataFrame, min_pairs: int = MIN_PAIRED_RUNS,
            extra: Sequence[str] = ()) -> list[str]:
    """Every caveat that applies, once each, in reading order; ``extra``: notes of the figures."""
    found = [small_sample_caveat(causal_only(metrics), min_pairs), lost_caveat(metrics),
             inconsistent_caveat(metrics), undefined_caveat(comps), smoother_caveat(filters_in_order(metrics))]
    return [c for c in found if c] + list(extra)


def caveats_md(items: Sequence[str]) -> str:
    """The "Caveats" section body: one bullet per caveat, or a line saying there is none."""
    return "\n".join(f"- {c}" for c in items) if items else "None: no run was lost and every pair has enough runs."
