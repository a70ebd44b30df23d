"""benchmarks/bench_per_run.py and per_run_parts.py: the arithmetic of the per-part table (the cost of an
extra run from two sizes, the medians and ranges) and the CPU-time wrapper. Nothing here runs ``mc``."""
from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def load(name):
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(BENCH))


@pytest.fixture(scope="module")
def bp():
    return load("bench_per_run")


def measurement(runs, draws, filt, metrics, writing, process, steps=39900):
    return {"runs": runs, "steps": steps,
            "cpu": {"draws": draws, "filter": filt, "metrics": metrics, "writing": writing, "process": process}}


def test_per_extra_run_is_the_difference_over_the_added_runs(bp):
    small = measurement(20, 0.25, 0.70, 0.05, 0.02, 2.30)
    large = measurement(120, 1.25, 2.70, 0.25, 0.06, 5.30)
    d = bp.per_run(small, large)  # (large - small) / 100 runs, in ms
    assert d["draws"] == pytest.approx(10.0)
    assert d["filter"] == pytest.approx(20.0)
    assert d["metrics"] == pytest.approx(2.0)
    assert d["writing"] == pytest.approx(0.4)
    assert d["process"] == pytest.approx(30.0)
    assert d["filter_us_step"] == pytest.approx(20.0e3 / 39900)  # 0.501 µs per run-step


def test_spread_is_median_and_range(bp):
    assert bp.spread([3.0, 1.0, 2.0]) == "2.00 (1.00-3.00)"
    assert bp.spread([1.0, 2.0]) == "1.50 (1.00-2.00)"


def test_timed_adds_cpu_time_per_label_and_passes_through():
    pr = load("per_run_parts")
    acc = {}

    def busy(n, *, k=1):
        t0 = time.process_time()
        while time.process_time() - t0 < 0.02:
            pass
        return n * k

    f = pr.timed(busy, "filter", acc)
    assert f(3, k=2) == 6 and f(1) == 1
    assert acc["filter"] >= 0.04  # two calls of at least 20 ms CPU each
    with pytest.raises(ZeroDivisionError):
        pr.timed(lambda: 1 / 0, "draws", acc)()
    assert "draws" in acc  # counted even when the call raises
