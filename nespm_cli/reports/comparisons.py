"""Head-to-head comparisons of the filters of a Monte Carlo folder: per metric the best filter and
its paired improvement over every other filter, with the paired bootstrap interval and whether it
is statistically and practically meaningful (:func:`compare_filters`); the tracks whose pairs are
too few for the percentile bootstrap (:func:`small_sample_tracks`)."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.reports.results import causal_only, check_metrics, filters_in_order, has_hpe
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    PRACTICAL_PCT,
    ci_marks,
    metric_keys,
    paired_averages,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    posterior_view,
)
from nespm_cli.reports.tables import filter_table

__all__ = ["OWN_COLUMN", "compare_filters", "default_keys", "small_sample_tracks"]

#: metric key -> the filter_table column of a filter's own value (over the runs no filter lost)
OWN_COLUMN: dict[str, str] = {"vrmse": "vrmse", "mrmse": "mrmse", "hpe": "hpe_rms", "hpe_final": "hpe_final"}


def default_keys(metrics: pd.DataFrame) -> list[str]:
    """The metrics compared: VRMSE, MRMSE and, with the HPE columns, the final (``hpe_final``, mean
    over runs) and RMS (``hpe``) horizontal position error."""
    return list(METRICS) + (["hpe_final", "hpe"] if has_hpe(metrics) else [])


def compare_filters(
    metrics: pd.DataFrame,
    n_boot: int = 2000,
    seed: int = 0,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
    keys: Sequence[str] | None = None,
) -> pd.DataFrame:
    """Per metric, the best filter and its paired improvement over every other filter.

    ``keys`` default to :func:`default_keys`. Only the causal filters take part: an RTS-smoother
    floor (``<filter>-rts``) is hindsight, never the best. The best filter is the one with the smaller paired track
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

    The RMS metrics are posterior (the t = 0 rule: the sums over the epochs after the first,
    :func:`stats.posterior_view`) where the folder has those sums; ``attrs["posterior"]`` says which.
    """
    check_metrics(metrics)
    metrics = posterior_view(causal_only(metrics))
    if keys is None:
        keys = default_keys(metrics)
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
        own = {f: float(own_table.loc[f, OWN_COLUMN[key]]) for f in filters}
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
    out.attrs.update(practical_pct=float(practical_pct), min_pairs=int(min_pairs),
                     posterior=bool(metrics.attrs.get("posterior", False)))
    return out


def small_sample_tracks(metrics: pd.DataFrame, min_pairs: int) -> dict[Any, int]:
    """Tracks where some pair of causal filters shares fewer than ``min_pairs`` kept runs: track -> fewest."""
    filters = filters_in_order(causal_only(metrics))
    fewest: dict[Any, int] = {}
    for i, a in enumerate(filters):
        for b in filters[i + 1:]:
            for track, n in paired_run_counts(metrics, a, b).items():
                fewest[track] = min(n, fewest.get(track, n))
    return {t: n for t, n in sorted(fewest.items()) if 0 < n < min_pairs}  # 0: comparison undefined

