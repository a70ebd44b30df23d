"""The tune report's held-out numbers by ``nespm report``'s rule (the epochs after t = 0, eq 50 per
track, eq 51 over tracks), recomputed here from the per-run, per-epoch series the held-out mc folders
keep; the consistency objective's own score held out; the convergence column; the model-parameter
lines (docs/tuning.md, "Reading the report")."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from nespm_cli.cli import main
from nespm_cli.reports.block_consistency import block_consistency
from nespm_cli.reports.markdown import fmt
from nespm_cli.reports.stats import improvement
from nespm_cli.reports.tune.heldout import heldout_rows, model_lines, model_note
from nespm_cli.reports.tune.searches import consistency_scores, convergence_of, convergence_text, filter_values
from nespm_cli.reports.verdict import consistency_summary
from nespm_cli.tuning.refine import verdict
from nespm_cli.tuning.spec import training_seed

CLI = ["tune", "--tracks", "5", "--runs", "3", "--filters", "ekf,ukf", "--dvl", "synthetic", "--window", "0:60",
       "--refine-trials", "0", "--trials", "3", "--level-runs", "3", "--no-progress"]


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune") / "t"
    assert main(CLI + ["--test-tracks", "6", "--test-runs", "4", "--out", str(out)]) == 0
    return out


def series(folder) -> pd.DataFrame:
    """Every run's per-epoch errors of an mc folder (its chunks)."""
    return pd.concat([pd.read_parquet(p) for p in sorted((folder / "chunks").glob("series-*.parquet"))],
                     ignore_index=True)


def rms(folder, f: str, first_epoch: int, col: str = "vel") -> float:
    """Eq 50 per track over the runs not lost from the per-epoch errors (epochs from ``first_epoch``),
    eq 51 over tracks; ``col`` vel (velocity error norm) or hpe (horizontal error)."""
    s = series(folder)
    s = s[(s["filter"] == f) & ~s["diverged"] & (s["epoch"] >= first_epoch)]
    sq = s["vel_err"] ** 2 if col == "vel" else s["north_err"] ** 2 + s["east_err"] ** 2
    per_track = sq.groupby(s["track"]).mean()
    return float(np.sqrt(per_track.mean()))


def row_of(text: str, start: str, section: str = "# Tuning report") -> str:
    """The first line of ``text`` starting with ``start`` after the heading ``section``."""
    return next(line for line in text[text.index(section):].splitlines() if line.startswith(start))


def test_heldout_vrmse_leaves_t0_out_as_the_mc_report(tuned):
    """The report's default and tuned VRMSE (and RMS horizontal error) are the values recomputed from the
    per-epoch errors without epoch 0, not those with it (the t = 0 rule of docs/report.md): dropping the rule
    fails here."""
    d, t = pd.read_parquet(tuned / "heldout-default" / "metrics.parquet"), pd.read_parquet(
        tuned / "heldout-tuned" / "metrics.parquet")
    rows = {r["filter"]: r for r in heldout_rows(d, t, ["vrmse", "hpe"], n_boot=200)}
    assert main(["report", str(tuned)]) == 0
    text = (tuned / "report.md").read_text()
    for f in ("ekf", "ukf"):
        r = rows[f]
        assert r["posterior"]
        for i, side in enumerate(("heldout-default", "heldout-tuned")):
            post, every = rms(tuned / side, f, 1), rms(tuned / side, f, 0)
            assert r["vrmse"][i] == pytest.approx(post, rel=1e-9)
            assert abs(every / post - 1) > 0.2  # the initial error weighs here: the rule matters
            assert r["hpe"][i] == pytest.approx(rms(tuned / side, f, 1, "hpe"), rel=1e-9)
        assert r["vrmse"][2] == pytest.approx(float(improvement(r["vrmse"][0], r["vrmse"][1])), rel=1e-12)
        line = row_of(text, f"| {f} | ", "## Held out")
        cells = [c.strip() for c in line.split("|")[1:-1]]
        assert cells[1:3] == [fmt(r["vrmse"][0]), fmt(r["vrmse"][1])]
        assert fmt(rms(tuned / "heldout-tuned", f, 0)) not in cells
        # the ANEES by the same rule: each run's mean NEES after t = 0 (nees_post), not the every-epoch nees
        assert r["posterior_nees"]
        for i, (side, part) in enumerate((("default", d), ("tuned", t))):
            mine = part[(part["filter"] == f) & ~part["diverged"]]
            post, every = float(mine["nees_post"].mean()), float(mine["nees"].mean())
            assert abs(post / every - 1) > 1e-3 and r["nees"][side][0] == pytest.approx(post, rel=1e-12)
            assert cells[4 + i].startswith(fmt(post, ".3g") + " [")
        # the consistency in the mc report's one wording (verdict.consistency_summary)
        held = tuned / "heldout-tuned"
        table = block_consistency(pd.read_parquet(held / "epochs.parquet"),
                                  json.loads((held / "manifest.json").read_text()))
        words = consistency_summary(table, t)
        assert row_of(text, f"| {f} | ", "in the mc report's words").endswith(f"| {words[f]} |")
    assert "run's mean NEES over the epochs after t = 0 (`nees_post`), as the mc report's" in text
    # the tuned filters compared: the same rule over the runs no filter lost
    vals = filter_values(t, "vrmse")
    for f in ("ekf", "ukf"):
        assert vals[f] == pytest.approx(rms(tuned / "heldout-tuned", f, 1), rel=1e-9)
        assert f"| {f} | {fmt(vals[f])} |" in text
    assert "window 0:60 s" in text and "the epochs after t = 0" in text


def test_convergence_column_and_its_fallback(tuned, tmp_path):
    """The training table says per filter what tune.json's verdict says; a folder without it gets the
    same verdict (tuning.refine.verdict) from its recorded profile and cross-check; never an empty cell."""
    shutil.copytree(tuned, tmp_path / "t")
    tuned = tmp_path / "t"
    rec = json.loads((tuned / "tune.json").read_text())
    rec["best"]["ekf"]["convergence"] = {"status": "converged", "short_by": 0.0, "by": "", "refine_trials": 12,
                                         "start": "ukf's values", "tolerance": 0.005}
    rec["best"]["ukf"]["convergence"] = {"status": "stopped short", "short_by": 0.031, "by": "profile alpha x3",
                                         "refine_trials": 0, "start": "own", "tolerance": 0.005}
    (tuned / "tune.json").write_text(json.dumps(rec))
    assert main(["report", str(tuned)]) == 0
    text = (tuned / "report.md").read_text()
    assert row_of(text, "| ekf | 0.").endswith(
        "| converged (tolerance 0.5 %; refined 12 trials from ukf's values) |")
    assert row_of(text, "| ukf | 0.").endswith("| stopped short by 3.1 % (profile alpha x3; tolerance 0.5 %) |")
    for b in rec["best"].values():  # an older folder: no verdict recorded
        del b["convergence"]
    (tuned / "tune.json").write_text(json.dumps(rec))
    assert main(["report", str(tuned)]) == 0
    text = (tuned / "report.md").read_text()
    for f, b in rec["best"].items():
        v = verdict(b["score"], b["profile"], b["cross"], None)
        assert convergence_of(b) == v and row_of(text, f"| {f} | 0.").endswith(f"| {convergence_text(v)} |")
    assert convergence_text(verdict(1.0, None, None, None)).startswith("not checked")


def test_consistency_objective_scored_held_out_by_its_own_rule(tmp_path):
    """With --objective consistency the report's held-out score is the objective's rule applied to an mc
    folder's per-epoch averages: on the training realizations it gives the training score of tune.json."""
    out = tmp_path / "c"
    assert main(CLI[:-5] + ["--objective", "consistency", "--trials", "2", "--no-profile", "--no-progress",
                            "--test-tracks", "6", "--test-runs", "3", "--out", str(out)]) == 0
    rec = json.loads((out / "tune.json").read_text())
    train = tmp_path / "train"
    assert main(["mc", "--config", str(out / "tuned.toml"), "--tracks", "5", "--runs", "3", "--dvl", "synthetic",
                 "--window", "0:60", "--seed", str(training_seed(0)), "--jobs", "1", "--no-progress", "--out",
                 str(train)]) == 0
    epochs = pd.read_parquet(train / "epochs.parquet")
    manifest = json.loads((train / "manifest.json").read_text())
    got = consistency_scores(epochs, manifest)
    for f in ("ekf", "ukf"):
        assert got[f] == pytest.approx(rec["best"][f]["score"], rel=1e-6)
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    assert "consistency score tuned" in text and "The consistency score is the objective's own" in text
    held = consistency_scores(pd.read_parquet(out / "heldout-tuned" / "epochs.parquet"),
                              json.loads((out / "heldout-tuned" / "manifest.json").read_text()))
    assert f"| {fmt(held['ekf'])} |" in row_of(text, "| ekf | ", "## Held out")


def test_model_lines_name_the_lever_arm():
    """A tuned filter not consistent held out gets a line: with a recorded DVL whose lever arm its model
    fixed, the lever arm and how to search it; with it searched, the other model parameters; the training
    tracks' ANEES spread at the level. A consistent one gets none."""
    space = {"ekf": [{"key": "r_scale_dvl", "kind": "R"}], "ukf": [{"key": "lever_arm_x_dvl", "kind": "model"}]}
    best = {"ekf": {"values": {"r_scale_dvl": 1.0}, "at_level_tracks": {"1": 3.0, "2": 12.8}},
            "ukf": {"values": {"lever_arm_x_dvl": -1.6}}}
    record = {"space": space, "best": best, "spec": {"filter_options": []}}
    sensors = {"dvl": {"source": "recorded", "lever_arm": [0.0, 0.0, 0.0]}}
    ekf = model_note("ekf", record, sensors)
    assert ekf.startswith("Its model puts the dvl at (0, 0, 0) m") and "'*.lever_arm_x_dvl=-3:3'" in ekf
    assert "spread from 3 to 12.8" in ekf and "time offset" not in ekf
    ukf = model_note("ukf", record, sensors)
    assert ukf.startswith("Its dvl lever arm was searched (lever_arm_x_dvl): (-1.6, 0, 0) m")
    assert "its model puts the dvl at (-1.6, 0, 0) m" in ukf  # y and z were not searched: still open
    record["space"]["ukf"] += [{"key": "lever_arm_y_dvl", "kind": "model"}, {"key": "lever_arm_z_dvl", "kind": "model"}]
    assert "time offset, scale factor or misalignment" in model_note("ukf", record, sensors)
    synthetic = model_note("ekf", record, {"dvl": {"source": "synthetic", "lever_arm": [0.0, 0.0, 0.0]}})
    assert "lever_arm_x_dvl" not in synthetic and "synthetic, drawn with its model's lever arms" in synthetic
    rows = [{"filter": "ekf", "nees": {"tuned": (4.0, 100)}}, {"filter": "ukf", "nees": {"tuned": (6.0, 100)}}]
    words = {"ekf": "consistent; mean NEES 4 below its band [5.3, 6.7], driven by velocity", "ukf": "consistent"}
    lines = model_lines(rows, words, record, sensors)  # the one wording (verdict.consistency_summary) as given
    assert len([x for x in lines if x.startswith("- **")]) == 1 and f"**ekf** tuned: {words['ekf']}. Its" in lines[2]
    assert model_lines(rows[1:], {"ukf": "consistent"}, record, sensors) == []
    lines = model_lines(rows, {}, record, sensors)  # no wording: the mean NEES's band word
    assert len(lines) == 4 and lines[2].startswith("- **ekf** tuned: conservative. Its model puts")


def test_objective_error_and_older_folders(tuned, tmp_path):
    """The objective's error is the horizontal one with position in the state; a held-out folder written
    before the posterior sums is reported over every epoch, and the report says so."""
    from nespm_cli.reports.tune.searches import accuracy_key

    assert accuracy_key({"spec": {"filter_config": {"state": "15"}}}) == "hpe"
    assert accuracy_key({"spec": {"filter_config": {"state": "12"}}}) == "vrmse" == accuracy_key({})
    out = tmp_path / "t"
    shutil.copytree(tuned, out)
    for side in ("heldout-default", "heldout-tuned"):
        p = out / side / "metrics.parquet"
        pd.read_parquet(p).drop(columns=["sse_vel_post", "sse_att_post", "sse_hpe_post", "n_post"]).to_parquet(p)
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    assert "every epoch including t = 0 (a folder written before the posterior sums" in text
    cells = [c.strip() for c in row_of(text, "| ekf | ", "## Held out").split("|")[1:-1]]
    assert cells[2] == fmt(rms(out / "heldout-tuned", "ekf", 0))


def test_a_tie_in_training_is_not_resolved_by_the_search(tuned, tmp_path):
    """One search per filter: where the two tuned filters' training scores lie within the searches'
    resolution (the tolerance, or what a search stopped short by), the comparison row says "not resolved by
    the search" with both figures; where they lie further apart, it does not."""
    from nespm_cli.reports.tune.searches import resolution, search_tie
    from nespm_cli.tuning.flat import training_score

    shutil.copytree(tuned, tmp_path / "t")
    tuned = tmp_path / "t"
    rec = json.loads((tuned / "tune.json").read_text())
    for b in rec["best"].values():
        b["flat"] = {"reset": []}
        b["convergence"] = {"status": "converged", "short_by": 0.0, "by": "", "tolerance": 0.005}
    rec["best"]["ekf"]["score"], rec["best"]["ukf"]["score"] = 0.1, 0.1003  # 0.3 % apart
    assert training_score(rec["best"]["ukf"]) == 0.1003 and resolution(rec["best"]["ekf"]) == 0.005
    assert search_tie(rec, "ekf", "ukf") == ("not resolved by the search: training scores 0.3 % apart, within "
                                             "the searches' 0.5 % resolution")
    (tuned / "tune.json").write_text(json.dumps(rec))
    assert main(["report", str(tuned)]) == 0
    text = (tuned / "report.md").read_text()
    worse = max(filter_values(pd.read_parquet(tuned / "heldout-tuned" / "metrics.parquet"), "vrmse").items(),
                key=lambda kv: kv[1])[0]
    assert row_of(text, f"| {worse} | ", "### The tuned filters compared").endswith(
        "**not resolved by the search: training scores 0.3 % apart, within the searches' 0.5 % resolution** |")
    # 0.8 % apart: ranked by the searches, unless one of them stopped short by more than that
    rec["best"]["ukf"]["score"] = 0.1008
    assert search_tie(rec, "ekf", "ukf") == ""
    rec["best"]["ekf"]["convergence"] = {"status": "stopped short", "short_by": 0.012, "by": "profile k x3",
                                         "tolerance": 0.005}
    assert search_tie(rec, "ekf", "ukf").endswith("0.8 % apart, within the searches' 1.2 % resolution")
    rec["best"]["ekf"]["convergence"]["short_by"] = 0.0
    (tuned / "tune.json").write_text(json.dumps(rec))
    assert main(["report", str(tuned)]) == 0
    assert "not resolved by the search" not in row_of((tuned / "report.md").read_text(), f"| {worse} | ",
                                                       "### The tuned filters compared")
