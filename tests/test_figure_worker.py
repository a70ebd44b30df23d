"""The report's second figure process (reports/figure_worker.py): how many processes draw, the same files
whichever draws them, and a worker that fails leaves its tracks to the report's own process."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from conftest import nespm
from nespm_cli.reports import figure_worker
from nespm_cli.reports.figure_worker import FigureWorker, figure_processes
from nespm_cli.reports.mc import write_mc_report


def test_processes_given_or_by_cores_and_tracks(monkeypatch):
    assert figure_processes(1, 5) == 1 and figure_processes(0, 4) == 1
    assert figure_processes(2, 2) == 2 and figure_processes(3, 5) == 2 and figure_processes(3, 1) == 1
    monkeypatch.setattr(figure_worker.os, "cpu_count", lambda: 2)
    assert figure_processes(None, 2) == 2 and figure_processes(None, 1) == 1
    monkeypatch.setattr(figure_worker.os, "cpu_count", lambda: 1)
    assert figure_processes(None, 4) == 1


def test_worker_returns_the_value_or_none_when_it_fails():
    assert FigureWorker(divmod, 17, 5).result() == (3, 2)  # run in the child, pickled back
    assert FigureWorker(divmod, 1, 0).result() is None  # ZeroDivisionError there: the caller draws


@pytest.fixture(scope="module")
def two_tracks(short_data_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("two-tracks") / "mc"
    rc, _, err = nespm("mc", "--data-dir", short_data_dir, "--tracks", "5", "6", "--runs", "3", "--filters",
                       "ekf,ukf", "--jobs", "1", "--no-progress", "--out", out)
    assert rc == 0, err
    return out


def _drawn(folder: Path) -> dict[str, bytes]:
    files = {p.name: p.read_bytes() for p in sorted((folder / "figures").glob("*.png"))}
    files["report.md"] = (folder / "report.md").read_bytes()
    return files


def test_the_same_files_from_one_process_or_two(two_tracks, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    shutil.copytree(two_tracks, one)
    shutil.copytree(two_tracks, two)
    write_mc_report(one, figure_jobs=1)
    write_mc_report(two, figure_jobs=2)
    a, b = _drawn(one), _drawn(two)
    assert any("track6" in name for name in a) and any("track5" in name for name in a)
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a)


def test_a_worker_that_cannot_draw_leaves_its_tracks_here(two_tracks, tmp_path, monkeypatch):
    """The worker is handed a figure function that fails in the child (a folder it cannot write): the
    report's process draws those tracks itself, and every figure is there."""
    ref, out = tmp_path / "ref", tmp_path / "out"
    shutil.copytree(two_tracks, ref)
    shutil.copytree(two_tracks, out)
    write_mc_report(ref, figure_jobs=1)
    real = figure_worker.FigureWorker

    class Failing(real):
        def __init__(self, fn, *args):
            super().__init__(fn, *args[:2], Path("/proc/nespm-no-such-folder"), *args[3:])

    monkeypatch.setattr("nespm_cli.reports.mc.FigureWorker", Failing)
    write_mc_report(out, figure_jobs=2)
    a, b = _drawn(ref), _drawn(out)
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a)
