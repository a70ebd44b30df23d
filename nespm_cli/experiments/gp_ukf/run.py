"""The GP-UKF experiment's runner (gp-ukf.md section 6): ideal UKF against GP-UKF on REMUS 100 helix runs.

The spec is :mod:`~nespm_cli.experiments.gp_ukf.spec`, the models :mod:`~nespm_cli.experiments.gp_ukf.model`,
the training :mod:`~nespm_cli.experiments.gp_ukf.training`; this module runs the three stages in order
(stage 1 through :func:`~nespm_cli.experiments.gp_ukf.training.train_models`).

Stages (docs/gp-ukf.md, "The experiment"):

1. **Training.** Run ``train_run`` (0: "the first set of data") is simulated at 5 Hz; the
   GP-f / GP-h training pairs are a seeded random 40 % of its samples
   (:func:`~nespm_cli.filters.gp_ukf.narx_training_data`), capped at ``max_points`` per model.
   The 22 GP outputs (12 state changes, 10 measurements) are fitted as 22 independent tasks
   in parallel (``parallel_map``) and merged into the two models (GP-h: by default one
   single-input GP per measurement on the state it measures, ``h_inputs="own"``; an output
   the optimizer left at its default start is refitted); the ideal UKF's fixed Q is
   the mean square one-step error of the true model on the same run. Everything is written
   once to ``OUT/models.npz`` and reused on resume.
2. **Evaluation.** Runs ``0 .. runs-1`` (the paper's Table 3 is "for 20 runs"; run 0 is
   evaluated too and flagged ``training_run``) in chunks of ``chunk_size`` runs. A chunk
   simulates its runs (a run depends only on ``(seed, run)``), draws each run's initial
   estimate from ``SeedSequence(seed, spawn_key=(run, 1))`` and runs ``ukf-ideal`` and
   ``gp-ukf`` batched over its runs. Each finished chunk writes
   ``chunks/series-<filter>-<first>.parquet`` then ``chunks/metrics-<filter>-<first>.parquet``
   atomically (the metrics file marks it complete); a re-run computes only what is missing.
3. **Assembly.** ``metrics.parquet`` (filter x run x state), ``epochs.parquet`` (filter x
   run x epoch at 1 Hz) and ``manifest.json`` (``"experiment": "gp-ukf"``).

Yaw is handled unwrapped: the true ψ and the compass reading are unwrapped along time per
run (the compass noise, 0.5°, is far below π), so the filters' state and their h are
continuous; the yaw error is wrapped to (−π, π] before any metric.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.parquet_files import write_parquet_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.chunks import write_chunk
from nespm_cli.experiments.gp_ukf.model import TRUE_H, TrueModel, simulate_prepared
from nespm_cli.experiments.gp_ukf.spec import EXPERIMENT, FILTERS, STATE_UNITS, GPSpec, validate
from nespm_cli.experiments.gp_ukf.training import load_models, train_models
from nespm_cli.experiments.store import ResultsFolder, Task
from nespm_cli.filters.gp_ukf import gp_ukf, ideal_ukf
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.vehicles import STATE_NAMES
from nespm_cli.vehicles.remus100 import IPSI

__all__ = ["EPOCH_STRIDE", "INIT_STREAM", "initial_estimate", "state_errors", "run_chunk", "assemble",
           "run_gp_experiment"]

EPOCH_STRIDE = 5  # epochs.parquet keeps every 5th sample (1 Hz)
INIT_STREAM = 1  # spawn_key stream of the initial-estimate error (stream 0: the simulator's sensors)


# --- chunks -----------------------------------------------------------------------------------

def _chunk_name(kind: str, filt: str, first: int) -> str:
    return f"{kind}-{filt}-{first:06d}.parquet"


def initial_estimate(spec: GPSpec, runs, x0_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x̂_0 (R, 12) = truth + N(0, P0) drawn per run from SeedSequence(seed, spawn_key=(run, 1)); P0 (12, 12)."""
    std = np.asarray(spec.p0_std, dtype=float)
    xi = np.stack([np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(int(r), INIT_STREAM)))
                   .standard_normal(12) for r in runs])
    return x0_true + std * xi, np.diag(std**2)


def state_errors(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """est − truth (R, T, 12) with the yaw error wrapped to (−π, π]."""
    e = est - truth
    e[..., IPSI] = wrap_angle(e[..., IPSI])
    return e


def run_chunk(spec: GPSpec, first: int, out_dir: str, experiment: str = "", filters: tuple = FILTERS) -> tuple[str, dict]:
    """Compute one chunk of ``filters`` and write its files (carrying the folder's ``experiment``
    digest, :mod:`nespm_cli.experiments.chunks`); return ``(chunk key, timings)``."""
    from threadpoolctl import threadpool_limits

    chunks = Path(out_dir) / "chunks"
    runs = np.arange(first, min(first + spec.chunk_size, spec.runs))
    todo = list(filters)
    timings: dict = {}
    key = f"{first:06d}"
    if not todo:
        return key, timings
    with threadpool_limits(1):
        sim, x, u, z = simulate_prepared(spec, runs)
        x0, P0 = initial_estimate(spec, runs, x[:, 0])
        models, Q, R = load_models(Path(out_dir))
        f = TrueModel(sim.params, substeps=spec.rk4_substeps)
        T = x.shape[1]
        for name in todo:
            t0 = time.perf_counter()
            if name == "ukf-ideal":
                res = ideal_ukf(x0, P0, u, z, f, TRUE_H, Q, R, keep_cov=False)
            else:
                res = gp_ukf(x0, P0, u, z, models, keep_cov=False)
            secs = time.perf_counter() - t0
            e_post = state_errors(res.x_post, x)
            e_pred = state_errors(res.x_pred, x)
            with np.errstate(invalid="ignore"):
                rmse_c = np.sqrt(np.mean(e_post[:, 1:] ** 2, axis=1))  # k >= 1 (R, 12)
                rmse_p = np.sqrt(np.mean(e_pred[:, 1:] ** 2, axis=1))
                sd_c = np.sqrt(np.mean(res.var_post[:, 1:], axis=1))
            Rn, S = len(runs), len(STATE_NAMES)  # rows: run-major, state-minor
            metrics = pd.DataFrame({
                "filter": name, "run": np.repeat(runs, S), "state": np.tile(STATE_NAMES, Rn),
                "unit": np.tile(STATE_UNITS, Rn), "training_run": np.repeat(runs == spec.train_run, S),
                "rmse_correction": rmse_c.ravel(), "rmse_prediction": rmse_p.ravel(), "sd_correction": sd_c.ravel(),
                "diverged": np.repeat(res.diverged.astype(bool), S),
                "diverged_at": np.repeat(res.diverged_at.astype(np.int64), S), "seconds": secs / Rn,
            })
            metrics["seed"] = spec.seed
            metrics["n_samples"] = T - 1
            k = np.arange(0, T, EPOCH_STRIDE)
            K = len(k)
            series = {"filter": name, "run": np.repeat(runs, K), "epoch": np.tile(k, Rn),
                      "t": np.tile(sim.t[k], Rn)}
            for s, sname in enumerate(STATE_NAMES):
                series[f"err_{sname}"] = e_post[:, k, s].ravel()
            series["pred_err_X"] = e_pred[:, k, 6].ravel()
            series["pred_err_Y"] = e_pred[:, k, 7].ravel()
            series["sd_X"] = np.sqrt(res.var_post[:, k, 6]).ravel()
            series["sd_Y"] = np.sqrt(res.var_post[:, k, 7]).ravel()
            for s, sname in ((6, "X"), (7, "Y"), (8, "Z")):
                series[f"{sname}_true"] = x[:, k, s].ravel()
            series["cross_track"] = sim.cross_track[:, k].ravel()
            series["diverged"] = np.repeat(res.diverged, K)
            # series first: a metrics file marks the chunk complete
            write_chunk(pd.DataFrame(series), chunks / _chunk_name("series", name, first), experiment)
            write_chunk(metrics, chunks / _chunk_name("metrics", name, first), experiment)
            timings[f"{name}-{first}"] = round(secs, 3)
    return key, timings


# --- the runner -------------------------------------------------------------------------------

def assemble(folder: ResultsFolder, firsts: list[int]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``metrics.parquet`` and ``epochs.parquet`` (sorted) from exactly the expected chunk files,
    each verified (:meth:`ResultsFolder.verified`)."""
    out = folder.out
    order = {f: i for i, f in enumerate(FILTERS)}
    sidx = {s: i for i, s in enumerate(STATE_NAMES)}
    metrics = pd.concat([pd.read_parquet(p) for p in folder.verified(
        [_chunk_name("metrics", f, f0) for f in FILTERS for f0 in firsts])], ignore_index=True)
    metrics = metrics.sort_values(["filter", "run", "state"], key=lambda c: c.map(order) if c.name == "filter"
                                  else (c.map(sidx) if c.name == "state" else c), kind="stable").reset_index(drop=True)
    epochs = pd.concat([pd.read_parquet(p) for p in folder.verified(
        [_chunk_name("series", f, f0) for f in FILTERS for f0 in firsts])], ignore_index=True)
    epochs = epochs.sort_values(["filter", "run", "epoch"], key=lambda c: c.map(order) if c.name == "filter" else c,
                                kind="stable").reset_index(drop=True)
    write_parquet_atomic(metrics, out / "metrics.parquet")
    write_parquet_atomic(epochs, out / "epochs.parquet")
    return metrics, epochs


def run_gp_experiment(out_dir: str | Path, runs: int = 20, seed: int = 0, duration_s: float = 800.0,
                      max_points: int = GPSpec.max_points, n_restarts: int = GPSpec.n_restarts,
                      chunk_size: int = GPSpec.chunk_size, execution: Execution | None = None, *,
                      jobs: int | None = None, progress: bool | None = None, argv=None, backend: str | None = None,
                      scheduler: str | None = None, **options) -> pd.DataFrame:
    """Run (or resume) the GP-UKF experiment into ``out_dir``; return the metrics table.

    ``options``: the other :class:`GPSpec` fields (``fraction``, ``train_run``,
    ``rk4_substeps``, ``p0_std``). ``execution`` (or its fields as keyword arguments: ``jobs``,
    ``backend``, ``scheduler``, ``progress``, ``argv``) does not change the results. Schema of
    the outputs: docs/gp-ukf.md.
    """
    ex = Execution.of(execution, jobs=jobs, progress=progress, argv=argv, backend=backend, scheduler=scheduler)
    unknown = set(options) - {f.name for f in dataclasses.fields(GPSpec)}
    if unknown:
        raise NespmError(f"run_gp_experiment: unknown option(s) {', '.join(sorted(unknown))}")
    spec = validate(GPSpec(runs=runs, seed=seed, duration_s=float(duration_s), max_points=max_points,
                           n_restarts=n_restarts, chunk_size=chunk_size, **options))
    ex.check()
    jobs, backend, argv = ex.jobs, ex.backend, (list(ex.argv) if ex.argv is not None else None)
    out = Path(out_dir)
    opts = {"experiment": EXPERIMENT, **spec.as_dict()}
    if (out / "models.npz").exists() and not (out / "manifest.json").exists():
        raise NespmError(f"{out}: has models.npz but no manifest.json; use a new --out folder")
    folder = ResultsFolder(out, opts, argv).open(experiment=EXPERIMENT, seed=spec.seed, jobs=jobs, backend=backend)
    folder.manifest.setdefault("training", None)

    firsts = list(range(0, spec.runs, spec.chunk_size))
    folder.ignore_strays({_chunk_name(k, f, f0) for k in ("metrics", "series") for f in FILTERS for f0 in firsts})

    def missing(f0: int) -> tuple:
        return tuple(f for f in FILTERS if not (folder.done(_chunk_name("metrics", f, f0))
                                                and folder.done(_chunk_name("series", f, f0))))

    todo = [Task(f"{f0:06d}", (spec, f0, str(out.resolve()), folder.experiment, fs), 1)
            for f0 in firsts for fs in [missing(f0)] if fs]
    bar = None
    if progress and not (out / "models.npz").exists():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(TextColumn("[bold]gp-ukf[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), transient=False)
        bar.start()
    try:
        fit_task = None

        def fit_progress(total, done):
            nonlocal fit_task
            if bar is None:
                return
            if fit_task is None:
                fit_task = bar.add_task(f"fit {total} GP outputs on run {spec.train_run}", total=total)
            bar.update(fit_task, completed=done)

        fitted_now = not (out / "models.npz").exists()
        info = train_models(spec, out, jobs, backend, scheduler, fit_progress if fitted_now else None)
    finally:
        if bar is not None:
            bar.stop()
    folder.manifest["training"] = info
    folder.save()
    folder.run(run_chunk, todo, ex, "gp-ukf", unit="chunks")
    metrics, _ = assemble(folder, firsts)
    folder.finish(chunks=len(firsts))
    return metrics
