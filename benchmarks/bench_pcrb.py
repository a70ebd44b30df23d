"""What the posterior Cramér–Rao bound adds to an EKF ``mc`` (issue 31: at most 10 %).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_pcrb.py [--runs 100] [--jobs 1]``.
Runs ``nespm mc --filters ekf --dvl synthetic`` on tracks 5 and 6 into a temporary folder, once
per case, and sets the bound's own seconds (the manifest's ``pcrb.seconds``, computed in the
parent after the chunks) beside the rest of the command's wall time. Cases: the papers' protocol
(every run one pattern: one Riccati recursion per track) and the dynamic schedule with 30 % DVL
dropouts (a bound per run). Writes ``results/bench/pcrb.json``. Not a test: wall times depend
on the machine.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {"papers": [], "dynamic-dropout": ["--schedule", "dynamic", "--sensor-option", "dvl.dropout=0.3"]}


def one(runs: int, jobs: int, extra: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "nespm_cli.cli", "mc", "--tracks", "5", "6", "--runs", str(runs), "--filters",
               "ekf", "--dvl", "synthetic", "--jobs", str(jobs), "--out", tmp, "--no-progress", *extra]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        pcrb = json.loads((Path(tmp) / "manifest.json").read_text())["pcrb"]
    rest = wall - pcrb["seconds"]
    return {"wall_s": round(wall, 2), "pcrb_s": pcrb["seconds"], "added_pct": round(100.0 * pcrb["seconds"] / rest, 1)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "pcrb.json"))
    a = ap.parse_args()
    res = {"runs": a.runs, "jobs": a.jobs}
    for name, extra in CASES.items():
        res[name] = one(a.runs, a.jobs, extra)
        print(f"{name:16s} mc wall {res[name]['wall_s']:7.2f} s, of which PCRB {res[name]['pcrb_s']:6.3f} s: "
              f"+{res[name]['added_pct']:.1f} % (target <= 10 %)")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
