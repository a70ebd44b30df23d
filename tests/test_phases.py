"""What ``report``, ``compare`` and ``import`` say while they work (issue 30, item 6: they printed
nothing for 20-60 s).

The library names its phases with :func:`nespm_cli.experiments.progress.phase`; the command's
:class:`~nespm_cli.experiments.progress.Status` shows them (a transient status on a terminal;
nothing off one, and nothing with ``--no-progress``, so logs and pipes stay as they were).
"""
from __future__ import annotations

import io

from conftest import nespm
from nespm_cli.experiments.progress import ACTIVE, Status, phase


def test_phase_goes_to_the_innermost_open_status_only():
    outer, inner = io.StringIO(), io.StringIO()
    phase("nobody listens")  # no Status open (the Python API): nothing, no error
    with Status("outer", stream=outer):
        phase("a")
        with Status("inner", stream=inner):
            phase("b")
        phase("c")
    phase("after")
    assert not ACTIVE
    assert [line.split(" (")[0] for line in outer.getvalue().splitlines()] == ["outer: a", "outer: c"]
    assert [line.split(" (")[0] for line in inner.getvalue().splitlines()] == ["inner: b"]
    quiet = io.StringIO()
    with Status("off", stream=quiet, plain=False):  # off a terminal, the report's own Status says nothing
        phase("x")
    with Status("no", stream=quiet, enabled=False):  # --no-progress
        phase("y")
    assert quiet.getvalue() == ""


def test_the_report_names_its_phases_in_order(short_data_dir, tmp_path):
    out = tmp_path / "f"
    rc, _, err = nespm("mc", "--tracks", "5", "--runs", "2", "--filters", "ins", "--jobs", "1", "--no-progress",
                       "--data-dir", short_data_dir, "--out", out)
    assert rc == 0, err
    from nespm_cli.reports.dispatch import write_report

    log = io.StringIO()
    with Status("nespm report", stream=log):  # line-based, to read them back
        write_report(out, None, n_boot=10)
    said = [line.split(": ", 1)[1].rsplit(" (", 1)[0] for line in log.getvalue().splitlines()]
    assert said[0] == "reading the results"
    assert said[1].startswith("tables and paired bootstrap intervals")
    figures = [s for s in said if s.startswith("figures: writing ")]
    assert len(figures) >= 3 and all(s.endswith(".png") for s in figures)
    assert said[-1] == "verdict and report.md"
    assert said.index(figures[0]) > 1
