"""The A-KIT table (``make akit``, nespm_cli/reports/akit_table.py): its numbers are the folders'.

Three small ``mc`` folders on the same realizations (embedded tracks 5 and 6 cut to 80 epochs,
4 runs) stand in for the target's: ``mc`` (the EKF, the model-based adaptive EKFs and anekf with
the packaged ProcessNet), ``mc-tuned`` (the same five, each with another R and the adaptive ones
with another window or forgetting factor, as a tuning would give) and ``mc-onnx`` (anekf with
another R, so that its row differs; the writer does not care which noise model ran). Every number
of the table is recomputed here from the folders' ``metrics.parquet`` with pandas alone.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import nespm
from nespm_cli.errors import NespmError
from nespm_cli.reports import akit_table
from nespm_cli.reports.akit_table import BEGIN, END, ROWS

ROOT = Path(__file__).resolve().parents[1]
COMMON = ["--tracks", "5", "6", "--runs", "4", "--jobs", "1", "--no-progress"]
#: stand-ins for tuned values: another R for every filter, another window or forgetting factor
TUNED = [a for o in ("ekf.r_scale_dvl=3", "iae-ekf.r_scale_dvl=2", "iae-ekf.window=10", "sh-ekf.r_scale_dvl=2",
                     "sh-ekf.forgetting=0.9", "vb-ekf.r_scale_dvl=2", "vb-ekf.rho=0.9", "anekf.r_scale_dvl=2")
         for a in ("--filter-option", o)]


@pytest.fixture(scope="module")
def folders(tmp_path_factory, short_data_dir):
    root = tmp_path_factory.mktemp("akit")
    data = ["--data-dir", str(short_data_dir)]
    for sub, extra in (("mc", ["--filters", "ekf,iae-ekf,sh-ekf,vb-ekf,anekf"]),
                       ("mc-tuned", ["--filters", "ekf,iae-ekf,sh-ekf,vb-ekf,anekf", *TUNED]),
                       ("mc-onnx", ["--filters", "anekf", "--filter-option", "anekf.r_scale_dvl=0.5"])):
        rc, _, err = nespm("mc", *COMMON, *data, *extra, "--out", root / sub)
        assert rc == 0, err
    return root


def _rows(root: Path) -> pd.DataFrame:
    """The three folders' metrics, filters named case/filter, straight from Parquet."""
    parts = []
    for case, sub in (("default", "mc"), ("tuned", "mc-tuned"), ("onnx", "mc-onnx")):
        m = pd.read_parquet(root / sub / "metrics.parquet")
        m["filter"] = case + "/" + m["filter"]
        parts.append(m)
    return pd.concat(parts, ignore_index=True)


def _expected(m: pd.DataFrame, name: str) -> dict:
    """Posterior RMS per track (sum of squares over epochs after t = 0), RMS over tracks; final
    errors and NEES (after t = 0: ``nees_post``, the t = 0 rule) averaged per track, then over tracks (no run
    is lost here)."""
    g = m[m["filter"] == name].groupby("track")
    per_track = lambda col: np.sqrt(g[col].sum() / g["n_post"].sum())  # noqa: E731
    return {"hpe": float(np.sqrt(np.mean(per_track("sse_hpe_post") ** 2))),
            "vrmse": float(np.sqrt(np.mean(per_track("sse_vel_post") ** 2))),
            "hpe_final": float(g["hpe_final"].mean().mean()),
            "hpe_final_pct": float(g["hpe_final_pct"].mean().mean()), "nees": float(g["nees_post"].mean().mean())}


def test_table_numbers_equal_those_recomputed_from_the_parquet_files(folders):
    text, numbers = akit_table.table(folders, n_boot=200)
    m = _rows(folders)
    assert not m["diverged"].any()
    exp = {name: _expected(m, name) for _, name in ROWS}
    assert len({round(e["hpe"], 12) for e in exp.values()}) == len(ROWS)  # eleven different rows
    ref_default, ref_tuned = exp["default/ekf"]["hpe"], exp["tuned/ekf"]["hpe"]
    for label, name in ROWS:
        got, e = numbers["rows"][label], exp[name]
        for key in ("hpe", "vrmse", "hpe_final", "hpe_final_pct", "nees"):
            assert got[key] == pytest.approx(e[key], rel=1e-12), (label, key)
        assert (got["counted"], got["lost"]) == (8, 0)
        for ref, gkey in ((ref_default, "over_default"), (ref_tuned, "over_tuned")):
            g = got[gkey]
            if g is None:
                continue
            assert g.point == pytest.approx(100 * (ref - e["hpe"]) / ref, rel=1e-9, abs=1e-12), (label, gkey)
            assert g.lo <= g.hi and math.isfinite(g.lo)
            assert g.mark == "†"  # 4 runs per track: too few to judge
        # the markdown row shows the same numbers
        line = next(li for li in text.splitlines() if li.startswith(f"| {label} |"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert float(cells[1]) == pytest.approx(e["hpe"], abs=5e-4)
        assert float(cells[3]) == pytest.approx(e["vrmse"], abs=5e-5)
        assert float(cells[4]) == pytest.approx(e["nees"], abs=5e-3)
        assert cells[7] == "8 / 0"
    s = numbers["summary"]
    learned, default = exp["default/anekf"]["hpe"], ref_default
    assert s["over_ekf"].point == pytest.approx(100 * (default - learned) / default, rel=1e-9)
    best = min(("default/iae-ekf", "default/sh-ekf", "default/vb-ekf"), key=lambda n: exp[n]["hpe"])
    assert s["best_model"] == best
    assert s["over_model"].point == pytest.approx(100 * (exp[best]["hpe"] - learned) / exp[best]["hpe"], rel=1e-9)
    share = s["over_tuned"].point / s["over_ekf"].point * 100 if s["over_ekf"].point > 0 else math.nan
    assert s["share_pct"] == pytest.approx(share, nan_ok=True)
    fair = exp["tuned/anekf"]["hpe"]
    assert s["tuned_over_tuned"].point == pytest.approx(100 * (ref_tuned - fair) / ref_tuned, rel=1e-9)
    best_tuned = min(("tuned/iae-ekf", "tuned/sh-ekf", "tuned/vb-ekf"), key=lambda n: exp[n]["hpe"])
    assert s["best_tuned_model"] == best_tuned
    b = exp[best_tuned]["hpe"]
    assert s["tuned_over_tuned_model"].point == pytest.approx(100 * (b - fair) / b, rel=1e-9)
    assert "**Every filter tuned with the same budget**" in text
    assert "**Published gains in kind?**" in text and "no significant gain" in text  # † rows are never significant


def test_write_replaces_only_the_lines_between_the_markers(folders, tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n{BEGIN}\nold table\n{END}\nafter\n", encoding="utf-8")
    text = akit_table.write(folders, readme, n_boot=50)
    new = readme.read_text(encoding="utf-8")
    assert new == f"# x\n\nbefore\n{BEGIN}\n{text}{END}\nafter\n"
    assert (folders / "akit-table.md").read_text(encoding="utf-8").endswith(text)
    akit_table.write(folders, readme, n_boot=50)  # idempotent
    assert readme.read_text(encoding="utf-8") == new


def test_missing_folder_or_marker_is_one_line(folders, tmp_path, capsys):
    with pytest.raises(NespmError, match=r"/mc: no metrics.parquet"):
        akit_table.table(tmp_path)  # empty folder: the first missing one is named
    (tmp_path / "README.md").write_text("no markers\n", encoding="utf-8")
    assert akit_table.main([str(folders), "--readme", str(tmp_path / "README.md")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("nespm: error: --readme") and BEGIN in err


def test_readme_has_the_akit_table_between_its_markers():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert text.count(BEGIN) == 1 and text.count(END) == 1 and text.index(BEGIN) < text.index(END)
    section = text[text.index("## The A-KIT question on the recorded data"):]
    assert section.index(BEGIN) < section.index(END)
    table = text[text.index(BEGIN):text.index(END)]
    assert re.search(r"^\| ANEKF \(ProcessNet\) \| \d", table, re.M), "the table the target writes is missing"


def test_setup_line_reads_the_training_and_tuning_records(tmp_path):
    """The training record of the weights (here the packaged ones) and tune.json give the line above the table."""
    import json
    import shutil

    from nespm_cli.learn.processnet import load_nets

    assert akit_table.setup_line(tmp_path) is None  # neither record: no line
    pkg = ROOT / "nespm_cli" / "learn" / "processnet.npz"
    shutil.copy(pkg, tmp_path / "processnet.npz")
    (tmp_path / "tune").mkdir()
    (tmp_path / "tune" / "tune.json").write_text(json.dumps(
        {"trials": 7, "objective": "rmse", "tuned_on": {"tracks": [1, 2], "runs": [0, 5], "seed": 1},
         "space": {"ekf": [], "anekf": []}}), encoding="utf-8")
    meta = load_nets(pkg)[1]
    line = akit_table.setup_line(tmp_path)
    assert f"accelerometer {meta['test']['acc']['spearman']:.3f}, gyro {meta['test']['gyro']['spearman']:.3f}" in line
    assert "ProcessNet trained on tracks 1, 2, 3, 4 (synthetic IMU, 24 realizations" in line
    assert "ekf, anekf each tuned by `nespm tune` on tracks 1, 2 (7 trials each, 5 runs per track, objective rmse)" in line
    (tmp_path / "tune" / "tune.json").write_text("{}", encoding="utf-8")
    with pytest.raises(NespmError, match="not the record of nespm train / nespm tune"):
        akit_table.setup_line(tmp_path)


def test_search_line_names_the_searches_that_stopped_short(tmp_path):
    """The cross-check of tune.json under the table: a filter whose best another's values beat by
    more than 2 % is named with the winner and the margin; none flagged is said too; no check, no line."""
    import json

    (tmp_path / "tune").mkdir()
    rec = tmp_path / "tune" / "tune.json"
    assert akit_table.search_line(tmp_path) is None  # no record
    best = {"ekf": {"cross": {"anekf": {"score": 0.0587, "gain": 0.061}, "vb-ekf": {"score": 0.0596, "gain": 0.047}}},
            "anekf": {"cross": {"ekf": {"score": 0.0706, "gain": -0.22}, "vb-ekf": {"score": 0.0836, "gain": -0.45}}},
            "sh-ekf": {"cross": {"anekf": {"score": 0.0612, "gain": 0.015}}}}
    rec.write_text(json.dumps({"best": best}), encoding="utf-8")
    line = akit_table.search_line(tmp_path)
    assert "for ekf (anekf's values 6 % better): those searches stopped short" in line
    assert "sh-ekf" not in line and "anekf (" not in line  # 1.5 % is within the 2 % rule; anekf's own best wins
    for b in best.values():
        for c in b["cross"].values():
            c["gain"] = min(c["gain"], 0.0)
    rec.write_text(json.dumps({"best": best}), encoding="utf-8")
    assert "no filter's own best is beaten" in akit_table.search_line(tmp_path)
    rec.write_text(json.dumps({"best": {"ekf": {"score": 1.0}}}), encoding="utf-8")
    assert akit_table.search_line(tmp_path) is None  # tuned without the profile: no cross-check
