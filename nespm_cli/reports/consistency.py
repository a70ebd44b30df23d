"""Consistency figures: the ANEES of each state block and the ANIS of each sensor over time against
their chi-square bounds, and Li & Zhao's noncredibility index (NCI) of each block.

* ANEES of a block at an epoch: the mean over the N runs (not lost) of each run's NEES of that
  block alone (3 dof; ``epochs.parquet``: ``nees_<block>_mean``, N = ``n_runs``). A consistent
  filter's lies inside ``chi2.ppf([0.025, 0.975], 3 N) / N`` at about 95 % of the epochs
  (:func:`nespm_cli.experiments.metrics.nees_band`); above it the filter is overconfident, below
  conservative.
* NCI of a block (``nci_<block>``, dB, studies run with ``--save-series axes``): 0 dB = credible,
  > 0 optimistic (covariance too small), < 0 pessimistic.
* ANIS of a sensor (``nis_<sensor>_mean``, averaging ``nis_<sensor>_n`` runs; only epochs that had
  its measurement): against ``chi2.ppf([0.025, 0.975], m n) / n`` with m the sensor's measurement
  size (:func:`nespm_cli.reports.results.sensor_dims`); drawn without bounds when m is unknown.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.block_consistency import CONSISTENT_SHARE, share_text
from nespm_cli.reports.figures import Drawn, drawn, drawn_rows, legend_outside, line_style, save_figure

#: the navigation blocks' ANEES columns and names; :data:`BIAS_BLOCKS` the bias blocks' (from the true biases)
BLOCKS = (("nees_vel_mean", "velocity"), ("nees_att_mean", "attitude"), ("nees_pos_mean", "position"))
BIAS_BLOCKS = (("nees_ba_mean", "accelerometer bias"), ("nees_bg_mean", "gyro bias"))
NCI_RE = re.compile(r"^nci_(vel|att|pos|ba|bg)(?:_mean)?$")
NIS_RE = re.compile(r"^nis_(.+)_mean$")


def anees_blocks(ep: pd.DataFrame, biases: bool = False) -> list[tuple[str, str]]:
    """The ``(column, label)`` of the navigation blocks (and with ``biases`` the bias blocks) with an
    ANEES in ``ep`` (some filter, some epoch)."""
    blocks = BLOCKS + (BIAS_BLOCKS if biases else ())
    return [(c, label) for c, label in blocks if c in ep.columns and np.isfinite(ep[c].to_numpy(float)).any()]


def nci_column(ep: pd.DataFrame, anees_col: str) -> str | None:
    """The NCI column of the block of ``anees_col`` (``nees_vel_mean`` -> ``nci_vel``), if ``ep`` has
    it with a finite value."""
    block = anees_col[len("nees_"):-len("_mean")]
    for c in ep.columns:
        m = NCI_RE.match(c)
        if m and m.group(1) == block and np.isfinite(ep[c].to_numpy(float)).any():
            return c
    return None


def inside_fraction(x: np.ndarray, n_runs: np.ndarray, dof: int = 3) -> float:
    """Fraction of the epochs whose average ``x`` lies inside its 95 % bounds for ``n_runs`` runs of a
    ``dof``-dimensional chi-square (epochs with ``n_runs`` 0 or a NaN do not count)."""
    ok = np.isfinite(x) & (n_runs > 0)
    if not ok.any():
        return float("nan")
    bounds = np.array([nees_band(dof, int(n)) for n in n_runs[ok]])
    return float(((x[ok] > bounds[:, 0]) & (x[ok] < bounds[:, 1])).mean())


def _bounds(ax, t: np.ndarray, n: np.ndarray, dof: int) -> tuple[np.ndarray, np.ndarray]:
    """Draw the 95 % bounds (dashed; per epoch, as the runs averaged may change) and return them."""
    ok = n > 0
    lo = np.full(len(n), np.nan)
    hi = np.full(len(n), np.nan)
    for k in np.unique(n[ok]):  # one chi-square quantile pair per distinct run count
        lo[n == k], hi[n == k] = nees_band(dof, int(k))
    ax.plot(t, lo, color="k", ls="--", lw=0.9, label="95 % bounds")
    ax.plot(t, hi, color="k", ls="--", lw=0.9)
    ax.axhline(float(dof), color="0.6", lw=0.6)
    return lo, hi


def _finish(ax, vals: list[np.ndarray], ylabel: str, title: str, last_row: bool) -> None:
    v = np.concatenate(vals) if vals else np.array([])
    v = v[np.isfinite(v) & (v > 0)]
    if v.size and v.max() / v.min() > 20:  # an inconsistent filter: orders of magnitude
        ax.set_yscale("log")
    if last_row:
        ax.set_xlabel("time since first epoch [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize="medium")
    ax.grid(alpha=0.3, which="both")
    legend_outside(ax)


def anees_figure(ep: pd.DataFrame, filters: list[str], colors: dict, title: str, path: Path) -> Path | None:
    """ANEES per block (navigation and bias blocks) over time (a row per block), one line per filter,
    the 95 % bounds dashed (log scale when the values span more than a factor 20); the legend gives
    each filter's fraction of epochs inside the bounds. With the NCI columns, the block's NCI [dB]
    beside it. None without an ANEES."""
    out = anees_drawn(ep, filters, colors, title, path)
    return None if out is None else out.path


def anees_drawn(ep: pd.DataFrame, filters: list[str], colors: dict, title: str, path: Path) -> Drawn | None:
    """:func:`anees_figure` with the numbers drawn: panels ``anees <block>`` / ``nci <block>``, series =
    filter or ``lo`` / ``hi`` (the bounds), x time [s]."""
    import matplotlib.pyplot as plt

    blocks = anees_blocks(ep, biases=True)
    if not blocks:
        return None
    ep = ep[ep["epoch"] > 0]
    with_nci = any(nci_column(ep, c) for c, _ in blocks)
    ncols = 2 if with_nci else 1
    fig, axes = plt.subplots(len(blocks), ncols, figsize=(7.5 * ncols + 2.5, 2.9 * len(blocks) + 0.5),
                             squeeze=False, sharex=True)
    parts = []
    for k, (row, (col, label)) in enumerate(zip(axes, blocks)):
        ax, vals, first = row[0], [], None
        last = k == len(blocks) - 1
        for i, f in enumerate(filters):
            d = ep[ep["filter"] == f].sort_values("t")
            x = d[col].to_numpy(float)
            if not np.isfinite(x).any():
                continue
            n = d["n_runs"].to_numpy()
            first = d if first is None else first
            ax.plot(d["t"], x, color=colors.get(f), label=f"{f} ({share_text(inside_fraction(x, n), CONSISTENT_SHARE)} inside)",
                    **line_style(i))
            vals.append(x)
            parts.append(drawn_rows(f"anees {label}", f, d["t"], x))
        if first is not None:
            lo, hi = _bounds(ax, first["t"].to_numpy(float), first["n_runs"].to_numpy(), 3)
            parts += [drawn_rows(f"anees {label}", "lo", first["t"], lo),
                      drawn_rows(f"anees {label}", "hi", first["t"], hi)]
            vals += [lo, hi]
        _finish(ax, vals, f"ANEES, {label} (3 dof)", f"{label}: ANEES, 95 % bounds dashed", last)
        if with_nci:
            _nci_panel(row[1], ep, col, label, filters, colors, parts, last, legend=k == 0)
    fig.suptitle(title, fontsize="medium", y=1.005)
    return drawn(save_figure(fig, path), parts)


def _nci_panel(ax, ep: pd.DataFrame, anees_col: str, label: str, filters: list[str], colors: dict,
               parts: list[pd.DataFrame], last_row: bool, legend: bool) -> None:
    """One block's NCI [dB] over time per filter, 0 dB (credible) marked; the legend (the same in every
    row) only with ``legend``."""
    col = nci_column(ep, anees_col)
    if col is None:
        ax.set_visible(False)
        return
    for i, f in enumerate(filters):
        d = ep[ep["filter"] == f].sort_values("t")
        x = d[col].to_numpy(float)
        if np.isfinite(x).any():
            ax.plot(d["t"], x, color=colors.get(f), label=f, **line_style(i))
            parts.append(drawn_rows(f"nci {label}", f, d["t"], x))
    ax.axhline(0.0, color="k", lw=0.9, label="0 dB: credible")
    if last_row:
        ax.set_xlabel("time since first epoch [s]")
    ax.set_ylabel(f"NCI, {label} [dB]")
    ax.set_title(f"{label}: noncredibility index (> 0: optimistic)", fontsize="medium")
    ax.grid(alpha=0.3)
    if legend:
        legend_outside(ax)


def anis_sensors(ep: pd.DataFrame) -> list[str]:
    """The sensors with an ANIS (``nis_<sensor>_mean`` and ``nis_<sensor>_n``, some finite value)."""
    out = []
    for c in ep.columns:
        m = NIS_RE.match(c)
        if m and f"nis_{m.group(1)}_n" in ep.columns and np.isfinite(ep[c].to_numpy(float)).any():
            out.append(m.group(1))
    return out


def anis_figure(ep: pd.DataFrame, filters: list[str], colors: dict, dims: dict[str, int | None], title: str,
                path: Path) -> Drawn | None:
    """ANIS per sensor over time (a row per sensor of :func:`anis_sensors`), one line (or markers, for
    a sparse sensor) per filter at the epochs with a measurement, the 95 % bounds for the sensor's
    measurement size ``dims[sensor]`` dashed (none when it is None). ``data``: panels ``anis <sensor>``,
    series = filter, ``lo``, ``hi``. None without an ANIS."""
    import matplotlib.pyplot as plt

    sensors = anis_sensors(ep)
    if not sensors:
        return None
    fig, axes = plt.subplots(len(sensors), 1, figsize=(10, 2.9 * len(sensors) + 0.5), squeeze=False, sharex=True)
    parts = []
    for k, (ax, s) in enumerate(zip(axes[:, 0], sensors)):
        mean, cnt, dof = f"nis_{s}_mean", f"nis_{s}_n", dims.get(s)
        vals, first = [], None
        for i, f in enumerate(filters):
            d = ep[(ep["filter"] == f) & (ep[cnt] > 0)].sort_values("t")
            x = d[mean].to_numpy(float)
            if not np.isfinite(x).any():
                continue
            first = d if first is None else first
            frac = f", {share_text(inside_fraction(x, d[cnt].to_numpy(), dof), CONSISTENT_SHARE)} inside" if dof else ""
            style = line_style(i) | ({"ls": "none", "marker": "o", "ms": max(7 - 2 * i, 3)} if len(d) < 60 else {})
            ax.plot(d["t"], x, color=colors.get(f), label=f"{f}{frac}", **style)
            vals.append(x)
            parts.append(drawn_rows(f"anis {s}", f, d["t"], x))
        if first is not None and dof:
            lo, hi = _bounds(ax, first["t"].to_numpy(float), first[cnt].to_numpy(), dof)
            parts += [drawn_rows(f"anis {s}", "lo", first["t"], lo), drawn_rows(f"anis {s}", "hi", first["t"], hi)]
            vals += [lo, hi]
        dof_text = f"{dof} dof" if dof else "dof unknown: no bounds"
        _finish(ax, vals, f"ANIS, {s} ({dof_text})", f"{s}: ANIS at the epochs with a measurement",
                k == len(sensors) - 1)
    fig.suptitle(title, fontsize="medium", y=1.005)
    return drawn(save_figure(fig, path), parts)


__all__ = ["BIAS_BLOCKS", "BLOCKS", "anees_blocks", "anees_drawn", "anees_figure", "anis_figure", "anis_sensors",
           "inside_fraction", "nci_column"]
