"""The speed claims that used to be wall-clock assertions in tests/ (issue 30: no test depends on
the machine's speed). Each claim is timed here, on this machine, against the bound the test once
asserted; the tests keep only their correctness statements.

Claims (name: what is timed, target):

* ``embedded-load``: building one embedded track from its packaged description (``build_arrays``, no cache)
  (was tests/test_embedded.py::test_fast), per track, < 0.2 s;
* ``real-tracks-load``: ``load_tracks(1..13)`` of the real Snapir folder, if there is one
  (was tests/test_tracks.py::test_real_tracks_load_fast), < 1 s;
* ``plausibility-100k``: ``plausibility.check_track_arrays`` on a clean 100,000-epoch track (no
  Python loop over epochs; tests/test_plausibility.py::test_findings_on_a_long_track), < 1 s;
* ``processnet-training``: 4 epochs of Adam on 3,000 white-noise windows, batch 32
  (tests/test_processnet.py::test_learns_white_noise_level), < 20 s;
* ``dask-worker-error``: a NespmError raised on a Dask worker (its data folder missing) reaching
  the client (tests/test_backend.py::test_worker_without_data_folder), < 30 s;
* ``dask-bogus-scheduler``: ``nespm mc --backend dask --scheduler`` with nothing listening, and
  with an address without a port (test_bogus_scheduler_address), each < 20 s;
* ``dask-silent-scheduler``: a port that accepts but never speaks, ``NESPM_DASK_TIMEOUT=2``
  (test_silent_scheduler_address_times_out), < 20 s.

The Dask claims are skipped when ``distributed`` is not installed.

Run from the repository root: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_claims.py
[--repeat 3] [--data-dir DIR] [--only NAME ...]``. Prints one line per claim (median and worst
of the repeats, target, ok/SLOW) and writes ``results/bench/claims.json``. Exit status 1 when a
claim is slower than its target (a statement about this machine at this moment, not a test).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIBLING_REAL_DATA = ROOT.parent / "shared" / "data" / "snapir-akit"


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def embedded_load() -> float:
    """The build itself (``build_arrays``): ``embedded_track`` reads the arrays back from the per-user
    cache once a process has built them, which would time a file read."""
    from nespm_cli.data.embedded import EMBEDDED_TRACKS, build_arrays

    worst = 0.0
    for n in EMBEDDED_TRACKS:
        worst = max(worst, _timed(lambda: build_arrays(n)))
    return worst


def real_tracks_load(data_dir: Path | None):
    if data_dir is None or not data_dir.is_dir():
        return None
    from nespm_cli.data.tracks import load_tracks

    return _timed(lambda: load_tracks(range(1, 14), data_dir))


def plausibility_100k() -> float:
    from nespm_cli.data import plausibility as P

    n = 100_000
    t = np.arange(n) * 0.1
    v = np.column_stack([np.full(n, 1.5), np.zeros(n), np.zeros(n)])
    lat = 0.5 + np.cumsum(np.r_[0.0, np.full(n - 1, 0.15 / 6.36e6)])
    gt = np.column_stack([t, np.full(n, 0.6), lat, np.full(n, -10.0), v, np.zeros((n, 3))])
    dvl = np.column_stack([t, v])
    return _timed(lambda: P.check_track_arrays("gt.csv", gt, "dvl.csv", dvl))


def processnet_training() -> float:
    from nespm_cli.learn.processnet import Adam, Normalizer, ProcessNet, mse_loss

    rng = np.random.default_rng(0)
    sigma = 7.3e-6
    norm = Normalizer.for_sensor("gyro", sigma, diff_order=0)
    s = rng.uniform(1, 6, 3000) * sigma
    X, y = s[:, None, None] * rng.standard_normal((3000, 100, 3)), np.repeat(s[:, None], 3, axis=1)
    net = ProcessNet(norm, seed=0, dtype=np.float32)
    F, T = norm.transform(X, np.float32), norm.encode(y).astype(np.float32)
    net.params["b5"][:] = T.mean()
    opt = Adam(net.params, lr=3e-3)

    def train():
        for _ in range(4):
            perm = rng.permutation(len(F))
            for k in range(0, len(F), 32):
                b = perm[k:k + 32]
                opt.step(net.backward(mse_loss(net.forward(F[b]), T[b])[1]))

    return _timed(train)


def _short_data(folder: Path) -> Path:
    from nespm_cli.data.embedded import embedded_track
    from nespm_cli.data.tracks import Track, write_akit

    tr = embedded_track(5)
    s = slice(0, 40)
    write_akit(Track(number=5, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=tr.euler[s], dvl=tr.dvl[s],
                     imu=None, source="short"), folder)
    return folder


def _nespm(*argv) -> int:
    from nespm_cli.cli import main

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main([str(a) for a in argv])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def dask_claims(tmp: Path) -> dict:
    """The three Dask failure paths, timed; {} without distributed."""
    try:
        import distributed
    except ImportError:
        return {}
    from nespm_cli.errors import NespmError
    from nespm_cli.experiments.backend import parallel_map
    from nespm_cli.experiments.mc import Cell, run_chunk
    from nespm_cli.experiments.spec import Spec

    for name in ("NESPM_DATA_DIR", "NESPM_DASK_SCHEDULER", "NESPM_DASK_TIMEOUT", "NESPM_DASK_WAIT"):
        os.environ.pop(name, None)
    data = _short_data(tmp / "data")
    argv = ["mc", "--tracks", "5", "--runs", "2", "--filters", "ekf", "--chunk-size", "2", "--no-progress",
            "--data-dir", str(data), "--backend", "dask"]
    out = {}
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as lc:
        spec = Spec(tracks=(5,), runs=2, filters=("ekf",), chunk_size=2, data_dir=str(tmp / "no-such-data"))
        (tmp / "out" / "chunks").mkdir(parents=True)

        def worker_error():
            try:
                list(parallel_map(run_chunk, [(Cell(spec), 5, 0, str(tmp / "out"))], 1, "dask", lc.scheduler_address))
            except NespmError:
                return
            raise SystemExit("dask-worker-error: no NespmError")

        out["dask-worker-error"] = _timed(worker_error)
    out["dask-bogus-scheduler"] = max(
        _timed(lambda a=a: _nespm(*argv, "--scheduler", a, "--out", tmp / "X"))
        for a in (f"tcp://127.0.0.1:{_free_port()}", "no-port-here"))
    os.environ["NESPM_DASK_TIMEOUT"] = "2"
    try:
        with socket.socket() as srv:
            srv.bind(("127.0.0.1", 0))
            srv.listen(8)
            address = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
            out["dask-silent-scheduler"] = _timed(lambda: _nespm(*argv, "--scheduler", address, "--out", tmp / "Y"))
    finally:
        os.environ.pop("NESPM_DASK_TIMEOUT", None)
    return out


TARGETS = {"embedded-load": 0.2, "real-tracks-load": 1.0, "plausibility-100k": 1.0, "processnet-training": 20.0,
           "dask-worker-error": 30.0, "dask-bogus-scheduler": 20.0, "dask-silent-scheduler": 20.0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--data-dir", type=Path, default=None,
                    help=f"real Snapir folder for real-tracks-load (default $NESPM_DATA_DIR or {SIBLING_REAL_DATA})")
    ap.add_argument("--only", nargs="*", choices=sorted(TARGETS), default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bench" / "claims.json")
    a = ap.parse_args()
    real = a.data_dir or (Path(os.environ["NESPM_DATA_DIR"]) if os.environ.get("NESPM_DATA_DIR") else SIBLING_REAL_DATA)
    wanted = set(a.only or TARGETS)
    samples: dict[str, list[float]] = {k: [] for k in TARGETS if k in wanted}
    for _ in range(a.repeat):
        for name, fn in (("embedded-load", embedded_load), ("real-tracks-load", lambda: real_tracks_load(real)),
                         ("plausibility-100k", plausibility_100k), ("processnet-training", processnet_training)):
            if name in wanted:
                v = fn()
                if v is not None:
                    samples[name].append(v)
        if wanted & {k for k in TARGETS if k.startswith("dask-")}:
            with tempfile.TemporaryDirectory() as tmp:
                for k, v in dask_claims(Path(tmp)).items():
                    if k in wanted:
                        samples[k].append(v)
    rows, slow = {}, False
    for name, vals in samples.items():
        if not vals:
            print(f"{name:24s} skipped")
            continue
        med, worst = float(np.median(vals)), float(max(vals))
        ok = worst < TARGETS[name]
        slow |= not ok
        rows[name] = {"median_s": med, "worst_s": worst, "target_s": TARGETS[name], "ok": ok, "n": len(vals)}
        print(f"{name:24s} median {med:8.3f} s  worst {worst:8.3f} s  target < {TARGETS[name]:g} s  "
              f"{'ok' if ok else 'SLOW'}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"claims": rows, "python": sys.version.split()[0], "numpy": np.__version__,
                                 "platform": platform.platform(), "cpus": os.cpu_count(),
                                 "load_average": os.getloadavg()}, indent=1))
    return 1 if slow else 0


if __name__ == "__main__":
    sys.exit(main())
