"""Progress: workers' per-epoch reports, the plain lines off a terminal, and mc's use of them."""
from __future__ import annotations

import io

import numpy as np

from conftest import nespm
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.experiments.progress import Progress, epoch_reporter, fmt_seconds, read_reports


def test_reporter_round_trip_and_throttle(tmp_path):
    report = epoch_reporter(tmp_path, "5-000000", 10)
    report(3)
    assert read_reports(tmp_path) == {"5-000000": (3, 10)}
    report(4)  # within the throttle interval: not written
    assert read_reports(tmp_path) == {"5-000000": (3, 10)}
    report(10)  # the last one always is
    assert read_reports(tmp_path) == {"5-000000": (10, 10)}


def test_plain_lines_with_eta():
    stream = io.StringIO()
    with Progress("mc", total=200, chunks=4, stream=stream, interval=0.0) as bar:
        bar.set_running(50)
        bar.chunk_done(100)
        bar.set_running(0)
    lines = stream.getvalue().splitlines()
    assert lines[0] == "mc: 4 chunks, 200 filter-epochs to compute"
    assert lines[1].startswith("mc: 25 % (50/200 filter-epochs, 0/4 chunks)") and "ETA" in lines[1]
    assert lines[-1].startswith("mc: 50 % (100/200 filter-epochs, 1/4 chunks)")
    assert fmt_seconds(75) == "75 s" and fmt_seconds(725) == "12 min 5 s" and fmt_seconds(None) == "?"


def test_eta_excludes_the_start_up(monkeypatch):
    """The kernels compile before the first unit is reported: an ETA from the whole elapsed time said
    "26 h" while they compiled. The ETA uses the rate since the first report: 60 s of start-up, 10
    units reported at 60 s, 100 at 69 s: 10 units/s, 900 left -> 90 s (the whole elapsed time: 621 s)."""
    import nespm_cli.experiments.progress as progress

    clock = [1000.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    bar = Progress("mc", total=1000, chunks=4, enabled=False)
    assert bar.eta() is None
    clock[0] += 60.0  # start-up: imports and compilation, no unit reported
    bar.set_running(10)
    assert bar.eta() is None and "ETA once a rate is measured" in bar.line()  # one report: no rate yet
    clock[0] += 9.0
    bar.set_running(100)
    assert abs(bar.eta() - 9.0 * 900 / 90) < 1e-9


def test_simulate_reports_every_epoch_of_every_filter(short_data_dir):
    spec = validate(Spec(tracks=(5,), runs=2, filters=("ins", "ekf"), data_dir=str(short_data_dir)))
    seen = []
    simulate(spec, 5, np.arange(2), progress=seen.append)
    n = 80 - 1  # the short tracks' epoch intervals
    assert seen == list(range(1, n + 1)) + list(range(n + 1, 2 * n + 1))


def test_mc_off_a_terminal_prints_start_and_end_lines(short_data_dir, tmp_path):
    rc, stdout, stderr = nespm("mc", "--tracks", "5", "--runs", "2", "--chunk-size", "1", "--filters", "ins",
                               "--data-dir", short_data_dir, "--out", tmp_path / "o")
    assert rc == 0, stderr
    lines = [line for line in stderr.splitlines() if "kernels" not in line]  # a first run compiles them first
    assert lines[0] == "mc: 2 chunks of 1 run, 158 filter-epochs to compute"
    assert lines[-1].startswith("mc: 100 % (158/158 filter-epochs, 2/2 chunks)")
    rc, _, stderr = nespm("mc", "--tracks", "5", "--runs", "2", "--chunk-size", "1", "--filters", "ins",
                          "--data-dir", short_data_dir, "--out", tmp_path / "o")
    assert rc == 0 and stderr == ""  # nothing left to compute: nothing to report
