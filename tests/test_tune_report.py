"""``nespm tune --test-tracks``: the held-out runs with the default and the tuned settings, the
report of a tuning folder, and ``mc`` on the tuning realizations saying so (docs/tuning.md)."""
from __future__ import annotations

import json

import pandas as pd

from nespm_cli.cli import main
from nespm_cli.tuning.spec import training_seed

CLI = ["tune", "--tracks", "5", "--runs", "3", "--filters", "ekf,ukf", "--dvl", "synthetic", "--window", "0:60",
       "--refine-trials", "0", "--trials", "4", "--no-progress"]


def test_heldout_report_and_training_warning(tmp_path, capsys):
    out = tmp_path / "t"
    assert main(CLI + ["--test-tracks", "6", "--test-runs", "3", "--out", str(out)]) == 0
    capsys.readouterr()
    # the held-out tuned folder is exactly mc with tuned.toml on the test tracks and --seed
    assert main(["mc", "--config", str(out / "tuned.toml"), "--tracks", "6", "--runs", "3", "--dvl", "synthetic",
                 "--window", "0:60", "--jobs", "1", "--no-progress", "--out", str(tmp_path / "mc")]) == 0
    a = pd.read_parquet(out / "heldout-tuned" / "metrics.parquet").sort_values(["filter", "run"])
    b = pd.read_parquet(tmp_path / "mc" / "metrics.parquet").sort_values(["filter", "run"])
    assert a["vrmse"].to_numpy().tolist() == b["vrmse"].to_numpy().tolist()
    assert "warning" not in capsys.readouterr().err  # held out: no training warning
    # the report of the tuning folder
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    for words in ("# Tuning report", "## Tuned values beside the defaults", "## Held out: tracks 6",
                  "### The tuned filters compared", "figures/convergence.png", "| ukf | alpha |",
                  "3 runs (seed 0), window 0:60 s", "over the epochs after t = 0"):
        assert words in text, words
    training = text[text.index("## Training scores"):text.index("## Tuned values")]
    for f in ("ekf", "ukf"):  # every filter's search: converged, stopped short or not checked, never silent
        row = next(x for x in training.splitlines() if x.startswith(f"| {f} |"))
        assert row.split("|")[-2].strip().startswith(("converged (", "stopped short", "not checked")), row
    assert (out / "figures" / "importance.png").stat().st_size > 1000
    rec = json.loads((out / "tune.json").read_text())
    assert set(rec["best"]["ukf"]["profile"]) == {p["key"] for p in rec["space"]["ukf"]}
    # mc on the tuning realizations: one warning line, and a caveat in its report
    seed = str(training_seed(0))
    assert main(["mc", "--config", str(out / "tuned.toml"), "--tracks", "5", "--runs", "2", "--dvl", "synthetic",
                 "--window", "0:60", "--seed", seed, "--jobs", "1", "--no-progress", "--out",
                 str(tmp_path / "train")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "training numbers" in line]
    assert len(err) == 2 and err[0].startswith("nespm: warning: ekf: its settings were tuned on these realizations")
    assert main(["report", str(tmp_path / "train")]) == 0
    text = (tmp_path / "train" / "report.md").read_text()
    assert "Training numbers: ukf" in text and "Tuned settings (nespm tune) for ekf, ukf: a difference" in text


def test_cross_check_scores_each_filter_with_the_others_values(tmp_path, capsys):
    """With one trial each (both filters at their defaults) the ekf scored with the ukf's values is
    its own best bit for bit (the ukf's alpha is not an ekf parameter) and vice versa: gain 0, no
    filter flagged. With four trials, the report flags exactly the filters whose cross score beats
    their own best by more than 2 % (tune.json's numbers)."""
    one = tmp_path / "one"
    assert main(CLI[:-3] + ["--trials", "1", "--no-progress", "--level-runs", "3", "--out", str(one)]) == 0
    rec = json.loads((one / "tune.json").read_text())
    for f, g in (("ekf", "ukf"), ("ukf", "ekf")):
        c = rec["best"][f]["cross"][g]
        assert c["score"] == rec["best"][f]["score"] and c["gain"] == 0.0
    assert main(["report", str(one)]) == 0
    text = (one / "report.md").read_text()
    assert "## Each filter with the others' values" in text and "at least as good as the others'" in text
    four = tmp_path / "four"
    assert main(CLI + ["--level-runs", "3", "--out", str(four)]) == 0
    capsys.readouterr()
    rec = json.loads((four / "tune.json").read_text())
    assert main(["report", str(four)]) == 0
    text = (four / "report.md").read_text()
    for f in ("ekf", "ukf"):
        (g, c), = rec["best"][f]["cross"].items()
        assert c["gain"] == (rec["best"][f]["score"] - c["score"]) / rec["best"][f]["score"]
        assert (f"- **{f}**: {g}'s searched values" in text) == (c["gain"] > 0.02)
