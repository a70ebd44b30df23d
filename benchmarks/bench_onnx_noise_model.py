"""ONNX noise model vs the numpy ProcessNet: inference cost per run-step (one window per run and
DVL interval), the packaged float32 ProcessNet exported by ``export_processnet``.

Target (issue 32): ONNX at most 2x the numpy inference. onnxruntime on one thread (as in the
runs: the loky workers each run one process). Needs ``pip install 'nespm[onnx]'``.

    PYTHONPATH=$PWD python benchmarks/bench_onnx_noise_model.py [--windows 4000] [--repeat 5]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from nespm_cli.learn.noise_model import reference_windows
from nespm_cli.learn.noise_models import export_processnet, load_noise_model


def best(f, repeat: int) -> float:
    f()  # warm-up
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--windows", type=int, default=4000)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    x = np.concatenate(reference_windows(), axis=-1).reshape(-1, 100, 6)
    x = np.tile(x, (a.windows // len(x) + 1, 1, 1))[:a.windows]
    with tempfile.TemporaryDirectory() as d:
        path = export_processnet(None, Path(d) / "processnet.onnx")
        numpy_model, onnx_model = load_noise_model(None), load_noise_model(str(path))
        tn = best(lambda: numpy_model.predict(x), a.repeat)
        to = best(lambda: onnx_model.predict(x), a.repeat)
        err = float(np.max(np.abs(onnx_model.predict(x) / numpy_model.predict(x) - 1)))
    print(f"{a.windows} windows (100 x 6), best of {a.repeat}")
    print(f"numpy ProcessNet : {tn / a.windows * 1e6:8.1f} us per run-step")
    print(f"ONNX (1 thread)  : {to / a.windows * 1e6:8.1f} us per run-step  ratio {to / tn:.2f} (target <= 2)")
    print(f"max relative std difference {err:.2e}")


if __name__ == "__main__":
    main()
