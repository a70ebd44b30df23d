"""``nespm tune --repeats K`` in the report: each filter's held-out error per search, their spread, and
"tuned A vs tuned B" over the runs and the searches (a two-level bootstrap), or "not resolved by the
search" when the searches' spread alone covers zero (docs/tuning.md, "Reading the report").

The fixture is a small real tune; the K-1 extra searches are written into its tune.json and held out
with ``run_mc`` on the same realizations with other values (what ``--repeats`` writes)."""
from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pandas as pd
import pytest

from nespm_cli.cli import main
from nespm_cli.errors import NespmError
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.mc import run_mc
from nespm_cli.experiments.spec import Spec
from nespm_cli.reports.markdown import fmt, pct
from nespm_cli.reports.stats import improvement
from nespm_cli.reports.tune.searches import compare_searches, consistency_scores, filter_values, search_errors
from nespm_cli.tuning.heldout import heldout_specs, tuned_dir

CLI = ["tune", "--tracks", "5", "--runs", "3", "--filters", "ekf,ukf", "--dvl", "synthetic", "--window", "0:60",
       "--refine-trials", "0", "--trials", "3", "--level-runs", "3", "--no-profile", "--no-progress", "--test-tracks",
       "6", "--test-runs", "4"]
STUDY = Spec(tracks=(5,), runs=3, filters=("ekf", "ukf"), dvl="synthetic", window="0:60")
#: per filter the DVL R factor of each search over tune.json's tuned values (search 0: heldout-tuned)
R_FACTORS = {"ekf": (1.0, 0.9, 1.1), "ukf": (4.0, 6.0, 8.0)}


def add_searches(out, factors: dict) -> dict:
    """Write K = len(factors[f]) searches into ``out``'s tune.json (search k: the tuned values with
    r_scale_dvl x factors[f][k]) and hold each out (``tuned_dir(k)``, search 0's folder made again when
    its values change); return the record."""
    rec = json.loads((out / "tune.json").read_text())
    k_max = len(next(iter(factors.values())))
    rec["repeats"], rec["search_seed"] = k_max, 11
    rec["searches"] = {f: [{"search": k, "search_seed": 11 + k, "score": b["score"] * (1 + 0.01 * k),
                            "values": {**b["values"], "r_scale_dvl": b["values"]["r_scale_dvl"] * factors[f][k]},
                            "convergence": {"status": "converged", "short_by": 0.0, "by": "", "refine_trials": 0,
                                            "start": "own", "tolerance": 0.005}}
                           for k in range(k_max)] for f, b in rec["best"].items()}
    for k in range(k_max):
        if k == 0 and all(fs[0] == 1.0 for fs in factors.values()):
            continue
        shutil.rmtree(out / tuned_dir(k), ignore_errors=True)
        r = {**rec, "best": {f: {"values": ss[k]["values"]} for f, ss in rec["searches"].items()}}  # search 0 too
        run_mc(heldout_specs(STUDY, r)[1], out / tuned_dir(k), Execution(jobs=1, progress=False))
    (out / "tune.json").write_text(json.dumps(rec))
    return rec


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune") / "t"
    assert main(CLI + ["--out", str(out)]) == 0
    return out


def test_two_level_interval_and_the_search_rule():
    """Without run noise the two-level interval is the searches' own: its ends are the improvements of the
    extreme pairs (every resample of two searches has a replicate of each extreme). The rule: not resolved
    when a pair of searches changes sign."""
    n_boot = 4000
    flat = lambda p: (np.asarray(p, float), np.repeat(np.asarray(p, float)[:, None], n_boot, axis=1))  # noqa: E731
    a, b = flat([1.0, 1.2]), flat([0.9, 0.95])
    c = compare_searches(a, b)
    assert c["lo"] == pytest.approx(float(improvement(1.0, 0.95)), rel=1e-12)
    assert c["hi"] == pytest.approx(float(improvement(1.2, 0.9)), rel=1e-12)
    assert c["point"] == pytest.approx(float(improvement(1.1, 0.925)), rel=1e-12) and c["resolved"]
    c = compare_searches(flat([1.0, 1.2]), flat([0.9, 1.1]))
    assert not c["resolved"] and c["pair_lo"] < 0 < c["pair_hi"]
    assert c["pair_lo"] == pytest.approx(float(improvement(1.0, 1.1))) and c["lo"] < 0 < c["hi"]


def test_searches_in_the_report(tuned, tmp_path):
    out = tmp_path / "t"
    shutil.copytree(tuned, out)
    rec = add_searches(out, R_FACTORS)
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    assert "### The searches (`--repeats`)" in text
    per = [pd.read_parquet(out / tuned_dir(k) / "metrics.parquet") for k in range(3)]
    errs, pairs_min = search_errors({f: per for f in ("ekf", "ukf")}, "vrmse", n_boot=2000)
    assert pairs_min == 4
    for f in ("ekf", "ukf"):
        for k in range(3):
            alone = filter_values(per[k], "vrmse")[f]  # no run lost: the same as over every search's runs
            assert errs[f][0][k] == pytest.approx(alone, rel=1e-12)
            s = rec["searches"][f][k]
            assert (f"| {f} | {k} | {11 + k} | {fmt(s['score'])} | converged (tolerance 0.5 %) | {fmt(alone)} |"
                    in text)
        p = errs[f][0]
        assert f"| {f} | {fmt(float(p.mean()))} | {fmt(float(p.min()))}–{fmt(float(p.max()))} |" in text
    best = min(("ekf", "ukf"), key=lambda f: errs[f][0].mean())
    other = ({"ekf", "ukf"} - {best}).pop()
    pairs = improvement(errs[other][0][:, None], errs[best][0][None, :])
    line = next(x for x in text.splitlines() if x.startswith(f"- tuned {best} vs tuned {other}:"))
    assert (": **not resolved by the search**" in line) == bool(pairs.min() < 0 < pairs.max())
    assert f"every pair of searches +{pct(pairs.min())} % to +{pct(pairs.max())} %" in line
    # every ukf search (R x4 to x8) is far worse than any ekf search: resolved, the ekf ahead
    assert best == "ekf" and pairs.min() > 0 and "not resolved" not in line
    c = compare_searches(errs[other], errs[best])
    runs_only = compare_searches((errs[other][0][:1], errs[other][1][:1]), (errs[best][0][:1], errs[best][1][:1]))
    assert c["hi"] - c["lo"] > runs_only["hi"] - runs_only["lo"]  # the searches widen the interval


def test_unresolved_searches_and_a_foreign_folder(tuned, tmp_path):
    out = tmp_path / "t"
    shutil.copytree(tuned, out)
    add_searches(out, {"ekf": (1.0, 0.3, 3.0), "ukf": (1.0, 0.3, 3.0)})  # the same spread for both: signs flip
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    line = next(x for x in text.splitlines() if x.startswith("- tuned "))
    assert line.endswith(": **not resolved by the search**.")
    rec = json.loads((out / "tune.json").read_text())
    (out / "tune.json").write_text(json.dumps({**rec, "objective": "consistency"}))  # its own score per search
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    held = consistency_scores(pd.read_parquet(out / tuned_dir(2) / "epochs.parquet"),
                              json.loads((out / tuned_dir(2) / "manifest.json").read_text()))
    assert "| held-out consistency score |" in text
    assert next(x for x in text.splitlines() if x.startswith("| ukf | 2 |")).endswith(f"| {fmt(held['ukf'])} |")
    shutil.rmtree(out / tuned_dir(2))  # a search not held out: said, the others compared
    assert main(["report", str(out)]) == 0
    assert "Held out: 2 of 3 searches" in (out / "report.md").read_text()
    other = dataclasses.replace(heldout_specs(STUDY, json.loads((out / "tune.json").read_text()))[1], seed=5)
    run_mc(other, out / tuned_dir(2), Execution(jobs=1, progress=False))
    with pytest.raises(NespmError, match="heldout-tuned-search2: not the realizations of"):
        from nespm_cli.reports.tune.report import write_tune_report
        write_tune_report(out)


def test_a_real_repeats_run(tmp_path):
    """``nespm tune --repeats 2`` as the lead's command writes it: the training table reads search 0's
    trials, the searches table each search's seed and held-out VRMSE (each folder by the rule above)."""
    out = tmp_path / "r"
    assert main(CLI[:11] + ["--repeats", "2", "--refine-trials", "0", "--trials", "2", "--level-runs", "3",
                           "--no-profile", "--no-progress", "--test-tracks", "6", "--test-runs", "3",
                           "--out", str(out)]) == 0
    assert main(["report", str(out)]) == 0
    text = (out / "report.md").read_text()
    rec = json.loads((out / "tune.json").read_text())
    per = [pd.read_parquet(out / tuned_dir(k) / "metrics.parquet") for k in range(2)]
    for f in ("ekf", "ukf"):
        for k, s in enumerate(rec["searches"][f]):
            row = next(x for x in text.splitlines() if x.startswith(f"| {f} | {k} | {s['search_seed']} |"))
            assert row.endswith(f"| {fmt(filter_values(per[k], 'vrmse')[f])} |")
    assert "- tuned " in text and "over runs and searches" in text
