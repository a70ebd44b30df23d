"""Per-axis error figures: each component's RMS error over the runs against the filter's own ±3σ.

``epochs.parquet`` of a study run with ``--save-series axes`` holds, per (track, filter, epoch) and
component label, ``rms_<label>`` (RMS over the runs not lost of that error component) and
``sig_<label>`` (square root of the mean over those runs of the filter's variance of it). A
consistent filter's RMS error runs at about 1σ, well inside the ±3σ envelope; an RMS error at or
beyond 3σ is an overconfident covariance. One figure per filter and track: a row per state block
(velocity, attitude in degrees, position when the state has it), a column per axis (N, E, D).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.reports.figures import Drawn, drawn, drawn_rows, save_figure, shade_outages

__all__ = ["AXIS_BLOCKS", "axes_blocks", "axes_figure", "has_axes"]

#: block -> (title, component labels, plotted unit, factor from the stored SI unit)
AXIS_BLOCKS: dict[str, tuple[str, tuple[str, str, str], str, float]] = {
    "vel": ("velocity error", ("dvN", "dvE", "dvD"), "m/s", 1.0),
    "att": ("attitude error", ("dpsiN", "dpsiE", "dpsiD"), "deg", 180.0 / math.pi),
    "pos": ("position error", ("dpN", "dpE", "dpD"), "m", 1.0),
}
AXIS_NAMES = ("north", "east", "down")


def _top(rms: np.ndarray, s3: np.ndarray) -> float:
    """The y extent of a panel: the whole RMS error and the 3σ envelope up to its 95th percentile, so
    that the initial covariance (often far wider than the rest) does not flatten the panel."""
    r = rms[np.isfinite(rms)]
    s = s3[np.isfinite(s3)]
    top = max(float(r.max()) if r.size else 0.0, float(np.percentile(s, 95)) if s.size else 0.0)
    return top if top > 0 else 1.0


def axes_blocks(ep: pd.DataFrame) -> list[str]:
    """The blocks of :data:`AXIS_BLOCKS` whose three ``rms_`` and ``sig_`` columns ``ep`` holds with
    some finite value."""
    out = []
    for block, (_, labels, _, _) in AXIS_BLOCKS.items():
        cols = [f"{k}_{lab}" for lab in labels for k in ("rms", "sig")]
        if all(c in ep.columns for c in cols) and np.isfinite(ep[cols].to_numpy(float)).any():
            out.append(block)
    return out


def has_axes(epochs: pd.DataFrame) -> bool:
    """Whether ``epochs`` holds the per-axis columns (a study run with ``--save-series axes``)."""
    return bool(axes_blocks(epochs))


def axes_figure(ep: pd.DataFrame, title: str, path: Path) -> Drawn | None:
    """One filter's per-axis figure from its epochs ``ep`` (one track, one filter): per block and axis
    the RMS error over the runs (solid) inside the shaded ±3σ envelope of the filter's own covariance
    (3 · ``sig_``), epochs without a DVL update shaded grey; the y range holds the whole RMS error and
    the envelope up to its 95th percentile (an initial transient may leave it). None without a block.

    Returns the :class:`Drawn` whose ``data`` has panels ``<block> <axis>`` (e.g. ``vel north``) and
    series ``rms``, ``3sigma`` (and ``root_pcrb``, the root of the posterior Cramér–Rao bound, where
    the epochs hold it) in the plotted unit (attitude in deg), ``x`` the time [s].
    """
    import matplotlib.pyplot as plt

    blocks = axes_blocks(ep)
    if not blocks:
        return None
    d = ep.sort_values("t")
    t = d["t"].to_numpy(float)
    fig, axes = plt.subplots(len(blocks), 3, figsize=(13.5, 2.9 * len(blocks) + 0.6), sharex=True, squeeze=False)
    parts = []
    for row, block in zip(axes, blocks):
        name, labels, unit, factor = AXIS_BLOCKS[block]
        for ax, lab, axis in zip(row, labels, AXIS_NAMES):
            rms = d[f"rms_{lab}"].to_numpy(float) * factor
            s3 = 3.0 * d[f"sig_{lab}"].to_numpy(float) * factor
            if "dvl_used" in d.columns:
                shade_outages(ax, t, d["dvl_used"].to_numpy(bool), label=False)
            ax.fill_between(t, -s3, s3, color="tab:blue", alpha=0.18, lw=0, label="±3σ (filter covariance)")
            ax.plot(t, s3, color="tab:blue", lw=0.8)
            ax.plot(t, -s3, color="tab:blue", lw=0.8)
            ax.plot(t, rms, color="k", lw=1.3, label="RMS error over runs")
            if f"pcrb_{lab}" in d.columns and np.isfinite(d[f"pcrb_{lab}"].to_numpy(float)).any():  # docs/pcrb.md
                root = np.sqrt(d[f"pcrb_{lab}"].to_numpy(float)) * factor
                ax.plot(t, root, color="tab:red", lw=0.9, ls="--", label="√PCRB (no causal filter below)")
                parts.append(drawn_rows(f"{block} {axis}", "root_pcrb", t, root))
            ax.axhline(0.0, color="0.4", lw=0.6)
            ax.set_ylim(-1.08 * _top(rms, s3), 1.08 * _top(rms, s3))
            ax.set_title(f"{name}, {axis}", fontsize="medium")
            ax.set_ylabel(f"{lab} [{unit}]")
            ax.grid(True, alpha=0.3)
            parts += [drawn_rows(f"{block} {axis}", "rms", t, rms), drawn_rows(f"{block} {axis}", "3sigma", t, s3)]
    for ax in axes[-1]:
        ax.set_xlabel("time since first epoch [s]")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper right", ncol=2, fontsize="small", frameon=False)
    fig.suptitle(title, fontsize="medium", x=0.02, ha="left")
    return drawn(save_figure(fig, path), parts)
