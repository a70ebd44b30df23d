"""benchmarks/compare_table.py: the pure functions behind bench_compare's table and README section
(medians, paired ratios, the dash for a filter a tree lacks, the marked section rewritten). Nothing
here runs or times a filter."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "compare_table.py"


@pytest.fixture(scope="module")
def ct():
    spec = importlib.util.spec_from_file_location("compare_table", PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def rounds(costs_per_round, filters):
    return [{"filters": list(filters), "cost_us": c} for c in costs_per_round]


def test_median_spread_and_paired_ratio(ct):
    assert ct.median([3.0, None, 1.0, 2.0]) == 2.0
    assert ct.median([None]) is None
    assert ct.spread([1.0, 2.0, 1.5]) == pytest.approx(1.0 / 1.5)
    assert ct.spread([2.0]) == 0.0
    # the median of the per-round ratios, not the ratio of the medians
    assert ct.paired_ratio([1.0, 4.0, 3.0], [2.0, 2.0, 1.0]) == 2.0
    assert ct.paired_ratio([1.0, None], [None, 2.0]) is None
    assert ct.fmt(None) == ct.DASH and ct.fmt(1.23456, 3) == "1.235"


def test_steps_table_dash_for_a_filter_the_base_lacks(ct):
    base = rounds([{"ekf": {"12": 0.5, "15": 0.6}, "ukf-nespm": {"12": 3.0, "15": 4.0}}] * 2, ["ekf", "ukf-nespm"])
    now = rounds([{"ekf": {"12": 0.5, "15": 0.4}, "ukf-nespm": {"12": 1.4, "15": 1.8},
                   "vb-ekf": {"12": 0.45, "15": None}}] * 2, ["ekf", "ukf-nespm", "vb-ekf"])
    md, verdicts = ct.steps_table(base, now)
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in md.splitlines()[2:]}
    assert list(rows) == ["ekf", "ukf-nespm", "vb-ekf"]
    assert rows["ekf"] == ["0.500", "0.500", "1.00", "0.600", "0.400", "0.67"]
    assert rows["vb-ekf"] == [ct.DASH, "0.450", ct.DASH, ct.DASH, ct.DASH, ct.DASH]
    assert "ukf-nespm, 12 states, R = 100: 1.400 µs (≤ 1.5 µs: met)" in verdicts
    assert any(v.startswith("EKF 15 states DVL+depth+fixes / 12 states DVL, now: 0.80 (≤ 1.3: met)") for v in verdicts)


def test_slower_filter_is_flagged(ct):
    base = rounds([{"ukf": {"12": 1.0, "15": 1.0}}], ["ukf"])
    now = rounds([{"ukf": {"12": 1.2, "15": 1.0}}], ["ukf"])
    _, verdicts = ct.steps_table(base, now)
    assert verdicts == ["ukf, 12 states: now/base 1.20 (slower than the base by more than 5 %)"]


def test_jobs_table_tune_memory_and_missing_base(ct):
    res = {"tune": {"trials": 50, "runs": 20, "mc_runs": 1000,
                    "now": {"tune": [{"cpu_s": 30.0}, {"cpu_s": 36.0}], "mc": [{"cpu_s": 25.0}, {"cpu_s": 24.0}]}},
           "main": {"base": [{"wall_s": 20.0, "cpu_s": 40.0, "maxrss_mb": 300.0, "tree_mb": 900.0}],
                    "now": [{"wall_s": 10.0, "cpu_s": 20.0, "maxrss_mb": 330.0, "tree_mb": 990.0}]},
           "memory": {"runs": [1000, 10000], "now": {"1000": [{"maxrss_mb": 500.0}], "10000": [{"maxrss_mb": 550.0}]}}}
    md, verdicts = ct.jobs_table(res)
    assert f"| {ct.DASH} | 1.35 (33.0 s / 24.5 s) |" in md
    assert "| main job wall [s] | 20.0 | 10.0 | 0.50 |" in md
    assert "| peak RSS 10,000 / 1,000 runs | — | 1.10 | |" in md
    assert "tuning overhead: 1.35 x one 1000-run mc (≤ 1.5: met)" in verdicts
    assert "memory 10,000 / 1,000 runs: 1.10 (≤ 1.2: met)" in verdicts


def test_rewrite_section_replaces_only_between_the_markers(ct):
    text = f"# B\n\nbefore\n\n{ct.BEGIN}\nold table\n{ct.END}\n\nafter\n"
    out = ct.rewrite_section(text, "new table\n")
    assert out == f"# B\n\nbefore\n\n{ct.BEGIN}\n\nnew table\n\n{ct.END}\n\nafter\n"
    assert ct.rewrite_section(out, "new table") == out  # idempotent


def test_rewrite_section_appends_when_absent_and_refuses_a_broken_one(ct):
    out = ct.rewrite_section("# B\n", "t")
    assert out.startswith("# B\n\n## ") and out.endswith(f"{ct.BEGIN}\n\nt\n\n{ct.END}\n")
    with pytest.raises(ValueError):
        ct.rewrite_section(f"x {ct.END} y {ct.BEGIN}", "t")
    with pytest.raises(ValueError):
        ct.rewrite_section(f"x {ct.BEGIN} y", "t")


@pytest.fixture(scope="module")
def bc():
    path = PATH.parent / "bench_compare.py"
    spec = importlib.util.spec_from_file_location("bench_compare", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_merge_takes_the_parts_not_measured_from_the_earlier_run(bc):
    res = {"base": "b27d778", "steps": {"base": [1], "now": [2]}, "tune": {"trials": 50}, "main": {"base": [], "now": []},
           "notes": []}
    old = {"base": "b27d778", "date": "d", "now": "fe909fd", "load": "1 and 5", "plan": {"rounds": 3},
           "steps": {"base": [0], "now": [0]}, "tune": {"trials": 50, "now": {"tune": [], "mc": []}},
           "main": {"base": [{"wall_s": 1.0}], "now": []}, "memory": {"runs": [1000, 10000]},
           "notes": ["The base has no `nespm tune`: its tuning overhead is \"—\"."]}
    bc.merge(res, old, ["steps"])
    assert res["steps"] == {"base": [1], "now": [2]}  # measured now: kept
    assert res["main"] is old["main"] and res["memory"] is old["memory"] and res["tune"] is old["tune"]
    assert res["notes"][0].startswith("The base has no `nespm tune`")
    assert res["notes"][-1].startswith("tune, main, memory: from the run of d against the same base")
    with pytest.raises(bc.Refused):
        bc.merge(dict(res, base="0000000"), old, ["steps"])


def test_bad_options_are_one_line_exit_2(bc, capsys):
    assert bc.main(["--base", "b27d778", "--parts", "steps,nope"]) == 2
    assert bc.main(["--base", "b27d778", "--epochs", "3"]) == 2
    assert bc.main(["--rounds", "2"]) == 2  # --base missing
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("bench_compare: ") for line in err)
