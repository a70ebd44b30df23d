"""Figures of a Monte Carlo report, per track, and how the report shows them.

Leading (the style of navigation papers): per-axis errors against the filter's ±3σ
(:mod:`~nespm_cli.reports.axes_figures`, studies run with ``--save-series axes``), ANEES per block
with the NCI and ANIS per sensor against their chi-square bounds
(:mod:`~nespm_cli.reports.consistency`), the horizontal error against the distance travelled and the
final-position scatter with CEP circles (:mod:`~nespm_cli.reports.position_figures`). Then the error
norms over time (mean ± 1 std) and the true vs mean estimated track. docs/report.md defines each.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from nespm_cli.reports.axes_figures import axes_figure, has_axes
from nespm_cli.reports.consistency import anees_figure, anis_figure, anis_sensors
from nespm_cli.reports.figures import (
    filter_colors,
    legend_outside,
    line_style,
    mean_std_band,
    save_figure,
    shade_outages,
    use_agg,
    use_log_between,
)
from nespm_cli.reports.markdown import DASH
from nespm_cli.reports.position_figures import final_scatter_figure, has_final, hpe_distance_figure
from nespm_cli.reports.results import filters_in_order, sensor_dims

__all__ = ["FIGURE_KINDS", "figure_notes", "figures_md", "plot_track_figures"]

#: figure kind (its file-name prefix) -> caption, in the order the report shows them
FIGURE_KINDS: dict[str, str] = {
    "axes": "Per-axis error of each filter: RMS over the runs (black) inside the ±3σ envelope of the filter's own "
            "covariance (blue), per state block and axis; grey = no DVL update.",
    "anees": "ANEES per state block against its 95 % chi-square bounds (dashed), and Li & Zhao's noncredibility "
             "index when recorded (0 dB = credible).",
    "anis": "ANIS per sensor at the epochs with a measurement, against its 95 % chi-square bounds (dashed).",
    "hpe_distance": "Horizontal position error, mean ± 1 std across the runs not lost, against the distance "
                    "travelled; dotted = constant % of the distance travelled (DT).",
    "final": "Final horizontal errors of the runs no filter lost, with the CEP50 (dashed) and R95 (solid) circles.",
    "vel": "Velocity-error norm, mean ± 1 std across the runs not lost (band clipped at 0); grey = no DVL update.",
    "att": "Misalignment norm, mean ± 1 std across the runs not lost.",
    "hpe": "Horizontal position error over time, mean ± 1 std across the runs not lost.",
    "path": "True vs mean estimated horizontal track.",
}
KIND_RE = re.compile(r"^(axes|anees|anis|hpe_distance|final|vel|att|hpe|path)_")


def _error_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], kind: str, title: str, path: Path
) -> Path:
    """Plot mean ± 1 std of an error norm over time per filter with outage shading (log scale when the
    filters lie more than a decade apart)."""
    import matplotlib.pyplot as plt

    col, label = {"vel": ("vel_err", "velocity error norm [m/s]"),
                  "att": ("att_err", "misalignment norm [rad]"),
                  "hpe": ("hpe", "horizontal position error [m]")}[kind]
    fig, ax = plt.subplots(figsize=(9, 4.8))
    for i, f in enumerate(filters):
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        mean_std_band(ax, d["t"], d[f"{col}_mean"], d[f"{col}_std"], colors[f], f, **line_style(i))
    grid = ep.groupby("t", sort=True)["dvl_used"].any()
    shade_outages(ax, grid.index.to_numpy(float), grid.to_numpy(bool))
    curves = [d[f"{col}_mean"].to_numpy(float) for _, d in ep[ep["t"] > 0].groupby("filter", sort=False)]
    if use_log_between(curves):  # e.g. a free INS beside aided filters: orders of magnitude apart
        ax.set_yscale("log")
    ax.set_xlabel("time since first epoch [s]")
    ax.set_ylabel(label)
    ax.set_title(title, fontsize="medium")
    ax.grid(True, alpha=0.3)
    legend_outside(ax)
    return save_figure(fig, path)


def _track_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], title: str, path: Path
) -> Path:
    """True vs mean estimated horizontal track (east, north) per filter, equal aspect."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    first = ep[ep["filter"] == filters[0]].sort_values("t")
    ax.plot(first["east_true"], first["north_true"], color="k", lw=2.0, label="truth")
    for i, f in enumerate(filters):
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        ax.plot(d["east_true"] + d["east_err_mean"], d["north_true"] + d["north_err_mean"],
                color=colors[f], label=f"{f} (mean estimate)", **(line_style(i + 1) | {"lw": 1.2}))
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title, fontsize="medium")
    ax.grid(True, alpha=0.3)
    legend_outside(ax)
    return save_figure(fig, path)


def plot_track_figures(
    epochs: pd.DataFrame, metrics: pd.DataFrame, fig_dir: Path, scenario: str | None = None,
    manifest: dict | None = None, tracks: Sequence[int] | None = None,
) -> list[Path]:
    """Write the PNGs of every track into ``fig_dir``; return their paths, track by track in the order
    of :data:`FIGURE_KINDS`: ``axes_<filter>_track<N>.png`` (with the per-axis columns),
    ``anees_track<N>.png`` (with the per-block NEES), ``anis_track<N>.png`` (with an ANIS; the sensors'
    measurement sizes from ``manifest``), ``hpe_distance_track<N>.png`` and ``final_track<N>.png`` (with
    the horizontal-position columns), ``vel_track<N>.png``, ``att_track<N>.png``, ``hpe_track<N>.png``
    (with ``hpe_mean``) and ``path_track<N>.png``. ``tracks``: only these (the filters' order, colours
    and everything else still taken from all of ``epochs`` and ``metrics``, so a track's files do not
    depend on which others are drawn with it).
    """
    use_agg()
    fig_dir.mkdir(parents=True, exist_ok=True)
    order = filters_in_order(metrics)
    filters = order + [f for f in (str(x) for x in pd.unique(epochs["filter"])) if f not in order]
    colors = filter_colors(filters)
    runs = metrics.groupby("track")["run"].nunique()
    dims = sensor_dims(manifest or {}, anis_sensors(epochs))
    paths: list[Path] = []
    for track in sorted(pd.unique(epochs["track"])):
        if tracks is not None and track not in tracks:
            continue
        ep = epochs[epochs["track"] == track]
        present = [f for f in filters if (ep["filter"] == f).any()]
        tail = f"track {track}, {int(runs.get(track, 0))} runs, scenario {scenario or DASH}"

        def at(name: str) -> Path:
            return fig_dir / f"{name}_track{track}.png"

        for f in present:
            axes = axes_figure(ep[ep["filter"] == f], f"{f}: per-axis RMS error and ±3σ — {tail}", at(f"axes_{f}"))
            paths += [axes.path] if axes is not None else []
        lead = [anees_figure(ep, present, colors, f"ANEES per block against its 95 % chi-square bounds — {tail}",
                             at("anees")),
                anis_figure(ep, present, colors, dims, f"ANIS per sensor — {tail}", at("anis")),
                hpe_distance_figure(ep, present, colors, f"Horizontal error against distance travelled — {tail}",
                                    at("hpe_distance")),
                final_scatter_figure(metrics[metrics["track"] == track], present, colors,
                                     f"Final horizontal error, CEP circles — {tail}", at("final"))]
        paths += [m if isinstance(m, Path) else m.path for m in lead if m is not None]
        paths.append(_error_figure(ep, present, colors, "vel", f"Velocity error, mean ± 1 std — {tail}", at("vel")))
        paths.append(_error_figure(ep, present, colors, "att", f"Misalignment, mean ± 1 std — {tail}", at("att")))
        if {"hpe_mean", "hpe_std"} <= set(ep.columns):
            paths.append(_error_figure(ep, present, colors, "hpe",
                                       f"Horizontal position error, mean ± 1 std — {tail}", at("hpe")))
        paths.append(_track_figure(ep, present, colors, f"Horizontal track — {tail}", at("path")))
    return paths


def figure_notes(epochs: pd.DataFrame | None, metrics: pd.DataFrame, manifest: dict | None = None) -> list[str]:
    """The caveats of the figures, once each: a study without the per-axis columns, a folder without
    the final error components, a sensor whose measurement size is unknown (its ANIS has no bounds)."""
    if epochs is None or epochs.empty:
        return []
    notes = []
    if not has_axes(epochs):
        notes.append("No per-axis error figure: it needs the per-axis series; run the study with "
                     "`--save-series axes`.")
    if not has_final(metrics) and "hpe_final" in metrics.columns:
        notes.append("No final-position scatter: `metrics.parquet` lacks `north_final` / `east_final` (written by "
                     "an older nespm).")
    unknown = [s for s, m in sensor_dims(manifest or {}, anis_sensors(epochs)).items() if m is None]
    if unknown:
        notes.append(f"ANIS of {', '.join(f'`{s}`' for s in unknown)} drawn without bounds: the measurement size of "
                     "the sensor is not known here (its plugin is not loaded).")
    return notes


def figures_md(figures: Sequence[Path], out_dir: Path) -> str:
    """The figures in the report: per kind of :data:`FIGURE_KINDS`, its caption in one line and its
    images (every track); the figures of an unknown kind last."""
    groups: dict[str, list[Path]] = {}
    for p in figures:
        m = KIND_RE.match(Path(p).stem)
        groups.setdefault(m.group(1) if m else "", []).append(Path(p))
    if not groups:
        return "No figures: `epochs.parquet` is absent."
    parts = []
    for kind in [*FIGURE_KINDS, ""]:
        if kind in groups:
            images = "\n".join(f"![{p.stem}]({p.relative_to(out_dir).as_posix()})" for p in groups[kind])
            parts.append((f"{FIGURE_KINDS[kind]}\n\n" if kind else "") + images)
    return "\n\n".join(parts)
