"""The sigma-point kernel alone (``filters.compiled.points.points_span_soa``), ns per run-step, this tree
against another (issue 41).

Each tree runs in its own process (``PYTHONPATH`` names it, so that ``nespm_cli`` is that tree's) on the
same random inputs: R runs of a 12- or 15-state layout (25 or 31 points), 100 IMU steps of 0.01 s, the
kernel compiled (or loaded from the per-user cache) before timing; each cell is the minimum of
``--calls`` calls, and the trees run in turn, round after round (the machine is shared). Prints one line per
tree, layout and R, then the table in the README's form.

Run: ``git worktree add /tmp/base <commit>`` then
``python benchmarks/bench_points_kernel.py --base /tmp/base [--runs 1 8 50] [--rounds 3]``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
import numpy as np
from nespm_cli.filters import kernels
from nespm_cli.filters.compiled import points as pk

import nespm_cli, pathlib
print(json.dumps({"tree": str(pathlib.Path(nespm_cli.__file__).resolve().parent.parent)}))
calls, out = int(sys.argv[1]), {}
for n in (12, 15):
    layout = kernels.LAYOUT_12 if n == 12 else kernels.LAYOUT_15
    for R in [int(a) for a in sys.argv[2:]]:
        rng = np.random.default_rng(3)
        M, S = 100, 2 * n + 1
        pos = np.column_stack([0.55 + 0.01 * rng.standard_normal(R), 0.6 + 0.01 * rng.standard_normal(R),
                               -20 + rng.standard_normal(R)])
        v, C = rng.standard_normal((R, 3)), np.linalg.qr(rng.standard_normal((R, 3, 3)))[0]
        ba, bg = 1e-3 * rng.standard_normal((R, 3)), 1e-4 * rng.standard_normal((R, 3))
        X = 1e-2 * rng.standard_normal((R, 2 * n, n))
        f, w = rng.standard_normal((R, M, 3)) + [0.0, 0.0, -9.8], 0.1 * rng.standard_normal((R, M, 3))
        args = (pos, v, C, ba, bg, X, f, w, np.full(M, 0.01), 0, M)
        o = np.empty((R, S, 3)), np.empty((R, S, 3)), np.empty((R, S, 3, 3)), np.zeros((R, S, 3))
        pk.points_span_soa(*args, *o, layout.offsets())
        best = float("inf")
        for _ in range(calls):
            t = time.perf_counter()
            pk.points_span_soa(*args, *o, layout.offsets())
            best = min(best, time.perf_counter() - t)
        out[f"{n} {R}"] = best / (R * M) * 1e9
print(json.dumps(out))
"""


def one(tree: Path, calls: int, runs: list[int]) -> dict:
    """ns per run-step by ``"n R"`` for ``tree`` (a fresh process)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    p = subprocess.run([sys.executable, "-c", CHILD, str(calls), *map(str, runs)], env=env, capture_output=True,
                       text=True, check=True, cwd=tempfile.gettempdir())  # not a tree's folder: "-c" puts the cwd first
    assert json.loads(p.stdout.strip().splitlines()[-2])["tree"] == str(tree.resolve()), "imported another tree"
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="a second tree (worktree of another commit)")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the tree under test (default: this one)")
    ap.add_argument("--runs", type=int, nargs="+", default=[1, 8, 50])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calls", type=int, default=25)
    a = ap.parse_args()
    trees = {"now": a.tree, "base": a.base}
    cells: dict[tuple[str, str], list[float]] = {}
    for r in range(a.rounds):
        for label, tree in trees.items():
            for key, ns in one(tree, a.calls, a.runs).items():
                cells.setdefault((label, key), []).append(ns)
                print(f"round {r + 1} {label} n,R={key}: {ns:.0f} ns per run-step", flush=True)
    print("\n| layout | runs | now | base | now / base (medians) |\n| --- | ---: | ---: | ---: | ---: |")
    for n in (12, 15):
        for R in a.runs:
            now, base = sorted(cells[("now", f"{n} {R}")]), sorted(cells[("base", f"{n} {R}")])
            ratio = now[len(now) // 2] / base[len(base) // 2]
            print(f"| {n} states | {R} | {now[0]:.0f}-{now[-1]:.0f} | {base[0]:.0f}-{base[-1]:.0f} | {ratio:.2f} |")


if __name__ == "__main__":
    main()
