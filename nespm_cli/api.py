"""The Python API: what the ``nespm`` command does, as functions with the CLI's numbers (docs/api.md).

    import nespm_cli.api as nespm

    spec = nespm.Spec(tracks=(5, 6), runs=100, filters=("ekf", "ukf", "ukf-nespm"))
    metrics = nespm.run_mc(spec, "results/main", jobs=2)      # = nespm mc --tracks 5 6 --runs 100 ...
    res = nespm.load("results/main")                          # metrics, epochs, manifest
    tables = nespm.report_tables("results/main")              # every table of the report, as DataFrames
    share = nespm.oracle_share("results/adapt/dvl")           # each adaptive filter's share of the oracle's gain
    nespm.write_report("results/main")                        # = nespm report results/main

Every coupling of options (the filter told the corruption's P0 and Q, the papers' DVL flags as
the DVL's options) happens in :func:`validate`, which :func:`run_mc` and :func:`run_sweep` call:
the same :class:`Spec` gives the same numbers from Python and from the command line (tests/test_api.py).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.errors import NespmError
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.mc import run_mc, simulate
from nespm_cli.experiments.metrics import DivergenceRule
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.experiments.sweep import run_sweep
from nespm_cli.filters.model import FilterConfig
from nespm_cli.reports.dispatch import write_report


@dataclass
class Results:
    """A finished results folder: ``metrics`` (one row per track, filter and run), ``epochs`` (one row per
    track, filter and epoch; None if absent) and ``manifest`` (dict); columns in docs/results-schema.md."""

    folder: Path
    metrics: pd.DataFrame
    epochs: pd.DataFrame | None
    manifest: dict


def load(folder: str | Path) -> Results:
    """Read a results folder written by ``mc``, ``sweep`` (or :func:`run_mc`, :func:`run_sweep`)."""
    import json

    folder = Path(folder)
    if not (folder / "metrics.parquet").is_file():
        raise NespmError(f"{folder}: no metrics.parquet (not a finished results folder)")
    mf = folder / "manifest.json"
    epochs = folder / "epochs.parquet"
    return Results(folder, pd.read_parquet(folder / "metrics.parquet"),
                   pd.read_parquet(epochs) if epochs.is_file() else None,
                   json.loads(mf.read_text()) if mf.is_file() else {})


def report_tables(folder: str | Path, reference: str | None = None, n_boot: int = 2000, seed: int = 0
                  ) -> dict[str, pd.DataFrame]:
    """Every table of a folder's report as a DataFrame (the report's numbers; docs/report.md).

    An ``mc`` folder: ``filters`` (track-averaged, eqs 50-52, improvements over ``reference``),
    ``tracks`` (per track), ``horizontal`` (horizontal position error, CEP50/R95), ``verdict``,
    ``comparisons`` (every pair), ``all_runs`` (every run counted, lost ranked worst), ``nees``,
    ``efficiency`` (RMSE / √PCRB per track, filter and block; NaN where unknown: docs/pcrb.md),
    ``consistency`` (per filter, block and sensor: the share of epochs inside the bounds) and, when an
    oracle is among the filters, ``oracle_share`` (:func:`oracle_share`'s table). A
    ``sweep`` folder, per swept value: ``sweep`` (per value and filter), ``improvements`` (over the
    baseline), ``verdict`` (the report's verdict rows, the horizontal position error ones included),
    ``horizontal`` (horizontal position error, CEP50/R95; None for a folder without it) and
    ``comparisons`` (every pair)."""
    from nespm_cli.reports.all_runs import all_runs_table
    from nespm_cli.reports.block_consistency import block_consistency
    from nespm_cli.reports.comparisons import compare_filters
    from nespm_cli.reports.efficiency_runs import needs_series, series_files
    from nespm_cli.reports.oracle_share import has_oracle
    from nespm_cli.reports.oracle_share import oracle_share as share_table
    from nespm_cli.reports.pcrb import efficiency_table
    from nespm_cli.reports.sweep_data import default_baseline
    from nespm_cli.reports.sweep_tables import (improvement_table, summary_rows, sweep_horizontal, sweep_table,
                                                sweep_verdict)
    from nespm_cli.reports.tables import (default_reference, filter_table, horizontal_table, nees_consistency,
                                          track_table)
    from nespm_cli.reports.verdict import verdict_table

    res = load(folder)
    m = res.metrics
    if "value" in m.columns:
        base = default_baseline(m, reference)
        comps = summary_rows(m, n_boot=n_boot, seed=seed)
        return {"sweep": sweep_table(m, n_boot=n_boot, seed=seed),
                "improvements": improvement_table(m, base, n_boot=n_boot, seed=seed),
                "verdict": sweep_verdict(m, base, n_boot=n_boot, seed=seed, comps=comps),
                "horizontal": sweep_horizontal(m), "comparisons": comps}
    ref = default_reference(m, reference)
    comps = compare_filters(m, n_boot=n_boot, seed=seed)
    blocks = block_consistency(res.epochs, res.manifest)
    share = {"oracle_share": share_table(m, n_boot=n_boot, seed=seed)} if has_oracle(m) else {}
    return {"filters": filter_table(m, ref, n_boot=n_boot, seed=seed), "tracks": track_table(m),
            "horizontal": horizontal_table(m),
            "verdict": verdict_table(m, ref, n_boot=n_boot, seed=seed, comps=comps, consistency=blocks),
            "comparisons": comps, "all_runs": all_runs_table(m, ref, n_boot=n_boot, seed=seed),
            "nees": nees_consistency(m), "consistency": blocks,
            "efficiency": efficiency_table(res.epochs, m, series_files(Path(folder), res.manifest)
                                           if needs_series(res.epochs) else ()), **share}


def oracle_share(folder: str | Path, n_boot: int = 2000, seed: int = 0, metric: str = "vrmse") -> pd.DataFrame:
    """The mc report's "Share of the oracle's gain" table of an ``mc`` folder (docs/adapting.md), the
    report's numbers: one row per adaptive filter F whose fixed counterpart B and B's oracle
    ``B-oracle`` O are among the filters, with ``filter``, ``base``, ``oracle``, ``metric``,
    ``base_value`` / ``filter_value`` / ``oracle_value`` (eq 51 after t = 0, over the runs none of the
    three lost) [the metric's unit: m/s for ``vrmse``, rad for ``mrmse``], ``oracle_gain`` [%] with
    ``oracle_gain_lo`` / ``oracle_gain_hi``, ``share`` = (V_B − V_F) / (V_B − V_O) [fraction, 1 = 100 %]
    with ``share_lo`` / ``share_hi`` (95 % paired bootstrap, ``n_boot`` resamples, ``seed``),
    ``pairs_min`` and ``note`` (why a share is undefined: NaN). Empty (the columns only) when an oracle
    is there but no adaptive filter with its counterpart. ``metric``: ``vrmse`` (the report's) or ``mrmse``.

    Raises :class:`NespmError` (one line) for a folder that is not a finished ``mc`` folder, one
    without an oracle among its filters, or a bad ``n_boot`` / ``metric``."""
    from nespm_cli.reports.oracle_share import has_oracle
    from nespm_cli.reports.oracle_share import oracle_share as share_table
    from nespm_cli.reports.results import check_n_boot, filters_in_order, load_results
    from nespm_cli.reports.stats import METRICS

    check_n_boot(n_boot)
    if metric not in METRICS:
        raise NespmError(f"oracle_share: metric must be one of {', '.join(METRICS)}, got {metric!r}")
    metrics = load_results(Path(folder))[0]
    if not has_oracle(metrics):
        raise NespmError(f"{folder}: no oracle among the filters ({', '.join(filters_in_order(metrics))}); "
                         "run the study with NAME-oracle beside NAME and the adaptive filters (docs/adapting.md)")
    return share_table(metrics, n_boot=n_boot, seed=seed, key=metric)


def compare(folders, labels=None, reference: str | None = None, n_boot: int = 2000) -> dict[str, pd.DataFrame]:
    """``nespm compare``'s tables: ``cases`` (per case and filter) and ``improvements`` (over the
    reference case), for folders on the same realizations (:mod:`nespm_cli.reports.cases`)."""
    from nespm_cli.reports.cases import case_improvements, case_table, load_cases
    from nespm_cli.reports.results import check_n_boot

    check_n_boot(n_boot)
    cases = load_cases(folders, labels)
    return {"cases": case_table(cases), "improvements": case_improvements(cases, reference, n_boot=n_boot)}


__all__ = ["CorruptionConfig", "DivergenceRule", "Execution", "FilterConfig", "NespmError", "Results", "Spec", "compare",
           "load", "oracle_share", "report_tables", "run_mc", "run_sweep", "simulate", "validate", "write_report"]
