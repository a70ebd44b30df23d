"""Figures of a sweep report: each metric against the swept value with its 95 % band, and each
filter's paired improvement over the baseline (the numbers of :func:`sweep_tables.improvement_points`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.figures import filter_colors, save_figure, use_agg, use_log_x, use_log_y
from nespm_cli.reports.results import filters_in_order, runs_per_track
from nespm_cli.reports.stats import METRICS, MIN_PAIRED_RUNS, NEES_DOF
from nespm_cli.reports.sweep_data import param_label, param_of, protocol_text
from nespm_cli.reports.sweep_tables import improvement_points, nees_runs

__all__ = ["plot_sweep_figures"]

# metric key -> (display name, unit, y-axis label); VRMSE/MRMSE as stats.METRICS
_ALL_METRICS: dict[str, tuple[str, str, str]] = {
    "vrmse": ("VRMSE", "m/s", "VRMSE [m/s]"),
    "mrmse": ("MRMSE", "rad", "MRMSE [rad]"),
    "nees": ("mean NEES", "", "mean NEES (6 DOF) [-]"),
    "div_rate": ("divergence rate", "", "divergence rate (diverged runs / runs) [-]"),
}



def _subtitle(metrics: pd.DataFrame, manifest: dict) -> str:
    tracks = ", ".join(str(t) for t in sorted(pd.unique(metrics["track"])))
    s = "track" if metrics["track"].nunique() == 1 else "tracks"
    text = f"{s} {tracks} · {runs_per_track(metrics)} runs per track"
    proto = protocol_text(metrics, manifest)
    return text + (f" · {proto}" if proto else "")


_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")


def _style(i: int) -> dict[str, Any]:
    """Marker shape and size of the i-th filter: later filters get smaller markers so that
    coinciding curves stay distinguishable."""
    return {"marker": _MARKERS[i % len(_MARKERS)], "ms": max(9.0 - 1.8 * i, 4.0)}


def _setup_axes(ax, values: Sequence[float], xlabel: str, ylabel: str, title: str, logy: bool) -> None:
    if use_log_x(values):
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    from matplotlib.ticker import NullLocator

    ax.set_xticks(list(values))
    ax.set_xticklabels([f"{v:g}" for v in values])
    ax.xaxis.set_minor_locator(NullLocator())
    lo, hi = float(min(values)), float(max(values))
    if use_log_x(values):  # 6 % of the span as margin on each side
        f = (hi / lo) ** 0.06
        ax.set_xlim(lo / f, hi * f)
    else:
        pad = 0.06 * (hi - lo) if hi > lo else max(0.1 * abs(lo), 1.0)
        ax.set_xlim(lo - pad, hi + pad)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize="medium")
    ax.grid(True, which="both", alpha=0.3)


def _metric_figure(
    table: pd.DataFrame, key: str, filters: Sequence[str], colors: dict, xlabel: str,
    title: str, path: Path, nees_band_: tuple[float, float, int] | None = None,
) -> Path:
    """Metric vs swept value, one line with markers and 95 % band per filter."""
    import matplotlib.pyplot as plt

    values = sorted(pd.unique(table["value"]))
    name, _, ylabel = _ALL_METRICS[key]
    fig, ax = plt.subplots(figsize=(8, 5))
    plotted = []
    for f in filters:
        d = table[table["filter"] == f].sort_values("value")
        y = d[key].to_numpy(float)
        if not np.isfinite(y).any():
            continue
        x = d["value"].to_numpy(float)
        lo, hi = d[f"{key}_lo"].to_numpy(float), d[f"{key}_hi"].to_numpy(float)
        ax.plot(x, y, lw=1.6, color=colors[f], label=f, **_style(list(colors).index(f)))
        ax.fill_between(x, lo, hi, color=colors[f], alpha=0.18, lw=0)
        plotted += [y, lo, hi]
    logy = False
    if nees_band_ is not None:
        blo, bhi, n = nees_band_
        ax.axhspan(blo, bhi, color="0.45", alpha=0.25, lw=0,
                   label=f"95 % band of a consistent filter (6 DOF, {n} runs): [{blo:.2f}, {bhi:.2f}]")
        ax.axhline(NEES_DOF, color="0.3", ls="--", lw=1.0)
        plotted += [np.array([blo, bhi])]
        logy = use_log_y(np.concatenate([np.ravel(p) for p in plotted]))
    elif key in METRICS:
        pts = table.loc[table["filter"].isin(filters), key].to_numpy(float)
        logy = use_log_y(pts)
    if key == "div_rate":
        ax.set_ylim(-0.03, 1.03)
    _setup_axes(ax, values, xlabel, ylabel, title, logy)
    if key != "div_rate":  # say why a value has no point
        lost = table[table["filter"].isin(filters)].groupby("value")
        for v, d in lost:
            if (d["runs"] > 0).all() and (d["diverged"] == d["runs"]).all():
                ax.annotate("all runs\ndiverged", (v, 0.03), xycoords=ax.get_xaxis_transform(),
                            ha="center", va="bottom", fontsize="small", color="firebrick")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")
    return save_figure(fig, path)


def _improvement_figure(
    imp: pd.DataFrame, filters: Sequence[str], colors: dict, xlabel: str, title: str, path: Path
) -> Path:
    """Two panels (VRMSE, MRMSE): improvement over the baseline vs value with paired bands."""
    import matplotlib.pyplot as plt

    values = sorted(pd.unique(imp["value"])) if not imp.empty else []
    base = imp.attrs.get("baseline", "baseline")
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), sharex=True)
    for ax, key in zip(axes, METRICS):
        name = METRICS[key][1]
        ax.axhline(0.0, color="k", lw=1.0)
        marked = False
        for f in filters:
            d = improvement_points(imp, key, f)  # the same numbers as the improvement table
            if d.empty:
                continue
            x = d["value"].to_numpy(float)
            y = d["imprv"].to_numpy(float)
            ax.plot(x, y, lw=1.6, color=colors[f], label=f"{f} vs {base}",
                    **_style(list(colors).index(f)))
            ax.fill_between(x, d["ci_lo"].to_numpy(float), d["ci_hi"].to_numpy(float),
                            color=colors[f], alpha=0.18, lw=0)
            ex = d["significant"].to_numpy(bool)
            if ex.any():
                ax.plot(x[ex], y[ex], ls="none", marker="*", ms=15, mfc=colors[f], mec="k", mew=0.9)
                marked = True
        if marked:  # one neutral legend entry for the highlighted points of every filter
            ax.plot([], [], ls="none", marker="*", ms=13, mfc="white", mec="k", mew=0.9,
                    label=f"95 % CI excludes 0 (≥ {imp.attrs.get('min_pairs', MIN_PAIRED_RUNS)} pairs per track)")
        if values:
            _setup_axes(ax, values, xlabel, f"{name} improvement over {base} [%]",
                        f"{name}: 100·({base} − filter)/{base}", False)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best", fontsize="small")
    fig.suptitle(title, fontsize="medium")
    return save_figure(fig, path)


def plot_sweep_figures(
    metrics: pd.DataFrame, manifest: dict, table: pd.DataFrame, imp: pd.DataFrame, fig_dir: Path
) -> list[Path]:
    """Write ``sweep_vrmse.png``, ``sweep_mrmse.png``, ``sweep_nees.png``,
    ``sweep_divergence.png`` and ``sweep_improvement.png`` into ``fig_dir``."""
    use_agg()
    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    filters = filters_in_order(metrics)
    colors = filter_colors(filters)
    param = param_of(metrics)
    xlabel = param_label(param)
    sub = _subtitle(metrics, manifest)
    n = nees_runs(metrics)
    blo, bhi = nees_band(NEES_DOF, n)
    paths = []
    for key, fname in (("vrmse", "sweep_vrmse"), ("mrmse", "sweep_mrmse"),
                       ("nees", "sweep_nees"), ("div_rate", "sweep_divergence")):
        name = _ALL_METRICS[key][0]
        title = f"{name} (95 % interval) vs {param}\n{sub}"
        paths.append(_metric_figure(table, key, filters, colors, xlabel, title, fig_dir / f"{fname}.png",
                                    nees_band_=(blo, bhi, n) if key == "nees" else None))
    base = imp.attrs.get("baseline", "")
    others = [f for f in filters if f != base]
    paths.append(_improvement_figure(
        imp, others, colors, xlabel,
        f"Improvement over {base} (paired 95 % interval) vs {param}\n{sub}",
        fig_dir / "sweep_improvement.png"))
    return paths


