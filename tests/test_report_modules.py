"""The shape of nespm_cli.reports: small modules (none over 500 lines), the public names other code
imports from ``reports.mc`` and ``reports.sweep`` still there, the shared pieces shared."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

REPORTS = Path(__file__).resolve().parents[1] / "nespm_cli" / "reports"
MAX_LINES = 500

#: names imported from these modules by the CLI, tests, benchmarks and experiments before the split
PUBLIC = {
    "nespm_cli.reports.mc": ["DEFAULT_REFERENCE", "default_reference", "track_table", "filter_table",
                             "horizontal_table", "compare_filters", "nees_consistency", "verdict_headline",
                             "render_report", "plot_track_figures", "beside_md", "folder_label", "write_mc_report"],
    "nespm_cli.reports.sweep": ["DEFAULT_BASELINE", "load_sweep", "check_sweep_metrics", "sweep_values",
                                "default_baseline", "wilson_interval", "use_log_x", "use_log_y", "filter_bootstrap",
                                "sweep_table", "improvement_table", "improvement_points", "nees_runs",
                                "summary_rows", "plot_sweep_figures", "render_sweep_report", "write_sweep_report"],
}


@pytest.mark.parametrize("path", sorted(REPORTS.glob("*.py")), ids=lambda p: p.name)
def test_no_report_module_over_500_lines(path: Path) -> None:
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.name}: {n} lines (split it: one concept per module)"


@pytest.mark.parametrize("module", sorted(PUBLIC))
def test_public_names_still_importable(module: str) -> None:
    mod = importlib.import_module(module)
    missing = [n for n in PUBLIC[module] if not hasattr(mod, n)]
    assert not missing, missing
    assert set(PUBLIC[module]) <= set(mod.__all__)


def test_mc_and_sweep_share_the_analysis() -> None:
    """The sweep's per-value comparisons and tables are the Monte Carlo ones, not copies; mc.py and
    sweep.py are thin (orchestration and re-exports)."""
    from nespm_cli.reports import comparisons, mc, sweep_tables, tables

    assert sweep_tables.compare_filters is comparisons.compare_filters is mc.compare_filters
    assert sweep_tables.filter_table is tables.filter_table is mc.filter_table
    for name in ("mc.py", "sweep.py"):
        tree = ast.parse((REPORTS / name).read_text())
        defs = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        assert defs == [f"write_{name[:-3]}_report"], defs
