"""Cost of position in the state and of more sensors, per run-step, side by side.

One run-step is one Monte Carlo run advanced by one IMU step (its share of every update included).
For each configuration the filter runs over the whole of embedded track 5 (400 s, 39,900 IMU
steps) on R = 100 realizations, on one core (BLAS and OpenMP held to one thread), the channels
built as ``mc`` builds them; the cost is the median of ``--repeat`` runs after a warm-up,
divided by R x steps (CPU time, ``time.process_time``). Configurations:

* ``12 dvl``: the papers' 12 states with the DVL at the GT epochs;
* ``15 dvl``: position in the state, the same DVL;
* ``15 dvl+depth+fix``: the DVL, the depth sensor (its default: at the GT epochs) and a
  horizontal fix every 60 s (on the IMU clock).

The configurations run in turn (A B C A B C ...); the ratio is the median of the paired ratios.

Run: ``.venv/bin/python benchmarks/bench_sensors.py [--filters ekf,ukf-nespm] [--repeat 3]``.
Writes ``results/bench/sensors.json``.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, before NumPy loads

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"12 dvl": ("12", ("dvl",)), "15 dvl": ("15", ("dvl",)), "15 dvl+depth+fix": ("15", ("dvl", "depth", "fix"))}


def inputs(state: str, sensors: tuple, R: int, epochs: int | None = None):
    """``(run_filter keyword arguments, IMU steps)`` for R realizations of track 5 (mc's own path);
    ``epochs``: only the first that many GT epochs (1 s each; None: the whole 400 s track)."""
    import dataclasses

    from nespm_cli.data.corruption import draw, imu_errors
    from nespm_cli.experiments.spec import Spec, filter_config, track_inputs, validate
    from nespm_cli.experiments.suite import sensor_suite
    from nespm_cli.filters import FilterConfig, initial_nav
    from nespm_cli.nav.synthesis import synthesize
    from nespm_cli.sensors.channels import build_channel

    spec = validate(Spec(tracks=(5,), runs=R, sensors=sensors, filters=("ekf",), filter_config=FilterConfig(state=state)))
    track, truth = track_inputs(spec, 5)
    if epochs is not None and epochs < len(track.t):  # the embedded track: no IMU file, no sensor files
        track = dataclasses.replace(track, **{k: getattr(track, k)[:epochs] for k in ("t", "pos", "v_n", "euler", "dvl")})
        truth = synthesize(track)
    e = truth.epoch_index
    runs = np.arange(R)
    real = draw(spec.seed, 5, runs, float(truth.t[e[-1]] - truth.t[e[0]]), spec.corruption)
    ef, ew = imu_errors(real, truth.t)
    nav0 = initial_nav(truth.pos[0], truth.v_n[0], truth.C_bn[0], real.dv0, real.dpsi0, real.dp0)
    channels = [build_channel(s, track, truth, spec.seed, 5, runs) for s in sensor_suite(spec)]
    return dict(cfg=filter_config(spec), f_meas=truth.f_b + ef, w_meas=truth.w_ib_b + ew, dt=truth.dt,
                epoch_index=e, nav0=nav0, channels=channels), len(truth.dt)


def main() -> None:
    from nespm_cli.filters import run_filter

    ap = argparse.ArgumentParser()
    ap.add_argument("--filters", default="ekf,ukf,ukf-nespm")
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "sensors.json"))
    a = ap.parse_args()
    res = {"runs": a.runs, "numpy": np.__version__, "cost_us": {}}
    print(f"cost per run-step [µs], R = {a.runs}, one core, median of {a.repeat}")
    print(f"{'filter':<12}" + "".join(f"{c:>20}" for c in CONFIGS) + f"{'ratio 15 all / 12':>20}")
    cases = {label: inputs(state, sensors, a.runs) for label, (state, sensors) in CONFIGS.items()}
    for name in a.filters.split(","):
        times: dict[str, list] = {label: [] for label in CONFIGS}
        ratios = []
        for label, (kw, _) in cases.items():
            run_filter(name, **kw)  # warm-up (and the kernels' compile, once per machine)
        for _ in range(a.repeat):  # the configurations in turn, so a busy moment hits all of them
            for label, (kw, _) in cases.items():
                t0 = time.process_time()  # CPU time: other jobs on the machine do not count
                run_filter(name, **kw)
                times[label].append(time.process_time() - t0)
            ratios.append(times["15 dvl+depth+fix"][-1] / times["12 dvl"][-1])
        row = {label: 1e6 * float(np.median(t)) / (a.runs * cases[label][1]) for label, t in times.items()}
        res["cost_us"][name] = row
        ratio = float(np.median(ratios))  # median of the paired ratios
        res.setdefault("ratio_15_all_over_12", {})[name] = ratio
        print(f"{name:<12}" + "".join(f"{row[c]:>20.3f}" for c in CONFIGS) + f"{ratio:>20.2f}", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
