"""Consistency figures: the ANEES of each state block over time against its chi-square bounds.

The ANEES of a block at an epoch is the mean over the N runs (not lost) of each run's NEES of that
block alone (3 dof; ``epochs.parquet``: ``nees_vel_mean``, ``nees_att_mean``, ``nees_pos_mean``).
A consistent filter's lies inside ``chi2.ppf([0.025, 0.975], 3 N) / N`` at about 95 % of the
epochs (:func:`nespm_cli.experiments.metrics.nees_band`); above it the filter is overconfident,
below conservative. The figure draws one panel per block the folder holds, the bounds dashed.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.figures import save_figure

BLOCKS = (("nees_vel_mean", "velocity"), ("nees_att_mean", "attitude"), ("nees_pos_mean", "position"))


def anees_blocks(ep: pd.DataFrame) -> list[tuple[str, str]]:
    """The ``(column, label)`` of the blocks with an ANEES in ``ep`` (some filter, some epoch)."""
    return [(c, label) for c, label in BLOCKS if c in ep.columns and np.isfinite(ep[c].to_numpy(float)).any()]


def inside_fraction(x: np.ndarray, n_runs: np.ndarray) -> float:
    """Fraction of the epochs whose ANEES ``x`` lies inside its 95 % bounds for ``n_runs`` runs (3 dof)."""
    ok = np.isfinite(x) & (n_runs > 0)
    if not ok.any():
        return float("nan")
    bounds = np.array([nees_band(3, int(n)) for n in n_runs[ok]])
    return float(((x[ok] > bounds[:, 0]) & (x[ok] < bounds[:, 1])).mean())


def anees_figure(ep: pd.DataFrame, filters: list[str], colors: dict, title: str, path: Path) -> Path | None:
    """ANEES per block over time, one line per filter, the 95 % bounds dashed (log scale when the
    values span more than a factor 20); the legend gives each filter's fraction of epochs inside the bounds. None without an ANEES."""
    import matplotlib.pyplot as plt

    blocks = anees_blocks(ep)
    if not blocks:
        return None
    fig, axes = plt.subplots(1, len(blocks), figsize=(5.2 * len(blocks), 3.8), squeeze=False)
    for ax, (col, label) in zip(axes[0], blocks):
        lo_hi = None
        vals = ep.loc[ep["epoch"] > 0, col].to_numpy(float)
        vals = vals[np.isfinite(vals) & (vals > 0)]
        for f in filters:
            d = ep[(ep["filter"] == f) & (ep["epoch"] > 0)].sort_values("epoch")
            x = d[col].to_numpy(float)
            if not np.isfinite(x).any():
                continue
            n = d["n_runs"].to_numpy()
            frac = inside_fraction(x, n)
            ax.plot(d["t"], x, color=colors.get(f), lw=1.0, label=f"{f} ({100 * frac:.0f} % inside)")
            lo_hi = nees_band(3, int(np.median(n[n > 0]))) if (n > 0).any() else lo_hi
        if lo_hi is not None:
            for b in lo_hi:
                ax.axhline(b, color="k", ls="--", lw=0.8)
        ax.axhline(3.0, color="0.6", lw=0.6)
        if vals.size and vals.max() / vals.min() > 20:  # an inconsistent filter: orders of magnitude
            ax.set_yscale("log")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"ANEES, {label} (3 dof)")
        ax.set_title(f"{label}: 95 % bounds dashed")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


__all__ = ["BLOCKS", "anees_blocks", "anees_figure", "inside_fraction"]
