"""One round of per run-step costs of every built-in filter, for ``bench_compare.py``.

Run in a subprocess whose ``PYTHONPATH`` names the tree under test (this one or a base commit's
worktree), so ``nespm_cli`` is that tree's while the measuring code is this file's. For each
filter and each layout (``12``: the papers' 12 states with the DVL; ``15``: position in the
state with the DVL, the depth sensor and a fix every 60 s) the filter runs once untimed (the
warm-up: compiled kernels loaded, caches filled), then ``--repeat`` times timed in CPU time of this
process (``time.process_time``, one core: BLAS and OpenMP held to one thread; the least of them
counts, as other jobs' load only ever adds to it) on R realizations of the
first ``--epochs`` GT epochs of embedded track 5, the inputs built as ``mc`` builds them
(:func:`bench_sensors.inputs`). The cost [µs] is that time over R x IMU steps.

Prints one JSON object: ``{"cost_us": {filter: {"12": µs or null, "15": µs or null}},
"errors": {...}, "filters": [the tree's built-ins], "steps": {layout: IMU steps}, "versions": {...}}``;
a filter the tree does not have is absent from ``filters``, one that fails in a layout is null
with its one-line error in ``errors``.

Run: ``PYTHONPATH=TREE python benchmarks/compare_steps.py [--filters ekf,ukf] [--epochs 100] [--runs 100]``.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, before NumPy loads

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_sensors, bench_run_step beside this file

#: layout label -> (error-state layout, sensors): the issue's two configurations
LAYOUTS = {"12": ("12", ("dvl",)), "15": ("15", ("dvl", "depth", "fix"))}


def measure(filters: list[str] | None, epochs: int | None, runs: int, repeat: int = 1) -> dict:
    """Cost per run-step [µs] of each filter in each layout of :data:`LAYOUTS` (module docstring)."""
    import numpy as np

    from bench_run_step import noise_for
    from bench_sensors import inputs
    from nespm_cli.filters import FILTERS, run_filter

    names = list(FILTERS) if filters is None else [f for f in filters if f in FILTERS]
    cases = {label: inputs(state, sensors, runs, epochs) for label, (state, sensors) in LAYOUTS.items()}
    cost: dict[str, dict] = {}
    errors: dict[str, str] = {}
    for name in names:
        cost[name] = {}
        for label, (kw, steps) in cases.items():
            try:
                ns = noise_for(name, kw["f_meas"], kw["w_meas"], kw["epoch_index"])
                run_filter(name, noise_std=ns, **kw)  # warm-up, not timed
                best = float("inf")
                for _ in range(repeat):
                    t0 = time.process_time()
                    run_filter(name, noise_std=ns, **kw)
                    best = min(best, time.process_time() - t0)
                cost[name][label] = 1e6 * best / (runs * steps)
            except Exception as exc:  # noqa: BLE001 - a filter without this layout: recorded, not fatal
                cost[name][label] = None
                errors[f"{name} {label}"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    versions = {"python": sys.version.split()[0], "numpy": np.__version__}
    try:
        import numba

        versions["numba"] = numba.__version__
    except ImportError:
        pass
    return {"cost_us": cost, "errors": errors, "filters": list(FILTERS), "runs": runs, "repeat": repeat,
            "steps": {label: steps for label, (_, steps) in cases.items()}, "versions": versions}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filters", default=None, help="comma list (default: every built-in of the tree)")
    ap.add_argument("--epochs", type=int, default=None, help="GT epochs of track 5 (default: all 400)")
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=1, help="timed runs per filter and layout (the least counts)")
    a = ap.parse_args(argv)
    if (a.epochs is not None and not 4 <= a.epochs <= 400) or a.runs < 1:
        print("compare_steps: --epochs must be 4-400 (track 5's GT epochs) and --runs at least 1", file=sys.stderr)
        sys.exit(2)
    res = measure(a.filters.split(",") if a.filters else None, a.epochs, a.runs, max(1, a.repeat))
    print(json.dumps(res))


if __name__ == "__main__":
    main()
