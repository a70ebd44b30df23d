"""The Monte Carlo runner: realizations x filters x tracks, in joblib workers, resumable.

The unit of work is a chunk: ``chunk_size`` consecutive runs of one track, run as one
batch through every requested filter (all filters see the identical realization). Each
finished chunk writes one Parquet file per filter into ``DIR/chunks/`` atomically; a
re-run of the same command skips those and only computes what is missing, then
assembles ``metrics.parquet`` and ``epochs.parquet`` (docs/results-schema.md).
"""
from __future__ import annotations

import dataclasses
import json
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.data.corruption import draw, imu_errors, true_biases
from nespm_cli.data.parquet_files import write_parquet_atomic
from nespm_cli.data.tracks import resolve_data_dir, track_files
from nespm_cli.errors import NespmError
from nespm_cli.experiments.accepted import accepted_residuals
from nespm_cli.experiments.assembly import epoch_table
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.chunking import chunk_detail, chunk_size_for
from nespm_cli.experiments.chunks import chunk_problem, concat_parquet, write_chunk
from nespm_cli.experiments.inputs import READ_HASHES, verify_read
from nespm_cli.experiments.pcrb_table import add_pcrb
from nespm_cli.experiments.realizations import oracle_noise
from nespm_cli.experiments.metrics import (alive_metrics, block_statistics, divergence, epoch_errors, epoch_nis,
                                          lost_epoch, run_metrics, sensor_nis, sensor_rejections,
                                          truth_free_epochs, truth_free_metrics)
from nespm_cli.experiments.spec import (NO_TRUTH, Spec, couple_filter, filter_config, filter_config_of, has_truth,
                                        load_filters, needs_noise_std, track_inputs, validate)
from nespm_cli.experiments.progress import compile_kernels, kernels_for
from nespm_cli.experiments.suite import load_sensors, sensor_plugin_files, sensor_suite, suite_record
from nespm_cli.experiments.store import GROWABLE, ResultsFolder, Task, chunk_firsts, file_hashes, run_blocks
from nespm_cli.filters import FilterConfig, initial_nav, run_filter
from nespm_cli.filters.kernels import kernel_backend
from nespm_cli.filters.options import training_overlap
from nespm_cli.filters.oracle import is_oracle
from nespm_cli.filters.registry import plugin_files
from nespm_cli.filters.smoother import smoothed_name, smoothed_of
from nespm_cli.learn.noise_model import default_weights
from nespm_cli.learn.noise_models import predict_interval_std
from nespm_cli.sensors.channels import build_channel
from nespm_cli.sensors.dvl import source_label
from nespm_cli.nav.earth import ned_offset

def simulate(spec: Spec, number: int, runs: np.ndarray, filters=None, clean: bool = False,
             progress: Callable[[int], None] | None = None, smooth=None, reuse: dict | None = None):
    """Run ``filters`` on the realizations ``runs`` of track ``number``.

    Returns ``({result: (FilterOutput, EpochErrors, seconds)}, truth, realization)``, a result
    for each filter and, for those in ``spec.smooth``, one for its smoothed solution
    (``<filter>-rts``; ``smooth``: those filters only, default ``spec.smooth``). Every filter
    sees the same IMU, initial errors and sensor channels (one per sensor of ``spec.sensors``,
    :func:`nespm_cli.sensors.channels.build_channel`). ``clean``: the error-free IMU, initial
    solution and measurements. ``progress(done)``, if given, is called with the filter-epochs
    done so far (filters run one after the other, each over the track's N-1 epoch intervals).
    ``reuse``: a dict the caller keeps across calls whose spec differs only in its filters and their
    options (``nespm tune``'s trials): the realization, IMU, initial solution and sensor channels of
    ``(number, runs, clean)`` are built once and read from it after (the same arrays: bit-identical). On a
    track without ground truth (``truth.known`` False) the errors are None: nothing to measure them against.
    """
    key = (number, tuple(int(r) for r in runs), bool(clean))
    if reuse is not None and key in reuse:
        track, truth, real, f, w, nav0, channels = reuse[key]
    else:
        track, truth, real, f, w, nav0, channels = realization_inputs(spec, number, runs, clean)
        if reuse is not None:
            reuse[key] = (track, truth, real, f, w, nav0, channels)
    e = truth.epoch_index
    C_t, v_t, p_t = truth.C_bn[e], truth.v_n[e], truth.pos[e]
    cfg = filter_config(spec)
    results = {}
    names = list(filters or spec.filters)
    noise_std, net_seconds = None, 0.0
    adaptive = [n for n in names if needs_noise_std(n)]
    if adaptive:  # one network pass per chunk, shared by the adaptive filters
        t0 = time.perf_counter()
        noise_std = predict_interval_std(f, w, e, spec.weights)
        net_seconds = time.perf_counter() - t0
    truths = oracle_noise(real, truth, channels) if any(is_oracle(n) for n in names) else None  # told to the oracles
    for i, name in enumerate(names):
        t0 = time.perf_counter()
        step = None if progress is None else (lambda k, base=i * (len(e) - 1): progress(base + k))
        out = run_filter(name, filter_config_of(spec, name, cfg), f, w, truth.dt, e, nav0=nav0,
                         noise_std=noise_std if name in adaptive else truths if is_oracle(name) else None,
                         progress=step, channels=channels, smooth=name in (spec.smooth if smooth is None else smooth))
        if name in adaptive:
            t0 -= net_seconds / len(adaptive)  # the shared network pass, split
        err = epoch_errors(out, v_t, C_t, p_t) if truth.known else None
        secs = time.perf_counter() - t0
        if out.smoothed is not None:  # its seconds: the filter's with the recording and the backward pass
            results[smoothed_name(name)] = (out.smoothed, epoch_errors(out.smoothed, v_t, C_t, p_t)
                                            if truth.known else None, secs)
        results[name] = (out, err, secs)
    return results, truth, real


def realization_inputs(spec: Spec, number: int, runs: np.ndarray, clean: bool = False) -> tuple:
    """What every filter of :func:`simulate` sees on track ``number`` in ``runs``: ``(track, truth,
    realization, f (R, M, 3) [m/s²], w (R, M, 3) [rad/s], nav0, channels)``."""
    track, truth = track_inputs(spec, number)
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    R = len(runs)
    real = draw(spec.seed, number, runs, float(t_rel[-1]), spec.corruption)
    C_t, v_t, p_t = truth.C_bn[e], truth.v_n[e], truth.pos[e]
    channels = [build_channel(s, track, truth, spec.seed, number, runs, clean) for s in sensor_suite(spec)]
    if clean:
        f = np.broadcast_to(truth.f_b, (R,) + truth.f_b.shape)
        w = np.broadcast_to(truth.w_ib_b, (R,) + truth.w_ib_b.shape)
        nav0 = initial_nav(p_t[0], v_t[0], C_t[0], np.zeros((R, 3)), np.zeros((R, 3)))
    else:
        # the corrupted IMU formed in the error rows (bit-identical to truth.f_b + e_f: one addition)
        f, w = imu_errors(real, truth.t, clean=(truth.f_b, truth.w_ib_b))
        nav0 = initial_nav(p_t[0], v_t[0], C_t[0], real.dv0, real.dpsi0, real.dp0)
    return track, truth, real, f, w, nav0, channels


def q_factors(noise_std, cfg: FilterConfig, R: int) -> dict:
    """Per-run mean of the (validated) network std over nominal: ``q_factor_acc``, ``q_factor_gyro`` (R,).

    NaN for the non-adaptive filters. With the ``dynamic`` schedule the injected factor is
    U[1, 6] (mean 3.5); with ``constant`` it is 1.
    """
    if noise_std is None:
        return {"q_factor_acc": np.full(R, np.nan), "q_factor_gyro": np.full(R, np.nan)}
    from nespm_cli.filters.adaptive import q_factor

    return {f"q_factor_{key}": q_factor(s, cfg, key).mean(axis=(1, 2))
            for key, s in (("acc", noise_std[0]), ("gyro", noise_std[1]))}


# --- chunked, resumable runner ---------------------------------------------------------

def chunk_name(kind: str, track: int, filt: str, first: int, tag: str = "") -> str:
    """The file name of one filter's chunk: ``<kind>-<tag><track>-<filter>-<first run>.parquet``."""
    return f"{kind}-{tag}{track}-{filt}-{first:06d}.parquet"


@dataclass(frozen=True)
class Cell:
    """One experiment of a run folder: ``mc`` has one, ``sweep`` one per swept value.

    ``tag`` prefixes its chunk files; ``columns`` are added to every row it writes.
    """

    spec: Spec
    tag: str = ""
    columns: tuple = ()
    experiment: str = ""  # the folder's experiment digest, carried by every chunk file (chunks.py)
    inputs: tuple = ()  # ((path, sha256), ...) of the input files as the manifest records them


def timing_key(tag: str, number: int, filt: str, first: int) -> str:
    """The key of one filter's chunk in the manifest's ``chunk_seconds``: ``<tag><track>-<filter>-<first run>``."""
    return f"{tag}{number}-{filt}-{first}"


def chunk_key(cell: Cell, number: int, first: int) -> str:
    """The name of a chunk in progress reports: ``<tag><track>-<first run>``."""
    return f"{cell.tag}{number}-{first:06d}"


def run_chunk(cell: Cell, number: int, first: int, out_dir: str, last: int | None = None,
              filters: tuple | None = None) -> dict:
    """Compute runs ``first .. last-1`` of track ``number`` for ``filters`` (default: every filter
    of the spec whose chunk is not finished) and write their files. Runs in a worker. ``last``
    defaults to ``first + chunk_size`` (at most ``runs``). Its progress goes to
    ``out_dir/chunks/.progress`` (:mod:`nespm_cli.experiments.progress`). The input files this
    process read must be the ones the manifest records (:func:`inputs.verify_read`)."""
    from nespm_cli.experiments.progress import epoch_reporter

    spec, tag, extra = cell.spec, cell.tag, dict(cell.columns)
    load_sensors(load_filters(spec))  # a worker process imports the user's filters and sensors first
    chunks = Path(out_dir) / "chunks"
    if last is None:
        last = min(first + spec.chunk_size, spec.runs)
    runs = np.arange(first, last)
    asked = [(r, f) for r, f in spec.outputs if filters is None or f in filters]
    # the results whose chunk files are missing or bad; a finished chunk is never rewritten (a smoothed
    # filter added to a folder runs its filter again, but leaves the filter's files alone)
    needed = {r for r, f in asked
              if any(chunk_problem(chunks / chunk_name(kind, number, r, first, tag), cell.experiment) is not None
                     for kind in ("metrics", "series"))}
    if filters is not None and not needed:  # asked explicitly to compute finished ones: do
        needed = {r for r, _ in asked}
    todo = list(dict.fromkeys(f for r, f in asked if r in needed))
    timings = {}
    if not todo:
        return timings
    n_epochs = len(track_inputs(spec, number)[1].epoch_index)  # cached; simulate reuses it
    verify_read(dict(cell.inputs), input_files(spec, (number,)))
    report = epoch_reporter(chunks, chunk_key(cell, number, first), len(todo) * (n_epochs - 1))
    try:
        results, truth, real = simulate(spec, number, runs, todo, progress=report,
                                        smooth={f for r, f in asked if r in needed and r != f})
    except MemoryError:
        raise NespmError(f"chunk {chunk_key(cell, number, first)}: out of memory for {len(runs)} runs "
                         f"(about {chunk_memory(spec, number, len(runs)) / 1e9:.1f} GB); use a smaller "
                         "--chunk-size or fewer --jobs") from None
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    cfg = filter_config(spec)
    # the biases are known where the bench put them (a recorded IMU has its own, unknown)
    bias_true = true_biases(real, truth.t[e] - truth.t[0]) if spec.imu == "synthetic" else None
    robust = robust_filters(spec, cfg)
    for name, (out, err, secs) in results.items():
        if name not in needed:
            continue
        errors = {}  # per epoch: error norms, per-block NEES and 1/2/3-sigma coverage (none without a truth)
        if err is None:  # no ground truth: the innovations only, no error (metrics.truth_free_metrics)
            m = truth_free_metrics(out)
            div = m["diverged"]
        else:
            div, why, inconsistent = divergence(err, out.diverged, t_rel, spec.divergence)
            m = run_metrics(err, div)
            m.update(alive_metrics(err, lost_epoch(err, why, out.lost_epoch, t_rel, spec.divergence), t_rel))
            m.update(sensor_nis(out))
            if out.lost_reason is not None:  # the engine's own reason ("noise-model": the learned model failed)
                why = np.where(out.lost_reason != "", out.lost_reason, why).astype(object)
            m["diverged_reason"] = why
            m["inconsistent"] = inconsistent
            m["drift_m_per_h"] = m["hpe_final"] / max(float(t_rel[-1]), 1e-9) * 3600.0
            errors = {"vel_err": err.vel.ravel(), "att_err": err.att.ravel(), "nees": err.nees.ravel(),
                      "north_err": err.ne[..., 0].ravel(), "east_err": err.ne[..., 1].ravel(),
                      **{k: v.ravel() for k, v in block_statistics(out, truth.v_n[e], truth.C_bn[e], truth.pos[e],
                                                                   bias_true, axes=spec.save_series == "axes").items()}}
        if robust:  # per sensor: rejected, applied and downweighted samples (a smoothed result: its filter's)
            base = smoothed_of(name) or name
            m.update(sensor_rejections(results[base][0] if base in results else out, robust.get(base, False)))
        m.update(q_factors(out.noise_std, cfg, len(runs)))
        m["noise_model_faults"] = (out.noise_faults if out.noise_faults is not None
                                   else np.zeros(len(runs), dtype=np.int64))
        df = pd.DataFrame({**extra, "track": number, "filter": name, "run": runs, "scenario": spec.scenario,
                           "schedule": spec.corruption.schedule, "seed": spec.seed, **m,
                           "seconds": secs / len(runs), "kernels": kernel_backend()})
        R, N = len(runs), len(e)
        errors.update({k: v.ravel() for k, v in epoch_nis(out, t_rel).items()})  # per-sensor NIS (NaN: none)
        series = pd.DataFrame({
            **extra, "track": number, "filter": name, "run": np.repeat(runs, N), "epoch": np.tile(np.arange(N), R),
            "t": np.tile(t_rel, R), **errors, "dvl_used": np.asarray(out.dvl_used, dtype=bool).reshape(R, N).ravel(),
            "diverged": np.repeat(div, N),
        })
        # series first: a metrics file marks the chunk complete
        write_chunk(series, chunks / chunk_name("series", number, name, first, tag), cell.experiment)
        write_chunk(df, chunks / chunk_name("metrics", number, name, first, tag), cell.experiment)
        timings[timing_key(tag, number, name, first)] = secs
    return timings


def robust_filters(spec: Spec, cfg: FilterConfig | None = None) -> dict[str, bool]:
    """``{filter: has a robust update}`` of the spec's filters (``--filter-option NAME.robust``), or ``{}``
    when none has one: then no rejection column is written (every chunk of a folder has the same columns)."""
    modes = {f: filter_config_of(spec, f, cfg).robust_update()[0] != "none" for f in spec.filters}
    return modes if any(modes.values()) else {}


def run_chunk_keyed(cell: Cell, number: int, first: int, out_dir: str, last: int | None = None,
                    filters: tuple | None = None) -> tuple[str, dict]:
    """:func:`run_chunk`, returning ``(chunk_key, timings)`` so the parent knows which chunk ended."""
    return chunk_key(cell, number, first), run_chunk(cell, number, first, out_dir, last, filters)


def chunk_tasks(cells: list[Cell], blocks: list[tuple[int, int]] | None = None) -> list[tuple[Cell, int, int, int]]:
    """``(cell, track, first, last)`` of every chunk: runs ``first .. last-1``.

    ``blocks`` are the run ranges ``[start, end)`` the folder was asked for, in order (one per
    ``--runs`` extension; default ``[(0, runs)]``); each is cut into chunks of ``chunk_size``
    from its start, so extending a folder never changes a finished chunk.
    """
    return [(c, n, f0, f1) for c in cells for n in c.spec.tracks
            for f0, f1 in chunk_firsts(blocks or [(0, c.spec.runs)], c.spec.chunk_size)]


def track_epochs(spec: Spec, number: int) -> int:
    """Number of GT epochs track ``number`` runs with (after its window; for progress totals)."""
    return len(track_inputs(spec, number)[0].t)


def assemble(folder: ResultsFolder, tasks: list, keys: tuple = ()) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``metrics.parquet`` and the epoch table from exactly the chunk files ``tasks`` expect,
    each verified (:meth:`ResultsFolder.verified`), in key order, one chunk in memory at a time.

    ``keys``: extra leading key columns (a sweep's ``param``, ``value``).
    """
    entries = sorted(((tuple(dict(c.columns)[k] for k in keys), n, r, f0, c.tag)
                      for c, n, f0, _ in tasks for r, _ in c.spec.outputs))
    metrics_paths = folder.verified([chunk_name("metrics", n, f, f0, tag) for _, n, f, f0, tag in entries])
    series_paths = folder.verified([chunk_name("series", n, f, f0, tag) for _, n, f, f0, tag in entries])
    concat_parquet(metrics_paths, folder.out / "metrics.parquet")
    epochs = epoch_table([((*kv, n, f), p) for (kv, n, f, _, _), p in zip(entries, series_paths)], keys)
    return pd.read_parquet(folder.out / "metrics.parquet"), epochs


def expected_chunks(tasks: list) -> set[str]:
    """The names of every chunk file ``tasks`` make (metrics and series of each filter and smoothed filter)."""
    return {chunk_name(kind, n, r, f0, c.tag) for c, n, f0, _ in tasks for r, _ in c.spec.outputs
            for kind in ("metrics", "series")}


def add_true_track(epochs: pd.DataFrame, spec: Spec) -> pd.DataFrame:
    parts = []
    for n, df in epochs.groupby("track", sort=True):
        _, truth = track_inputs(spec, int(n))
        p = truth.pos[truth.epoch_index]
        ne = ned_offset(p, p[0])
        df = df.copy()
        df["north_true"] = ne[df["epoch"].to_numpy(), 0]
        df["east_true"] = ne[df["epoch"].to_numpy(), 1]
        parts.append(df)
    return pd.concat(parts, ignore_index=True)


def run_mc(spec: Spec, out_dir: str | Path, execution: Execution | None = None, *, jobs: int | None = None,
           progress: bool | None = None, argv=None, backend: str | None = None,
           scheduler: str | None = None) -> pd.DataFrame:
    """Run (or resume) the experiment into ``out_dir``; return the metrics table. ``execution``
    says where the chunks run (:class:`~nespm_cli.experiments.backend.Execution`; the keyword
    arguments are its fields, for scripts written before it)."""
    ex = Execution.of(execution, jobs=jobs, progress=progress, argv=argv, backend=backend, scheduler=scheduler)
    spec = validate(spec)
    for line in training_overlap(spec.filter_options, spec.seed, spec.tracks, spec.runs):  # nespm tune's
        warnings.warn(line, TrainingWarning, stacklevel=2)
    return run_cells([Cell(spec)], spec.as_dict(), out_dir, ex)


def labelled_record(spec: Spec) -> dict:
    """The manifest's ``sensors`` cell of ``spec`` (:func:`suite_record`) with each source as the report names
    it: a recorded sensor of an embedded track is ``embedded`` (generated in code,
    :func:`nespm_cli.sensors.dvl.source_label`)."""
    data_dir = resolve_data_dir(spec.data_dir)
    return {n: {**o, "source": source_label(o.get("source"), data_dir)} for n, o in suite_record(spec).items()}


class TrainingWarning(UserWarning):
    """A filter's tuned settings run on the realizations they were tuned on (one ``nespm: warning:`` line)."""


def input_files(spec: Spec, tracks: tuple | None = None) -> list[Path]:
    """Every file the numbers of ``spec`` depend on: each track's GT and DVL (and IMU with
    ``--imu recorded``), the ProcessNet weights of adaptive filters, the corrections file and
    the code of every plugin filter (a file, a module or an entry point: all its files). Their
    hashes go into the manifest (docs/results-schema.md). ``tracks``: only these tracks' files."""
    files: list[Path] = []
    if spec.data_dir is not None:
        for n in (spec.tracks if tracks is None else tracks):
            files += track_files(n, spec.data_dir, spec.imu == "recorded")
    if any(needs_noise_std(f) for f in spec.filters):
        files.append(Path(spec.weights) if spec.weights else default_weights())
    if spec.corrections:
        files.append(Path(spec.corrections))
    for f in spec.filters:
        files += plugin_files(f)
    return files + sensor_plugin_files(spec)


def manifest_inputs(cells: list[Cell]) -> dict[str, str]:
    """``{path: sha256}`` of every input file of ``cells``: the tracks' files as this process read
    them (:data:`inputs.READ_HASHES`), the others as they are now."""
    files = sorted({str(p.resolve()) for c in cells for p in input_files(c.spec)})
    return {p: READ_HASHES.get(p) or file_hashes([p])[p] for p in files}


def run_cells(cells: list[Cell], options: dict, out_dir: str | Path, execution: Execution = Execution(),
              label: str = "mc") -> pd.DataFrame:
    """Run (or resume, or extend to more runs) validated ``cells`` into ``out_dir``; ``options``
    identify the experiment (:class:`nespm_cli.experiments.store.ResultsFolder`).

    ``execution`` says where chunks run (:mod:`nespm_cli.experiments.backend`); it does not
    change the results.
    """
    ex = execution.check()  # before --out is created
    size = chunk_size_for(cells[0].spec.chunk_size, out_dir, cells[0].spec.runs,
                          sum(len(c.spec.tracks) for c in cells), ex.jobs)  # given, the folder's, or by runs and jobs
    cells = [dataclasses.replace(c, spec=dataclasses.replace(c.spec, chunk_size=size)) for c in cells]
    options = {**options, "chunk_size": size}
    check_memory(chunk_tasks(cells), ex)  # before anything is written (a first block's chunks are the largest)
    folder = ResultsFolder(out_dir, options, list(ex.argv) if ex.argv is not None else None, extendable=GROWABLE)
    first = cells[0].spec
    inputs = manifest_inputs(cells)
    folder.open(inputs=inputs, seed=first.seed, data_dir=first.data_dir or "embedded",
                filter_config={c.tag or "all": dataclasses.asdict(c.spec.filter_config) for c in cells},
                sensors={c.tag or "all": labelled_record(c.spec) for c in cells})
    blocks = run_blocks(folder.old, first.runs)
    folder.manifest["run_blocks"] = [list(b) for b in blocks]
    folder.manifest["accepted_residuals"] = accepted_residuals(c.spec for c in cells)  # docs/results-schema.md
    folder.save()
    out = folder.out
    cells = [dataclasses.replace(c, experiment=folder.experiment, inputs=tuple(sorted(inputs.items()))) for c in cells]
    tasks = chunk_tasks(cells, blocks)
    folder.ignore_strays(expected_chunks(tasks))
    check_memory(tasks, ex)

    def missing(c: Cell, n: int, f0: int) -> tuple[str, ...]:
        return tuple(dict.fromkeys(f for r, f in c.spec.outputs
                                   if not (folder.done(chunk_name("metrics", n, r, f0, c.tag))
                                           and folder.done(chunk_name("series", n, r, f0, c.tag)))))

    todo = [Task(chunk_key(c, n, f0), (_absolute(c), n, f0, str(out.resolve()), f1, fs),
                 len(fs) * (track_epochs(c.spec, n) - 1))
            for c, n, f0, f1 in tasks for fs in [missing(c, n, f0)] if fs]
    sizes = [t.args[4] - t.args[2] for t in todo]  # runs per chunk (the largest decides which Φ kernel runs)
    if todo and ex.local:  # before the progress bar: its ETA starts with the chunks
        compile_kernels(label, ex.progress, kernels=tuple(dict.fromkeys(
            k for c in cells for k in kernels_for(c.spec.filters, c.spec.filter_config.layout, max(sizes)))))
    folder.run(run_chunk_keyed, todo, ex, label, detail=chunk_detail(sizes))
    recover_timings(folder.manifest["chunk_seconds"], tasks, out / "chunks")
    metrics, epochs = assemble(folder, tasks, tuple(k for k, _ in cells[0].columns))
    if has_truth(first):
        epochs = add_true_track(epochs, first)
        epochs, folder.manifest["pcrb"] = add_pcrb(epochs, cells, tuple(k for k, _ in cells[0].columns))  # docs/pcrb.md
    else:  # no ground truth: innovation statistics only (no error, no bound); the manifest says so
        epochs = truth_free_epochs(epochs)
        folder.manifest["pcrb"] = {"status": "unknown", "reason": NO_TRUTH, "seconds": 0.0}
        folder.manifest["ground_truth"] = False
    write_parquet_atomic(epochs, out / "epochs.parquet")
    folder.finish(chunks=len(tasks))
    return metrics


ROW_BYTES = 600  # [B] one metrics row in memory (pandas, ~35 columns), for the size check of a study


def chunk_memory(spec: Spec, number: int, runs: int) -> float:
    """Estimated peak bytes of one chunk of ``runs`` runs of track ``number`` in a worker: the IMU
    and its errors (R x M x 3 floats, six arrays alive at once) and every filter's per-epoch
    output, errors and series rows (about 700 bytes per run, epoch and result), and a smoothed
    filter's record (three n x n matrices and the solution per run and GT epoch; measurement times
    between epochs add to it)."""
    truth = track_inputs(spec, number)[1]
    M, N = len(truth.dt), len(truth.epoch_index)
    n = spec.filter_config.layout.n
    return float(runs) * (M * 3 * 8 * 6 + N * len(spec.outputs) * 700 + N * len(spec.smooth) * (3 * n * n + 30) * 8)


def check_memory(tasks: list, execution: Execution) -> None:
    """Refuse, before any chunk runs, chunks that the local workers cannot hold together (one line
    with the estimate). Remote Dask workers are not checked (their memory is not known here)."""
    from nespm_cli.experiments.backend import ENV_SCHEDULER

    jobs = execution.jobs
    if not tasks or (execution.backend == "dask" and (execution.scheduler or os.environ.get(ENV_SCHEDULER))):
        return
    avail = available_memory()
    if avail is None:
        return
    rows = sum(len(c.spec.outputs) * (f1 - f0) for c, _, f0, f1 in tasks)
    if rows * ROW_BYTES > avail / 2:
        raise NespmError(f"--runs {tasks[0][0].spec.runs}: the metrics table would hold {rows} rows (about "
                         f"{rows * ROW_BYTES / 1e9:.1f} GB in memory), more than half the {avail / 1e9:.1f} GB free here; "
                         "split the study into folders of fewer runs")
    c, n, f0, f1 = max(tasks, key=lambda t: t[3] - t[2])
    need = chunk_memory(c.spec, n, f1 - f0)
    workers = max(1, min(jobs, len(tasks)))
    if need * workers > avail:
        raise NespmError(f"--chunk-size {c.spec.chunk_size}: a chunk of {f1 - f0} runs needs about {need / 1e9:.1f} GB "
                         f"per worker ({workers} worker(s): {need * workers / 1e9:.1f} GB), more than the "
                         f"{avail / 1e9:.1f} GB free here; use a smaller --chunk-size or fewer --jobs")


def available_memory() -> float | None:
    """Bytes of memory available to new work (``MemAvailable`` of /proc/meminfo), or None if unknown."""
    try:
        for line in Path("/proc/meminfo").read_text(encoding="ascii", errors="replace").splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def recover_timings(chunk_seconds: dict, tasks: list, chunks: Path) -> None:
    """Fill in the timing of chunks that finished (their files are on disk) but whose worker's
    answer never reached a manifest (the parent was killed in between): from the chunk's own
    ``seconds`` column (seconds per run)."""
    for c, n, f0, _ in tasks:
        for filt, _ in c.spec.outputs:
            key = timing_key(c.tag, n, filt, f0)
            path = chunks / chunk_name("metrics", n, filt, f0, c.tag)
            if key not in chunk_seconds and chunk_problem(path, c.experiment) is None:
                chunk_seconds[key] = float(pd.read_parquet(path, columns=["seconds"])["seconds"].sum())


def _absolute(cell: Cell) -> Cell:
    """The cell as sent to a worker: data folder and weights as absolute paths (same numbers)."""
    s = cell.spec
    kw = {k: str(Path(v).resolve()) for k, v in (("data_dir", s.data_dir), ("weights", s.weights)) if v}
    return dataclasses.replace(cell, spec=dataclasses.replace(s, **kw)) if kw else cell
