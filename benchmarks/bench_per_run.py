"""The cost of one extra Monte Carlo run, per part, EKF against UKF-NESPM (issue 41 item 2).

``nespm mc --tracks 5 --runs R --filters F --chunk-size 200 --jobs 1`` (one chunk, one core) for
R = ``--small`` and ``--large`` runs; the cost of an extra run is the difference over ``large - small``
(what every run costs, without the start-up and the per-chunk constants). Each measurement is a fresh
process (:mod:`per_run_parts`: CPU time per part, user + system, so page faults count) whose
``PYTHONPATH`` names one tree: this one, or ``--base DIR`` too (a worktree of another commit, e.g.
``git worktree add /tmp/base HEAD``), so that other developers' edits do not move a tree's numbers.
The trees, filters and sizes run in turn, round after round (the machine is shared: other jobs' load
hits every cell alike); each cell is the median over the rounds with its range.

Parts: ``draws`` (``mc.realization_inputs``: the IMU errors, the corrupted IMU, initial errors, sensor
channels), ``filter`` (``run_filter``), ``metrics`` (the rest of the chunk: error norms, NEES, the
tables), ``writing`` (``write_chunk``: Parquet and its hash), ``process`` (the whole command).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_per_run.py [--base /tmp/base] [--rounds 3]``
(writes ``results/bench/per_run.json``; prints the table in the README's form).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PARTS = ("draws", "filter", "metrics", "writing", "process")


def one(tree: Path, runs: int, filt: str) -> dict:
    """One :mod:`per_run_parts` measurement of ``tree`` (its last stdout line, JSON)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    env.pop("NESPM_DATA_DIR", None)  # the embedded track 5
    with tempfile.TemporaryDirectory(prefix="per-run-") as tmp:
        p = subprocess.run([sys.executable, str(HERE / "per_run_parts.py"), "--runs", str(runs), "--filter", filt,
                            str(Path(tmp) / "out")], env=env, capture_output=True, text=True, cwd=tmp)
    if p.returncode:
        raise SystemExit(f"{tree}: {filt} R={runs}: {p.stderr.strip().splitlines()[-1:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def per_run(small: dict, large: dict) -> dict:
    """Per extra run [ms] of each part, and the filter's [µs per run-step]."""
    n = large["runs"] - small["runs"]
    d = {k: (large["cpu"][k] - small["cpu"][k]) / n * 1e3 for k in PARTS}
    d["filter_us_step"] = d["filter"] * 1e3 / large["steps"]
    return d


def spread(xs: list[float]) -> str:
    """``median (min-max)``."""
    return f"{statistics.median(xs):.2f} ({min(xs):.2f}-{max(xs):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="a second tree (worktree of another commit), measured in turn")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the tree under test (default: this one)")
    ap.add_argument("--also", action="append", default=[], metavar="LABEL=DIR",
                    help="more trees measured in turn (e.g. a proposed change to other files)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--small", type=int, default=20)
    ap.add_argument("--large", type=int, default=120)
    ap.add_argument("--filters", default="ekf,ukf-nespm")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bench" / "per_run.json")
    a = ap.parse_args()
    trees = {"now": a.tree} if a.base is None else {"base": a.base, "now": a.tree}
    trees.update(dict((x.split("=", 1)[0], Path(x.split("=", 1)[1])) for x in a.also))
    filters = a.filters.split(",")
    load0 = os.getloadavg()[0]
    rounds: list[dict] = []
    for i in range(a.rounds):
        got: dict = {}
        for label, tree in trees.items():
            for filt in filters:
                m = {r: one(tree, r, filt) for r in (a.small, a.large)}
                got.setdefault(label, {})[filt] = per_run(m[a.small], m[a.large])
        rounds.append(got)
        print(f"round {i + 1}: " + json.dumps({t: {f: {k: round(v, 2) for k, v in d.items()} for f, d in g.items()}
                                                 for t, g in got.items()}), file=sys.stderr)
    load1 = os.getloadavg()[0]
    print(f"Per extra run [ms CPU], {a.small} -> {a.large} runs in one chunk, one core, median (range) of "
          f"{a.rounds} rounds; load {load0:.1f} -> {load1:.1f}\n")
    print("| tree | filter | draws | filter | filter [µs/run-step] | metrics | writing | outside the filter | "
          "whole command |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for label in trees:
        for filt in filters:
            xs = [r[label][filt] for r in rounds]
            outside = [x["process"] - x["filter"] for x in xs]
            print(f"| {label} | {filt} | " + " | ".join(spread([x[k] for x in xs]) for k in
                                                       ("draws", "filter", "filter_us_step", "metrics", "writing"))
                  + f" | {spread(outside)} | {spread([x['process'] for x in xs])} |")
    if len(filters) == 2:
        print()
        for label in trees:
            ratios = [r[label][filters[1]]["process"] / r[label][filters[0]]["process"] for r in rounds]
            print(f"{label}: {filters[1]} / {filters[0]} per extra run (whole command): {spread(ratios)}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"rounds": rounds, "trees": {k: str(v) for k, v in trees.items()},
                                 "small": a.small, "large": a.large, "load": [load0, load1]}, indent=1))


if __name__ == "__main__":
    main()
