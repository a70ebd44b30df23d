"""Cost per run-step of the adaptive-R EKFs (``iae-ekf``, ``sh-ekf``, ``vb-ekf``) relative to ``ekf``.

Issue 32 asks each at most 1.5x the EKF. The four filters run interleaved (so a busy machine
slows them alike) over the first ``--epochs`` GT epochs of embedded track 5 (synthetic DVL at 1
Hz, 100 IMU steps per epoch) on R = 1, 8, 32, 100 realizations, on one core; the cost is the
minimum of ``--repeat`` runs divided by R x steps, and the ratio is to the EKF's at the same R.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_adaptive_r.py [--epochs 40] [--repeat 7]``.
Writes ``results/bench/adaptive_r.json``.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, before NumPy loads

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
FILTERS = ("ekf", "iae-ekf", "sh-ekf", "vb-ekf")
SIZES = (1, 8, 32, 100)


def main() -> None:
    from bench_run_step import inputs, run_once

    ap = argparse.ArgumentParser()
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "adaptive_r.json"))
    a = ap.parse_args()
    steps = (a.epochs - 1) * 100
    res = {"epochs": a.epochs, "steps": steps, "cost_us": {}, "ratio_to_ekf": {}}
    print(f"cost per run-step [µs] and ratio to ekf, {steps} IMU steps, one core, min of {a.repeat}")
    for R in SIZES:
        args = inputs(a.epochs, R)
        for f in FILTERS:
            run_once(f, args, None)  # warm-up
        t = {f: [] for f in FILTERS}
        for _ in range(a.repeat):
            for f in FILTERS:
                t[f].append(run_once(f, args, None))
        cost = {f: 1e6 * min(v) / (R * steps) for f, v in t.items()}
        res["cost_us"][R] = cost
        res["ratio_to_ekf"][R] = {f: cost[f] / cost["ekf"] for f in FILTERS[1:]}
        print(f"R={R:<4} ekf {cost['ekf']:.2f} µs; " + ", ".join(f"{f} {cost[f]:.2f} µs (x{cost[f] / cost['ekf']:.2f})"
                                                           for f in FILTERS[1:]), flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
