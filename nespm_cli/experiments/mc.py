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
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.data.corruption import CorruptionConfig, draw, dvl_noise, imu_errors
from nespm_cli.filters.adaptive import BIAS_MODES
from nespm_cli.learn.noise_model import WINDOW, default_weights, load_weights, predict_interval_std
from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import body_rate_at_epochs, dvl_velocity
from nespm_cli.nav.earth import ned_offset
from nespm_cli.data.embedded import embedded_track
from nespm_cli.filters import FilterConfig, initial_nav, run_filter
from nespm_cli.filters.kernels import kernel_backend
from nespm_cli.filters.registry import discover_plugins, filter_names, get_filter, load_plugin
from nespm_cli.experiments.metrics import DivergenceRule, divergence, epoch_errors, run_metrics
from nespm_cli.experiments.store import (ResultsFolder, Task, chunk_firsts, file_hashes, run_blocks,
                                        write_parquet_atomic)
from nespm_cli.data.corruption import check_seed
from nespm_cli.data.corrections import IDENTITY_AXES, Corrections, apply_corrections, resolve
from nespm_cli.nav.synthesis import ImuTruth, from_recorded, synthesize
from nespm_cli.data.tracks import Track, available_tracks, load_track, resolve_data_dir

SCENARIOS = ("nominal", "outage")


@dataclass(frozen=True)
class Spec:
    """Everything that determines an experiment's numbers (``jobs`` does not)."""

    tracks: tuple = (5, 6)
    runs: int = 100
    filters: tuple = ("ekf", "ukf", "ukf-nespm")
    scenario: str = "nominal"
    seed: int = 0
    chunk_size: int = 50
    data_dir: str | None = None
    imu: str = "synthetic"
    dvl: str = "recorded"
    dvl_lever_arm: tuple = (0.0, 0.0, 0.0)
    dvl_r_std: float | None = None  # None: 0.02 synthetic, 0.1 recorded
    outage_start: float = 180.0
    outage_length: float = 20.0
    imu_axes: str = IDENTITY_AXES  # recorded IMU axis mapping (data/corrections.py)
    imu_time_offset: float = 0.0  # [s] recorded IMU stamp minus GT time
    imu_time_drift: float = 0.0  # [s/s] growth of that offset with GT time (a clock-rate error)
    dvl_time_offset: float = 0.0  # [s] DVL stamp minus GT time
    window: str | None = None  # "START:END" [s] of the GT file time to use
    corrections: str | None = None  # corrections.json (nespm check): per-track values of the four above
    track_corrections: tuple = ()  # resolved by validate: ((track, Corrections), ...), what the runs use
    divergence: DivergenceRule = field(default_factory=DivergenceRule)  # when a run counts as diverged
    weights: str | None = None  # ProcessNet file of the adaptive filters; None: the packaged default
    filter_plugins: tuple = ()  # user filter files or modules (docs/plugins.md), loaded before the filters run
    corruption: CorruptionConfig = field(default_factory=CorruptionConfig)
    filter_config: FilterConfig = field(default_factory=FilterConfig)

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["tracks"] = list(self.tracks)
        d["filters"] = list(self.filters)
        return json.loads(json.dumps(d, default=list))


def validate(spec: Spec) -> Spec:
    """Check every option against the data; return the spec with ``data_dir`` resolved."""
    check_domains(spec)
    if spec.chunk_size < 1:
        raise NespmError(f"--chunk-size must be at least 1, got {spec.chunk_size}")
    spec = load_filters(spec)
    for f in spec.filters:
        if f not in filter_names():
            raise NespmError(f"--filters: unknown filter {f!r}; choose from {', '.join(filter_names())}")
    if len(set(spec.filters)) != len(spec.filters) or not spec.filters:
        raise NespmError("--filters: give each filter once, at least one")
    if spec.scenario not in SCENARIOS:
        raise NespmError(f"--scenario: unknown scenario {spec.scenario!r}; choose from {', '.join(SCENARIOS)}")
    if spec.imu not in ("synthetic", "recorded"):
        raise NespmError(f"--imu: choose synthetic or recorded, got {spec.imu!r}")
    if spec.dvl not in ("synthetic", "recorded"):
        raise NespmError(f"--dvl: choose synthetic or recorded, got {spec.dvl!r}")
    if spec.filter_config.time_update not in ("dvl", "imu"):
        raise NespmError(f"--time-update: choose dvl or imu, got {spec.filter_config.time_update!r}")
    fc = spec.filter_config
    if fc.adaptive_bias not in BIAS_MODES:
        raise NespmError(f"--adaptive-bias: choose {' or '.join(BIAS_MODES)}, got {fc.adaptive_bias!r}")
    for flag, v in (("--tau", fc.tau), ("--tau-a", fc.tau_a), ("--tau-g", fc.tau_g)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise NespmError(f"{flag} must be a positive number of seconds, got {v:g}")
    lo, hi = fc.q_clip
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= 1 <= hi):
        raise NespmError(f"--q-clip must satisfy 0 < low <= 1 <= high, got {lo:g} {hi:g}")
    adaptive = any(needs_noise_std(f) for f in spec.filters)
    if adaptive:
        load_weights(spec.weights)  # a missing or foreign file fails now, in one line
    d = resolve_data_dir(spec.data_dir)
    have = available_tracks(d)
    for n in spec.tracks:
        if n not in have:
            where = d if d is not None else "the embedded default"
            raise NespmError(f"--tracks: no track {n} in {where}; available: {', '.join(map(str, have))}")
    for n in spec.tracks:
        load_track(n, d)  # validates every file up front
    spec = dataclasses.replace(spec, data_dir=str(Path(d).resolve()) if d is not None else None,
                               corrections=str(Path(spec.corrections).expanduser().resolve()) if spec.corrections else None,
                               weights=(str(Path(spec.weights).expanduser().resolve())
                                        if spec.weights and Path(spec.weights).expanduser().is_file() else spec.weights))
    spec = dataclasses.replace(spec, track_corrections=resolve_corrections(spec))
    durations = {n: prepared(n, spec.data_dir, spec.imu, corrections_for(spec, n))[0].duration
                 for n in spec.tracks}
    if adaptive and spec.imu == "recorded":  # one network window per DVL interval
        for n in spec.tracks:
            steps = np.diff(prepared(n, spec.data_dir, spec.imu, corrections_for(spec, n))[1].epoch_index)
            if not np.all(steps >= WINDOW):
                raise NespmError(f"--imu recorded: track {n} has {int(steps.min())}-{int(steps.max())} IMU steps "
                                 f"per DVL interval; the adaptive filters need at least {WINDOW}")
    if spec.scenario == "outage":
        if spec.outage_length <= 0 or spec.outage_start <= 0:
            raise NespmError("--outage-start and --outage-length must be positive")
        for n in spec.tracks:
            dur = durations[n]
            if spec.outage_start + spec.outage_length > dur:
                raise NespmError(
                    f"--outage-start {spec.outage_start:g} + --outage-length {spec.outage_length:g} s "
                    f"ends past track {n}'s end ({dur:.1f} s)"
                )
    return dataclasses.replace(spec, filter_config=filter_config(spec))  # what the filters use, recorded as such


MAX_LEVER_ARM = 100.0  # [m] a DVL farther than this from the INS is a units or sign mistake


def check_domains(spec: Spec) -> None:
    """Every option's domain, before anything is read or written (one-line NespmError)."""
    def finite(x) -> bool:
        return x is not None and np.isfinite(x)

    if spec.runs < 1:
        raise NespmError(f"--runs must be at least 1, got {spec.runs}")
    check_seed(spec.seed)
    if len(set(spec.tracks)) != len(spec.tracks):
        dup = next(n for n in spec.tracks if list(spec.tracks).count(n) > 1)
        raise NespmError(f"--tracks: track {dup} is given more than once")
    if any(n < 1 for n in spec.tracks):
        raise NespmError(f"--tracks: track numbers are positive, got {min(spec.tracks)}")
    fc = spec.filter_config
    if not (finite(fc.alpha) and 0 < fc.alpha <= 1):
        raise NespmError(f"--alpha must satisfy 0 < alpha <= 1 (the UKF's sigma-point spread), got {fc.alpha:g}")
    if spec.dvl_r_std is not None and not (finite(spec.dvl_r_std) and spec.dvl_r_std > 0):
        raise NespmError(f"--dvl-r-std must be a positive std [m/s], got {spec.dvl_r_std:g}")
    for flag, v in (("--acc-bias-rw", fc.acc_bias_rw), ("--gyro-bias-rw", fc.gyro_bias_rw)):
        if not (finite(v) and v >= 0):
            raise NespmError(f"{flag} must be a finite random walk >= 0, got {v:g}")
    lever = np.asarray(spec.dvl_lever_arm, dtype=float)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)) or np.abs(lever).max() > MAX_LEVER_ARM:
        raise NespmError(f"--dvl-lever-arm must be three finite numbers within +-{MAX_LEVER_ARM:g} m, "
                         f"got {' '.join(f'{x:g}' for x in lever.ravel())}")
    for flag, v in (("--outage-start", spec.outage_start), ("--outage-length", spec.outage_length)):
        if not finite(v):
            raise NespmError(f"{flag} must be a finite number of seconds, got {v:g}")
    d = spec.divergence
    for flag, v in (("--diverge-att-deg", d.att_deg), ("--diverge-nees", d.nees), ("--diverge-window", d.window_s)):
        if not (finite(v) and v > 0):
            raise NespmError(f"{flag} must be a positive number, got {v:g}")
    if not (finite(d.after_s) and d.after_s >= 0):
        raise NespmError(f"--diverge-after must be a number of seconds >= 0, got {d.after_s:g}")


def load_filters(spec: Spec) -> Spec:
    """Import the spec's filter plugins and the installed ``nespm.filters`` entry points (in the
    parent and again in every worker; idempotent); return the spec with plugin files as
    absolute paths (module names stay as given)."""
    discover_plugins()
    plugins = []
    for p in spec.filter_plugins:
        load_plugin(p)
        path = Path(str(p)).expanduser()
        plugins.append(str(path.resolve()) if path.is_file() else str(p))
    return dataclasses.replace(spec, filter_plugins=tuple(plugins))


def needs_noise_std(name: str) -> bool:
    """Whether filter ``name`` takes the ProcessNet noise std (the adaptive filters)."""
    return bool(get_filter(name).needs_noise_std)


def resolve_corrections(spec: Spec) -> tuple:
    """``((track, Corrections), ...)`` for every track of ``spec`` (:func:`corrections.resolve`)."""
    per = resolve(spec.tracks, spec.imu, spec.corrections, spec.imu_axes, spec.imu_time_offset,
                  spec.dvl_time_offset, spec.window, spec.imu_time_drift)
    return tuple(per.items())


def corrections_for(spec: Spec, number: int) -> Corrections:
    """The corrections track ``number`` runs with (resolved by :func:`validate`)."""
    if spec.track_corrections:
        return dict(spec.track_corrections)[number]
    return dict(resolve_corrections(dataclasses.replace(spec, tracks=(number,))))[number]


@lru_cache(maxsize=16)
def prepared(number: int, data_dir: str | None, imu: str,
             corrections: Corrections = Corrections()) -> tuple[Track, ImuTruth]:
    """Track (corrected) and its 100 Hz truth/IMU, computed once per worker process."""
    # None is the embedded default here (validate resolved $NESPM_DATA_DIR on the client), never
    # the worker's own $NESPM_DATA_DIR
    track = load_track(number, data_dir) if data_dir is not None else embedded_track(number)
    track = apply_corrections(track, corrections)
    return track, (synthesize(track) if imu == "synthetic" else from_recorded(track))


def dvl_mask(spec: Spec, t_rel: np.ndarray) -> np.ndarray:
    """Epochs (N,) at which a DVL update is applied (never at epoch 0)."""
    m = np.ones(len(t_rel), dtype=bool)
    m[0] = False
    if spec.scenario == "outage":
        m &= ~((t_rel >= spec.outage_start - 1e-9) & (t_rel < spec.outage_start + spec.outage_length - 1e-9))
    return m


def filter_config(spec: Spec) -> FilterConfig:
    r = spec.dvl_r_std if spec.dvl_r_std is not None else (0.02 if spec.dvl == "synthetic" else 0.1)
    return dataclasses.replace(spec.filter_config, dvl_std=r, lever_arm=tuple(spec.dvl_lever_arm))


def simulate(spec: Spec, number: int, runs: np.ndarray, filters=None, clean: bool = False,
             progress: Callable[[int], None] | None = None):
    """Run ``filters`` on the realizations ``runs`` of track ``number``.

    Returns ``{filter: (FilterOutput, EpochErrors, seconds)}`` plus the truth object.
    ``progress(done)``, if given, is called with the filter-epochs done so far (filters run one
    after the other, each over the track's N-1 epoch intervals).
    """
    track, truth = prepared(number, spec.data_dir, spec.imu, corrections_for(spec, number))
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    R = len(runs)
    real = draw(spec.seed, number, runs, float(t_rel[-1]), spec.corruption)
    lever = np.asarray(spec.dvl_lever_arm, dtype=float)
    C_t, v_t, p_t = truth.C_bn[e], truth.v_n[e], truth.pos[e]
    if spec.dvl == "synthetic":
        dvl = dvl_velocity(C_t, v_t, body_rate_at_epochs(truth.C_bn, truth.dt, truth.epoch_index), lever)
        dvl = np.broadcast_to(dvl, (R,) + dvl.shape)
        if not clean:
            dvl = dvl + dvl_noise(real, len(e))
    else:
        dvl = np.broadcast_to(np.asarray(track.dvl, dtype=float), (R, len(e), 3))
    if clean:
        f = np.broadcast_to(truth.f_b, (R,) + truth.f_b.shape)
        w = np.broadcast_to(truth.w_ib_b, (R,) + truth.w_ib_b.shape)
        nav0 = initial_nav(p_t[0], v_t[0], C_t[0], np.zeros((R, 3)), np.zeros((R, 3)))
    else:
        ef, ew = imu_errors(real, truth.t)
        f, w = truth.f_b + ef, truth.w_ib_b + ew
        nav0 = initial_nav(p_t[0], v_t[0], C_t[0], real.dv0, real.dpsi0)
    mask = dvl_mask(spec, t_rel)
    cfg = filter_config(spec)
    results = {}
    names = list(filters or spec.filters)
    noise_std, net_seconds = None, 0.0
    adaptive = [n for n in names if needs_noise_std(n)]
    if adaptive:  # one network pass per chunk, shared by the adaptive filters
        t0 = time.perf_counter()
        noise_std = predict_interval_std(f, w, e, spec.weights)
        net_seconds = time.perf_counter() - t0
    for i, name in enumerate(names):
        t0 = time.perf_counter()
        step = None if progress is None else (lambda k, base=i * (len(e) - 1): progress(base + k))
        out = run_filter(name, cfg, f, w, truth.dt, e, dvl, mask, nav0,
                         noise_std if name in adaptive else None, progress=step)
        if name in adaptive:
            t0 -= net_seconds / len(adaptive)  # the shared network pass, split
        err = epoch_errors(out, v_t, C_t, p_t)
        results[name] = (out, err, time.perf_counter() - t0)
    return results, truth, real


def q_factors(noise_std, cfg: FilterConfig, R: int) -> dict:
    """Per-run mean of the (validated) network std over nominal: ``q_factor_acc``, ``q_factor_gyro`` (R,).

    NaN for the non-adaptive filters. With the ``dynamic`` schedule the injected factor is
    U[1, 6] (mean 3.5); with ``constant`` it is 1.
    """
    if noise_std is None:
        return {"q_factor_acc": np.full(R, np.nan), "q_factor_gyro": np.full(R, np.nan)}
    from nespm_cli.filters.adaptive import valid_std

    out = {}
    for key, s, nominal in (("acc", noise_std[0], cfg.acc_noise), ("gyro", noise_std[1], cfg.gyro_noise)):
        out[f"q_factor_{key}"] = valid_std(s, nominal, tuple(cfg.q_clip)).mean(axis=(1, 2)) / nominal
    return out


# --- chunked, resumable runner ---------------------------------------------------------

def _chunk_name(kind: str, track: int, filt: str, first: int, tag: str = "") -> str:
    return f"{kind}-{tag}{track}-{filt}-{first:06d}.parquet"


@dataclass(frozen=True)
class Cell:
    """One experiment of a run folder: ``mc`` has one, ``sweep`` one per swept value.

    ``tag`` prefixes its chunk files; ``columns`` are added to every row it writes.
    """

    spec: Spec
    tag: str = ""
    columns: tuple = ()


def timing_key(tag: str, number: int, filt: str, first: int) -> str:
    """The key of one filter's chunk in the manifest's ``chunk_seconds``: ``<tag><track>-<filter>-<first run>``."""
    return f"{tag}{number}-{filt}-{first}"


def chunk_key(cell: Cell, number: int, first: int) -> str:
    """The name of a chunk in progress reports: ``<tag><track>-<first run>``."""
    return f"{cell.tag}{number}-{first:06d}"


def run_chunk(cell: Cell, number: int, first: int, out_dir: str, last: int | None = None) -> dict:
    """Compute runs ``first .. last-1`` of track ``number`` (all filters not yet on disk) and
    write their files. Runs in a worker. ``last`` defaults to ``first + chunk_size`` (at most
    ``runs``). Its progress goes to ``out_dir/chunks/.progress`` (:mod:`nespm_cli.experiments.progress`)."""
    from nespm_cli.experiments.progress import epoch_reporter

    spec, tag, extra = cell.spec, cell.tag, dict(cell.columns)
    load_filters(spec)  # a worker process imports the user's filters before it runs them
    chunks = Path(out_dir) / "chunks"
    if last is None:
        last = min(first + spec.chunk_size, spec.runs)
    runs = np.arange(first, last)
    todo = [f for f in spec.filters if not (chunks / _chunk_name("metrics", number, f, first, tag)).exists()]
    timings = {}
    if not todo:
        return timings
    n_epochs = len(prepared(number, spec.data_dir, spec.imu, corrections_for(spec, number))[1].epoch_index)  # cached; simulate reuses it
    report = epoch_reporter(chunks, chunk_key(cell, number, first), len(todo) * (n_epochs - 1))
    results, truth, _ = simulate(spec, number, runs, todo, progress=report)
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    for name, (out, err, secs) in results.items():
        div, why = divergence(err, out.diverged, t_rel, spec.divergence)
        m = run_metrics(err, div)
        m["diverged_reason"] = why
        m.update(q_factors(out.noise_std, filter_config(spec), len(runs)))
        df = pd.DataFrame({**extra, "track": number, "filter": name, "run": runs, "scenario": spec.scenario,
                           "schedule": spec.corruption.schedule, "seed": spec.seed, **m,
                           "seconds": secs / len(runs), "kernels": kernel_backend()})
        R, N = err.vel.shape
        series = pd.DataFrame({
            **extra, "track": number, "filter": name, "run": np.repeat(runs, N), "epoch": np.tile(np.arange(N), R),
            "t": np.tile(t_rel, R), "vel_err": err.vel.ravel(), "att_err": err.att.ravel(),
            "nees": err.nees.ravel(), "north_err": err.ne[..., 0].ravel(), "east_err": err.ne[..., 1].ravel(),
            "dvl_used": np.tile(out.dvl_used, R), "diverged": np.repeat(div, N),
        })
        # series first: a metrics file marks the chunk complete
        write_parquet_atomic(series, chunks / _chunk_name("series", number, name, first, tag))
        write_parquet_atomic(df, chunks / _chunk_name("metrics", number, name, first, tag))
        timings[timing_key(tag, number, name, first)] = secs
    return timings


def run_chunk_keyed(cell: Cell, number: int, first: int, out_dir: str, last: int | None = None) -> tuple[str, dict]:
    """:func:`run_chunk`, returning ``(chunk_key, timings)`` so the parent knows which chunk ended."""
    return chunk_key(cell, number, first), run_chunk(cell, number, first, out_dir, last)


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
    return len(prepared(number, spec.data_dir, spec.imu, corrections_for(spec, number))[0].t)


def assemble(out: Path, keys: tuple = ()) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Concatenate the chunk files into metrics.parquet and aggregate epochs.parquet.

    ``keys``: extra leading key columns (a sweep's ``param``, ``value``).
    """
    keys = list(keys)
    chunks = out / "chunks"
    metrics = pd.concat([pd.read_parquet(p) for p in sorted(chunks.glob("metrics-*.parquet"))], ignore_index=True)
    metrics = metrics.sort_values(keys + ["track", "filter", "run"], kind="stable").reset_index(drop=True)
    series = pd.concat([pd.read_parquet(p) for p in sorted(chunks.glob("series-*.parquet"))], ignore_index=True)
    series["hpe"] = np.hypot(series["north_err"], series["east_err"])  # horizontal position error [m]
    err_cols = ["vel_err", "att_err", "nees", "north_err", "east_err", "hpe"]
    series.loc[series["diverged"], err_cols] = np.nan  # diverged runs count in no mean
    series["ok"] = ~series["diverged"]
    g = series.groupby(keys + ["track", "filter", "epoch"], sort=True)
    std0 = lambda x: x.std(ddof=0)  # noqa: E731
    epochs = g.agg(t=("t", "first"), vel_err_mean=("vel_err", "mean"), vel_err_std=("vel_err", std0),
                   att_err_mean=("att_err", "mean"), att_err_std=("att_err", std0),
                   nees_mean=("nees", "mean"), north_err_mean=("north_err", "mean"),
                   east_err_mean=("east_err", "mean"), hpe_mean=("hpe", "mean"), hpe_std=("hpe", std0),
                   dvl_used=("dvl_used", "first"),
                   n_runs=("ok", "sum")).reset_index()
    epochs["n_runs"] = epochs["n_runs"].astype(np.int64)
    write_parquet_atomic(metrics, out / "metrics.parquet")
    return metrics, epochs


def add_true_track(epochs: pd.DataFrame, spec: Spec) -> pd.DataFrame:
    parts = []
    for n, df in epochs.groupby("track", sort=True):
        _, truth = prepared(int(n), spec.data_dir, spec.imu, corrections_for(spec, int(n)))
        p = truth.pos[truth.epoch_index]
        ne = ned_offset(p, p[0])
        df = df.copy()
        df["north_true"] = ne[df["epoch"].to_numpy(), 0]
        df["east_true"] = ne[df["epoch"].to_numpy(), 1]
        parts.append(df)
    return pd.concat(parts, ignore_index=True)


def run_mc(spec: Spec, out_dir: str | Path, jobs: int = 2, progress: bool = True, argv=None,
           backend: str = "loky", scheduler: str | None = None) -> pd.DataFrame:
    """Run (or resume) the experiment into ``out_dir``; return the metrics table."""
    spec = validate(spec)
    return run_cells([Cell(spec)], spec.as_dict(), out_dir, jobs=jobs, progress=progress, argv=argv,
                     backend=backend, scheduler=scheduler)


def input_files(spec: Spec) -> list[Path]:
    """Every file the numbers of ``spec`` depend on: each track's GT and DVL (and IMU with
    ``--imu recorded``), the ProcessNet weights of adaptive filters, the corrections file and
    the filter plugin files. Their hashes go into the manifest (docs/results-schema.md)."""
    files: list[Path] = []
    if spec.data_dir is not None:
        for n in spec.tracks:
            tdir = Path(spec.data_dir) / f"Trajectory{n}"
            names = ["GT", "DVL"] + (["IMU"] if spec.imu == "recorded" else [])
            files += [tdir / f"{k}_trajectory{n}.csv" for k in names]
    if any(needs_noise_std(f) for f in spec.filters):
        files.append(Path(spec.weights) if spec.weights else default_weights())
    if spec.corrections:
        files.append(Path(spec.corrections))
    files += [Path(p) for p in spec.filter_plugins if Path(p).is_file()]
    return files


def run_cells(cells: list[Cell], options: dict, out_dir: str | Path, jobs: int = 2, progress: bool = True,
              argv=None, label: str = "mc", backend: str = "loky", scheduler: str | None = None) -> pd.DataFrame:
    """Run (or resume, or extend to more runs) validated ``cells`` into ``out_dir``; ``options``
    identify the experiment (:class:`nespm_cli.experiments.store.ResultsFolder`).

    ``backend``/``scheduler`` choose where chunks run (:mod:`nespm_cli.experiments.backend`);
    they do not change the results.
    """
    from nespm_cli.experiments.backend import check_backend

    if jobs < 1:
        raise NespmError(f"--jobs must be at least 1, got {jobs}")
    check_backend(backend)  # before --out is created
    folder = ResultsFolder(out_dir, options, argv, extendable=("runs",))
    first = cells[0].spec
    files = sorted({p.resolve() for c in cells for p in input_files(c.spec)})
    folder.open(inputs=file_hashes(files), seed=first.seed, data_dir=first.data_dir or "embedded",
                filter_config={c.tag or "all": dataclasses.asdict(c.spec.filter_config) for c in cells})
    blocks = run_blocks(folder.old, first.runs)
    folder.manifest["run_blocks"] = [list(b) for b in blocks]
    folder.save()
    out = folder.out
    tasks = chunk_tasks(cells, blocks)

    def missing(c: Cell, n: int, f0: int) -> list[str]:
        return [f for f in c.spec.filters if not folder.done(_chunk_name("metrics", n, f, f0, c.tag))]

    todo = [Task(chunk_key(c, n, f0), (_absolute(c), n, f0, str(out.resolve()), f1), k * (track_epochs(c.spec, n) - 1))
            for c, n, f0, f1 in tasks for k in [len(missing(c, n, f0))] if k]
    folder.run(run_chunk_keyed, todo, jobs, backend, scheduler, label, progress)
    recover_timings(folder.manifest["chunk_seconds"], tasks, out / "chunks")
    metrics, epochs = assemble(out, tuple(k for k, _ in cells[0].columns))
    epochs = add_true_track(epochs, first)
    write_parquet_atomic(epochs, out / "epochs.parquet")
    folder.finish(chunks=len(tasks))
    return metrics


def recover_timings(chunk_seconds: dict, tasks: list, chunks: Path) -> None:
    """Fill in the timing of chunks that finished (their files are on disk) but whose worker's
    answer never reached a manifest (the parent was killed in between): from the chunk's own
    ``seconds`` column (seconds per run)."""
    for c, n, f0, _ in tasks:
        for filt in c.spec.filters:
            key = timing_key(c.tag, n, filt, f0)
            path = chunks / _chunk_name("metrics", n, filt, f0, c.tag)
            if key not in chunk_seconds and path.exists():
                chunk_seconds[key] = float(pd.read_parquet(path, columns=["seconds"])["seconds"].sum())


def _absolute(cell: Cell) -> Cell:
    """The cell as sent to a worker: data folder and weights as absolute paths (same numbers)."""
    s = cell.spec
    kw = {k: str(Path(v).resolve()) for k, v in (("data_dir", s.data_dir), ("weights", s.weights)) if v}
    return dataclasses.replace(cell, spec=dataclasses.replace(s, **kw)) if kw else cell


def couple_filter(fcfg: FilterConfig, corr: CorruptionConfig) -> FilterConfig:
    """The filter told the truth about the corruption: P0 from the initial-error and bias
    std, Q's white noise from the injected per-sample noise (docs/filters.md)."""
    att = [corr.misalignment_deg] * 3
    if corr.heading_deg is not None:
        att[2] = corr.heading_deg
    return dataclasses.replace(
        fcfg, p0_vel=(corr.vel_h_std, corr.vel_h_std, corr.vel_v_std), p0_att_deg=tuple(att),
        p0_acc_bias=corr.acc_bias, p0_gyro_bias=corr.gyro_bias, acc_noise=corr.acc_noise,
        gyro_noise=corr.gyro_noise)
