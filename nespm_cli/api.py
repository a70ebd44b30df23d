"""The Python API: what the ``nespm`` command does, as functions with the CLI's numbers (docs/api.md).

    import nespm_cli.api as nespm

    spec = nespm.Spec(tracks=(5, 6), runs=100, filters=("ekf", "ukf", "ukf-nespm"))
    metrics = nespm.run_mc(spec, "results/main", jobs=2)      # = nespm mc --tracks 5 6 --runs 100 ...
    res = nespm.load("results/main")                          # metrics, epochs, manifest
    tables = nespm.report_tables("results/main")              # every table of the report, as DataFrames
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


__all__ = ["CorruptionConfig", "DivergenceRule", "Execution", "FilterConfig", "NespmError", "Results", "Spec", "load", "run_mc",
           "run_sweep", "simulate", "validate", "write_report"]
