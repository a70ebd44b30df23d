"""Report of a Monte Carlo results folder (``nespm mc``): :func:`write_mc_report` reads the folder,
computes the tables, draws the figures and writes ``report.md``.

The pieces live in their own modules, re-exported here for the code that imports them from
``nespm_cli.reports.mc``: :mod:`~nespm_cli.reports.tables` (per-filter tables, eqs 50-53),
:mod:`~nespm_cli.reports.comparisons` (head-to-head paired comparisons),
:mod:`~nespm_cli.reports.wording`, :mod:`~nespm_cli.reports.mc_markdown` and
:mod:`~nespm_cli.reports.mc_figures`. :func:`nespm_cli.reports.dispatch.write_report` picks this
module for an ordinary Monte Carlo folder; docs/report.md defines every column and figure.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.experiments.progress import phase
from nespm_cli.reports.block_consistency import CONSISTENT_SHARE, block_consistency, check_share
from nespm_cli.reports.comparisons import compare_filters
from nespm_cli.reports.figure_worker import FigureWorker, figure_processes
from nespm_cli.reports.mc_figures import figure_notes, plot_track_figures
from nespm_cli.reports.efficiency_runs import needs_series, series_files
from nespm_cli.reports.pcrb import pcrb_md
from nespm_cli.reports.mc_markdown import beside_md, folder_label, render_report
from nespm_cli.reports.results import load_results, scenario_of
from nespm_cli.reports.stats import PRACTICAL_PCT, check_practical_pct
from nespm_cli.reports.tables import (
    DEFAULT_REFERENCE,
    default_reference,
    filter_table,
    horizontal_table,
    nees_consistency,
    track_table,
)
from nespm_cli.reports.verdict import verdict_table
from nespm_cli.reports.wording import verdict_headline

__all__ = [
    "DEFAULT_REFERENCE",
    "default_reference",
    "track_table",
    "filter_table",
    "horizontal_table",
    "compare_filters",
    "nees_consistency",
    "verdict_headline",
    "verdict_table",
    "render_report",
    "plot_track_figures",
    "beside_md",
    "folder_label",
    "write_mc_report",
]


def write_mc_report(out_dir: Path, reference: str | None = None, n_boot: int = 2000,
                    practical_pct: float = PRACTICAL_PCT, beside: Sequence[Path] = (), all_runs: str = "median",
                    consistent_share: float = CONSISTENT_SHARE, figure_jobs: int | None = 1) -> Path:
    """Write ``out_dir/report.md`` and ``out_dir/figures/*.png`` of a Monte Carlo folder; return the
    report path.

    Figures are skipped when ``epochs.parquet`` is absent. The bootstrap seed is 0.
    ``reference`` is the filter whose improvement over each row is shown (:func:`default_reference`);
    ``practical_pct`` [%] (default :data:`PRACTICAL_PCT`) is the smallest |improvement| the
    verdict calls practically meaningful. ``beside``: other Monte Carlo folders whose numbers
    are set beside this one's (:func:`beside_md`), e.g. the synthetic-IMU run of a recorded one.
    ``consistent_share``: the least share of epochs inside the bounds for a block to be consistent
    (:mod:`~nespm_cli.reports.block_consistency`). ``figure_jobs``: processes drawing the figures, 1 (default:
    here) or 2 (the later half of the tracks in a second process), None: 2 where the machine has two cores and
    the folder two tracks or more (:func:`~nespm_cli.reports.figure_worker.figure_processes`; ``nespm report``);
    the same files either way.
    """
    check_share(consistent_share)
    check_practical_pct(practical_pct)
    out_dir = Path(out_dir)
    phase("reading the results")
    metrics, epochs, manifest = load_results(out_dir)
    others = []
    for b in beside:
        m_b, _, man_b = load_results(Path(b))
        others.append((folder_label(Path(b), man_b), m_b))
    beside_text = (beside_md(metrics, folder_label(out_dir, manifest), others, scenario_of(metrics, manifest))
                   if others else "")
    seed = 0
    figures: list[Path] = []
    drawing = epochs is not None and not epochs.empty
    fig_args = (epochs, metrics, out_dir / "figures", scenario_of(metrics, manifest), manifest)
    tracks = sorted(epochs["track"].unique()) if drawing else []
    mine, theirs, worker = None, [], None
    if figure_processes(figure_jobs, len(tracks)) > 1:  # the later half of the tracks in a second process
        mine, theirs = tracks[:(len(tracks) + 1) // 2], tracks[(len(tracks) + 1) // 2:]
        worker = FigureWorker(plot_track_figures, *fig_args, theirs)
    phase(f"tables and paired bootstrap intervals ({n_boot} resamples)")
    table = filter_table(metrics, reference, n_boot=n_boot, seed=seed)
    tt = track_table(metrics)
    if drawing:
        figures = plot_track_figures(*fig_args, mine)
    phase("consistency, the PCRB and the pairwise comparisons")  # while the second process draws (if it still does)
    comps = compare_filters(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct)
    consistency = block_consistency(epochs, manifest, share=consistent_share)
    consistency_by_track = block_consistency(epochs, manifest, by_track=True, share=consistent_share)
    pcrb = pcrb_md(epochs, manifest, metrics, series_files(out_dir, manifest) if needs_series(epochs) else ())
    if worker is not None:
        phase("figures: waiting for the second process")
        drawn = worker.result()
        figures += drawn if drawn is not None else plot_track_figures(*fig_args, theirs)
    phase("verdict and report.md")
    text = render_report(metrics, manifest, table, tt, figures, out_dir, n_boot, seed,
                         practical_pct=practical_pct, beside=beside_text, all_runs=all_runs,
                         notes=figure_notes(epochs, metrics, manifest), consistency=consistency,
                         consistency_by_track=consistency_by_track, pcrb=pcrb, comps=comps)
    path = out_dir / "report.md"
    write_text_atomic(path, text)
    return path
