"""Monte Carlo runner benchmark: the whole ``mc`` job and the cost of batching.

Run: ``.venv/bin/python benchmarks/bench_mc.py [--data-dir DIR] [--runs 100]``.
Writes ``results/bench/mc.json``. Figures are whole-process wall times on this machine
(2 cores); the issue's targets: ``mc --tracks 5 6 --runs 100 --filters ekf,ukf,ukf-nespm``
under 5 minutes, and 32 runs in one batch under 4 times the cost of one run.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def batch_cost(data_dir: str | None, filt: str, sizes=(1, 32)) -> dict:
    """Wall seconds of one filter over track 5 for a batch of each size (median of 3)."""
    from nespm_cli.experiments.inputs import prepared
    from nespm_cli.experiments.mc import simulate
    from nespm_cli.experiments.spec import Spec, validate

    spec = validate(Spec(tracks=(5,), runs=max(sizes), filters=(filt,), data_dir=data_dir))
    prepared(5, spec.data_dir, spec.imu)  # synthesis outside the timing
    out = {}
    for n in sizes:
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            simulate(spec, 5, np.arange(n), [filt])
            times.append(time.perf_counter() - t0)
        out[n] = float(np.median(times))
    return out


def whole_mc(data_dir: str | None, runs: int, jobs: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "nespm_cli.cli", "mc", "--tracks", "5", "6", "--runs", str(runs),
               "--filters", "ekf,ukf,ukf-nespm", "--jobs", str(jobs), "--out", tmp, "--no-progress"]
        if data_dir:
            cmd += ["--data-dir", data_dir]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    res = {"data_dir": a.data_dir or "embedded", "runs": a.runs, "jobs": a.jobs}
    for filt in ("ekf", "ukf-nespm"):
        c = batch_cost(a.data_dir, filt)
        res[f"batch_{filt}"] = {"1_run_s": round(c[1], 3), "32_runs_s": round(c[32], 3), "ratio": round(c[32] / c[1], 2)}
        print(f"{filt:10s} 1 run {c[1]:6.2f} s   32 runs in one batch {c[32]:6.2f} s   ratio {c[32] / c[1]:.2f} (target < 4)")
    w = whole_mc(a.data_dir, a.runs, a.jobs)
    res["mc_wall_s"] = round(w, 1)
    print(f"mc --tracks 5 6 --runs {a.runs} --filters ekf,ukf,ukf-nespm --jobs {a.jobs}: {w:.1f} s wall (target < 300 s)")
    out = ROOT / "results" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    (out / "mc.json").write_text(json.dumps(res, indent=2))
    print(f"wrote {out / 'mc.json'}")


if __name__ == "__main__":
    main()
