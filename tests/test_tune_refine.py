"""A search that converges and says when it did not; the search's seed apart from the data's; K
independent searches; a study file that is not a database; the searches on a Dask cluster
(docs/tuning.md, "A search that converges"; docs/cluster.md)."""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from nespm_cli.cli import main
from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.refine import LEVELS, TOLERANCE, pattern_search, verdict
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec

SMALL = dict(tracks=(5,), runs=3, filters=("ekf",), dvl="synthetic", window="0:60")
CLI = ["tune", "--tracks", "5", "--runs", "3", "--filters", "ekf", "--dvl", "synthetic", "--window", "0:60",
       "--no-progress", "--no-profile", "--trials", "2"]


def test_pattern_search_finds_a_minimum_to_its_smallest_step():
    """On a smooth bowl in the search coordinates (log x for a log range, x for a linear one) the
    search ends within its smallest step of the minimum, says it finished, and is a pure function of
    the scores it is given (the same calls twice)."""
    params = [Param("f", "a", 0.01, 100.0), Param("f", "b", 0.1, 10.0), Param("f", "c", -3.0, 3.0, log=False)]
    best = {"a": 0.37, "b": 4.1, "c": -1.2}

    def bowl(x):
        calls.append(dict(x))
        return 1.0 + (math.log(x["a"] / best["a"])) ** 2 + 3 * math.log(x["b"] / best["b"]) ** 2 + (x["c"] - best["c"]) ** 2

    calls = []
    res = pattern_search(bowl, {"a": 1.0, "b": 1.0, "c": 0.0}, bowl({"a": 1.0, "b": 1.0, "c": 0.0}), params, 400)
    first = list(calls)
    calls.clear()
    again = pattern_search(bowl, {"a": 1.0, "b": 1.0, "c": 0.0}, bowl({"a": 1.0, "b": 1.0, "c": 0.0}), params, 400)
    assert first == calls and res == again
    assert res["finished"] and res["evaluations"] < 400
    smallest_log, smallest_lin = math.log(3.0) / 2 ** LEVELS, 2.0 / 2 ** LEVELS
    assert abs(math.log(res["values"]["a"] / best["a"])) <= smallest_log
    assert abs(math.log(res["values"]["b"] / best["b"])) <= smallest_log
    assert abs(res["values"]["c"] - best["c"]) <= smallest_lin
    short = pattern_search(bowl, {"a": 1.0, "b": 1.0, "c": 0.0}, 99.0, params, 5)
    assert not short["finished"] and short["evaluations"] == 5


def test_verdict_words():
    prof = {"k": {"score_low": 1.0, "score_high": 0.9}}
    v = verdict(1.0, prof, {"ukf": {"score": 0.999}}, {"evaluations": 7, "finished": True, "start": "own"})
    assert v["status"] == "stopped short" and v["short_by"] == pytest.approx(0.1) and v["by"] == "profile k x3"
    v = verdict(1.0, {"k": {"score_low": 1.0, "score_high": 1.0}}, {"ukf": {"score": 0.99}}, None)
    assert v["status"] == "stopped short" and v["by"] == "ukf's values"
    ok = verdict(1.0, {"k": {"score_low": 1.01, "score_high": 1.0 - TOLERANCE / 2}}, {},
                 {"evaluations": 7, "finished": True, "start": "own"})
    assert ok["status"] == "converged" and ok["short_by"] == 0.0
    out = verdict(1.0, {}, {}, {"evaluations": 7, "finished": False, "start": "own"})
    assert out["status"] == "stopped short" and "budget" in out["by"]
    assert verdict(1.0, None, None, None)["status"] == "not checked"


def test_the_closing_line_gives_a_gap_only_above_the_tolerance():
    """``nespm tune``'s line per filter: a budget that ran out with every check below the tolerance is
    "stopped short (the refinement budget ... ran out)", never "stopped short by 0.0 %"; a check above
    it gives its gain and the step."""
    from nespm_cli.reports.tune.searches import convergence_word

    spent = verdict(1.0, {"k": {"score_low": 1.0, "score_high": 1.0 - TOLERANCE / 10}}, {},
                    {"evaluations": 171, "finished": False, "start": "own"})
    assert convergence_word(spent) == "stopped short (the refinement budget (171 trials) ran out)"
    short = verdict(1.0, {"k": {"score_low": 1.0, "score_high": 0.969}}, {}, {"evaluations": 9, "finished": True})
    assert convergence_word(short) == "stopped short by 3.1 % (profile k x3)"
    assert convergence_word(verdict(1.0, {}, {}, {"evaluations": 9, "finished": True})) == "converged"
    assert convergence_word(verdict(1.0, None, None, None)) == "convergence not checked"


def test_refinement_finishes_a_short_search_and_the_report_says_so(tmp_path):
    """Two global trials leave the EKF short of its optimum: the profile at that best beats it (stopped
    short, said); with the refinement the best improves on every global trial, the profile's steps at
    the end point do not beat it (converged), and the refinement's trials are kept with their phase."""
    space = (("*", "acc_noise_scale", 0.01, 10.0), ("*", "r_scale_dvl", 0.1, 30.0)) + tuple(
        ("*", k, None, None) for k in ("gyro_noise_scale", "acc_bias_rw_scale", "gyro_bias_rw_scale", "p0_vel_scale",
                                       "p0_att_scale", "p0_acc_bias_scale", "p0_gyro_bias_scale"))
    spec = Spec(**SMALL, sensor_options=(("dvl", "r_std", "0.004"),))
    t = TuneSpec(spec, trials=2, objective="consistency", ranges=space, refine_trials=0)
    short = run_tune(t, tmp_path / "short")["best"]["ekf"]
    assert short["convergence"]["status"] == "stopped short" and short["convergence"]["short_by"] > TOLERANCE
    rec = run_tune(TuneSpec(spec, trials=2, objective="consistency", ranges=space), tmp_path / "refined")
    b = rec["best"]["ekf"]
    trials = pd.read_parquet(tmp_path / "refined" / "trials.parquet")
    glob = trials[trials["phase"] == "search"]
    assert len(glob) == 2 and b["score"] < glob["score"].min() * (1 - 0.1)
    assert b["phase"] == "refine" and b["convergence"]["status"] == "converged", b["convergence"]
    assert 0 < (trials["phase"] == "refine").sum() <= b["convergence"]["refine_trials"]  # a point seen before is not run again
    for pr in b["profile"].values():  # the end point's profile: no step better (by the tolerance)
        assert min(pr["score_low"], pr["score_high"]) >= b["score"] * (1 - TOLERANCE)
    # rerun: the refinement replays from the stored scores, nothing new is run
    again = run_tune(TuneSpec(spec, trials=2, objective="consistency", ranges=space), tmp_path / "refined")
    assert again["best"]["ekf"]["values"] == b["values"]
    assert len(pd.read_parquet(tmp_path / "refined" / "trials.parquet")) == len(trials)


def test_search_seed_apart_from_the_data_seed(tmp_path):
    """--search-seed changes the sampler's suggestions, not the training realizations (the default
    trial scores the same); the same --search-seed under two --seed values suggests alike in the
    search coordinates only where the data agree — here: the data differ, the default's score too."""
    base = ["--refine-trials", "0", "--trials", "4"]
    for name, extra in (("a", []), ("b", ["--search-seed", "7"]), ("c", ["--search-seed", "8"]),
                        ("d", ["--search-seed", "7", "--seed", "3"])):
        assert main(CLI[:-2] + base + extra + ["--out", str(tmp_path / name)]) == 0
    t = {n: pd.read_parquet(tmp_path / n / "trials.parquet").sort_values("trial") for n in "abcd"}
    assert t["a"]["score"].iloc[0] == t["b"]["score"].iloc[0] == t["c"]["score"].iloc[0]  # the same data
    assert not np.array_equal(t["b"]["p_acc_noise_scale"].iloc[1:], t["c"]["p_acc_noise_scale"].iloc[1:])
    assert t["d"]["score"].iloc[0] != t["b"]["score"].iloc[0]  # other data ...
    assert np.array_equal(t["d"]["p_acc_noise_scale"].iloc[1:10], t["b"]["p_acc_noise_scale"].iloc[1:10])  # ... same draws
    rec = json.loads((tmp_path / "b" / "tune.json").read_text())
    assert rec["search_seed"] == 7 and rec["tuned_on"]["seed_of"] == 0


def test_repeats_are_independent_searches_on_the_same_data(tmp_path):
    """Three searches of 4 trials: tuned.toml holds the one with the lowest training score (--pick best, the
    default). In this setting it is not the first (search 2's 1.1 % below searches 0 and 1, which end on the
    default: far beyond round-off), so search 0 is held out in a folder of its own."""
    assert main(CLI[:-1] + ["4", "--refine-trials", "0", "--repeats", "3", "--test-tracks", "6", "--test-runs", "2",
                            "--out", str(tmp_path / "t")]) == 0
    rec = json.loads((tmp_path / "t" / "tune.json").read_text())
    runs = rec["searches"]["ekf"]
    assert [r["search"] for r in runs] == [0, 1, 2] and len({r["search_seed"] for r in runs}) == 3
    scores = [r["score"] for r in runs]
    k = int(np.argmin(scores))
    assert k != 0 and min(scores[:k]) > 1.005 * scores[k], scores  # the setting's point (docstring)
    assert rec["pick"] == "best" and rec["picked"] == {"ekf": k} and rec["best"]["ekf"]["values"] == runs[k]["values"]
    assert f"# ekf: search {k} of 3 (the lowest training score" in (tmp_path / "t" / "tuned.toml").read_text()
    trials = pd.read_parquet(tmp_path / "t" / "trials.parquet")
    a, b = (trials[trials["search"] == j].sort_values("trial") for j in (0, 1))
    assert a["score"].iloc[0] == b["score"].iloc[0]  # the default, on the same training runs
    assert a["p_acc_noise_scale"].iloc[1] != b["p_acc_noise_scale"].iloc[1]
    # every search held out in its own folder (search 0's too: heldout-tuned holds tuned.toml's, search k's)
    for d in ("heldout-default", "heldout-tuned", "heldout-tuned-search0", "heldout-tuned-search1",
              "heldout-tuned-search2"):
        assert (tmp_path / "t" / d / "metrics.parquet").exists(), d
    tuned, own = (pd.read_parquet(tmp_path / "t" / d / "metrics.parquet") for d in ("heldout-tuned",
                                                                                   f"heldout-tuned-search{k}"))
    pd.testing.assert_frame_equal(tuned.drop(columns="seconds"), own.drop(columns="seconds"))
    assert main(["report", str(tmp_path / "t")]) == 0
    assert f"ekf search {k}." in (tmp_path / "t" / "report.md").read_text()
    # --pick first: tuned.toml holds search 0's values again, and search 0 is heldout-tuned
    assert main(CLI[:-1] + ["4", "--refine-trials", "0", "--repeats", "3", "--pick", "first",
                            "--out", str(tmp_path / "f")]) == 0
    first = json.loads((tmp_path / "f" / "tune.json").read_text())
    assert first["picked"] == {"ekf": 0} and first["best"]["ekf"]["values"] == runs[0]["values"]


def test_pick_best_takes_the_lowest_training_score_and_first_the_first():
    from nespm_cli.tuning.run import pick_searches

    searches = [{"ekf": {"score": 0.30}, "ukf": {"score": 0.20}}, {"ekf": {"score": 0.25}, "ukf": {"score": 0.20}},
                {"ekf": {"score": 0.27}, "ukf": {"score": 0.21}}]
    assert pick_searches(searches, "best") == {"ekf": 1, "ukf": 0}  # a tie: the first of the equal ones
    assert pick_searches(searches, "first") == {"ekf": 0, "ukf": 0}


@pytest.mark.parametrize("name", ["study.journal", "study.db"])
@pytest.mark.parametrize("content", [b"", b"\x00\x01garbage" * 64, b"just some text\n", "truncated"])
def test_a_study_file_that_is_not_a_study_is_one_line(tmp_path, capsys, content, name):
    """The journal (what tune writes) and the SQLite study.db (a tuning from before it, still continued):
    empty, random bytes, text, or a real one cut short, each one line naming the file, nothing written."""
    out = tmp_path / "t"
    out.mkdir()
    if content == "truncated" and name == "study.db":  # a real SQLite file (rollback journal: all in the file) cut to a third
        import sqlite3

        con = sqlite3.connect(out / name)
        con.execute("CREATE TABLE t (i INTEGER PRIMARY KEY, x TEXT)")
        con.executemany("INSERT INTO t (x) VALUES (?)", [("x" * 200,) for _ in range(2000)])
        con.commit()
        con.close()
        data = (out / name).read_bytes()
        (out / name).write_bytes(data[: len(data) // 3])
    elif content == "truncated":  # a real journal, cut in its middle
        assert main(CLI + ["--refine-trials", "0", "--trials", "2", "--out", str(tmp_path / "whole")]) == 0
        data = (tmp_path / "whole" / name).read_bytes()
        assert data.count(b"\n") > 10
        (out / name).write_bytes(data[: len(data) // 2 + 7])
        capsys.readouterr()
    else:
        (out / name).write_bytes(content)
    before = sorted(p.name for p in out.iterdir())
    rc = main(CLI + ["--refine-trials", "0", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and name in err and "Traceback" not in err, err
    assert sorted(p.name for p in out.iterdir()) == before


def test_dask_backend_gives_the_local_values(tmp_path):
    """tune --backend dask on a local 2-worker cluster: a task per filter, each study one writer: the
    trials (global search and refinement) equal --jobs 1's bit for bit."""
    pytest.importorskip("distributed")
    argv = CLI[:-2] + ["--filters", "ekf,ukf", "--trials", "3", "--refine-trials", "6"]
    assert main(argv + ["--out", str(tmp_path / "one")]) == 0
    assert main(argv + ["--backend", "dask", "--jobs", "2", "--out", str(tmp_path / "dask")]) == 0
    cols = ["filter", "search", "trial", "phase", "score"]
    one, dask = (pd.read_parquet(tmp_path / d / "trials.parquet") for d in ("one", "dask"))
    pcols = [c for c in one.columns if c.startswith("p_")]
    pd.testing.assert_frame_equal(one[cols + pcols], dask[cols + pcols])
    assert json.loads((tmp_path / "dask" / "tune.json").read_text())["backend"] == "dask"


def test_pattern_search_moves_on_a_sufficient_decrease_only():
    """A gain below :data:`MOVE` (a tenth of the verdict's tolerance) is not a move: on a slope of 1e-4
    per first step the search does not crawl but finishes where it started, after one pass per level
    and the last pass (2 points per parameter each); a slope of 1e-3 per step moves it."""
    from nespm_cli.tuning.refine import MOVE

    params = [Param("f", "a", 0.01, 100.0), Param("f", "b", 0.01, 100.0)]
    for slope, moves in ((0.2 * MOVE, False), (2.0 * MOVE, True)):
        def score(x, slope=slope):
            return 1.0 - slope * math.log(x["a"]) / math.log(3.0)

        res = pattern_search(score, {"a": 1.0, "b": 1.0}, 1.0, params, 1000)
        assert res["finished"]
        assert (res["values"]["a"] > 1.0) == moves, res
        if not moves:
            assert res["evaluations"] == 2 * len(params) * (LEVELS + 2)


def ridge_case(seed: int):
    """A score with a ridge across the axes (three log factors that only their differences pin within
    the budget, like make tune-main's accelerometer noise, R and P0 of attitude), seven weakly seen
    factors and a lever arm; its minimum is 1 at a random point."""
    rng = np.random.default_rng(seed)
    params = [Param("f", f"p{i}", 0.1, 10.0) for i in range(10)] + [Param("f", "lev", -4.6, 1.4, log=False)]
    opt = np.exp(rng.uniform(-1.0, 1.0, 10))

    def score(x):
        u = [math.log(x[f"p{i}"] / opt[i]) for i in range(10)]
        return (1 + 0.3 * (u[0] - u[4]) ** 2 + 0.3 * (u[0] - u[7]) ** 2 + 0.002 * (u[0] + u[4] + u[7]) ** 2
                + sum(0.02 * u[i] ** 2 for i in (1, 2, 3, 5, 6, 8, 9)) + 0.5 * (x["lev"] + 1.6) ** 2)

    return params, score, {**{p.key: 1.0 for p in params[:10]}, "lev": -1.0}


def test_the_model_follows_a_ridge_that_polls_along_the_axes_do_not():
    """Within the default budget, the refinement (BOBYQA's model, then the polls) ends on average nearer
    the minimum than the polls alone (measured over 5 seeds: mean gap 0.0040 against 0.0060; 0.0127 for
    the polls without pattern moves), says it finished, finds the lever arm to its finer linear step
    (1/96 of the range, 0.0625 m), and is a pure function of the scores (the same calls twice)."""
    from nespm_cli.tuning.refine import auto_budget, refine

    gaps_model, gaps_polls = [], []
    for seed in range(5):
        params, score, x0 = ridge_case(seed)
        budget = auto_budget(params)
        res = refine(score, x0, score(x0), params, budget)
        assert res["finished"] and res["evaluations"] <= budget and res["model"] > 0
        assert abs(res["values"]["lev"] + 1.6) <= 6.0 / 96
        gaps_model.append(res["score"] - 1)
        gaps_polls.append(pattern_search(score, x0, score(x0), params, budget)["score"] - 1)
        calls = []
        again = refine(lambda x: calls.append(dict(x)) or score(x), x0, score(x0), params, budget)
        assert again == res and len(calls) == res["evaluations"]
    assert np.mean(gaps_model) < np.mean(gaps_polls), (gaps_model, gaps_polls)
