"""Benchmark of the numeric foundation: IMU synthesis and the batched na_cycle.

Run from the repository root:

    PYTHONPATH=. .venv/bin/python benchmarks/bench_foundation.py [--data-dir DIR] [--out FILE]

* IMU synthesis (``synthesis.synthesize``) of one 400 s track (400 GT epochs -> 39,900 IMU
  steps), median of 7 runs. Target: < 2 s.
* ``strapdown.na_cycle`` on 1, 25, 100 and 2,500 states (2,500 = 100 MC runs x 25 sigma
  points), median of 50 calls each, reported in microseconds per call and per state.
  Target: < 2 us/state at 2,500 states.

The track is recorded Snapir track 1 from ``--data-dir`` (default ``../shared/data/snapir-akit``
next to the repository) when it exists, else embedded track 1. Results are printed as a table
and written as JSON to ``results/bench/foundation.json`` (``results/`` is git-ignored).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import scipy

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nespm_cli.nav.rotations import euler_to_dcm  # noqa: E402
from nespm_cli.nav.strapdown import na_cycle  # noqa: E402
from nespm_cli.nav.synthesis import synthesize  # noqa: E402
from nespm_cli.data.tracks import load_track  # noqa: E402

DEFAULT_DATA_DIR = REPO.parent / "shared" / "data" / "snapir-akit"
TARGET_SYNTH_S = 2.0
TARGET_NA_US_PER_STATE = 2.0
BATCHES = (1, 25, 100, 2500)


def median_time(fn, repeats: int, warmup: int = 1) -> tuple[float, list[float]]:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def get_track(data_dir: Path | None):
    if data_dir is not None and data_dir.is_dir():
        return load_track(1, data_dir), f"{data_dir}/Trajectory1"
    from nespm_cli.data.embedded import embedded_track

    return embedded_track(1), "embedded track 1"


def bench_synthesis(track, repeats: int = 7) -> dict:
    med, times = median_time(lambda: synthesize(track), repeats)
    s = synthesize(track)
    return {
        "gt_epochs": int(len(track.t)),
        "imu_steps": int(s.steps),
        "duration_s": float(track.t[-1] - track.t[0]),
        "repeats": repeats,
        "median_s": med,
        "min_s": min(times),
        "max_s": max(times),
        "target_s": TARGET_SYNTH_S,
        "meets_target": med < TARGET_SYNTH_S,
    }


def bench_na_cycle(track, n: int, repeats: int = 50) -> dict:
    """na_cycle on n states scattered around the track's first epoch, one IMU sample each."""
    rng = np.random.default_rng(n)
    pos = np.asarray(track.pos[0]) + rng.normal(size=(n, 3)) * np.array([1e-6, 1e-6, 1.0])
    v = np.asarray(track.v_n[0]) + rng.normal(scale=0.05, size=(n, 3))
    C = euler_to_dcm(np.asarray(track.euler[0]) + rng.normal(scale=0.01, size=(n, 3)))
    f = np.array([0.0, 0.0, -9.8]) + rng.normal(scale=0.1, size=(n, 3))
    w = rng.normal(scale=0.05, size=(n, 3))
    dt = 0.01
    med, times = median_time(lambda: na_cycle(pos, v, C, f, w, dt), repeats, warmup=3)
    us = med * 1e6
    out = {
        "states": n,
        "repeats": repeats,
        "median_us_per_call": us,
        "min_us_per_call": min(times) * 1e6,
        "median_us_per_state": us / n,
    }
    if n == 2500:
        out["target_us_per_state"] = TARGET_NA_US_PER_STATE
        out["meets_target"] = us / n < TARGET_NA_US_PER_STATE
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data-dir", type=Path, default=DEFAULT_DATA_DIR)
    ap.add_argument("--out", type=Path, default=REPO / "results" / "bench" / "foundation.json")
    args = ap.parse_args(argv)

    track, source = get_track(args.data_dir)
    synth = bench_synthesis(track)
    cycles = [bench_na_cycle(track, n) for n in BATCHES]

    print(f"track: {source} ({synth['gt_epochs']} GT epochs, {synth['imu_steps']} IMU steps)")
    print()
    print(f"{'benchmark':<28}{'median':>14}{'per state':>14}{'target':>12}")
    print("-" * 68)
    mark = "ok" if synth["meets_target"] else "MISSED"
    print(f"{'IMU synthesis (400 s)':<28}{synth['median_s']:>12.3f} s{'':>14}{'< 2 s':>9} {mark}")
    for c in cycles:
        tgt = ""
        if "target_us_per_state" in c:
            tgt = f"{'< 2 us':>9} " + ("ok" if c["meets_target"] else "MISSED")
        print(
            f"{'na_cycle x ' + str(c['states']):<28}{c['median_us_per_call']:>11.1f} us"
            f"{c['median_us_per_state']:>11.3f} us{tgt}"
        )

    result = {
        "benchmark": "foundation",
        "timestamp": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "track": source,
        "synthesis": synth,
        "na_cycle": cycles,
        "machine": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print()
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
