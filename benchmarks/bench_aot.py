"""Ahead-of-time compiled kernels (numba.pycc) against the JIT's per-user cache (issue 41 item 1).

Builds the default ``mc``'s two kernels, ``points_span_soa`` (UKF-NESPM's sigma points) and
``transition_span_12`` (the EKF's and UKF's Φ, run by run), as a C extension with ``numba.pycc`` for each
``--targets`` CPU (``generic``: the portable x86-64 a wheel would ship; ``x86-64-v3``: AVX2 and FMA,
CPUs since about 2015; ``host``: this machine's), each build in a fresh process with an empty kernel
cache, timed as a whole (CPU, user + system, gcc's link included). Then, in one process: the import
time of the built modules (they do not import numba), and per kernel and R the ns per run-step (minimum of ``--calls`` calls, 100 IMU
steps of random 12-state inputs, as ``bench_points_kernel.py``) of each build beside the JIT-compiled
kernel, and whether each build's outputs are the JIT's to the bit. Nothing is written into the tree
(a temporary folder holds the builds and a kernel cache of their own).

``numba.pycc`` is pending deprecation in numba; this measures whether the route would serve, it is
not used by nespm (benchmarks/README.md says what was measured and why the cache stays).

Run: ``PYTHONPATH=. python benchmarks/bench_aot.py [--targets generic x86-64-v3 host] [--runs 1 8 50]``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

BUILD = r"""
import sys, warnings
warnings.simplefilter("ignore")
from numba.pycc import CC
from nespm_cli.filters.compiled.points import points_span_soa
from nespm_cli.filters.compiled.unrolled_12 import transition_span_12
target, out, name = sys.argv[1:4]
cc = CC(name)
cc.output_dir = out
if target != "generic":
    cc.target_cpu = target
A1, A2, A3, A4, I1 = "f8[::1]", "f8[:, ::1]", "f8[:, :, ::1]", "f8[:, :, :, ::1]", "i8[::1]"
cc.export("points_span_soa", f"void({A2}, {A2}, {A3}, {A2}, {A2}, {A3}, {A3}, {A3}, {A1}, i8, i8, {A3}, {A3}, {A4}, "
          f"{A3}, {I1})")(points_span_soa.py_func)
cc.export("transition_span_12", f"void({A2}, {A2}, {A3}, {A2}, {A2}, {A3}, {A3}, {A1}, i8, i8, {A3})")(
    transition_span_12.py_func)
cc.compile()
"""

COMPARE = r"""
import importlib, json, sys, time
import numpy as np
out, calls, names, runs = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(","), [int(a) for a in sys.argv[4:]]
sys.path.insert(0, out)
t = time.perf_counter()
mods = {n: importlib.import_module(n) for n in names}
res = {"import_s": time.perf_counter() - t, "numba_imported": "numba" in sys.modules, "cells": []}
from nespm_cli.filters import kernels
from nespm_cli.filters.compiled.points import points_span_soa
from nespm_cli.filters.compiled.unrolled_12 import transition_span_12
off = kernels.LAYOUT_12.offsets()
for R in runs:
    rng = np.random.default_rng(3)
    n, M = 12, 100
    S = 2 * n + 1
    pos = np.column_stack([0.55 + 0.01 * rng.standard_normal(R), 0.6 + 0.01 * rng.standard_normal(R),
                           -20 + rng.standard_normal(R)])
    v, C = rng.standard_normal((R, 3)), np.ascontiguousarray(np.linalg.qr(rng.standard_normal((R, 3, 3)))[0])
    ba, bg = 1e-3 * rng.standard_normal((R, 3)), 1e-4 * rng.standard_normal((R, 3))
    X = 1e-2 * rng.standard_normal((R, 2 * n, n))
    f, w = rng.standard_normal((R, M, 3)) + [0.0, 0.0, -9.8], 0.1 * rng.standard_normal((R, M, 3))
    dt = np.full(M, 0.01)
    builds = {"jit": (points_span_soa, transition_span_12)}
    builds.update({k.removeprefix("nespm_aot_"): (m.points_span_soa, m.transition_span_12) for k, m in mods.items()})
    ref = {}
    for label, (points, transition) in builds.items():
        o = np.empty((R, S, 3)), np.empty((R, S, 3)), np.empty((R, S, 3, 3)), np.zeros((R, S, 3))
        best_p = best_t = float("inf")
        for _ in range(calls):
            t = time.perf_counter()
            points(pos, v, C, ba, bg, X, f, w, dt, 0, M, *o, off)
            best_p = min(best_p, time.perf_counter() - t)
            p2, v2, C2, Phi = pos.copy(), v.copy(), C.copy(), np.empty((R, 12, 12))
            t = time.perf_counter()
            transition(p2, v2, C2, ba, bg, f, w, dt, 0, M, Phi)
            best_t = min(best_t, time.perf_counter() - t)
        got = [*o[:3], p2, v2, C2, Phi]
        ref.setdefault("jit", got)
        same = all(np.array_equal(a, b) for a, b in zip(ref["jit"], got))
        res["cells"].append({"build": label, "R": R, "points_ns": best_p / (R * M) * 1e9,
                             "transition_ns": best_t / (R * M) * 1e9, "same_bits": same})
print(json.dumps(res))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", nargs="+", default=["generic", "x86-64-v3", "host"])
    ap.add_argument("--runs", type=int, nargs="+", default=[1, 8, 50])
    ap.add_argument("--calls", type=int, default=25)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="nespm-aot-") as tmp:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "NESPM_CACHE_DIR": str(Path(tmp) / "cache")}
        names = []
        for target in a.targets:
            name = "nespm_aot_" + target.replace("-", "_")
            t0, c0 = time.perf_counter(), os.times()
            cache = {"NESPM_CACHE_DIR": str(Path(tmp) / f"cache-{target}")}  # each build compiles the helpers too
            subprocess.run([sys.executable, "-c", BUILD, target, tmp, name], env={**env, **cache}, check=True, cwd=tmp)
            c1 = os.times()
            cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
            print(f"build {target}: {cpu:.2f} CPU-s, {time.perf_counter() - t0:.2f} s wall (a fresh process)", flush=True)
            names.append(name)
        p = subprocess.run([sys.executable, "-c", COMPARE, tmp, str(a.calls), ",".join(names), *map(str, a.runs)],
                           env=env, check=True, cwd=tmp, capture_output=True, text=True)
        res = json.loads(p.stdout.strip().splitlines()[-1])
    print(f"\nimporting the {len(names)} built modules: {res['import_s'] * 1e3:.1f} ms; numba imported by them: "
          f"{res['numba_imported']}")
    print("\n| build | runs | points [ns/run-step] | Φ 12 [ns/run-step] | the JIT's bits |\n| --- | ---: | ---: | ---: | --- |")
    for c in res["cells"]:
        print(f"| {c['build']} | {c['R']} | {c['points_ns']:.0f} | {c['transition_ns']:.0f} | "
              f"{'same' if c['same_bits'] else 'DIFFERENT'} |")


if __name__ == "__main__":
    main()
