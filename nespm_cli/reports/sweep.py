"""Report of an error-regime sweep folder (``nespm sweep ... --out DIR``): :func:`write_sweep_report`.

For each swept value and filter the report gives the track-averaged VRMSE and MRMSE (anukf.md eqs
50-52), the mean NEES and the divergence rate, each with a 95 % interval, and the improvement of
each filter over a baseline filter with a paired bootstrap interval; a verdict per value names the
best filter from head-to-head paired comparisons. The pieces live in their own modules, re-exported
here: :mod:`~nespm_cli.reports.sweep_data` (loading, parameter, baseline),
:mod:`~nespm_cli.reports.sweep_tables`, :mod:`~nespm_cli.reports.sweep_figures`,
:mod:`~nespm_cli.reports.sweep_markdown`.
"""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.reports.figures import use_log_x, use_log_y
from nespm_cli.reports.stats import PRACTICAL_PCT, wilson_interval
from nespm_cli.reports.sweep_data import (
    DEFAULT_BASELINE,
    check_sweep_metrics,
    default_baseline,
    load_sweep,
    sweep_values,
)
from nespm_cli.reports.sweep_figures import plot_sweep_figures
from nespm_cli.reports.efficiency_runs import needs_series, series_files
from nespm_cli.reports.pcrb import SECTION as PCRB_SECTION, pcrb_md
from nespm_cli.reports.sweep_markdown import render_sweep_report
from nespm_cli.reports.sweep_tables import (
    filter_bootstrap,
    improvement_points,
    improvement_table,
    nees_runs,
    summary_rows,
    sweep_table,
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
    "summary_rows",
    "plot_sweep_figures",
    "render_sweep_report",
    "write_sweep_report",
]


def write_sweep_report(out_dir: Path, baseline: str | None = None, n_boot: int = 2000,
                       practical_pct: float = PRACTICAL_PCT, all_runs: str = "median") -> Path:
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
                               practical_pct=practical_pct, all_runs=all_runs)
    epochs_path = out_dir / "epochs.parquet"  # the bound per swept value (docs/pcrb.md)
    epochs = pd.read_parquet(epochs_path) if epochs_path.is_file() else None
    files = series_files(out_dir, manifest) if needs_series(epochs) else ()
    text = text.rstrip("\n") + f"\n\n{PCRB_SECTION}\n\n{pcrb_md(epochs, manifest, metrics, files)}\n"
    path = out_dir / "report.md"
    write_text_atomic(path, text)
    return path
