"""``nespm report``: write the report of a results folder with the module of its experiment.

The manifest's ``experiment`` picks the module: ``gp-ukf`` -> :mod:`nespm_cli.reports.gp_ukf`;
otherwise a ``metrics.parquet`` with a ``param`` column is a sweep folder
(:mod:`nespm_cli.reports.sweep`) and anything else an ordinary Monte Carlo folder
(:mod:`nespm_cli.reports.mc`, which reports a missing or unreadable folder).
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

from nespm_cli.errors import NespmError
from nespm_cli.reports.gp_ukf import write_gp_report
from nespm_cli.reports.all_runs import ALL_RUNS
from nespm_cli.reports.mc import write_mc_report
from nespm_cli.reports.stats import PRACTICAL_PCT, check_practical_pct
from nespm_cli.reports.sweep import write_sweep_report
from nespm_cli.reports.tune.report import is_tune_folder, write_tune_report

__all__ = ["PRACTICAL_PCT", "experiment_of", "write_report"]


def experiment_of(out_dir: Path) -> str:
    """``"gp-ukf"``, ``"sweep"`` or ``"mc"``: which report a results folder gets."""
    out_dir = Path(out_dir)
    try:
        experiment = json.loads((out_dir / "manifest.json").read_text(encoding="utf-8")).get("experiment")
    except (OSError, ValueError, AttributeError):
        experiment = None  # the mc loader reports a missing or unreadable manifest
    if experiment == "gp-ukf":
        return "gp-ukf"
    try:  # schema only; an unreadable file is reported by the mc loader
        import pyarrow.parquet as pq

        is_sweep = "param" in pq.read_schema(out_dir / "metrics.parquet").names
    except Exception:
        is_sweep = False
    return "sweep" if is_sweep else "mc"


class UnfinishedWarning(UserWarning):
    """The folder is being written, or its experiment did not finish (one ``nespm: warning:`` line)."""


def warn_if_unfinished(out_dir: Path) -> None:
    """Say so when ``out_dir`` is being written by another process (e.g. extended to more runs)
    or its last run did not finish: the report then shows only the results assembled before."""
    from nespm_cli.experiments.store import writer_pid

    pid = writer_pid(out_dir)
    if pid is not None:
        warnings.warn(f"{out_dir}: another nespm process (pid {pid}) is writing this folder now; the report "
                      "shows the results assembled before it started; report again when it has finished",
                      UnfinishedWarning, stacklevel=3)
        return
    try:
        finished = json.loads((out_dir / "manifest.json").read_text(encoding="utf-8")).get("finished", True)
    except (OSError, ValueError, AttributeError, RecursionError):
        return
    if finished is None and (out_dir / "metrics.parquet").exists():
        warnings.warn(f"{out_dir}: its last run did not finish (interrupted?); the report shows the results "
                      "assembled before; re-run the same command to complete it", UnfinishedWarning, stacklevel=3)


def write_report(out_dir: Path, reference: str | None = None, n_boot: int = 2000,
                 practical_pct: float = PRACTICAL_PCT, beside=(), all_runs: str = "median",
                 consistent_share: float | None = None, figure_jobs: int | None = 1) -> Path:
    """Write ``out_dir/report.md`` and its figures; return the report path.

    ``reference`` is the mc report's reference filter and the sweep report's baseline (it does
    not apply to a GP-UKF folder); ``practical_pct`` [%] (default :data:`PRACTICAL_PCT`) is the
    smallest |improvement| the verdict calls practically meaningful. The bootstrap seed is 0.
    ``beside``: other Monte Carlo folders set beside an mc folder's numbers. ``all_runs``: with
    ``median`` (default), where a run was lost, the comparison over every run with lost runs ranked
    worst (:mod:`nespm_cli.reports.all_runs`); ``none`` leaves it out. ``consistent_share``: the least
    share of epochs inside the bounds for a block or sensor to be consistent (an mc folder's report;
    default :data:`~nespm_cli.reports.block_consistency.CONSISTENT_SHARE`). ``figure_jobs``: processes
    drawing an mc folder's figures (default 1: here; None: 2 where the machine has two cores and the folder two
    tracks or more, what ``nespm report`` does: :mod:`nespm_cli.reports.figure_worker`); the same files.
    """
    if all_runs not in ALL_RUNS:
        raise NespmError(f"--all-runs: choose {' or '.join(ALL_RUNS)}, got {all_runs!r}")
    check_practical_pct(practical_pct)
    from nespm_cli.reports.results import check_n_boot

    check_n_boot(n_boot)
    out_dir = Path(out_dir)
    if is_tune_folder(out_dir):  # nespm tune (reports/tune/report.py)
        return write_tune_report(out_dir, n_boot=n_boot)
    if out_dir.is_dir():
        from nespm_cli.reports.results import check_figures_dir

        check_figures_dir(out_dir)  # never drawn through an OUT/figures link
    warn_if_unfinished(out_dir)
    kind = experiment_of(out_dir)
    if consistent_share is not None and kind != "mc":
        raise NespmError(f"--consistent-share: the report of a {kind} folder judges no per-block consistency; "
                         "leave the option out")
    if kind == "gp-ukf":
        return write_gp_report(out_dir, n_boot=n_boot)  # --baseline does not apply
    if kind == "sweep":
        return write_sweep_report(out_dir, reference, n_boot=n_boot, practical_pct=practical_pct, all_runs=all_runs)
    from nespm_cli.reports.innovation import is_truth_free, write_innovation_report

    if is_truth_free(out_dir):  # a track spec without [gt]: innovation statistics only
        return write_innovation_report(out_dir)
    for b in beside:
        if experiment_of(Path(b)) != "mc":
            raise NespmError(f"--beside {b}: not a folder written by 'nespm mc'")
    share = {} if consistent_share is None else {"consistent_share": consistent_share}
    return write_mc_report(out_dir, reference, n_boot=n_boot, practical_pct=practical_pct, beside=beside,
                           all_runs=all_runs, figure_jobs=figure_jobs, **share)
