"""How far the pinned regression numbers move between BLAS/LAPACK kernels and SIMD targets.

A one-off measurement behind the tolerances of ``tests/test_regression.py`` and
``tests/test_real_regression.py`` (their docstrings quote the result). Each variant runs the
same ``nespm mc`` commands in a fresh process whose environment selects another OpenBLAS
kernel (``OPENBLAS_CORETYPE``) or switches NumPy's runtime SIMD dispatch down to the baseline
(``NPY_DISABLE_CPU_FEATURES``); the numbers of every variant are compared with the default
one, per filter and column, as the largest relative difference.

Never set these variables in tests or CI: this script exists so that nobody has to.

    .venv/bin/python benchmarks/blas_spread.py [--real DIR] [--out results/bench/blas-spread.json]

Variants a machine's CPU cannot run (e.g. SkylakeX without AVX-512) crash with an illegal
instruction; they are reported as such and skipped.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nespm_cli.data.embedded import embedded_track  # noqa: E402
from nespm_cli.data.track import Track  # noqa: E402
from nespm_cli.data.tracks import write_akit  # noqa: E402

CORETYPES = ("Haswell", "SkylakeX", "Zen", "Sandybridge", "Nehalem", "Prescott")
NUMPY_BASELINE = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR AVX2 FMA3 F16C AVX"
COLUMNS = ("vrmse", "mrmse", "nees", "sse_vel", "sse_att")
FILTERS = "ins,ekf,ukf,ukf-nespm,anekf,anukf,anukf-nespm,ckf,ckf-nespm,iekf"


def short_folder(folder: Path, number: int = 5, epochs: int = 40) -> Path:
    tr = embedded_track(number)
    s = slice(0, epochs)
    write_akit(Track(number=tr.number, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=tr.euler[s],
                     dvl=tr.dvl[s], imu=None, source="short"), folder)
    return folder


def cases(short: Path, real: Path | None) -> dict[str, list[str]]:
    """The commands of the two regression tests (without --out)."""
    base = ["--tracks", "5", "--runs", "4", "--seed", "7", "--chunk-size", "2", "--no-progress", "--data-dir",
            str(short)]
    out = {
        "nominal": base + ["--filters", FILTERS, "--jobs", "2"],
        "dynamic": base + ["--filters", "anukf-nespm", "--schedule", "dynamic", "--jobs", "1"],
        "outage": base + ["--filters", "ekf", "--scenario", "outage", "--outage-start", "15", "--outage-length", "10",
                          "--jobs", "1"],
        "synthetic-dvl": base + ["--filters", "ukf", "--dvl", "synthetic", "--jobs", "1"],
        "alpha-0.5": base + ["--filters", "ukf-nespm,anukf-nespm", "--alpha", "0.5", "--jobs", "1"],
    }
    if real is not None:
        out["real"] = ["--tracks", "5", "6", "--runs", "8", "--seed", "3", "--filters",
                       "ekf,ukf,ukf-nespm,anekf,anukf,anukf-nespm", "--data-dir", str(real), "--no-progress"]
    return out


def run_variant(env_extra: dict, commands: dict, tmp: Path) -> dict[str, pd.DataFrame] | str:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES",
                                                           "NESPM_DATA_DIR")}
    env.update(env_extra)
    env["PYTHONPATH"] = str(ROOT)  # the tree this script sits in, whatever is installed
    got = {}
    for case, argv in commands.items():
        out = tmp / f"{case}-{abs(hash(tuple(env_extra.items())))}"
        r = subprocess.run([sys.executable, "-m", "nespm_cli.cli", "mc", *argv, "--out", str(out)], env=env,
                           capture_output=True, text=True, cwd=str(ROOT))
        if r.returncode != 0:
            return f"exit {r.returncode}: {(r.stderr.strip().splitlines() or ['?'])[-1][:200]}"
        got[case] = pd.read_parquet(out / "metrics.parquet").sort_values(["track", "filter", "run"])
    return got


def spread(ref: dict, other: dict) -> dict:
    """``{case: {filter: {column: max relative difference}}}``."""
    out = {}
    for case, a in ref.items():
        b = other[case]
        per = {}
        for filt, ga in a.groupby("filter"):
            gb = b[b["filter"] == filt]
            per[filt] = {}
            for c in COLUMNS:
                x, y = ga[c].to_numpy(float), gb[c].to_numpy(float)
                ok = np.isfinite(x) & np.isfinite(y)
                rel = np.abs(x[ok] - y[ok]) / np.maximum(np.abs(x[ok]), 1e-300)
                per[filt][c] = float(rel.max()) if ok.any() else 0.0
        out[case] = per
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default_real = ROOT.parent / "shared" / "data" / "snapir-akit"
    ap.add_argument("--real", default=str(default_real) if default_real.is_dir() else None)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench" / "blas-spread.json"))
    args = ap.parse_args()
    variants = {"default": {}}
    variants.update({f"OPENBLAS_CORETYPE={c}": {"OPENBLAS_CORETYPE": c} for c in CORETYPES})
    variants["NPY_DISABLE_CPU_FEATURES=<AVX and up>"] = {"NPY_DISABLE_CPU_FEATURES": NUMPY_BASELINE}
    variants["both: Nehalem + NumPy baseline"] = {"OPENBLAS_CORETYPE": "Nehalem",
                                                  "NPY_DISABLE_CPU_FEATURES": NUMPY_BASELINE}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        commands = cases(short_folder(tmp / "short"), Path(args.real) if args.real else None)
        results = {}
        for name, env in variants.items():
            print(f"running {name} ...", flush=True)
            results[name] = run_variant(env, commands, tmp)
    ref = results["default"]
    if isinstance(ref, str):
        sys.exit(f"the default variant failed: {ref}")
    report = {"variants": {}, "max": {}}
    for name, got in results.items():
        if name == "default":
            continue
        if isinstance(got, str):
            report["variants"][name] = got
            print(f"{name}: not runnable here ({got})")
            continue
        s = spread(ref, got)
        report["variants"][name] = s
        for case, per in s.items():
            for filt, cols in per.items():
                key = f"{case}/{filt}"
                report["max"][key] = max(report["max"].get(key, 0.0), max(cols.values()))
    print("\nlargest relative difference from the default variant, over every variant and column:")
    for key, v in sorted(report["max"].items()):
        print(f"  {key:28s} {v:.2e}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
