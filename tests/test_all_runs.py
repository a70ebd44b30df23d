"""Every run counted (issue 23 item 1): medians over all runs with a lost run ranked the worst."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, cli
from nespm_cli.reports.all_runs import all_runs_table, paired_change, run_errors


def _metrics(errors: dict[str, list[float]], lost: dict[str, list[int]] | None = None) -> pd.DataFrame:
    rows = []
    for f, errs in errors.items():
        for r, e in enumerate(errs):
            bad = r in (lost or {}).get(f, [])
            rows.append({"track": 5, "run": r, "filter": f, "vrmse": np.nan if bad else e,
                         "mrmse": np.nan if bad else e / 10, "diverged": bad, "sse_vel": e * e, "sse_att": 1.0,
                         "n_samples": 1, "nees": 6.0})
    return pd.DataFrame(rows)


def test_paired_change_ranks_lost_runs():
    e_f = np.array([1.0, np.inf, 2.0, np.inf])
    e_r = np.array([2.0, 1.0, np.inf, np.inf])
    np.testing.assert_array_equal(paired_change(e_f, e_r), [50.0, -np.inf, np.inf, 0.0])


def test_a_filter_never_looks_better_for_losing_runs():
    """Filter `a` is better than `b` on the runs it keeps but loses its 4 hardest of 10: over the kept
    runs its errors look small; over all runs its median is above b's and it is worse in the paired
    median (lost runs are its worst)."""
    b = [1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.7, 1.8, 1.9]
    a = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 9, 9, 9, 9]
    m = _metrics({"a": a, "b": b}, lost={"a": [6, 7, 8, 9]})
    E = run_errors(m, "vrmse")
    assert np.isinf(E["a"]).sum() == 4
    kept = m[~m["diverged"]]
    assert kept[kept["filter"] == "a"]["vrmse"].mean() < kept[kept["filter"] == "b"]["vrmse"].mean()
    t = all_runs_table(m, "b", n_boot=200).set_index(["metric", "filter"])
    assert t.loc[("vrmse", "a"), "median"] == pytest.approx(np.median([0.5, 0.6, 0.7, 0.8, 0.9, 1.0] + [np.inf] * 4))
    assert t.loc[("vrmse", "a"), "lost"] == 4 and t.loc[("vrmse", "b"), "lost"] == 0
    # paired: runs 0-5 a better (+), runs 6-9 a lost (−∞): median of 10 = mean of the 5th and 6th values
    d = np.sort(paired_change(np.array(a[:6] + [np.inf] * 4), np.array(b)))
    assert t.loc[("vrmse", "a"), "imprv"] == pytest.approx(np.median(d))
    # a filter that loses more than half its runs has an infinite median
    m2 = _metrics({"a": a, "b": b}, lost={"a": [4, 5, 6, 7, 8, 9]})
    t2 = all_runs_table(m2, "b", n_boot=0).set_index(["metric", "filter"])
    assert np.isinf(t2.loc[("vrmse", "a"), "median"]) and t2.loc[("vrmse", "a"), "imprv"] == -np.inf


def test_report_section_appears_where_runs_were_lost(tmp_path, capsys, no_env_data_dir):
    """At 60 deg of misalignment runs are lost, and the report then holds the every-run-counted section once."""
    out = tmp_path / "lost"
    rc, _, err = cli(capsys, "mc", "--tracks", "1", "--runs", "6", "--filters", "ekf,ukf-nespm,ins",
                     "--misalignment-deg", "60", "--dvl", "synthetic", "--no-progress", "--jobs", "1", "--out", out)
    assert rc == 0, err
    rc, _, err = cli(capsys, "report", out, "--n-boot", "100")
    assert rc == 0, err
    text = (out / "report.md").read_text()
    assert text.count("## Every run counted") == 1 and "median over all runs (lost = worst)" in text
    rc, _, err = cli(capsys, "report", out, "--n-boot", "100", "--all-runs", "none")
    assert rc == 0, err
    assert "## Every run counted" not in (out / "report.md").read_text()
    rc, o, err = cli(capsys, "report", out, "--all-runs", "cap")
    assert_one_error_line(rc, o, err, "--all-runs")
