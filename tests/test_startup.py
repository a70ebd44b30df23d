"""The ``nespm`` command starts without the heavy numeric stack (issue 30, item 2).

``nespm --help``, ``nespm report --help`` and ``nespm tracks`` (on the embedded tracks) import
neither pandas, scipy, matplotlib nor numba: those cost about a second before any work
(``python -X importtime -c "import nespm_cli.cli"``). Each case runs in a fresh interpreter
and reads ``sys.modules`` after the command returned, so the verdict does not depend on the
machine's speed (no timing here; benchmarks/ measures the time). ``nespm tracks`` also imports
neither the option tables of the experiment commands nor what their defaults pull (the experiment
spec, the filters, the sensors: issue 41).
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import env_without_data_dir

HEAVY = ("pandas", "scipy", "matplotlib", "numba")

PROBE = """
import contextlib, io, json, sys
from nespm_cli.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    rc = main(json.loads(sys.argv[1]))
print(json.dumps({"rc": rc, "out": out.getvalue(), "modules": sorted(sys.modules)}))
"""


def imported_by(argv: list[str]) -> dict:
    """``{"rc", "out", "modules"}`` of ``nespm ARGV`` run in a fresh interpreter (embedded tracks)."""
    p = subprocess.run([sys.executable, "-c", PROBE, json.dumps(argv)], capture_output=True, text=True,
                       env=env_without_data_dir(), timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.splitlines()[-1])


def heavy(modules: list[str]) -> list[str]:
    return sorted({m.split(".")[0] for m in modules} & set(HEAVY))


@pytest.mark.parametrize("argv", [["--help"], ["report", "--help"], ["mc", "--help"]])
def test_help_imports_no_heavy_package(argv):
    r = imported_by(argv)
    assert r["rc"] == 0
    assert "Usage: nespm" in r["out"]
    assert heavy(r["modules"]) == [], f"nespm {' '.join(argv)} imported {heavy(r['modules'])}"


def test_help_imports_no_reader_runner_or_report():
    """The option defaults come from light config modules: the track readers, the ProcessNet
    training, the results store, the runners and the report are imported only when a command runs."""
    mods = imported_by(["--help"])["modules"]
    for m in ("nespm_cli.data.tracks", "nespm_cli.data.csvtable", "nespm_cli.learn.training",
              "nespm_cli.experiments.store", "nespm_cli.experiments.mc", "nespm_cli.experiments.gp_ukf.run",
              "nespm_cli.experiments.gp_ukf.model", "nespm_cli.experiments.gp_ukf.training",
              "nespm_cli.reports.stats", "nespm_cli.nav.kernels"):
        assert m not in mods, m


def test_tracks_on_the_embedded_default_imports_no_heavy_package():
    r = imported_by(["tracks", "--no-progress"])
    assert r["rc"] == 0
    assert "the embedded default" in r["out"]
    rows = [line for line in r["out"].splitlines() if line.strip("│ ").split(" ")[0] in "123456"]
    assert len(rows) >= 6, r["out"]  # all six tracks listed, with their numbers
    assert heavy(r["modules"]) == [], f"nespm tracks imported {heavy(r['modules'])}"


#: what ``nespm tracks`` does not need (issue 41): the option tables of the experiment commands, whose
#: defaults come from the experiment spec, and through it the filter engine, the sensors and the metrics
NOT_FOR_TRACKS = ("nespm_cli.cli.options", "nespm_cli.experiments.spec", "nespm_cli.experiments.metrics",
                  "nespm_cli.filters", "nespm_cli.sensors", "nespm_cli.learn")


def test_tracks_on_the_embedded_default_imports_no_filter_spec_or_option_table():
    """``nespm tracks`` takes its options from the light cli.data_options and lists the embedded tracks
    without importing the filters (or any module under them), the sensors or the experiment spec."""
    r = imported_by(["tracks", "--no-progress"])
    assert r["rc"] == 0 and "the embedded default" in r["out"]
    loaded = [m for m in r["modules"] if any(m == p or m.startswith(p + ".") for p in NOT_FOR_TRACKS)]
    assert loaded == [], f"nespm tracks imported {loaded}"
    assert "nespm_cli.cli.tracks_command" in r["modules"]


def test_the_light_modules_keep_their_old_names():
    """What moved to a light module is still importable from where it was (same object)."""
    from nespm_cli.experiments import gp_ukf, inputs
    from nespm_cli.experiments.gp_ukf import run, spec
    from nespm_cli.nav import synthesis
    from nespm_cli.reports import stats, thresholds

    # the GP-UKF package re-exports its spec's names and the runner's entry point (same objects)
    assert gp_ukf.GPSpec is spec.GPSpec and gp_ukf.validate is spec.validate and gp_ukf.FILTERS is spec.FILTERS
    assert gp_ukf.run_gp_experiment is run.run_gp_experiment
    assert stats.PRACTICAL_PCT == thresholds.PRACTICAL_PCT == 1.0
    assert inputs.DEFAULT_IMU_RATE == synthesis.DEFAULT_IMU_RATE == 100.0
