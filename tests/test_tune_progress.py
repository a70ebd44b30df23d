"""``nespm tune`` reports progress with ``--jobs`` workers too (a thread reading the studies): a line
per 10 completed trials and the last, each with the best score so far; every filter's first trial
is its default setting with workers too (queued before they start); with at least as many filters
as workers each study has one writer, so the values are those of ``--jobs 1``, bit for bit."""
from __future__ import annotations

from nespm_cli.cli import main
from nespm_cli.tuning.progress import progress_line


def test_progress_lines():
    assert progress_line("ekf", 10, 25, 0.5) == "ekf: 10/25 trials, best score 0.5"
    assert progress_line("ekf", 11, 25, 0.5) is None
    assert progress_line("ekf", 25, 25, 0.25) == "ekf: 25/25 trials, best score 0.25"


def test_workers_report_progress_and_start_at_the_defaults(tmp_path, capsys):
    argv = ["tune", "--tracks", "5", "--runs", "2", "--trials", "10", "--filters", "ekf,ukf", "--window", "0:30",
            "--dvl", "synthetic", "--level-runs", "2", "--no-profile", "--refine-trials", "12"]
    rc = main(argv + ["--jobs", "2", "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert rc == 0, err
    lines = [x for x in err.splitlines() if x.startswith("ekf: 10/10 trials, best score ")]
    assert len(lines) == 1, err
    assert any(x.startswith("ukf: 10/10 trials") for x in err.splitlines()), err
    import json

    best = json.loads((tmp_path / "t" / "tune.json").read_text())["best"]
    assert all(b["default_trial"] is not None and b["default_score"] is not None for b in best.values()), best
    assert not any("profile" in b for b in best.values())  # --no-profile
    assert main(argv + ["--jobs", "1", "--no-progress", "--out", str(tmp_path / "one")]) == 0
    one = json.loads((tmp_path / "one" / "tune.json").read_text())["best"]
    assert {f: b["values"] for f, b in best.items()} == {f: b["values"] for f, b in one.items()}
    import pandas as pd

    cols = ["filter", "trial", "score"] + [c for c in pd.read_parquet(tmp_path / "one" / "trials.parquet").columns
                                           if c.startswith("p_")]
    two, single = (pd.read_parquet(tmp_path / d / "trials.parquet")[cols] for d in ("t", "one"))
    pd.testing.assert_frame_equal(two, single)
