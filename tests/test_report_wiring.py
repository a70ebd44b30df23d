"""Issue 39 items 3-5 wired into the reports: the mc report's vertical RMS and mean NEES after t = 0 (the t = 0
rule, ``vert_rms_post`` / ``nees_post``) with captions that say so, its consistency cells in the one wording of
``verdict.consistency_summary``, its robust-update section (reports/robust_counts.py) with a gated filter's counts,
and a ``--tune-range`` of a noise scale outside ``filters.options.SCALE_LIMITS`` refused in one line.

One tiny mc: track 5, 0-60 s, 8 runs, synthetic DVL with 5 % outliers of 10x its std, ekf gated (χ²), ukf plain.
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from nespm_cli.cli import main
from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec
from nespm_cli.reports.block_consistency import block_consistency
from nespm_cli.reports.markdown import fmt
from nespm_cli.reports.mc import write_mc_report
from nespm_cli.reports.mc_markdown import ROBUST_SECTION
from nespm_cli.reports.stats import lost_by_any
from nespm_cli.reports.verdict import consistency_summary
from nespm_cli.tuning.space import Param, apply_ranges

RUNS = 8
N_BOOT = 200


@pytest.fixture(autouse=True)
def embedded(monkeypatch):
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The tiny mc folder and its report's text."""
    import os

    import nespm_cli.api as nespm

    os.environ.pop("NESPM_DATA_DIR", None)
    out = tmp_path_factory.mktemp("wiring") / "mc"
    spec = Spec(tracks=(5,), runs=RUNS, dvl="synthetic", filters=("ekf", "ukf"), window="0:60",
                sensor_options=(("dvl", "outliers", "0.05:10"),), filter_options=(("ekf", "robust", "gate"),))
    nespm.run_mc(spec, out, progress=False)
    text = write_mc_report(out, n_boot=N_BOOT).read_text(encoding="utf-8")
    return out, text


def section(text: str, heading: str) -> str:
    """The body of the ``## heading`` section of ``text`` (up to the next ``## ``)."""
    start = text.index(heading + "\n")
    end = text.find("\n## ", start + len(heading))
    return text[start:end if end > 0 else None]


def cells(text: str, start: str) -> list[str]:
    """The cells of the first table row of ``text`` starting with ``start``."""
    line = next(x for x in text.splitlines() if x.startswith(start))
    return [c.strip() for c in line.split("|")[1:-1]]


def vertical(metrics: pd.DataFrame, column: str) -> dict[str, float]:
    """Per filter the vertical RMS of track 5 recomputed from the per-run ``column`` (each run's RMS over its
    epochs, all runs the same epochs): the RMS over the runs no filter lost."""
    kept = metrics[~lost_by_any(metrics)]
    return {f: float(np.sqrt(np.mean(np.square(g[column].to_numpy(float))))) for f, g in kept.groupby("filter")}


def test_rejection_section_shows_the_gated_filters_counts(folder):
    """The section appears with the counts of metrics.parquet: the gated ekf rejected about the injected 5 %
    (within the binomial spread of 472 samples: 23.6 ± 3 sigma of 4.7, and its 0.1 % false alarms), the plain
    ukf none; every sample rejected or applied."""
    out, text = folder
    m = pd.read_parquet(out / "metrics.parquet")
    body = section(text, ROBUST_SECTION)
    got = {}
    for f in ("ekf", "ukf"):
        d = m[m["filter"] == f]
        rej, app = int(d["rejected_dvl"].sum()), int(d["applied_dvl"].sum())
        row = cells(body, f"| {f} | dvl (outliers: 0.05:10) |")
        assert row[2:5] == [str(RUNS), str(rej), str(app)], row
        got[f] = (rej, app)
    total = sum(got["ukf"])
    assert got["ukf"][0] == 0 and sum(got["ekf"]) == total
    expected = 0.05 * total
    assert abs(got["ekf"][0] - expected) <= 3 * np.sqrt(total * 0.05 * 0.95) + 0.001 * total + 1
    # the section sits with the consistency, before the figures
    assert text.index("## Consistency per block and sensor") < text.index(ROBUST_SECTION) < text.index("## Figures")


def test_mean_nees_and_caption_after_t0(folder):
    """The caption says the mean NEES is after t = 0 (`nees_post`); the table's value is the mean of nees_post over
    the runs kept, not that of the every-epoch nees (they differ on these runs)."""
    out, text = folder
    m = pd.read_parquet(out / "metrics.parquet")
    assert "each run's mean NEES over the epochs after t = 0 (`nees_post`)" in text
    assert "t = 0 included (1 epoch in N" not in text and "has no posterior NEES" not in text
    main_table = section(text, "## Track-averaged results (eq 51)")
    for f, label in (("ekf", "ekf"), ("ukf", "ukf (reference)")):
        d = m[(m["filter"] == f) & ~m["diverged"]]
        post, every = fmt(float(d["nees_post"].mean()), ".2f"), fmt(float(d["nees"].mean()), ".2f")
        assert post != every
        assert cells(main_table, f"| {label} |")[7] == post


def test_consistency_cells_are_the_one_wording(folder):
    """Each filter's consistency cell of the main table is consistency_summary's (blocks, and the mean NEES outside
    its band with the block that drives it): the plain ukf's mean NEES (about 22) lies far above its band
    [3.84, 8.63], driven by its velocity block (85 % of its epochs above)."""
    out, text = folder
    m = pd.read_parquet(out / "metrics.parquet")
    epochs = pd.read_parquet(out / "epochs.parquet")
    manifest = json.loads((out / "manifest.json").read_text())
    words = consistency_summary(block_consistency(epochs, manifest), m, shares=False)
    main_table = section(text, "## Track-averaged results (eq 51)")
    for f, label in (("ekf", "ekf"), ("ukf", "ukf (reference)")):
        assert cells(main_table, f"| {label} |")[9] == words[f]
    assert "above its band [3.84, 8.63], driven by velocity" in words["ukf"]
    assert "the words say where and name the block that drives it" in main_table


def test_vertical_rms_after_t0(folder):
    """The report's vertical RMS is the recomputation from vert_rms_post (the epochs after t = 0), not from the
    every-epoch vert_rms (they differ at the report's 3 digits here); the caption says which."""
    out, text = folder
    m = pd.read_parquet(out / "metrics.parquet")
    post, every = vertical(m, "vert_rms_post"), vertical(m, "vert_rms")
    body = section(text, "## Horizontal position error")
    assert "the epochs after t = 0 (`vert_rms_post`, as RMS HPE)" in body
    for f in ("ekf", "ukf"):
        assert fmt(post[f], ".3g") != fmt(every[f], ".3g")
        for track in ("5", "average"):  # one track: eq 51 over tracks is the track's value
            assert cells(body, f"| {track} | {f} |")[8] == fmt(post[f], ".3g")


def test_older_folder_says_every_epoch_and_has_no_robust_section(folder, tmp_path):
    """A folder without nees_post, vert_rms_post and the robust counts: the captions say every epoch, t = 0
    included, the vertical RMS is the every-epoch one, and no robust section."""
    out, _ = folder
    old = tmp_path / "old"
    shutil.copytree(out, old, ignore=shutil.ignore_patterns("report.md", "figures"))
    p = old / "metrics.parquet"
    m = pd.read_parquet(p)
    m = m.drop(columns=[c for c in m.columns if c in ("nees_post", "vert_rms_post")
                        or c.startswith(("rejected_", "applied_", "downweighted_"))])
    m.to_parquet(p)
    text = write_mc_report(old, n_boot=N_BOOT).read_text(encoding="utf-8")
    assert ROBUST_SECTION not in text
    assert "this folder's `metrics.parquet` has no `nees_post`" in text
    body = section(text, "## Horizontal position error")
    assert "no `vert_rms_post`" in body
    every = vertical(m, "vert_rms")
    assert cells(body, "| 5 | ekf |")[8] == fmt(every["ekf"], ".3g")
    d = m[(m["filter"] == "ekf") & ~m["diverged"]]
    main_table = section(text, "## Track-averaged results (eq 51)")
    assert cells(main_table, "| ekf |")[7] == fmt(float(d["nees"].mean()), ".2f")


TUNE = ["tune", "--tracks", "5", "--runs", "2", "--filters", "ekf,ukf", "--dvl", "synthetic", "--window", "0:60",
        "--trials", "2", "--no-progress"]


@pytest.mark.parametrize("given, words", [
    ("ekf.acc_noise_scale=1e-5:10", "--tune-range ekf.acc_noise_scale=1e-05:10: outside the limits of a noise "
                                    "scale, 0.001 to 1000"),
    ("*.r_scale_dvl=0.5:2000", "--tune-range *.r_scale_dvl=0.5:2000: outside the limits of a noise scale"),
    ("ukf.p0_att_scale=0.0001:0.01", "--tune-range ukf.p0_att_scale=0.0001:0.01: outside the limits"),
])
def test_tune_range_outside_scale_limits_refused(tmp_path, capsys, given, words):
    """One line naming the option, the key, the range given and the limits; exit 2; nothing written."""
    out = tmp_path / "t"
    rc = main(TUNE + ["--tune-range", given, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and words in err and len(err.splitlines()) == 1, err
    assert "Traceback" not in err and not out.exists()


def test_scale_limits_in_apply_ranges():
    """The limits themselves are accepted; a scale range past either is refused; a plugin's own option and a lever
    arm are not noise scales (their ranges are their own)."""
    space = {"ekf": [Param("ekf", "acc_noise_scale", 0.1, 10.0), Param("ekf", "r_scale_dvl", 0.1, 10.0, kind="R"),
                     Param("ekf", "window", 5.0, 120.0, default=30.0, kind="plugin")]}
    got = apply_ranges(space, [("ekf", "acc_noise_scale", 1e-3, 1e3), ("ekf", "window", 1.0, 5000.0)])
    assert [(p.key, p.low, p.high) for p in got["ekf"]] == [("acc_noise_scale", 1e-3, 1e3), ("r_scale_dvl", 0.1, 10.0),
                                                           ("window", 1.0, 5000.0)]
    for low, high in ((9.99e-4, 1.0), (1.0, 1.0001e3)):
        with pytest.raises(NespmError, match=r"--tune-range \*\.r_scale_dvl=.*outside the limits"):
            apply_ranges(space, [("*", "r_scale_dvl", low, high)])
