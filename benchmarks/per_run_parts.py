"""One measurement of ``nespm mc`` split into its parts, for ``bench_per_run.py`` (issue 41 item 2).

Run in a subprocess whose ``PYTHONPATH`` names the tree under test, so ``nespm_cli`` is that tree's
while the measuring code is this file's. It runs ``nespm mc --tracks 5 --runs R --filters F
--chunk-size 200 --jobs 1`` in this process (one chunk, no worker: loky runs it here) with the
functions that ``experiments.mc`` calls wrapped to add up their CPU time (``time.process_time``, user +
system: page faults count): ``realization_inputs`` (the draws: IMU errors, initial errors, sensor
channels), ``run_filter`` (the filter), ``write_chunk`` (Parquet writing and hashing) and ``run_chunk``
(the chunk as a whole; what is left of it, the metrics, is ``run_chunk`` minus the three). The
whole process's CPU time is given too (``os.times``: imports, spec, report of the folder).

Prints one JSON object ``{"runs": R, "filter": F, "cpu": {part: CPU-s}, "steps": IMU steps of the
track}`` on its last line. Run: ``PYTHONPATH=TREE python benchmarks/per_run_parts.py --runs 120 --filter ukf-nespm OUT``.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, before NumPy loads

import argparse  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import time  # noqa: E402

PARTS = ("draws", "filter", "writing", "chunk")  # the wrapped functions' labels (metrics: derived)


def timed(f, label: str, acc: dict):
    """``f`` adding its CPU time [s] to ``acc[label]`` (not re-entrant: the parts do not nest)."""

    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            acc[label] = acc.get(label, 0.0) + time.process_time() - t0

    return wrapper


def measure(runs: int, filt: str, out: str) -> dict:
    """CPU seconds per part of one ``mc`` (module docstring)."""
    from nespm_cli.cli import main
    from nespm_cli.experiments import mc

    acc: dict[str, float] = {}
    mc.realization_inputs = timed(mc.realization_inputs, "draws", acc)
    shape: list[int] = []
    run_filter = mc.run_filter

    def filter_(name, cfg, f, *args, **kwargs):  # the IMU steps M of f (R, M, 3), for the cost per run-step
        shape[:] = f.shape
        return run_filter(name, cfg, f, *args, **kwargs)

    mc.run_filter = timed(filter_, "filter", acc)
    mc.write_chunk = timed(mc.write_chunk, "writing", acc)
    mc.run_chunk = timed(mc.run_chunk, "chunk", acc)
    shutil.rmtree(out, ignore_errors=True)
    rc = main(["mc", "--tracks", "5", "--runs", str(runs), "--filters", filt, "--chunk-size", "200",
               "--jobs", "1", "--out", out])
    if rc:
        raise SystemExit(f"mc failed ({rc})")
    t = os.times()
    cpu = {k: acc.get(k, 0.0) for k in PARTS}
    cpu["metrics"] = cpu["chunk"] - cpu["draws"] - cpu["filter"] - cpu["writing"]
    cpu["process"] = t.user + t.system
    cpu["sys"] = t.system
    shutil.rmtree(out, ignore_errors=True)
    return {"runs": runs, "filter": filt, "cpu": cpu, "steps": int(shape[1])}


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="scratch folder (removed before and after)")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--filter", default="ekf")
    a = ap.parse_args()
    print(json.dumps(measure(a.runs, a.filter, a.out)))


if __name__ == "__main__":
    main_()
