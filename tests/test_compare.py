"""nespm compare: cases on provably identical realizations, paired by (track, run)."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_one_error_line, cli, nespm
from nespm_cli.errors import NespmError
from nespm_cli.reports.cases import case_improvements, case_table, load_cases
from nespm_cli.reports.tables import filter_table, horizontal_table

COMMON = ["--tracks", "1", "2", "--runs", "6", "--state", "15", "--dvl", "synthetic", "--filters", "ekf,iekf",
          "--no-progress", "--jobs", "2"]


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    root = tmp_path_factory.mktemp("cases")
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("NESPM_DATA_DIR", raising=False)
        for name, sensors in (("dvl", ["--sensors", "dvl"]), ("depth", ["--sensors", "dvl,depth"]),
                              ("fix", ["--sensors", "dvl,depth,fix", "--sensor-option", "fix.interval=30"])):
            rc, _, err = nespm("mc", *COMMON, *sensors, "--out", root / name)
            assert rc == 0, err
    return root


def test_case_table_equals_each_folders_own_report_numbers(cases):
    """compare's case table holds each folder's own report numbers (VRMSE, RMS HPE, CEP50, NIS of the fixes)."""
    cs = load_cases([cases / "dvl", cases / "fix"])
    table = case_table(cs).set_index(["case", "filter"])
    for c in cs:
        ft = filter_table(c.metrics, None, n_boot=0).set_index("filter")
        ht = horizontal_table(c.metrics)
        ht = ht[ht["track"].isna()].set_index("filter")
        for f in ("ekf", "iekf"):
            row = table.loc[(c.label, f)]
            assert row["vrmse"] == pytest.approx(ft.loc[f, "vrmse"], rel=1e-12)
            assert row["hpe_rms"] == pytest.approx(ht.loc[f, "hpe_rms"], rel=1e-12)
            assert row["cep50"] == pytest.approx(ht.loc[f, "cep50"], rel=1e-12)
    assert np.isnan(table.loc[("dvl", "ekf"), "nis_fix"]) and 1.0 < table.loc[("fix", "ekf"), "nis_fix"] < 3.0


def test_improvement_is_the_paired_change_of_the_same_filter(cases):
    """No run is lost here, so the point improvement is 100 (ref − case) / ref of the case table's
    track-averaged numbers; fixes every 30 s cut the RMS horizontal error (interval above 0)."""
    cs = load_cases([cases / "dvl", cases / "depth", cases / "fix"])
    table = case_table(cs).set_index(["case", "filter"])
    imp = case_improvements(cs, n_boot=400).set_index(["case", "filter"])
    for case in ("depth", "fix"):
        for f in ("ekf", "iekf"):
            ref, new = table.loc[("dvl", f), "hpe_rms"], table.loc[(case, f), "hpe_rms"]
            assert imp.loc[(case, f), "hpe"] == pytest.approx(100 * (ref - new) / ref, rel=1e-9)
            assert imp.loc[(case, f), "pairs"] == 12
    assert (imp.loc["fix", "hpe_lo"] > 10).all()  # fixes: a large, paired gain
    # depth observes the vertical channel: the vertical RMS falls by far
    assert (table.xs("depth")["vert_rms"] < 0.5 * table.xs("dvl")["vert_rms"]).all()


def test_folders_of_other_realizations_are_refused_naming_the_difference(cases, tmp_path, monkeypatch):
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)
    rc, _, err = nespm("mc", *COMMON, "--seed", "7", "--out", tmp_path / "seed7")
    assert rc == 0, err
    with pytest.raises(NespmError, match=r"differ in seed"):
        load_cases([cases / "dvl", tmp_path / "seed7"])
    with pytest.raises(NespmError, match="at least two"):
        load_cases([cases / "dvl"])
    with pytest.raises(NespmError, match="--labels"):
        load_cases([cases / "dvl", cases / "fix"], labels=["a", "a"])


def test_compare_command_writes_the_report(cases, tmp_path, capsys):
    rc, out, err = cli(capsys, "compare", cases / "dvl", cases / "fix", "--labels", "DVL,DVL+fixes",
                       "--out", tmp_path / "cmp", "--n-boot", "200")
    assert rc == 0, err
    text = (tmp_path / "cmp" / "compare.md").read_text()
    assert "| DVL+fixes | `ekf` |" in text and "against `DVL`" in text
    assert (tmp_path / "cmp" / "figures" / "compare.png").stat().st_size > 10_000
    rc, out, err = cli(capsys, "compare", cases / "dvl", tmp_path / "nothing", "--out", tmp_path / "c2")
    assert_one_error_line(rc, out, err, "not a finished results folder")
