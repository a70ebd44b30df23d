"""Cost per run-step of every built-in filter against the batch size, on one core, and a profile.

A run-step is one Monte Carlo run advanced by one IMU step (the time update over that step
plus its share of the DVL updates). For each filter and each batch size R in 1, 8, 32, 100
the filter runs over the first ``--epochs`` GT epochs of embedded track 5 (100 IMU steps per
epoch) on R realizations; the cost is the median wall time of ``--repeat`` runs divided by
R x steps. BLAS and OpenMP are held to one thread. ``--profile FILTER`` adds the top
functions by own time for that filter at R = 100.

Run: ``.venv/bin/python benchmarks/bench_run_step.py [--epochs 40] [--repeat 3] [--profile ukf-nespm]``.
Writes ``results/bench/run_step.json``.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, before NumPy loads

import argparse  # noqa: E402
import cProfile  # noqa: E402
import dataclasses  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FILTERS = ("ins", "ekf", "ukf", "ukf-nespm", "anekf", "anukf", "anukf-nespm", "ckf", "ckf-nespm", "iekf")
SIZES = (1, 8, 32, 100)


def inputs(epochs: int, R: int):
    """Everything ``run_filter`` takes for R realizations of the cut track (mc's own path)."""
    from nespm_cli.data.corruption import CorruptionConfig, draw, imu_errors
    from nespm_cli.data.embedded import embedded_track
    from nespm_cli.filters import FilterConfig, initial_nav
    from nespm_cli.nav.synthesis import synthesize

    tr = embedded_track(5)
    tr = dataclasses.replace(tr, t=tr.t[:epochs], pos=tr.pos[:epochs], v_n=tr.v_n[:epochs],
                             euler=tr.euler[:epochs], dvl=tr.dvl[:epochs])
    truth = synthesize(tr)
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[0]
    real = draw(0, 5, np.arange(R), float(t_rel[-1]), CorruptionConfig())
    ef, ew = imu_errors(real, truth.t)
    nav0 = initial_nav(truth.pos[0], truth.v_n[0], truth.C_bn[0], real.dv0, real.dpsi0)
    dvl = np.broadcast_to(np.asarray(tr.dvl), (R, len(e), 3))
    mask = np.ones(len(e), dtype=bool)
    mask[0] = False
    return FilterConfig(), truth.f_b + ef, truth.w_ib_b + ew, truth.dt, e, dvl, mask, nav0


def run_once(name: str, args, noise_std) -> float:
    from nespm_cli.filters import run_filter

    t0 = time.perf_counter()
    run_filter(name, *args, noise_std)
    return time.perf_counter() - t0


def noise_for(name: str, f_meas, w_meas, epoch_index):
    """The packaged noise model's std per run and DVL interval for an adaptive filter, else None
    (``f_meas``, ``w_meas`` (R, M, 3) [m/s², rad/s]; ``epoch_index`` (N,))."""
    from nespm_cli.experiments.spec import needs_noise_std

    try:  # the noise models' registry (issue 32), else the older single ProcessNet module
        from nespm_cli.learn.noise_models import predict_interval_std
    except ImportError:
        from nespm_cli.learn.noise_model import predict_interval_std

    if not needs_noise_std(name):
        return None
    return predict_interval_std(f_meas, w_meas, epoch_index)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--filters", default=",".join(FILTERS))
    ap.add_argument("--profile", default="ukf-nespm")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "run_step.json"))
    a = ap.parse_args()
    res = {"epochs": a.epochs, "steps": (a.epochs - 1) * 100, "numpy": np.__version__, "cost_us": {}}
    steps = (a.epochs - 1) * 100
    print(f"cost per run-step [µs], {steps} IMU steps, one core, median of {a.repeat}")
    print(f"{'filter':<12}" + "".join(f"{'R=' + str(r):>10}" for r in SIZES))
    for name in a.filters.split(","):
        row = {}
        for R in SIZES:
            args = inputs(a.epochs, R)
            ns = noise_for(name, args[1], args[2], args[4])
            run_once(name, args, ns)  # warm-up
            t = float(np.median([run_once(name, args, ns) for _ in range(a.repeat)]))
            row[R] = 1e6 * t / (R * steps)
        res["cost_us"][name] = row
        print(f"{name:<12}" + "".join(f"{row[R]:>10.2f}" for R in SIZES), flush=True)
    if a.profile:
        args = inputs(a.epochs, 100)
        ns = noise_for(a.profile, args[1], args[2], args[4])
        prof = cProfile.Profile()
        prof.enable()
        run_once(a.profile, args, ns)
        prof.disable()
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(12)
        res["profile"] = {"filter": a.profile, "top_tottime": buf.getvalue()}
        print(buf.getvalue())
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
