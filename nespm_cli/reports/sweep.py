"""Report of an error-regime sweep folder (``nespm sweep ... --out DIR``).

A sweep folder has the schema of ``docs/results-schema.md`` plus two leading columns
``param`` (str) and ``value`` (float). The same run index is the same realization across
filters and values, so per value the comparison of two filters is paired.

For each swept value and filter the report gives the track-averaged VRMSE and MRMSE
(anukf.md eqs 50-52), the mean NEES and the divergence rate, each with a 95 % interval, and
the improvement of each filter over a baseline filter with a paired bootstrap interval; a
summary per value names the best filter from head-to-head paired comparisons
(:func:`nespm_cli.reports.mc.compare_filters`). The equations and the bootstraps are those of
:mod:`nespm_cli.reports.stats`, the formatting and markdown those of
:mod:`nespm_cli.reports.markdown`; the improvement table and the improvement figure both read
:func:`improvement_points`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.figures import filter_colors, save_figure
from nespm_cli.reports.markdown import DASH, SIG_MARK, SMALL_MARK, fmt, fmt_imprv, header_line, md_table
from nespm_cli.reports.mc import compare_filters, filter_table, verdict_headline
from nespm_cli.reports.results import (
    METRICS_COLUMNS,
    check_metrics,
    filters_in_order,
    read_results_folder,
    require_columns,
    runs_per_track,
    scenario_of,
    unique_text,
)
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    NEES_DOF,
    PRACTICAL_PCT,
    ci_marks,
    lost_by_any,
    interval_mark,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    resample_counts,
    rmse,
    track_average,
    track_rng,
    wilson_interval,
)

__all__ = [
    "DEFAULT_BASELINE",
    "load_sweep",
    "check_sweep_metrics",
    "sweep_values",
    "default_baseline",
    "wilson_interval",
    "use_log_x",
    "use_log_y",
    "filter_bootstrap",
    "sweep_table",
    "improvement_table",
    "improvement_points",
    "nees_runs",
    "plot_sweep_figures",
    "render_sweep_report",
    "write_sweep_report",
]

DEFAULT_BASELINE = "ekf"
SWEEP_COLUMNS: tuple[str, ...] = ("param", "value")

# metric key -> (display name, unit, y-axis label); VRMSE/MRMSE as stats.METRICS
_ALL_METRICS: dict[str, tuple[str, str, str]] = {
    "vrmse": ("VRMSE", "m/s", "VRMSE [m/s]"),
    "mrmse": ("MRMSE", "rad", "MRMSE [rad]"),
    "nees": ("mean NEES", "", "mean NEES (6 DOF) [-]"),
    "div_rate": ("divergence rate", "", "divergence rate (diverged runs / runs) [-]"),
}


# ----------------------------------------------------------------------------- loading


def check_sweep_metrics(metrics: pd.DataFrame, where: object = "metrics") -> None:
    """Validate a sweep metrics table: columns, one parameter, finite values and, per
    value, the (track, filter, run) uniqueness of :func:`results.check_metrics`."""
    require_columns(metrics, SWEEP_COLUMNS + METRICS_COLUMNS, where)
    if metrics.empty:
        raise NespmError(f"{where}: no rows")
    params = [str(p) for p in pd.unique(metrics["param"])]
    if len(params) != 1:
        raise NespmError(f"{where}: expected one swept parameter, found {', '.join(params)}")
    values = metrics["value"].to_numpy(dtype=float)
    if not np.all(np.isfinite(values)):
        raise NespmError(f"{where}: non-finite swept value")
    for v, sub in metrics.groupby("value", sort=True):
        check_metrics(sub, f"{where} (value {v:g})")


def load_sweep(out_dir: Path) -> tuple[pd.DataFrame, dict]:
    """Read and validate ``metrics.parquet`` and ``manifest.json`` (optional) of a sweep folder."""
    metrics, manifest = read_results_folder(Path(out_dir), "sweep")
    check_sweep_metrics(metrics, Path(out_dir) / "metrics.parquet")
    return metrics, manifest


def sweep_values(metrics: pd.DataFrame) -> list[float]:
    """The swept values, ascending."""
    return sorted(float(v) for v in pd.unique(metrics["value"]))


def _param(metrics: pd.DataFrame) -> str:
    return str(metrics["param"].iloc[0])


def _param_label(param: str) -> str:
    """Axis label with unit from ``sweep.PARAMS``, else the parameter name."""
    try:
        from nespm_cli.experiments.sweep import PARAMS
    except Exception:  # pragma: no cover - sweep.py imports the experiment machinery
        return param
    return PARAMS[param].label if param in PARAMS else param


def default_baseline(metrics: pd.DataFrame, baseline: str | None = None) -> str:
    """``baseline`` if given (must be a filter of the results), else ``ekf`` if present,
    else the first filter."""
    names = filters_in_order(metrics)
    if baseline:
        if baseline not in names:
            raise NespmError(
                f"--baseline: unknown filter '{baseline}': the results hold {', '.join(names)}"
            )
        return baseline
    return DEFAULT_BASELINE if DEFAULT_BASELINE in names else names[0]


# ----------------------------------------------------------------------------- statistics


def use_log_x(values: Sequence[float]) -> bool:
    """Log x-axis when every value is positive and max / min > 100."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    return bool(v.size > 1 and v.min() > 0 and v.max() / v.min() > 100)


def use_log_y(values: Sequence[float] | np.ndarray) -> bool:
    """Log y-axis when the finite positive values span more than one decade."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v) & (v > 0)]
    return bool(v.size > 1 and v.max() / v.min() > 10)


def filter_bootstrap(
    metrics: pd.DataFrame, filt: str, n_boot: int = 2000, seed: int = 0
) -> dict[str, np.ndarray]:
    """Bootstrap replicates of one filter's track-averaged VRMSE, MRMSE and mean NEES.

    ``metrics`` holds one swept value. Per track, the non-diverged runs of ``filt`` are
    resampled with replacement (vectorized multiplicities, as in
    :func:`stats.paired_bootstrap`, with the same ``(seed, track)`` streams); eqs 50-52
    are recomputed per track and averaged over tracks (eq 51); the NEES is the mean over the
    resampled runs of all tracks. VRMSE/MRMSE replicates are NaN when some track has no
    non-diverged run; NEES replicates are NaN when no run has a finite NEES (``ins``).
    """
    keys = list(METRICS) + ["nees"]
    out = {k: np.full(max(n_boot, 0), np.nan) for k in keys}
    d = metrics[(metrics["filter"] == filt) & ~lost_by_any(metrics)]  # the runs no filter lost
    if d.empty or n_boot < 1:
        return out
    per_track: dict[str, list[np.ndarray]] = {k: [] for k in METRICS}
    complete = True
    nees_sum = np.zeros(n_boot)
    nees_cnt = np.zeros(n_boot)
    for track in sorted(pd.unique(d["track"])):
        t = d[d["track"] == track].sort_values("run")
        if len(t) == 0:
            complete = False
            continue
        counts = resample_counts(len(t), n_boot, track_rng(seed, track))
        for key, (sse_col, _, _) in METRICS.items():
            per_track[key].append(rmse(t[sse_col], t["n_samples"], counts))
        nees = t["nees"].to_numpy(float)
        fin = np.isfinite(nees)
        nees_sum += counts[:, fin] @ nees[fin]
        nees_cnt += counts[:, fin].sum(axis=1)
    if complete:
        for key in METRICS:
            out[key] = track_average(per_track[key])
    with np.errstate(divide="ignore", invalid="ignore"):
        out["nees"] = np.where(nees_cnt > 0, nees_sum / np.where(nees_cnt > 0, nees_cnt, 1), np.nan)
    return out


def sweep_table(metrics: pd.DataFrame, n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """One row per (value, filter), values ascending, filters in order of appearance.

    Columns: ``value``, ``filter``; ``vrmse``, ``mrmse`` (track average, eqs 50-52, over the
    non-diverged runs, as :func:`mc.filter_table`) and ``nees`` (mean per-run NEES of the
    non-diverged runs), each with ``<key>_lo`` / ``<key>_hi`` (95 % bootstrap percentile
    interval, :func:`filter_bootstrap`); ``diverged``, ``runs``, ``div_rate`` =
    diverged / runs with its 95 % Wilson interval ``div_rate_lo`` / ``div_rate_hi``.
    A filter absent at a value gets NaN metrics and 0 runs.
    """
    check_sweep_metrics(metrics)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    filters = filters_in_order(metrics)
    rows = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v]
        ft = filter_table(sub, None, n_boot=0, seed=seed).set_index("filter")
        for f in filters:
            row: dict[str, Any] = {"value": v, "filter": f}
            if f in ft.index:
                r = ft.loc[f]
                boot = filter_bootstrap(sub, f, n_boot=n_boot, seed=seed)
                for key in ("vrmse", "mrmse", "nees"):
                    row[key] = float(r[key])
                    row[f"{key}_lo"], row[f"{key}_hi"] = percentile_ci(boot[key])
                k, n = int(r["diverged"]), int(r["runs"])
            else:
                for key in ("vrmse", "mrmse", "nees"):
                    row[key] = row[f"{key}_lo"] = row[f"{key}_hi"] = math.nan
                k, n = 0, 0
            row["diverged"], row["runs"] = k, n
            row["div_rate"] = k / n if n else math.nan
            row["div_rate_lo"], row["div_rate_hi"] = wilson_interval(k, n)
            rows.append(row)
    return pd.DataFrame(rows)


def improvement_table(
    metrics: pd.DataFrame,
    baseline: str | None = None,
    n_boot: int = 2000,
    seed: int = 0,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> pd.DataFrame:
    """Improvement of each non-baseline filter over the baseline, per value, percent.

    ``100 · (metric_baseline − metric_filter) / metric_baseline`` (positive = the filter is
    better) for VRMSE and MRMSE over the runs that diverged in neither filter (so a filter
    is not credited for the runs its baseline lost); ``<key>_ci_lo`` / ``<key>_ci_hi`` is the 95 % paired
    bootstrap interval of :func:`stats.paired_bootstrap` (runs diverged in neither filter,
    the same resample for both) and ``<key>_ci_excludes_0`` flags an interval without 0;
    ``pairs_min`` is the fewest paired runs on a track and ``<key>_significant`` = excludes 0
    and ``pairs_min >= min_pairs``. ``attrs["baseline"]`` names the baseline. This table is
    the only source of the improvements of the sweep report's table and figure.
    """
    base = default_baseline(metrics, baseline)
    rows = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v]
        for f in filters_in_order(metrics):
            if f == base:
                continue
            row: dict[str, Any] = {"value": v, "filter": f}
            boot = paired_bootstrap(sub, base, f, n_boot=n_boot, seed=seed)
            paired = paired_improvement(sub, base, f)  # on the runs diverged in neither, as the interval
            counts = paired_run_counts(sub, base, f)
            row["pairs_min"] = min(counts.values()) if counts else 0
            for key in METRICS:
                row[f"{key}_imprv"] = paired[key]
                lo, hi = percentile_ci(boot[key])
                row[f"{key}_ci_lo"], row[f"{key}_ci_hi"] = lo, hi
                excludes, significant, _ = ci_marks(lo, hi, row["pairs_min"], min_pairs)
                row[f"{key}_ci_excludes_0"] = excludes
                row[f"{key}_significant"] = significant
            rows.append(row)
    cols = ["value", "filter", "pairs_min"] + [
        f"{k}_{s}" for k in METRICS for s in ("imprv", "ci_lo", "ci_hi", "ci_excludes_0", "significant")
    ]
    out = pd.DataFrame(rows, columns=cols)
    out.attrs["baseline"] = base
    out.attrs["min_pairs"] = int(min_pairs)
    return out


def improvement_points(imp: pd.DataFrame, key: str, filt: str) -> pd.DataFrame:
    """The points of one filter's improvement curve, values ascending: ``value``, ``imprv``,
    ``ci_lo``, ``ci_hi``, ``significant``, ``mark`` (``*``, ``†`` or ``""``). Both the
    improvement table and the improvement figure are drawn from this (one run set: the pairs)."""
    min_pairs = imp.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    d = imp[imp["filter"] == filt].sort_values("value")
    small = d["pairs_min"].to_numpy(int) < min_pairs if "pairs_min" in d else np.zeros(len(d), bool)
    sig = (d[f"{key}_significant"] if f"{key}_significant" in d else d[f"{key}_ci_excludes_0"]).to_numpy(bool)
    return pd.DataFrame({
        "value": d["value"].to_numpy(float),
        "imprv": d[f"{key}_imprv"].to_numpy(float),
        "ci_lo": d[f"{key}_ci_lo"].to_numpy(float),
        "ci_hi": d[f"{key}_ci_hi"].to_numpy(float),
        "significant": sig,
        "mark": np.where(small, SMALL_MARK, np.where(sig, SIG_MARK, "")),
    })


def summary_rows(
    metrics: pd.DataFrame, n_boot: int = 2000, seed: int = 0, practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
) -> pd.DataFrame:
    """:func:`mc.compare_filters` per swept value (column ``value`` first)."""
    parts = []
    for v in sweep_values(metrics):
        sub = metrics[metrics["value"] == v].drop(columns=["param", "value"])
        c = compare_filters(sub, n_boot=n_boot, seed=seed, practical_pct=practical_pct, min_pairs=min_pairs)
        parts.append(c.assign(value=v)[["value"] + list(c.columns)])
    return pd.concat(parts, ignore_index=True)


def nees_runs(metrics: pd.DataFrame) -> int:
    """Realizations per value, i.e. distinct (track, run) pairs (the largest over values)."""
    n = metrics.groupby("value")[["track", "run"]].apply(lambda d: len(d.drop_duplicates()))
    return int(n.max())


# ----------------------------------------------------------------------------- figures


def _protocol(metrics: pd.DataFrame, manifest: dict) -> str:
    """``schedule …, scenario …, DVL …, IMU …`` from the metrics columns / manifest options."""
    options = manifest.get("options") or {}
    parts = []
    if "schedule" in metrics.columns:
        parts.append(f"schedule {unique_text(metrics['schedule'])}")
    elif options.get("schedule"):
        parts.append(f"schedule {options['schedule']}")
    scen = scenario_of(metrics, manifest)
    if scen:
        parts.append(f"scenario {scen}")
    if options.get("dvl"):
        parts.append(f"DVL {options['dvl']}")
    if options.get("imu"):
        parts.append(f"IMU {options['imu']}")
    return ", ".join(parts)


def _subtitle(metrics: pd.DataFrame, manifest: dict) -> str:
    tracks = ", ".join(str(t) for t in sorted(pd.unique(metrics["track"])))
    s = "track" if metrics["track"].nunique() == 1 else "tracks"
    text = f"{s} {tracks} · {runs_per_track(metrics)} runs per track"
    proto = _protocol(metrics, manifest)
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (after selecting the backend)

    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    filters = filters_in_order(metrics)
    colors = filter_colors(filters)
    param = _param(metrics)
    xlabel = _param_label(param)
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


# ----------------------------------------------------------------------------- markdown


def _cell(v: float, lo: float, hi: float, spec: str = ".4g") -> str:
    """``value [lo, hi]``; just the value when the interval is undefined; dash for NaN."""
    if not np.isfinite(v):
        return DASH
    if np.isfinite(lo) and np.isfinite(hi):
        return f"{fmt(v, spec)} [{fmt(lo, spec)}, {fmt(hi, spec)}]"
    return fmt(v, spec)


def _metric_md(table: pd.DataFrame, key: str, filters: Sequence[str], xlabel: str) -> str:
    rows = []
    for v, d in table.groupby("value", sort=True):
        d = d.set_index("filter")
        cells = [f"{v:g}"]
        for f in filters:
            r = d.loc[f]
            if key == "div_rate":
                cells.append(DASH if r["runs"] == 0 else
                             f"{_cell(r['div_rate'], r['div_rate_lo'], r['div_rate_hi'], '.2f')} "
                             f"({int(r['diverged'])}/{int(r['runs'])})")
            else:
                spec = ".2f" if key == "nees" and abs(r[key]) < 100 else ".4g"
                cells.append(_cell(r[key], r[f"{key}_lo"], r[f"{key}_hi"], spec))
        rows.append(cells)
    return md_table([xlabel] + list(filters), rows)


def _improvement_md(imp: pd.DataFrame, key: str, filters: Sequence[str], xlabel: str) -> str:
    """Rows = values, columns = filters: ``point % [lo, hi] mark`` from :func:`improvement_points`."""
    values = sorted(pd.unique(imp["value"]))
    cols = {f: improvement_points(imp, key, f).set_index("value") for f in filters}
    rows = []
    for v in values:
        cells = [f"{v:g}"]
        for f in filters:
            r = cols[f].loc[v]
            cells.append(fmt_imprv(r["imprv"], r["ci_lo"], r["ci_hi"], r["mark"]))
        rows.append(cells)
    return md_table([xlabel] + list(filters), rows)


_SHORT_VERDICT = {
    "better": "meaningful",
    "worse": "meaningful (the other is better)",
    "no practical difference": "no practical difference",
    "not significant": "not significant",
    "too few runs": "too few paired runs",
    "undefined": "undefined",
}


def _summary_md(comps: pd.DataFrame, practical_pct: float, min_pairs: int) -> str:
    """Per value and metric: the best filter (head to head, paired) and each comparison."""
    p = f"{practical_pct:g} %"
    intro = (
        f"Per value, head to head on the runs both filters kept: the best filter and its paired "
        f"improvement 100 · (other − best) / other [95 % CI] over each other filter. *meaningful* = "
        f"the interval excludes 0 (with at least {min_pairs} paired runs per track, else "
        f"`{SMALL_MARK}` and \"too few paired runs\") and |improvement| ≥ {p}; *no practical "
        f"difference* = |improvement| < {p}, significant or not."
    )
    names = {"vrmse": "VRMSE", "mrmse": "MRMSE", "hpe": "RMS HPE"}
    rows = []
    for v, cv in comps.groupby("value", sort=True):
        for key in pd.unique(cv["metric"]):
            c = cv[cv["metric"] == key]
            first = c.iloc[0]
            if first["best"] is None:
                rows.append([f"{v:g}", names[key], "undefined (every run diverged on some track)", DASH])
                continue
            if first["verdict"] == "only filter":
                rows.append([f"{v:g}", names[key], f"only `{first['best']}`", DASH])
                continue
            cells = []
            for r in c.itertuples(index=False):
                mark = interval_mark(r.significant, r.pairs_min, min_pairs)
                cells.append(f"vs `{r.other}` {fmt_imprv(r.imprv, r.ci_lo, r.ci_hi, mark)} "
                             f"{_SHORT_VERDICT[r.verdict]}")
            rows.append([f"{v:g}", names[key], verdict_headline(c), "; ".join(cells)])
    return intro + "\n\n" + md_table(["value", "metric", "verdict", "best vs each other filter"], rows)


def render_sweep_report(
    metrics: pd.DataFrame,
    manifest: dict,
    table: pd.DataFrame,
    imp: pd.DataFrame,
    figures: Sequence[Path],
    out_dir: Path,
    n_boot: int,
    seed: int,
    practical_pct: float = PRACTICAL_PCT,
    comps: pd.DataFrame | None = None,
) -> str:
    """The full markdown text of a sweep's ``report.md`` (``comps``: :func:`summary_rows`,
    computed here when not given)."""
    min_pairs = imp.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    if comps is None:
        comps = summary_rows(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                             min_pairs=min_pairs)
    param = _param(metrics)
    label = _param_label(param)
    values = sweep_values(metrics)
    filters = filters_in_order(metrics)
    base = imp.attrs["baseline"]
    others = [f for f in filters if f != base]
    n = nees_runs(metrics)
    blo, bhi = nees_band(NEES_DOF, n)
    proto = _protocol(metrics, manifest)
    figs = {Path(p).stem: Path(p).relative_to(out_dir).as_posix() for p in figures}

    def fig(stem: str) -> str:
        return f"\n\n![{stem}]({figs[stem]})" if stem in figs else ""

    header = (
        f"**Sweep:** parameter `{param}` ({label}); values {', '.join(f'{v:g}' for v in values)}; "
        f"baseline `{base}`" + (f"; protocol: {proto}" if proto else "") + "."
    )
    div_lines = []
    for r in table[table["diverged"] > 0].itertuples(index=False):  # values ascending
        if r.diverged == r.runs:
            div_lines.append(f"- value {r.value:g}, `{r.filter}`: every run diverged "
                             f"({r.diverged}/{r.runs}); its error metrics are undefined ({DASH}).")
        else:
            div_lines.append(f"- value {r.value:g}, `{r.filter}`: {r.diverged} of {r.runs} runs "
                             "diverged (lost) and are left out of every filter's error metrics.")
    div_text = "\n".join(div_lines) if div_lines else "No run diverged."
    definitions = f"""## Definitions

- Each value is one paired Monte Carlo experiment; run `r` of track `N` is the same realization
  (the same standard normals, scaled by the value) for every filter and every value.
- **VRMSE** (anukf.md eq 50) per track: `sqrt(sum(sse_vel) / sum(n_samples))` over the runs that
  no filter lost at that value (every filter judged on the same runs; a filter that lost every
  run of a track is left out of that rule); **MRMSE** (eq 52) likewise with `sse_att`; both
  averaged over tracks as `sqrt(mean over tracks of RMSE_track²)` (eq 51). **mean NEES**: mean
  of the per-run, epoch-averaged 6-DOF NEES of `[δv, δψ]` over those runs.
  **Divergence rate**: the filter's lost runs / runs (all tracks): a non-finite state, a speed
  above 50 m/s or an attitude error above `--diverge-att-deg`. A run failing only the NEES test
  is *inconsistent*, not lost: it keeps its errors.
- **Intervals** `[lo, hi]`: 95 % bootstrap percentile intervals ({n_boot} resamples, seed {seed});
  the runs of each track are resampled with replacement and the metric recomputed. The
  divergence rate has a 95 % Wilson score interval.
- **Improvement over `{base}`**: `100 · (metric_{base} − metric_filter) / metric_{base}`; positive
  means the filter has the smaller error. Point and interval are over the runs that diverged in
  neither the filter nor `{base}` (the pairs), in the table and the figure alike (both read the
  same `improvement_points`). Its interval is a *paired* bootstrap: per track, the pairs are
  resampled and the same resample is used for both filters. `{SIG_MARK}` marks an interval that
  excludes 0; `{SMALL_MARK}` an interval from fewer than {min_pairs} paired runs on some track, where the
  percentile bootstrap is unreliable and no significance is claimed. With divergences two
  filters' improvements over `{base}` are over different pairs and the per-filter VRMSE table over
  each filter's own runs, so they need not rank two filters alike: the **Summary** compares every
  two filters head to head on their own pairs.
- **Practically meaningful**: |improvement| ≥ {practical_pct:g} % (`practical_pct`); below it the
  Summary says "no practical difference" even when the interval excludes 0.
"""
    sections = [
        f"# nespm sweep report: {param}",
        header,
        header_line(metrics, manifest),
        "## Summary\n\n" + _summary_md(comps, practical_pct, min_pairs),
        definitions.rstrip(),
        "## Track-averaged VRMSE [m/s] (eqs 50–51)\n\n"
        + _metric_md(table, "vrmse", filters, label) + fig("sweep_vrmse"),
        "## Track-averaged MRMSE [rad] (eqs 51–52)\n\n"
        + _metric_md(table, "mrmse", filters, label) + fig("sweep_mrmse"),
        "## Mean NEES (6 DOF)\n\n"
        f"95 % consistency band for {n} runs: **[{blo:.2f}, {bhi:.2f}]** "
        f"(`nees_band(6, {n})`, i.e. χ²₍{NEES_DOF * n}₎ quantiles / {n}). It is the band of one "
        f"epoch's NEES averaged over {n} runs of a consistent filter, so a filter whose mean NEES "
        "lies above it is overconfident (its covariance is too small) and one below it is "
        "conservative; the per-run epoch average shown here fluctuates less than one epoch's "
        "mean, so the band is a lenient test.\n\n"
        + _metric_md(table, "nees", filters, label) + fig("sweep_nees"),
        "## Divergences\n\nRate `diverged / runs` [95 % Wilson interval] (count).\n\n"
        + _metric_md(table, "div_rate", filters, label) + "\n\n" + div_text + fig("sweep_divergence"),
        f"## Improvement over `{base}` [%] (paired 95 % interval)\n\n"
        + ("**VRMSE**\n\n" + _improvement_md(imp, "vrmse", others, label)
           + "\n\n**MRMSE**\n\n" + _improvement_md(imp, "mrmse", others, label)
           if others else "Only one filter: no improvement to show.")
        + fig("sweep_improvement"),
    ]
    return "\n\n".join(sections) + "\n"


# ----------------------------------------------------------------------------- entry point


def write_sweep_report(out_dir: Path, baseline: str | None = None, n_boot: int = 2000,
                       practical_pct: float = PRACTICAL_PCT) -> Path:
    """Write ``out_dir/report.md`` and ``out_dir/figures/sweep_*.png`` for a sweep folder;
    return the report path. The bootstrap seed is 0; ``practical_pct`` as in
    :func:`dispatch.write_report`."""
    out_dir = Path(out_dir)
    metrics, manifest = load_sweep(out_dir)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    seed = 0
    base = default_baseline(metrics, baseline)
    table = sweep_table(metrics, n_boot=n_boot, seed=seed)
    imp = improvement_table(metrics, base, n_boot=n_boot, seed=seed)
    figures = plot_sweep_figures(metrics, manifest, table, imp, out_dir / "figures")
    text = render_sweep_report(metrics, manifest, table, imp, figures, out_dir, n_boot, seed,
                               practical_pct=practical_pct)
    path = out_dir / "report.md"
    write_text_atomic(path, text)
    return path
