"""Horizontal-position figures: the horizontal error against the distance travelled, and the final
horizontal errors of the runs with their CEP circles.

* Distance travelled [m]: along the true track, the cumulative sum of ``hypot(Δnorth_true,
  Δeast_true)`` between consecutive epochs of ``epochs.parquet`` (the path length, as the metrics'
  ``distance``); the horizontal error is ``hpe_mean`` ± ``hpe_std`` across the runs not lost, and
  dotted lines mark constant fractions of the distance travelled (the field's "% of DT").
* Final errors: ``north_final``, ``east_final`` [m] (nav − truth) of each run of ``metrics.parquet``
  that no filter lost, one panel per filter with the CEP50 and R95 circles about the truth
  (:func:`nespm_cli.experiments.metrics.cep` of those runs' ``hpe_final``: the radii holding 50 % and
  95 % of them; the same runs and numbers as the report's horizontal-position table).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import cep
from nespm_cli.reports.figures import (
    Drawn,
    drawn,
    drawn_rows,
    legend_outside,
    line_style,
    mean_std_band,
    save_figure,
    use_log_between,
)
from nespm_cli.reports.stats import lost_by_any

__all__ = ["FINAL_COLUMNS", "distance_travelled", "final_scatter_figure", "has_final", "hpe_distance_figure"]

FINAL_COLUMNS = ("north_final", "east_final", "hpe_final")
#: fractions of the distance travelled drawn as guides [%]
DT_GUIDES = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)
#: panels of the final scatter whose extent is within this factor of the smallest share one scale
SHARED_SCALE = 5.0


def _reach(runs: pd.DataFrame, r95: float) -> float:
    """Half-width [m] of a scatter panel: the largest final error component or R95, plus 12 %."""
    xy = runs[["north_final", "east_final"]].to_numpy(float)
    big = float(np.nanmax(np.abs(xy))) if np.isfinite(xy).any() else 0.0
    return max(big, r95 if np.isfinite(r95) else 0.0, 1e-9) * 1.12


def _metres(x: float) -> str:
    """A length for a label: three significant digits, whole metres from 1000 m."""
    return f"{x:.0f}" if abs(x) >= 1000 else f"{x:.3g}"


def distance_travelled(north: Any, east: Any) -> np.ndarray:
    """(N,) distance along a track [m] from its north / east positions (N,) [m]: 0 at the first epoch."""
    n, e = np.asarray(north, dtype=float), np.asarray(east, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(n), np.diff(e)))])


def hpe_distance_figure(ep: pd.DataFrame, filters: Sequence[str], colors: dict, title: str,
                        path: Path) -> Drawn | None:
    """Horizontal error (mean ± 1 std across the runs not lost) against the distance travelled, one
    curve per filter of ``filters`` present in ``ep`` (one track), with dotted guides at constant
    % of the distance travelled; a log scale when the filters' errors lie more than a decade apart (a
    free INS beside aided filters, :func:`figures.use_log_between`). None without ``hpe_mean``.
    ``data``: panel ``hpe``, series = filter (x distance [m], y mean error [m]) and ``<p> % DT`` for
    the guides drawn."""
    import matplotlib.pyplot as plt

    if not {"hpe_mean", "hpe_std"} <= set(ep.columns):
        return None
    fig, ax = plt.subplots(figsize=(9, 4.8))
    parts, means, uppers, dist_max = [], [], [], 0.0
    for i, f in enumerate(f for f in filters if (ep["filter"] == f).any()):
        d = ep[ep["filter"] == f].sort_values("t")
        x = distance_travelled(d["north_true"], d["east_true"])
        m, s = d["hpe_mean"].to_numpy(float), d["hpe_std"].to_numpy(float)
        if not np.isfinite(m).any():
            continue
        mean_std_band(ax, x, m, s, colors.get(f), f, **line_style(i))
        parts.append(drawn_rows("hpe", f, x, m))
        means.append(m[x > 0])
        uppers.append((m + np.nan_to_num(s))[x > 0])
        dist_max = max(dist_max, float(x[-1]))
    vals = np.concatenate(means) if means else np.array([])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if dist_max > 0 and vals.size:
        log = use_log_between(means)
        up = np.concatenate(uppers)
        lo, top = float(vals.min()), float(np.nanmax(up))
        ylim = (0.5 * lo, 2.0 * top) if log else (0.0, 1.05 * top)
        xs = np.linspace(0.0, dist_max, 200)
        for g in (g for g in DT_GUIDES if (lo if log else 0.05 * top) <= g / 100 * dist_max <= 3 * top):
            ax.plot(xs, g / 100 * xs, color="0.35", ls=":", lw=1.0)
            end = g / 100 * dist_max
            at = (dist_max, end, "bottom") if end <= ylim[1] else (ylim[1] / (g / 100), ylim[1], "top")
            ax.annotate(f"{g:g} % DT", at[:2], fontsize="x-small", color="0.3", ha="right", va=at[2])
            parts.append(drawn_rows("hpe", f"{g:g} % DT", xs, g / 100 * xs))
        if log:
            ax.set_yscale("log")
        ax.set_ylim(*ylim)
        ax.set_xlim(0.0, dist_max)
    ax.set_xlabel("distance travelled along the true track [m]")
    ax.set_ylabel("horizontal position error [m]")
    ax.set_title(title, fontsize="medium")
    ax.grid(True, alpha=0.3)
    legend_outside(ax)
    return drawn(save_figure(fig, path), parts)


def has_final(metrics: pd.DataFrame) -> bool:
    """Whether ``metrics`` holds the final error components (:data:`FINAL_COLUMNS`)."""
    return all(c in metrics.columns for c in FINAL_COLUMNS)


def final_scatter_figure(metrics: pd.DataFrame, filters: Sequence[str], colors: dict, title: str,
                         path: Path) -> Drawn | None:
    """Final horizontal errors (east, north) [m] of the runs of ``metrics`` (one track) that no filter
    lost, one panel per filter of ``filters``, the CEP50 (dashed) and R95 (solid) circles about the
    truth, equal scales on every panel. None without :data:`FINAL_COLUMNS` or a run to draw.
    ``data``: per panel (filter) series ``runs`` (x east, y north), ``cep50`` and ``r95`` (x = y = radius)."""
    import matplotlib.pyplot as plt

    if not has_final(metrics):
        return None
    kept = metrics[~lost_by_any(metrics).to_numpy(bool)]
    present = [f for f in filters if np.isfinite(kept.loc[kept["filter"] == f, "hpe_final"].to_numpy(float)).any()]
    if not present:
        return None
    radii = {f: (cep(kept.loc[kept["filter"] == f, "hpe_final"], 0.5),
                 cep(kept.loc[kept["filter"] == f, "hpe_final"], 0.95)) for f in present}
    reach = {f: _reach(kept[kept["filter"] == f], radii[f][1]) for f in present}
    common = max(r for r in reach.values() if r <= SHARED_SCALE * min(reach.values()))
    cols = min(len(present), 4)
    nrows = math.ceil(len(present) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.9 * cols, 4.1 * nrows + 0.5), squeeze=False)
    circle = np.linspace(0.0, 2 * math.pi, 241)
    parts = []
    for ax, f in zip(axes.ravel(), present):
        d = kept[kept["filter"] == f]
        e, n = d["east_final"].to_numpy(float), d["north_final"].to_numpy(float)
        c50, r95 = radii[f]
        lim = common if reach[f] <= common else reach[f]
        ax.scatter(e, n, s=14, color=colors.get(f), alpha=0.75, lw=0)
        ax.plot(c50 * np.cos(circle), c50 * np.sin(circle), color="k", ls="--", lw=1.0, label="CEP50")
        ax.plot(r95 * np.cos(circle), r95 * np.sin(circle), color="k", ls="-", lw=1.0, label="R95")
        ax.plot([0.0], [0.0], marker="+", color="k", ms=10)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.locator_params(nbins=5)
        own = "" if lim == common else ", own scale"
        ax.set_title(f"{f} ({np.isfinite(e).sum()} runs{own})\nCEP50 {_metres(c50)} m, R95 {_metres(r95)} m",
                     fontsize="medium")
        ax.set_xlabel("east error [m]")
        ax.set_ylabel("north error [m]")
        ax.grid(True, alpha=0.3)
        parts += [drawn_rows(f, "runs", e, n), drawn_rows(f, "cep50", [c50], [c50]), drawn_rows(f, "r95", [r95], [r95])]
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper right", ncol=2, fontsize="small", frameon=False)
    for ax in axes.ravel()[len(present):]:
        ax.set_visible(False)
    fig.suptitle(title, fontsize="medium")
    return drawn(save_figure(fig, path), parts)
