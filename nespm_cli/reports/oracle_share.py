"""How much of the oracle's gain each adaptive filter captures (docs/adapting.md).

For an adaptive filter F, its fixed counterpart B (:func:`nespm_cli.filters.oracle.fixed_counterpart`:
``anekf``, ``iae-ekf``, ``sh-ekf``, ``vb-ekf``, ``aq-ekf`` → ``ekf``) and B's oracle O = ``B-oracle``
(B told the true Q(t) and R(t), :mod:`nespm_cli.filters.oracle`), all three in one Monte Carlo folder:

    share = (V_B − V_F) / (V_B − V_O)

with V the track average (eq 51) of the per-track RMSE (eq 50) of the metric (VRMSE by default), over
the runs none of the three lost, after t = 0 (the t = 0 rule, :func:`~nespm_cli.reports.stats.posterior_view`).
1: F gains what knowing the noise gains; 0: F gains nothing over B; < 0: F is worse than B; > 1: F
beats the oracle (possible: the oracle is told the noise, not the best filter, e.g. it trusts outliers).

Interval: the paired percentile bootstrap of the reports (:func:`~nespm_cli.reports.stats.resample_counts`
per track with :func:`~nespm_cli.reports.stats.track_rng`, the same resample for the three filters), the
share recomputed per resample. Where the oracle's own gain over B is not positive (its interval is not
above 0), the share's denominator can be ~0 or negative and the share is reported as undefined rather
than as a number.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.filters.oracle import ORACLE_SUFFIX, fixed_counterpart, is_oracle
from nespm_cli.filters.registry import get_filter
from nespm_cli.reports.markdown import DASH, fmt, md_table
from nespm_cli.reports.results import causal_only, filters_in_order
from nespm_cli.reports.stats import (METRICS, MIN_PAIRED_RUNS, improvement, over_tracks, percentile_ci,
                                     posterior_view, resample_counts, track_rng, track_value)

COLUMNS = ["filter", "base", "oracle", "metric", "base_value", "filter_value", "oracle_value", "oracle_gain",
           "oracle_gain_lo", "oracle_gain_hi", "share", "share_lo", "share_hi", "pairs_min", "note"]


def counterpart(name: str) -> str | None:
    """The fixed counterpart of filter ``name`` (None: not adaptive, an oracle, or not registered here)."""
    try:
        return fixed_counterpart(name, get_filter(name))
    except NespmError:
        return None


def triples(filters: Sequence[str]) -> list[tuple[str, str, str]]:
    """``(F, B, O)`` for every adaptive filter F of ``filters`` whose fixed counterpart B and B's oracle O
    are among them, in the order of ``filters``."""
    have = set(filters)
    out = []
    for f in filters:
        if is_oracle(f):
            continue
        b = counterpart(f)
        if b is not None and b in have and b + ORACLE_SUFFIX in have:
            out.append((f, b, b + ORACLE_SUFFIX))
    return out


def has_oracle(metrics: pd.DataFrame) -> bool:
    """Whether ``metrics`` holds an oracle's rows."""
    return any(is_oracle(f) for f in filters_in_order(metrics))


def kept_runs(metrics: pd.DataFrame, track, names: Sequence[str]) -> list[pd.DataFrame]:
    """Per filter of ``names``, its rows on ``track`` for the runs none of them lost, aligned by run."""
    sub = metrics[metrics["track"] == track]
    rows = [sub[sub["filter"] == n].set_index("run") for n in names]
    common = rows[0].index
    for r in rows[1:]:
        common = common.intersection(r.index)
    common = common.sort_values()
    lost = np.zeros(len(common), dtype=bool)
    for r in rows:
        lost |= r.loc[common, "diverged"].to_numpy(bool)
    keep = common[~lost]
    return [r.loc[keep] for r in rows]


def share_values(vb, vf, vo):
    """The share ``(V_B − V_F) / (V_B − V_O)`` (floats or arrays of replicates; NaN where V_B = V_O)."""
    den = np.asarray(vb, dtype=float) - np.asarray(vo, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den != 0, (np.asarray(vb, dtype=float) - np.asarray(vf, dtype=float)) / den, np.nan)


def oracle_share(metrics: pd.DataFrame, n_boot: int = 2000, seed: int = 0, key: str = "vrmse") -> pd.DataFrame:
    """One row per adaptive filter with its fixed counterpart and that filter's oracle in ``metrics``
    (:func:`triples`): ``base_value``, ``filter_value``, ``oracle_value`` (eq 51 over the runs none of the
    three lost), ``oracle_gain`` [%] (the papers' improvement of O over B) with its interval, ``share``
    with its 95 % paired-bootstrap interval, ``pairs_min`` (fewest kept runs on a track) and ``note``
    (why a share is undefined, or that it rests on fewer than :data:`MIN_PAIRED_RUNS` runs).
    ``attrs["posterior"]``: whether the errors are the posterior ones (after t = 0)."""
    metrics = posterior_view(causal_only(metrics))
    rows = []
    for f, b, o in triples(filters_in_order(metrics)):
        tracks = sorted(set.intersection(*(set(metrics.loc[metrics["filter"] == n, "track"]) for n in (f, b, o))))
        per = {n: [] for n in (b, f, o)}
        reps = {n: [] for n in (b, f, o)}
        pairs = []
        for track in tracks:
            B, F, O = kept_runs(metrics, track, (b, f, o))
            pairs.append(len(B))
            if len(B) == 0:
                continue
            counts = resample_counts(len(B), n_boot, track_rng(seed, track)) if n_boot > 0 else None
            for n, T in ((b, B), (f, F), (o, O)):
                per[n].append(track_value(T, key))
                if counts is not None:
                    reps[n].append(track_value(T, key, counts))
        pairs_min = min(pairs) if pairs else 0
        if not pairs or pairs_min == 0:
            rows.append(dict(zip(COLUMNS, [f, b, o, key] + [math.nan] * 9 + [0, "no run kept by all three"])))
            continue
        v = {n: float(over_tracks(per[n], key)) for n in (b, f, o)}
        gain = float(improvement(v[b], v[o]))
        share = float(share_values(v[b], v[f], v[o]))
        g_lo = g_hi = s_lo = s_hi = math.nan
        if n_boot > 0:
            r = {n: over_tracks(reps[n], key) for n in (b, f, o)}
            g_lo, g_hi = percentile_ci(improvement(r[b], r[o]))
            s_lo, s_hi = percentile_ci(share_values(r[b], r[f], r[o]))
        note = ""
        if not (np.isfinite(g_lo) and g_lo > 0):
            note = "no share: the oracle's gain over the fixed filter is not positive (its interval is not above 0)"
            share = s_lo = s_hi = math.nan
        elif pairs_min < MIN_PAIRED_RUNS:
            note = f"fewer than {MIN_PAIRED_RUNS} runs on a track: the interval is not trusted"
        rows.append(dict(zip(COLUMNS, [f, b, o, key, v[b], v[f], v[o], gain, g_lo, g_hi, share, s_lo, s_hi,
                                       pairs_min, note])))
    out = pd.DataFrame(rows, columns=COLUMNS)
    out.attrs["posterior"] = bool(metrics.attrs.get("posterior", False))
    return out


def pct(x: float) -> str:
    """A share in percent: whole below -1 % and above 1 %, one decimal in between (``0.4``, not ``0``, for a
    small share; ``-0.0`` written ``0.0``)."""
    v = 100 * x
    text = f"{v:.0f}" if abs(v) >= 0.95 else f"{v:.1f}"
    return text[1:] if text in ("-0", "-0.0") else text


def share_md(table: pd.DataFrame, n_boot: int) -> str:
    """The report's section text of :func:`oracle_share`'s table ("" without a row). A note every row of two or
    more has (e.g. no share: the oracle gains nothing, on each adaptive filter) is said once under the table."""
    if table.empty:
        return ""
    name, unit = METRICS[str(table["metric"].iloc[0])][1:]
    headers = ["filter", "fixed", "oracle", f"fixed {name} [{unit}]", f"filter {name}", f"oracle {name}",
               "oracle's gain [95 % CI]", "share of the oracle's gain [95 % CI]", "runs"]
    notes = set(table["note"])
    common = notes.pop() if len(table) > 1 and len(notes) == 1 else ""
    out = []
    for r in table.itertuples():
        gain = DASH if not np.isfinite(r.oracle_gain) else (
            f"{r.oracle_gain:+.1f} % [{r.oracle_gain_lo:+.1f}, {r.oracle_gain_hi:+.1f}]")
        share = DASH if not np.isfinite(r.share) else (
            f"{pct(r.share)} % [{pct(r.share_lo)}, {pct(r.share_hi)}]")
        out.append([r.filter, r.base, r.oracle, fmt(r.base_value), fmt(r.filter_value), fmt(r.oracle_value), gain,
                    share + (f" ({r.note})" if r.note and not common else ""), str(r.pairs_min)])
    epochs = "after t = 0" if table.attrs.get("posterior") else "over every epoch (no posterior sums in this folder)"
    once = f"\n\nEvery row: {common}." if common else ""
    return ("Share = (fixed − filter) / (fixed − oracle) of the track-averaged " + name + " (eq 51, " + epochs
            + ", over the runs none of the three lost): 100 % is what knowing the true Q(t) and R(t) gives, 0 % no "
            f"gain over the fixed filter. Paired percentile bootstrap over runs ({n_boot} resamples, the same for "
            "the three filters); the oracle is the fixed filter told the true noise (outliers are not noise it is "
            "told: docs/adapting.md).\n\n" + md_table(headers, out) + once)


__all__ = ["COLUMNS", "counterpart", "has_oracle", "kept_runs", "oracle_share", "pct", "share_md", "share_values",
           "triples"]
