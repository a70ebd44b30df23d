"""Consistency judged per block and sensor from the share of epochs inside the per-epoch bounds.

A filter is consistent when its covariance matches its errors at every epoch, block by block. A
mean NEES over the runs and the whole track hides an overconfident block behind a conservative one
and an early transient behind a long calm, and its band (for one epoch's average) is lenient for a
time average. So each state block (velocity, attitude, position, the bias blocks; 3 dof) and each
sensor's innovation (NIS, m dof) is judged on its own, over the epochs after t = 0:

* at each epoch the ANEES (ANIS) over the ``n`` runs averaged lies inside, above or below its 95 %
  bounds ``chi2.ppf([0.025, 0.975], dof n) / n`` (:func:`nespm_cli.experiments.metrics.nees_band`);
* the block is **consistent** when at least :data:`CONSISTENT_SHARE` of its epochs lie inside,
  else **mixed** when at least :data:`MIXED_SHARE` of its epochs lie above and as many below (too
  small a covariance at some epochs, too large at others: a mean over them says nothing), else
  **overconfident** when more of its epochs lie above than below (covariance too small), else
  **conservative**;
* a filter is consistent when every block and sensor is; otherwise its word names the blocks that
  are not, each with its share inside.

A consistent filter has 95 % of its epochs inside in expectation; neighbouring epochs are strongly
correlated (the same runs, a slowly varying error), so the share of one study scatters far more
than a binomial of that many epochs would: 80 % allows for that and for the first transient while
a filter off by a factor 2 in its covariance lies inside at well under half of the epochs (the
ANEES of 8 runs has a band of about ×0.5 .. ×1.6). docs/report.md, "Consistency".
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.results import sensor_dims

__all__ = ["BLOCK_NAMES", "CONSISTENT_SHARE", "MIXED_SHARE", "block_consistency", "consistency_md", "consistency_words",
           "epoch_shares", "share_text"]

#: the least share of epochs inside the 95 % bounds for a block or sensor to count as consistent
CONSISTENT_SHARE = 0.8
#: the least share of epochs above and, at once, below the bounds for a block or sensor to be called mixed
MIXED_SHARE = 0.2
#: block -> name, in the order of the tables
BLOCK_NAMES = {"vel": "velocity", "att": "attitude", "pos": "position", "ba": "accelerometer bias",
               "bg": "gyro bias"}


def epoch_shares(x: np.ndarray, n: np.ndarray, dof: int) -> tuple[float, float, float, int]:
    """``(inside, above, below, epochs)``: the shares of the epochs whose average ``x`` over ``n`` runs
    lies inside, above and below its 95 % bounds for ``dof`` (epochs with ``n`` 0 or a NaN ``x`` do not
    count; NaN shares without an epoch)."""
    x, n = np.asarray(x, float), np.asarray(n, float)
    ok = np.isfinite(x) & (n > 0)
    if not ok.any():
        return math.nan, math.nan, math.nan, 0
    x, n = x[ok], n[ok].astype(int)
    lo, hi = np.empty(len(n)), np.empty(len(n))
    for k in np.unique(n):  # one chi-square quantile pair per distinct run count
        lo[n == k], hi[n == k] = nees_band(dof, int(k))
    above, below = float((x > hi).mean()), float((x < lo).mean())
    return 1.0 - above - below, above, below, int(len(x))


def share_text(value: float, threshold: float) -> str:
    """A share of epochs in whole percent, ``79 %``, unless rounding would put it on the other side of the
    ``threshold`` its word is judged against (79.7 % printed ``80 %`` beside *not consistent* at 80 %): then
    one decimal, rounded away from the threshold (``79.7 %``; 79.96 % is ``79.9 %``, never ``80.0 %``), so the
    number printed agrees with the word; ``—`` for NaN."""
    if not np.isfinite(value):
        return "—"
    v, t = 100 * value, 100 * threshold
    text = f"{v:.0f}"
    if (float(text) >= t) != (value >= threshold):
        step = math.floor if value < threshold else math.ceil
        text = f"{step(round(v * 10, 6)) / 10:.1f}"
    return f"{text} %"


def _word(inside: float, above: float, below: float, share: float = CONSISTENT_SHARE) -> str:
    if not np.isfinite(inside):
        return "—"
    if inside >= share:
        return "consistent"
    if above >= MIXED_SHARE and below >= MIXED_SHARE:
        return "mixed"
    return "overconfident" if above > below else "conservative"


def check_share(share: float) -> float:
    """``share`` as a float in (0, 1], or one line naming ``--consistent-share``."""
    from nespm_cli.errors import NespmError

    share = float(share)
    if not (0.0 < share <= 1.0):
        raise NespmError(f"--consistent-share must be a fraction in (0, 1] of the epochs, got {share:g}")
    return share


def block_consistency(epochs: pd.DataFrame | None, manifest: dict | None = None,
                      by_track: bool = False, share: float = CONSISTENT_SHARE) -> pd.DataFrame:
    """One row per (filter, item) (and ``track`` with ``by_track``; else the epochs of every track pooled):
    ``item`` a block of :data:`BLOCK_NAMES` (``kind`` ``ANEES``, 3 dof) or a sensor (``kind`` ``ANIS``, its
    measurement size from the manifest, :func:`results.sensor_dims`; a sensor of unknown size is left out),
    ``name``, ``dof``, ``mean`` (the mean over the epochs of the ANEES / ANIS), ``inside``, ``above``,
    ``below`` (:func:`epoch_shares`), ``epochs`` and ``word`` (consistent, overconfident, conservative).
    The epochs after t = 0 (epoch > 0) count; an empty frame without ``epochs`` or any ANEES column.
    ``share``: the least share inside for *consistent* (default :data:`CONSISTENT_SHARE`; ``attrs["share"]``)."""
    share = check_share(share)
    cols = ["track", "filter", "kind", "item", "name", "dof", "mean", "inside", "above", "below", "epochs", "word"]
    if epochs is None or epochs.empty or "n_runs" not in epochs.columns:
        out = pd.DataFrame(columns=cols)
        out.attrs["share"] = share
        return out
    ep = epochs[epochs["epoch"] > 0]
    items: list[tuple[str, str, str, str, str, int]] = [
        ("ANEES", b, name, f"nees_{b}_mean", "n_runs", 3) for b, name in BLOCK_NAMES.items()
        if f"nees_{b}_mean" in ep.columns]
    sensors = [c[4:-5] for c in ep.columns if c.startswith("nis_") and c.endswith("_mean")
               and f"{c[:-5]}_n" in ep.columns]
    for s, m in sensor_dims(manifest or {}, sensors).items():
        if m:
            items.append(("ANIS", s, f"{s} NIS", f"nis_{s}_mean", f"nis_{s}_n", int(m)))
    rows = []
    keys = ["track", "filter"] if by_track else ["filter"]
    for key, d in ep.groupby(keys, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        for kind, item, name, col, ncol, dof in items:
            x = d[col].to_numpy(float)
            if not np.isfinite(x).any():
                continue
            inside, above, below, k = epoch_shares(x, d[ncol].to_numpy(float), dof)
            rows.append({"track": key[0] if by_track else None, "filter": key[-1], "kind": kind, "item": item,
                         "name": name, "dof": dof, "mean": float(np.nanmean(x)), "inside": inside,
                         "above": above, "below": below, "epochs": k, "word": _word(inside, above, below, share)})
    out = pd.DataFrame(rows, columns=cols)
    out.attrs["share"] = share
    return out


def consistency_words(table: pd.DataFrame, shares: bool = True) -> dict[Any, str]:
    """Per filter (per ``(track, filter)`` for a per-track table) of :func:`block_consistency`: ``consistent``
    when every block and sensor is, else the items that are not with their word and share inside, e.g.
    ``overconfident: velocity 7 %; conservative: dvl NIS 30 %`` (without ``shares``: ``overconfident: velocity;
    conservative: dvl NIS``; no entry for a filter without a row)."""
    out: dict[Any, str] = {}
    if table.empty:
        return out
    keys = ["filter"] if table["track"].isna().all() else ["track", "filter"]
    share = table.attrs.get("share", CONSISTENT_SHARE)
    for key, d in table.groupby(keys, sort=False):
        key = key[0] if len(keys) == 1 and isinstance(key, tuple) else key
        bad = d[d["word"] != "consistent"]
        if bad.empty:
            out[key] = "consistent"
            continue
        parts = []
        for word in ("overconfident", "mixed", "conservative"):
            w = bad[bad["word"] == word]
            if len(w):
                parts.append(f"{word}: " + ", ".join(r.name + (f" {share_text(r.inside, share)}" if shares else "")
                                                     for r in w.itertuples()))
        out[key] = "; ".join(parts)
    return out


def consistency_md(table: pd.DataFrame, label=lambda f: f) -> str:
    """Markdown of :func:`block_consistency` (pooled over tracks): per filter and block or sensor the mean
    ANEES / ANIS over the epochs, its expectation (dof), the shares of the epochs inside, above and below the
    95 % bounds and the word; ``label`` names a filter (e.g. the smoother floor's label)."""
    from nespm_cli.reports.markdown import md_table

    headers = ["Method", "block or sensor", "statistic", "mean (expected)", "inside", "above", "below",
               "epochs", "consistency"]
    share = table.attrs.get("share", CONSISTENT_SHARE)
    rows = [[label(r.filter), r.name, r.kind, f"{r.mean:.3g} ({r.dof})", share_text(r.inside, share),
             share_text(r.above, MIXED_SHARE), share_text(r.below, MIXED_SHARE), str(r.epochs), r.word]
            for r in table.itertuples(index=False)]
    return (f"Per state block (ANEES, 3 dof) and sensor (ANIS, its measurement size): at each epoch after t = 0 the "
            "average over the runs not lost against its 95 % bounds `chi2.ppf([0.025, 0.975], dof n) / n` (n = the "
            f"runs averaged), every track's epochs pooled. *consistent*: at least "
            f"{100 * share:g} % of "
            "the epochs inside; else *mixed* (at least "
            f"{100 * MIXED_SHARE:.0f} % of the epochs above and as many below: too small a covariance at some epochs, "
            "too large at others), *overconfident* (more epochs above: covariance too small) or *conservative* "
            "(more below). A filter is consistent when every block and sensor is.\n\n" + md_table(headers, rows))
