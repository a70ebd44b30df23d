"""Training the GP-UKF experiment's models (gp-ukf.md section 6, stage 1): the GP-f / GP-h
outputs of the training run fitted as independent worker tasks (refitted where the optimizer
stayed at its default start), merged into the two models and written once to ``OUT/models.npz``
with the ideal UKF's Q and R; :func:`load_models` reads them back.
"""
from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np

from nespm_cli.data.atomic import write_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.gp_ukf.model import (MEAS_COLUMNS, MeasuredStateGP, TrueModel, ideal_Q, ideal_R,
                                                simulate_prepared)
from nespm_cli.experiments.gp_ukf.spec import GPSpec
from nespm_cli.filters.gp_ukf import GPUKFModels, narx_training_data
from nespm_cli.learn.gp import GPModel, theta_default

FIT_RETRIES = 2  # refits of an output left at the default start, each with one random restart
RETRY_SEED_STEP = 1000


def subsample(n: int, max_points: int, seed: int) -> np.ndarray:
    """Rows kept of ``n``: all, or the seeded random ``max_points`` that ``GPModel.fit`` would keep."""
    if n <= max_points:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_points, replace=False))


def _fit_output(kind: str, j: int, X: np.ndarray, y: np.ndarray, n_restarts: int,
                seed: int) -> tuple[str, int, dict, float, int]:
    """Fit one GP output on its (already subsampled) rows, a worker task.

    gp.py's L-BFGS-B sometimes stops at the default start (its first step makes K singular,
    the objective returns a constant with zero gradient and the line search gives up). Such an
    output is refitted up to :data:`FIT_RETRIES` times with one random restart, seeds
    ``seed + 1000 k``; the fit keeps the best likelihood of its starts. Returns
    ``(kind, j, GPModel.arrays(), seconds, retries used)``.
    """
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    with threadpool_limits(1):  # multi-threaded BLAS is many times slower on a shared CPU
        gp = GPModel(len(X), n_restarts, seed).fit(X, y[:, None])
        k = 0
        while at_default_start(gp)[0] and k < FIT_RETRIES:
            k += 1
            gp = GPModel(len(X), max(1, n_restarts), seed + RETRY_SEED_STEP * k).fit(X, y[:, None])
    return kind, j, gp.arrays(), time.perf_counter() - t0, k


def at_default_start(gp: GPModel) -> np.ndarray:
    """(d_out,) True where the optimizer returned the default start unchanged (a failed first
    line search: gp.py's L-BFGS-B stops there when its first step makes K singular)."""
    t0 = np.exp(theta_default(gp.d_in))
    return (gp.const == t0[0]) & (gp.noise == t0[-1]) & np.all(gp.length == t0[1:-1], axis=1)


def merge_outputs(parts: list[dict]) -> GPModel:
    """One :class:`GPModel` from single-output models fitted on the same rows (same seed, X).

    Output j's arrays are concatenated in order; the result predicts exactly as the parts do.
    """
    first = parts[0]
    for p in parts[1:]:
        if not np.array_equal(p["X_train"], first["X_train"]):
            raise NespmError("merge_outputs: the single-output GPs were fitted on different rows")
    metas = [json.loads(str(p["meta"])) for p in parts]
    warnings = [w.replace("output 0", f"output {j}", 1) for j, m in enumerate(metas) for w in m["fit_warnings"]]
    meta = dict(metas[0], fit_warnings=warnings)
    arrays = {"X_train": first["X_train"], "x_mean": first["x_mean"], "x_scale": first["x_scale"],
              "meta": np.array(json.dumps(meta))}
    for k in ("Y_train", "y_mean", "y_scale", "const", "length", "noise", "log_marginal_likelihood"):
        arrays[k] = np.concatenate([np.asarray(p[k]) for p in parts], axis=-1 if k == "Y_train" else 0)
    return GPModel.from_arrays(arrays)



def _save_npz_atomic(path: Path, arrays: dict) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, lambda tmp: tmp.write_bytes(buf.getvalue()))


def train_models(spec: GPSpec, out: Path, jobs: int, backend: str, scheduler: str | None,
                 progress=None) -> dict:
    """Fit (or load) ``OUT/models.npz``; return its summary (fit seconds, training sizes, learnt
    noise std per output, the ideal Q's std, refits, fit warnings), stored in the manifest.

    ``progress``: optional callable(total, done) for a progress bar.
    """
    from nespm_cli.experiments.backend import parallel_map

    path = out / "models.npz"
    if path.exists():
        with np.load(path, allow_pickle=False) as a:
            info = json.loads(str(a["experiment_info"]))
        return info
    t0 = time.perf_counter()
    _, x, u, z = simulate_prepared(spec, [spec.train_run])
    x, u, z = x[0], u[0], z[0]
    Xf, Yf, Xh, Yh = narx_training_data(x, u, z, spec.fraction, spec.seed)
    # the seeds of fit_gp_ukf_models (GP-f seed, GP-h seed + 1) and GPModel's subsample
    kf, kh = subsample(len(Xf), spec.max_points, spec.seed), subsample(len(Xh), spec.max_points, spec.seed + 1)
    Xf, Yf, Xh, Yh = Xf[kf], Yf[kf], Xh[kh], Yh[kh]
    tasks = [("f", j, Xf, Yf[:, j], spec.n_restarts, spec.seed) for j in range(Yf.shape[1])]
    own = spec.h_inputs == "own"
    tasks += [("h", j, Xh[:, [MEAS_COLUMNS[j]]] if own else Xh, Yh[:, j], spec.n_restarts, spec.seed + 1)
              for j in range(Yh.shape[1])]
    retries = {}
    parts: dict = {"f": {}, "h": {}}
    cpu = 0.0
    if progress:
        progress(len(tasks), 0)
    for done, (kind, j, arrays, secs, k) in enumerate(parallel_map(_fit_output, tasks, jobs, backend, scheduler), 1):
        parts[kind][j] = arrays
        cpu += secs
        if k:
            retries[f"{kind}{j}"] = k
        if progress:
            progress(len(tasks), done)
    gf = merge_outputs([parts["f"][j] for j in range(Yf.shape[1])])
    hp = [parts["h"][j] for j in range(Yh.shape[1])]
    gh = MeasuredStateGP([GPModel.from_arrays(p) for p in hp], MEAS_COLUMNS) if own else merge_outputs(hp)
    f = TrueModel(substeps=spec.rk4_substeps)
    # ARD pushes the length scale of an irrelevant input to its upper bound: expected, not listed
    notable = lambda w: [m for m in w if "length scale" not in m or "1e+04" not in m]  # noqa: E731
    info = {"fit_seconds": round(time.perf_counter() - t0, 3), "fit_cpu_seconds": round(cpu, 3),
            "n_train_f": int(gf.n_train), "n_train_h": int(gh.n_train),
            "noise_std_f": [float(v) for v in np.sqrt(gf.noise_var())],
            "noise_std_h": [float(v) for v in np.sqrt(gh.noise_var())],
            "q_ideal_std": [float(v) for v in np.sqrt(np.diag(ideal_Q(x, u, f)))],
            "fit_warnings": {"f": notable(gf.fit_warnings), "h": notable(gh.fit_warnings)},
            "refits": dict(sorted(retries.items())),
            "at_default_start": [f"f{j}" for j in np.flatnonzero(at_default_start(gf))]
            + [f"h{j}" for j, p in enumerate(hp) if at_default_start(GPModel.from_arrays(p))[0]]}
    arrays = {**gf.arrays("f/"), **gh.arrays("h" if own else "h/")}
    arrays["h_inputs"] = np.array(spec.h_inputs)
    for name in ("f_states", "h_states"):  # the layout of GPUKFModels.save: all states are inputs
        arrays[name] = np.array([], dtype=int)
        arrays[name + "_all"] = np.array(True)
    arrays["ideal_Q"] = np.diag(np.asarray(info["q_ideal_std"]) ** 2)
    arrays["ideal_R"] = ideal_R()
    arrays["experiment_info"] = np.array(json.dumps(info))
    _save_npz_atomic(path, arrays)
    return info


def load_models(out: Path) -> tuple[GPUKFModels, np.ndarray, np.ndarray]:
    """``(GP-UKF models, ideal Q (12, 12), ideal R (10, 10))`` from ``OUT/models.npz``."""
    path = Path(out) / "models.npz"
    try:
        with np.load(path, allow_pickle=False) as a:
            if str(a["h_inputs"]) == "own":
                models = GPUKFModels(GPModel.from_arrays(a, "f/"), MeasuredStateGP.from_arrays(a, "h"))
            else:
                models = GPUKFModels.load(path)
            return models, np.asarray(a["ideal_Q"]), np.asarray(a["ideal_R"])
    except (OSError, KeyError, ValueError) as exc:
        raise NespmError(f"{path}: unreadable model file ({exc.__class__.__name__}); delete it to refit") from None
