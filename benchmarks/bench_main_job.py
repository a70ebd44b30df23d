"""The main job, whole command, against a baseline commit side by side; the first-run compile
cost; and where a chunk's time goes (issue 15, points 3, 4 and the 5x target).

1. ``nespm mc --tracks 5 6 --runs 100`` (ekf, ukf, ukf-nespm; 2 jobs) of this tree and of
   ``--baseline`` (default: the last commit before the compiled loop), run in turn A B A B ...
   in fresh output folders; wall seconds per run, medians and the pair-by-pair ratio.
   The baseline is checked out with ``git worktree`` under ``results/bench/`` and imported
   from there with this tree's virtualenv (same Python and packages).
2. Compile cost: :func:`nespm_cli.filters.kernels.warm_up` in a new process with an empty
   ``NUMBA_CACHE_DIR`` (compiles), then again with that cache (loads).
3. Split of one chunk (track 5, 50 runs, in-process, one core): synthesis of the clean IMU,
   the corruption draws, each filter, assembling the results (errors, metrics, Parquet), and
   ``nespm report`` of the finished folder.

Run: ``.venv/bin/python benchmarks/bench_main_job.py [--repeat 3] [--baseline REV] [--runs 100]``.
Writes ``results/bench/main_job.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
BASELINE = "c581e37"  # the last commit before the compiled time loop (issue 15)
MAIN = ["mc", "--tracks", "5", "6", "--filters", "ekf,ukf,ukf-nespm", "--no-progress"]


def command(src: Path, args: list[str]) -> list[str]:
    """``nespm args`` importing the package from ``src``."""
    code = f"import sys; sys.path.insert(0, {str(src)!r}); from nespm_cli.cli import main; sys.exit(main())"
    return [PY, "-c", code, *args]


def timed(cmd: list[str], env: dict | None = None) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd[3:])}\n{r.stderr}")
    return time.perf_counter() - t0


def baseline_tree(rev: str) -> Path:
    path = ROOT / "results" / "bench" / f"baseline-{rev}"
    if not path.exists():
        subprocess.run(["git", "worktree", "add", "--detach", str(path), rev], cwd=ROOT, check=True,
                       capture_output=True)
    return path


def side_by_side(rev: str, runs: int, repeat: int) -> dict:
    base = baseline_tree(rev)
    work = ROOT / "results" / "bench" / "main-job"
    times = {"this": [], "baseline": []}
    for i in range(repeat):
        for who, src in (("this", ROOT), ("baseline", base)):
            out = work / who
            shutil.rmtree(out, ignore_errors=True)
            t = timed(command(src, MAIN + ["--runs", str(runs), "--out", str(out)]))
            times[who].append(t)
            print(f"  run {i + 1} {who:<8} {t:7.1f} s", flush=True)
    ratios = [b / a for a, b in zip(times["this"], times["baseline"])]
    return {"baseline": rev, "runs": runs, "seconds": times,
            "median_this_s": statistics.median(times["this"]),
            "median_baseline_s": statistics.median(times["baseline"]),
            "speedup_median_of_pairs": statistics.median(ratios), "speedups": ratios}


def compile_cost() -> dict:
    code = "from nespm_cli.filters.kernels import warm_up; print(warm_up())"
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        res = {}
        for key in ("cold_s", "cached_s"):
            r = subprocess.run(command(ROOT, [])[:2] + [f"import sys; sys.path.insert(0, {str(ROOT)!r}); {code}"],
                               cwd=ROOT, env=env, capture_output=True, text=True, check=True)
            res[key] = float(r.stdout.strip().splitlines()[-1])
    return res


def split(runs: int) -> dict:
    """Seconds of each part of one real chunk (``mc.run_chunk``: track 5, ``runs`` runs, the main
    job's filters, in-process, one core), from a profile of it: cumulative time of the
    functions that do each part."""
    import cProfile
    import pstats

    from nespm_cli.experiments import inputs, mc, spec as spec_mod

    spec = spec_mod.validate(spec_mod.Spec(tracks=(5,), runs=runs, chunk_size=runs))
    parts = {"synthesis": ("prepared_version",), "corruption": ("draw", "imu_errors", "dvl_noise", "initial_nav"),
             "filters": ("run_filter",),
             "assembling results": ("epoch_errors", "divergence", "run_metrics", "q_factors", "write_chunk",
                                    "DataFrame.__init__")}
    inputs.prepared_version.cache_clear()
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "chunks").mkdir()
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        mc.run_chunk(mc.Cell(spec), 5, 0, tmp)
        prof.disable()
        total = time.perf_counter() - t0
    cum: dict[str, float] = {}
    for (_, _, name), (_, _, _, ct, _) in pstats.Stats(prof).stats.items():
        cum[name] = max(cum.get(name, 0.0), ct)
    out = {k: sum(cum.get(n, 0.0) for n in names) for k, names in parts.items()}
    out["other"] = max(total - sum(out.values()), 0.0)
    out["total (profiled)"] = total
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--skip-side-by-side", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "main_job.json"))
    a = ap.parse_args()
    res = {}
    if not a.skip_side_by_side:
        print(f"main job ({' '.join(MAIN)} --runs {a.runs}), this tree vs {a.baseline}:")
        res["main_job"] = side_by_side(a.baseline, a.runs, a.repeat)
        mj = res["main_job"]
        print(f"  median {mj['median_this_s']:.1f} s vs {mj['median_baseline_s']:.1f} s: "
              f"{mj['speedup_median_of_pairs']:.2f}x faster (median of pairs)")
        t0 = time.perf_counter()
        timed(command(ROOT, ["report", str(ROOT / "results" / "bench" / "main-job" / "this")]))
        res["report_s"] = time.perf_counter() - t0
        print(f"  nespm report of that folder: {res['report_s']:.1f} s")
    res["compile"] = compile_cost()
    print(f"kernels: first compile {res['compile']['cold_s']:.1f} s, from the cache {res['compile']['cached_s']:.2f} s")
    res["split_track5_chunk"] = split(min(a.runs, 50))
    sp = res["split_track5_chunk"]
    total = sp["total (profiled)"]
    print(f"one chunk (track 5, {min(a.runs, 50)} runs, one core, profiled), {total:.1f} s:")
    for k, v in sp.items():
        print(f"  {k:<22} {v:7.2f} s  {100 * v / total:5.1f} %")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
