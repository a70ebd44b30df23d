"""The ``nespm`` command line: parse, call the library, print.

Every bad input ends in one line ``nespm: error: ...`` on stderr and exit code 2.
"""
from __future__ import annotations

import functools
import inspect
import re
import json
import sys
import time
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np
import typer
from typer.exceptions import Abort, Exit, TyperException

from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.errors import NespmError
from nespm_cli.experiments.gp_ukf import GPSpec
from nespm_cli.experiments.spec import Spec
from nespm_cli.experiments.metrics import DivergenceRule
from nespm_cli.filters import FilterConfig
from nespm_cli.reports.stats import PRACTICAL_PCT

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    help="Monte Carlo experiments for nonlinear INS/DVL navigation filters (EKF, UKF, UKF-NESPM and their "
    "adaptive ProcessNet versions ANEKF, ANUKF, ANUKF-NESPM).\n\n"
    "Tracks come from --data-dir (A-KIT layout: TrajectoryN/{GT,DVL}_trajectoryN.csv), else "
    "$NESPM_DATA_DIR, else six embedded Snapir-like tracks.",
)

DATA_DIR = typer.Option(None, "--data-dir", help="Folder in the A-KIT layout (default: $NESPM_DATA_DIR, else the embedded tracks).")


def _tracks(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(x) for x in text.replace(",", " ").split())
    except ValueError:
        raise NespmError(f"--tracks: expected track numbers like '5 6' or '5,6', got {text!r}") from None
    if not out:
        raise NespmError("--tracks: give at least one track number")
    return out


def _filters(text: str) -> tuple[str, ...]:
    return tuple(x.strip().lower() for x in text.split(",") if x.strip())


#: option name -> field of the config dataclass it sets (where the names differ, or the class)
CORRUPTION_FIELDS = {"schedule": "schedule", "segment_length": "segment_s", "dynamic_bias": "dynamic_bias",
                     "dvl_noise": "dvl_noise", "misalignment_deg": "misalignment_deg", "heading_deg": "heading_deg",
                     "vel_h_std": "vel_h_std", "vel_v_std": "vel_v_std", "acc_noise": "acc_noise",
                     "gyro_noise": "gyro_noise", "acc_bias": "acc_bias", "gyro_bias": "gyro_bias",
                     "pos_h_std": "pos_h_std", "pos_v_std": "pos_v_std"}
FILTER_FIELDS = ("acc_bias_rw", "gyro_bias_rw", "alpha", "tau", "tau_a", "tau_g", "adaptive_bias", "q_clip",
                 "time_update", "state")


def default(cls, name: str):
    """The default of field ``name`` of dataclass ``cls``: the one place every option default lives."""
    import dataclasses

    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()


def _corruption(kw: dict) -> CorruptionConfig:
    """Pop the corruption options (:data:`CORRUPTION_FIELDS`) from ``kw``."""
    return CorruptionConfig(**{field: kw.pop(opt) for opt, field in CORRUPTION_FIELDS.items()})


def _warning_mode(mode: str) -> None:
    from nespm_cli.data.plausibility import set_warning_mode

    if mode not in ("warn", "ignore", "error"):
        raise NespmError(f"--data-warnings: choose warn, ignore or error, got {mode!r}")
    set_warning_mode(mode)


def _sensor_option(text: str) -> tuple[str, str, str]:
    """``NAME.KEY=VALUE`` -> ``(NAME, KEY, VALUE)`` (one-line error otherwise)."""
    m = re.fullmatch(r"\s*([A-Za-z0-9_-]+)\.([A-Za-z0-9_]+)\s*=(.*)", text)
    if not m:
        raise NespmError(f"--sensor-option {text!r}: expected NAME.KEY=VALUE, e.g. fix.interval=10")
    return m.group(1), m.group(2), m.group(3).strip()


def _spec(**kw):
    """The Spec of the common options; every coupling of options (P0 from the corruption, the DVL
    flags as the DVL's options) happens in the library (experiments.spec.validate), not here."""
    from nespm_cli.experiments.metrics import DivergenceRule
    from nespm_cli.experiments.spec import Spec

    _warning_mode(kw.pop("data_warnings"))
    corr = _corruption(kw)
    kw["filter_plugins"] = tuple(kw.get("filter_plugins") or ())
    kw["sensor_plugins"] = tuple(kw.get("sensor_plugins") or ())
    kw["sensors"] = tuple(s.strip() for s in kw.pop("sensors_").split(",") if s.strip())
    kw["sensor_options"] = tuple(_sensor_option(o) for o in kw.pop("sensor_option") or ())
    fields = {k: kw.pop(k) for k in FILTER_FIELDS}
    fcfg = FilterConfig(**{**fields, "q_clip": tuple(fields["q_clip"])})
    kw["divergence"] = DivergenceRule(att_deg=kw.pop("diverge_att_deg"), nees=kw.pop("diverge_nees"),
                                      window_s=kw.pop("diverge_window"), after_s=kw.pop("diverge_after"))
    return Spec(corruption=corr, filter_config=fcfg, **kw)


_CORRUPTION = [  # (name, type, default, flag, help): the realizations (mc, sweep, run, corrupt)
    ("schedule", str, default(CorruptionConfig, "schedule"), "--schedule", "IMU error schedule: constant (UKF-NESPM paper) or dynamic (ANUKF paper: noise and bias x U[1,6] per segment)."),
    ("segment_length", float, default(CorruptionConfig, "segment_s"), "--segment-length", "Dynamic schedule segment [s]."),
    ("dynamic_bias", str, default(CorruptionConfig, "dynamic_bias"), "--dynamic-bias", "Dynamic schedule biases: run (x the run's first-segment factor, held) or segment (x every segment's factor: 20 s bias steps)."),
    ("seed", int, default(Spec, "seed"), "--seed", "Master seed; run r of track N draws from SeedSequence(seed, spawn_key=(N, r, stream))."),
    ("data_dir", Optional[str], default(Spec, "data_dir"), "--data-dir", "Folder in the A-KIT layout (default: $NESPM_DATA_DIR, else the embedded tracks)."),
    ("dvl_noise", float, default(CorruptionConfig, "dvl_noise"), "--dvl-noise", "Synthetic DVL noise std [m/s]."),
    ("misalignment_deg", float, default(CorruptionConfig, "misalignment_deg"), "--misalignment-deg", "Initial misalignment std per axis [deg]."),
    ("heading_deg", Optional[float], default(CorruptionConfig, "heading_deg"), "--heading-deg", "Initial heading (yaw-axis) misalignment std [deg]; default: --misalignment-deg."),
    ("vel_h_std", float, default(CorruptionConfig, "vel_h_std"), "--vel-h-std", "Initial north/east velocity error std [m/s]."),
    ("vel_v_std", float, default(CorruptionConfig, "vel_v_std"), "--vel-v-std", "Initial down velocity error std [m/s]."),
    ("acc_noise", float, default(CorruptionConfig, "acc_noise"), "--acc-noise", "Accelerometer white noise std per 100 Hz sample [m/s^2]."),
    ("gyro_noise", float, default(CorruptionConfig, "gyro_noise"), "--gyro-noise", "Gyro white noise std per sample [rad/s]."),
    ("acc_bias", float, default(CorruptionConfig, "acc_bias"), "--acc-bias", "Accelerometer bias std [m/s^2]."),
    ("gyro_bias", float, default(CorruptionConfig, "gyro_bias"), "--gyro-bias", "Gyro bias std [rad/s]."),
    ("pos_h_std", float, default(CorruptionConfig, "pos_h_std"), "--pos-h-std", "Initial north/east position error std [m] (0 in the papers; with --state 15 the filter's P0 follows it)."),
    ("pos_v_std", float, default(CorruptionConfig, "pos_v_std"), "--pos-v-std", "Initial down position error std [m]."),
]

_RECORDED = [  # corrections of recorded data (docs/checking-data.md): mc, sweep, run, train
    ("imu_axes", str, default(Spec, "imu_axes"), "--imu-axes", "Recorded IMU axis mapping: corrected body axis i is the i-th signed recorded axis, e.g. x,-y,z (nespm check finds it)."),
    ("imu_time_offset", float, default(Spec, "imu_time_offset"), "--imu-time-offset", "Recorded IMU stamp minus GT time [s]; subtracted from the IMU stamps (nespm check measures it)."),
    ("imu_time_drift", float, default(Spec, "imu_time_drift"), "--imu-time-drift", "Recorded IMU clock drift [s/s]: stamp - GT time = offset + drift * GT time (nespm check measures it)."),
    ("dvl_time_offset", float, default(Spec, "dvl_time_offset"), "--dvl-time-offset", "DVL stamp minus GT time [s]; the DVL is re-sampled at the GT epochs from its shifted stamps."),
    ("window", Optional[str], default(Spec, "window"), "--window", "START:END [s, GT file time]: use only these GT epochs of every track (e.g. 20:400)."),
    ("corrections", Optional[str], default(Spec, "corrections"), "--corrections", "Per-track corrections (imu_axes, offsets, window) from the corrections.json that 'nespm check' writes; an option given explicitly overrides it for every track."),
]

_KERNELS = ("kernels", Optional[str], None, "--kernels",
            "The filters' IMU-rate loop: auto (compiled with numba where installed), numba, or numpy (the "
            "reference); default $NESPM_KERNELS, else auto. The same numbers to round-off either way (docs/architecture.md); not part of an "
            "experiment's identity, like --jobs.")

_COMMON = [  # the options that define an experiment: the realizations, the data, the filters
    *_CORRUPTION,
    ("data_warnings", str, "warn", "--data-warnings", "Data that looks wrong but may be legitimate (irregular epoch steps, fast turns, a DVL speed far from the GT's, ...): warn (one line each), ignore, or error (exit 2). Clear mistakes are always errors."),
    ("scenario", str, default(Spec, "scenario"), "--scenario", "nominal, or outage: no DVL for --outage-length s from --outage-start s."),
    ("state", str, default(FilterConfig, "state"), "--state", "Error-state layout: 12 (the papers': velocity, attitude, biases), 15 (position first) or a comma list of blocks from pos,vel,att,ba,bg (docs/sensors.md)."),
    ("sensors_", str, ",".join(default(Spec, "sensors")), "--sensors", "Comma list of measurement sources, applied in this order at equal times: dvl, depth, fix, or a plugin's (docs/sensors.md)."),
    ("sensor_option", Optional[List[str]], None, "--sensor-option", "NAME.KEY=VALUE for a sensor of --sensors, e.g. fix.interval=10, fix.std=1, depth.std=0.05, dvl.outage=180:200; repeatable; [sensors.NAME] tables in a --config file."),
    ("sensor_plugins", Optional[List[str]], None, "--sensor-plugin", "A Python file (or module) defining your own sensors with nespm_cli.sensors.register; repeatable; then name them in --sensors (docs/sensors.md)."),
    ("imu_rate", float, default(Spec, "imu_rate"), "--imu-rate", "Rate of the synthesized IMU [Hz]: round(rate x GT step) steps per GT interval (the noise std options are per sample at this rate)."),
    ("imu", str, default(Spec, "imu"), "--imu", "synthetic (inverse strapdown of GT: exact truth) or recorded (IMU_trajectoryN.csv)."),
    *_RECORDED,
    ("dvl", str, default(Spec, "dvl"), "--dvl", "recorded (the track's DVL file) or synthetic (C_n^b v + w_nb x l + N(0, dvl-noise^2))."),
    ("dvl_lever_arm", Tuple[float, float, float], default(Spec, "dvl_lever_arm"), "--dvl-lever-arm", "DVL lever arm X Y Z [m, body] in the measurement model (and in synthetic DVL)."),
    ("dvl_r_std", Optional[float], default(Spec, "dvl_r_std"), "--dvl-r-std", "Filter DVL std [m/s] (default 0.02 with synthetic DVL, 0.1 with recorded)."),
    ("outage_start", float, default(Spec, "outage_start"), "--outage-start", "Outage start [s after the first epoch]."),
    ("outage_length", float, default(Spec, "outage_length"), "--outage-length", "Outage length [s]."),
    ("diverge_att_deg", float, default(DivergenceRule, "att_deg"), "--diverge-att-deg", "A run counts as diverged when its attitude error exceeds this [deg] after --diverge-after (also: non-finite state, speed > 50 m/s)."),
    ("diverge_nees", float, default(DivergenceRule, "nees"), "--diverge-nees", "...or when its NEES averaged over --diverge-window s exceeds this after --diverge-after (6-dof chi-square 99.9 %: 22.5)."),
    ("diverge_window", float, default(DivergenceRule, "window_s"), "--diverge-window", "Window of the NEES divergence test [s]."),
    ("diverge_after", float, default(DivergenceRule, "after_s"), "--diverge-after", "Seconds after the start before the attitude and NEES tests apply (initial errors may be large)."),
    ("filter_acc_noise", Optional[float], None, "--filter-acc-noise", "Accelerometer white noise std per sample in the filters' Q [m/s^2]; default: the injected --acc-noise. With a recorded IMU add its own noise in quadrature (nespm check measures it)."),
    ("filter_gyro_noise", Optional[float], None, "--filter-gyro-noise", "Gyro white noise std per sample in the filters' Q [rad/s]; default: the injected --gyro-noise (see --filter-acc-noise)."),
    ("acc_bias_rw", float, default(FilterConfig, "acc_bias_rw"), "--acc-bias-rw", "Filter accelerometer bias random walk [m/s^2/sqrt(s)]."),
    ("gyro_bias_rw", float, default(FilterConfig, "gyro_bias_rw"), "--gyro-bias-rw", "Filter gyro bias random walk [rad/s/sqrt(s)]."),
    ("alpha", float, default(FilterConfig, "alpha"), "--alpha", "UKF sigma-point spread alpha (beta = 2, kappa = 0)."),
    ("filter_plugins", Optional[List[str]], None, "--filter-plugin", "A Python file (or module) defining your own filters with nespm_cli.filters.registry.register; repeatable; then name them in --filters (docs/plugins.md)."),
    ("weights", Optional[str], default(Spec, "weights"), "--weights", "ProcessNet weights (.npz from 'nespm train') for anekf/anukf/anukf-nespm; default: the packaged ones (embedded tracks 1-4)."),
    ("tau", Optional[float], default(FilterConfig, "tau"), "--tau", "Adaptive Q, eqs 44/46: q = std^2 * tau [s]; default: the IMU step."),
    ("tau_a", Optional[float], default(FilterConfig, "tau_a"), "--tau-a", "Adaptive Q, eq 45: q_v = q_a * tau_a [s]; default: the time-update span."),
    ("tau_g", Optional[float], default(FilterConfig, "tau_g"), "--tau-g", "Adaptive Q, eq 47: q_psi = q_g * tau_g [s]; default: the time-update span."),
    ("adaptive_bias", str, default(FilterConfig, "adaptive_bias"), "--adaptive-bias", "Adaptive Q bias blocks: nominal (the fixed random walk), scaled (x (std/nominal)^2, matches --dynamic-bias segment) or paper (q_a, q_g of eq 43)."),
    ("q_clip", Tuple[float, float], default(FilterConfig, "q_clip"), "--q-clip", "Validity bounds LOW HIGH on the network std, as multiples of the nominal std."),
    ("time_update", str, default(FilterConfig, "time_update"), "--time-update", "dvl: one time update per DVL interval (sigma points carried through all its IMU steps); imu: every IMU step."),
]


_PARALLEL = [  # where the chunks of a resumable experiment run (mc, sweep, gp-ukf)
    ("jobs", int, 2, "--jobs", "Local worker processes: loky, or the local Dask cluster (results do not depend on it)."),
    ("backend", str, "loky", "--backend", "Where chunks run: loky (local processes) or dask (a Dask cluster; pip install 'nespm[dask]')."),
    ("scheduler", Optional[str], None, "--scheduler", "Dask scheduler address (tcp://host:8786) or scheduler file; default $NESPM_DASK_SCHEDULER, else a local cluster of --jobs workers (docs/cluster.md)."),
    ("no_progress", bool, False, "--no-progress", "No progress (a bar on a terminal, else a line on stderr every 15 s with the ETA)."),
    _KERNELS,
]

_RUNNER = [  # options of the commands that run many realizations (mc, sweep)
    ("tracks_", str, " ".join(map(str, default(Spec, "tracks"))), "--tracks", "Track numbers: --tracks 5 6 or --tracks 5,6."),
    ("runs", int, default(Spec, "runs"), "--runs", "Monte Carlo runs per track."),
    ("filters_", str, ",".join(default(Spec, "filters")), "--filters", "Comma list of ins, ekf, ukf, ukf-nespm, anekf, anukf, anukf-nespm, ckf, ckf-nespm, iekf (docs/filters.md), or a plugin's."),
    ("chunk_size", int, default(Spec, "chunk_size"), "--chunk-size", "Runs per batch, the resumable unit."),
    ("config", Optional[str], None, "--config", "TOML file of options (keys are option names: runs = 100, tracks = [5, 6]); options on the command line override it. See experiments/."),
    *_PARALLEL,
]


def _options(*groups):
    """Give a command (which takes ``**kw``) the options of ``groups`` after its own."""
    def deco(f):
        own = [p for p in inspect.signature(f).parameters.values() if p.kind != p.VAR_KEYWORD]
        extra = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, annotation=t,
                                   default=typer.Option(d, flag, help=h, show_default=d is not None))
                 for group in groups for n, t, d, flag, h in group]

        @functools.wraps(f)
        def wrapper(**kwargs):
            if "kernels" in kwargs:  # for this process and the workers it starts (they inherit it)
                from nespm_cli.filters.kernels import kernel_mode, set_kernel_mode

                mode = kwargs.pop("kernels")
                set_kernel_mode(kernel_mode() if mode is None else mode)
            return f(**kwargs)

        wrapper.__signature__ = inspect.Signature(own + extra)
        return wrapper
    return deco




@app.command()
def tracks(data_dir: Optional[str] = DATA_DIR,
           no_progress: bool = typer.Option(False, "--no-progress", help="Do not say which track is being read."),
           data_warnings: str = typer.Option("warn", "--data-warnings", help="warn, ignore or error on data that looks wrong but may be legitimate.")) -> None:
    """List the tracks: duration, distance, speed, yaw rate, depth, DVL residual and lever arm."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from nespm_cli.experiments.progress import Status
    from nespm_cli.data.tracks import available_tracks, load_track, resolve_data_dir, track_summary

    _warning_mode(data_warnings)
    d = resolve_data_dir(data_dir)
    table = Table(title=escape(f"tracks in {d if d else 'the embedded default'}"))
    for c in ("track", "duration [s]", "epochs", "distance [m]", "mean speed [m/s]", "max yaw rate [deg/s]",
              "depth [m]", "IMU", "DVL resid std [m/s]", "lever arm ± 1σ [m]"):
        table.add_column(escape(c), justify="right")
    warnings = []
    numbers = available_tracks(d)
    with Status("nespm tracks", enabled=not no_progress, plain=False) as status:
        for i, n in enumerate(numbers, 1):
            status(f"reading and fitting track {n} ({i}/{len(numbers)})")
            s = track_summary(load_track(n, d))
            arm = ", ".join(f"{x:.2f}±{e:.2f}" for x, e in zip(s["lever_arm"], s["lever_arm_std"]))
            flag = " (?)" if s["lever_arm_warning"] else ""
            table.add_row(str(n), f"{s['duration_s']:.1f}", str(s["epochs"]), f"{s['distance_m']:.0f}",
                          f"{s['mean_speed']:.2f}", f"{s['max_yaw_rate_dps']:.1f}",
                          f"{s['depth_min']:.1f}-{s['depth_max']:.1f}", "yes" if s["imu"] else "no",
                          f"{s['dvl_resid_std']:.3f}", escape(f"({arm}){flag}"))
            if s["lever_arm_warning"]:
                warnings.append(s["lever_arm_warning"])
    Console(width=None if sys.stdout.isatty() else 200).print(table)
    for w in warnings:
        typer.echo(f"warning: {w}")


@app.command()
def check(
    data_dir: Optional[str] = DATA_DIR,
    tracks_: Optional[str] = typer.Option(None, "--tracks", help="Tracks to check (default: all)."),
    out: str = typer.Option("results/check", "--out", help="Folder for check.md, check.json, corrections.json and figures."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures (faster)."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say which track is being checked."),
    data_warnings: str = typer.Option("warn", "--data-warnings", help="warn, ignore or error on data that looks wrong but may be legitimate."),
) -> None:
    """Check a track folder against its ground truth: recorded IMU (axes, time offset, windowed
    biases, attitude drift) and DVL (lever arm, scale, misalignment, time offset); a verdict per
    track and the options that apply the corrections (docs/checking-data.md)."""
    from nespm_cli.experiments.check import check_folder
    from nespm_cli.experiments.progress import Status
    from nespm_cli.reports.check import summary_table, write_check_report

    _warning_mode(data_warnings)
    numbers = _tracks(tracks_) if tracks_ else None
    with Status("nespm check", enabled=not no_progress) as status:
        result = check_folder(data_dir, numbers, status=status)
        status("writing the report")
        path = write_check_report(result, out, figures=not no_figures)
    typer.echo(summary_table(result))
    for r in result["tracks"]:
        for f in r["findings"]:
            typer.echo(f"track {r['track']}: {f}")
    typer.echo(f"wrote {path} and {Path(out) / 'corrections.json'} (use: --corrections {Path(out) / 'corrections.json'})")


@app.command()
@_options(_CORRUPTION)
def corrupt(
    tracks_: str = typer.Option("5 6", "--tracks", help="Track numbers, e.g. '5 6' or 5,6."),
    runs: int = typer.Option(100, "--runs", help="Monte Carlo runs per track."),
    out: Path = typer.Option(..., "--out", help="Output folder (realizations.parquet, realizations.json)."),
    materialize: bool = typer.Option(False, "--materialize", help="Also write the 100 Hz IMU error streams (large)."),
    **kw,
) -> None:
    """Draw the realizations (initial errors, biases, schedule factors) into DIR/realizations.parquet.

    Takes every corruption option of mc, so it writes exactly the realizations that mc with the
    same options runs. A folder holding different realizations is never overwritten."""
    from nespm_cli.experiments.realizations import write_realizations

    seed, data_dir = kw.pop("seed"), kw.pop("data_dir")
    path, fresh = write_realizations(_tracks(tracks_), runs, seed, _corruption(kw), out, data_dir=data_dir,
                                     materialize=materialize)
    typer.echo(f"wrote {path}" if fresh else f"{path} already holds these realizations; nothing written")


@app.command()
@_options(_COMMON, [_KERNELS])
def run(
    track: int = typer.Option(..., "--track", help="Track number."),
    filt: str = typer.Option("ukf-nespm", "--filter", help="ins, ekf, ukf, ukf-nespm, anekf, anukf, anukf-nespm, ckf, ckf-nespm or iekf (docs/filters.md)."),
    run: int = typer.Option(0, "--run", help="Realization index (same index = same realization as in mc)."),
    clean: bool = typer.Option(False, "--clean", help="No corruption: exact initial state, clean IMU, noise-free synthetic DVL."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object with the run's metrics."),
    out: Optional[str] = typer.Option(None, "--out", help="Write the run's time series (Parquet, or CSV if the name ends in .csv)."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say what is being done (on stderr)."),
    **kw,
) -> None:
    """Run one realization of one filter on one track; print its metrics."""
    from nespm_cli.experiments.single_run import run_single

    from nespm_cli.experiments.progress import Status

    spec = _spec(tracks=(track,), runs=run + 1, filters=(filt.lower(),), **kw)
    t0 = time.perf_counter()
    with Status("nespm run", enabled=not no_progress) as status:
        summary = run_single(spec, track, filt.lower(), run, clean=clean, out=out, status=status)
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    if as_json:
        typer.echo(json.dumps(summary))
    else:
        for k, v in summary.items():
            typer.echo(f"{k:>12}: {v}")


def _run_many(tracks_: str, runs: int, filters_: str, jobs: int, chunk_size: int,
              no_progress: bool, backend: str, scheduler: Optional[str], **kw):
    """Shared body of mc and sweep: build the spec, run, print the summary line."""
    kw.pop("config")  # always None: --config is expanded before parsing (_expand_config); declared for --help
    spec = _spec(tracks=_tracks(tracks_), runs=runs, filters=_filters(filters_), chunk_size=chunk_size, **kw)
    t0 = time.perf_counter()
    return spec, t0, _execution(jobs, backend, scheduler, no_progress)


def _execution(jobs: int, backend: str, scheduler: Optional[str], no_progress: bool):
    """The Execution of the parallel options (where the chunks run; no number depends on it)."""
    from nespm_cli.experiments.backend import Execution

    return Execution(jobs=jobs, backend=backend, scheduler=scheduler, progress=not no_progress,
                     argv=("nespm", *_ARGV))


def _summary(m, t0: float, out: str) -> None:
    div = int(m["diverged"].sum())
    typer.echo(f"{len(m)} rows in {time.perf_counter() - t0:.1f} s, {div} diverged "
               f"-> {out}/metrics.parquet; next: nespm report {out}")


@app.command()
@_options(_RUNNER, _COMMON)
def mc(
    out: str = typer.Option("results/mc", "--out", help="Output folder."),
    **kw,
) -> None:
    """Monte Carlo: every filter on the same realizations; metrics/epochs Parquet, manifest; resumable."""
    from nespm_cli.experiments.mc import run_mc

    spec, t0, ex = _run_many(**kw)
    _summary(run_mc(spec, out, ex), t0, out)


@app.command()
@_options(_RUNNER, _COMMON)
def sweep(
    param: str = typer.Option(..., "--param", help="Parameter to sweep: misalignment-deg, heading-deg, vel-std, acc-bias, gyro-bias, acc-noise, gyro-noise, dvl-noise (with --dvl synthetic), outage-length, alpha."),
    values: str = typer.Option(..., "--values", help="Comma-separated values, e.g. 0.01,0.1,1,10."),
    out: str = typer.Option("results/sweep", "--out", help="Output folder."),
    **kw,
) -> None:
    """Paired Monte Carlo per value of one parameter (same seeds across values and filters); resumable."""
    from nespm_cli.experiments.sweep import parse_values, run_sweep

    spec, t0, ex = _run_many(**kw)
    _summary(run_sweep(spec, param, parse_values(values), out, ex), t0, out)


@app.command()
def report(
    out_dir: Path = typer.Argument(..., help="Folder written by 'nespm mc', 'nespm sweep' or 'nespm gp-ukf'."),
    baseline: Optional[str] = typer.Option(None, "--baseline", help="Filter whose improvement over each other row is shown (the papers' 'Imprv.' column)."),
    n_boot: int = typer.Option(2000, "--n-boot", help="Paired bootstrap resamples for the 95 % intervals."),
    practical: float = typer.Option(PRACTICAL_PCT, "--practical", help="Smallest improvement [%] the summary calls practically meaningful (a difference must also be statistically significant)."),
    beside: Optional[List[Path]] = typer.Option(None, "--beside", help="Another mc folder whose numbers are set beside this one's (e.g. the synthetic-IMU run of a recorded-IMU one); repeatable."),
) -> None:
    """Write DIR/report.md (Tables I/II layout, paired 95 % intervals, published values) and figures."""
    from nespm_cli.reports.dispatch import write_report

    path = write_report(out_dir, baseline, n_boot=n_boot, practical_pct=practical, beside=tuple(beside or ()))
    typer.echo(path.read_text(encoding="utf-8"))
    typer.echo(f"wrote {path}")


@app.command()
def export(
    folder: Path = typer.Argument(..., help="A finished 'nespm mc' or 'nespm sweep' folder."),
    fmt: str = typer.Option("csv", "--format", help="csv (one file per table) or mat (one MATLAB .mat, a struct per table)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Output folder (default FOLDER/export)."),
    series: bool = typer.Option(False, "--series", help="Also the per-run per-epoch errors of the chunk series files (large)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace existing output files."),
) -> None:
    """Export metrics, epochs (and --series) as CSV or a MATLAB .mat file (docs/results-schema.md)."""
    from nespm_cli.reports.export import export_folder

    for p in export_folder(folder, fmt, out, series, overwrite):
        typer.echo(f"wrote {p}")


def _epoch_bar(bar, epochs: int):
    """A ``train_processnet`` progress callback that advances one rich bar per sensor."""
    tasks: dict = {}

    def progress(info: dict) -> None:
        key = info.get("sensor", "?")
        if key not in tasks:
            tasks[key] = bar.add_task(key, total=info.get("epochs") or epochs)
        desc = f"{key} epoch {info.get('epoch', 0)}"
        if "val_loss" in info:
            desc += f" val {info['val_loss']:.4g}"
        bar.update(tasks[key], completed=info.get("epoch", 0), description=desc)
    return progress


_IMU = [o for o in _COMMON if o[0] == "imu"]


@app.command()
@_options(_IMU, _RECORDED)
def train(
    tracks_: str = typer.Option("1 2 3 4", "--tracks", help="Training tracks, e.g. '1 2 3 4'."),
    test_tracks: str = typer.Option("5 6", "--test-tracks", help="Held-out tracks for the Spearman check."),
    out: Path = typer.Option(..., "--out", help="Weights file (.npz); a loss-curve PNG is written beside it."),
    runs: int = typer.Option(24, "--runs", help="Dynamic-schedule realizations per training track."),
    epochs: int = typer.Option(12, "--epochs", help="Maximum epochs (early stopping on the validation loss)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the realizations, the split and the initial weights."),
    data_dir: Optional[str] = DATA_DIR,
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
    **kw,
) -> None:
    """Train the accelerometer and gyro ProcessNets (anukf.md eqs 34-42) on dynamic-schedule windows."""
    from nespm_cli.learn.training import train_processnet

    train_t, test_t = _tracks(tracks_), _tracks(test_tracks)
    if not str(out).endswith(".npz"):
        raise NespmError(f"--out {out}: the weights file name must end in .npz")
    if runs < 1 or epochs < 1:
        raise NespmError("--runs and --epochs must be at least 1")
    from nespm_cli.data.tracks import available_tracks, resolve_data_dir

    d = resolve_data_dir(data_dir)
    have = available_tracks(d)
    for n in train_t + test_t:
        if n not in have:
            raise NespmError(f"--tracks: no track {n} in {d if d else 'the embedded default'}; available: "
                             f"{', '.join(map(str, have))}")
    from nespm_cli.data.corrections import resolve

    imu = kw["imu"]
    if imu not in ("synthetic", "recorded"):
        raise NespmError(f"--imu: choose synthetic or recorded, got {imu!r}")
    corr = resolve(train_t + test_t, imu, kw["corrections"], kw["imu_axes"], kw["imu_time_offset"],
                   kw["dvl_time_offset"], kw["window"], kw["imu_time_drift"])
    bar = None
    if not no_progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(TextColumn("[bold]train[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn())
        bar.start()
    progress = _epoch_bar(bar, epochs) if bar is not None else None
    try:
        s = train_processnet(train_t, test_t, data_dir, out, runs=runs, epochs=epochs, seed=seed, progress=progress,
                             imu=imu, corrections=corr)
    finally:
        if bar is not None:
            bar.stop()
    typer.echo(f"Spearman (predicted vs injected noise std, tracks {' '.join(map(str, test_t))}): "
               f"acc {s['spearman']['acc']:.3f}, gyro {s['spearman']['gyro']:.3f}")
    from nespm_cli.reports.training import plot_history

    plot = plot_history(s["history"], Path(s["path"]).with_suffix(".png"), s["test"])
    typer.echo(f"trained in {s['seconds']:.1f} s -> {s['path']} (loss curves {plot})")


@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", help="Data folder to write (A-KIT layout, usable as --data-dir)."),
    runs: int = typer.Option(1, "--runs", help="Simulated runs; run i becomes track first-number + i."),
    duration: float = typer.Option(800.0, "--duration", help="Seconds per run (the paper's helix: 800)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the sensor noise (run r: SeedSequence(seed, spawn_key=(r, 0)))."),
    first_number: int = typer.Option(1, "--first-number", help="Track number of the first run."),
    dvl: str = typer.Option("measured", "--dvl", help="DVL file: measured (the simulated sensor) or true."),
) -> None:
    """Simulate REMUS 100 helix runs (gp-ukf.md section 6: 6-DOF model, LOS guidance, PIDs on
    noisy, 12-bit sensors) and write them as tracks: 1 Hz GT and DVL, 100 Hz IMU."""
    from nespm_cli.vehicles import simulate_runs, write_tracks

    if runs < 1 or first_number < 1:
        raise NespmError("--runs and --first-number must be at least 1")
    if not (duration >= 2.0 and duration <= 36000):
        raise NespmError(f"--duration must be between 2 and 36000 s, got {duration:g}")
    if dvl not in ("measured", "true"):
        raise NespmError(f"--dvl: choose measured or true, got {dvl!r}")
    if out.exists() and not out.is_dir():
        raise NespmError(f"--out {out}: exists and is not a folder")
    t0 = time.perf_counter()
    res = simulate_runs(runs, duration_s=duration, seed=seed)
    paths = write_tracks(res, out, first_number=first_number, dvl=dvl)
    settle = min(100.0, duration / 2)
    xt = np.abs(res.cross_track[:, res.t >= settle])
    typer.echo(f"{len(paths)} tracks ({first_number}-{first_number + len(paths) - 1}) in {time.perf_counter() - t0:.1f} s "
               f"-> {out}; max cross-track error after {settle:g} s {xt.max():.2f} m; next: nespm tracks --data-dir {out}")


@app.command("gp-ukf")
@_options(_PARALLEL)
def gp_ukf_cmd(
    out: str = typer.Option("results/gp-ukf", "--out", help="Output folder."),
    runs: int = typer.Option(default(GPSpec, "runs"), "--runs", help="Helix runs; run 0 trains the GPs and is evaluated too (as the paper)."),
    duration: float = typer.Option(default(GPSpec, "duration_s"), "--duration", help="Seconds per run (a multiple of 0.2 s, >= 10)."),
    seed: int = typer.Option(default(GPSpec, "seed"), "--seed", help="Master seed: run r's sensor noise SeedSequence(seed, spawn_key=(r, 0)), its initial estimate (r, 1)."),
    max_points: int = typer.Option(default(GPSpec, "max_points"), "--max-points", help="Training points per GP model (from the 40 % sample of the training run)."),
    restarts: int = typer.Option(default(GPSpec, "n_restarts"), "--restarts", help="Extra random optimizer starts per GP output."),
    h_inputs: str = typer.Option(default(GPSpec, "h_inputs"), "--h-inputs", help="GP-h inputs: own (each measurement from the state it measures) or state (all 12 states, the paper's)."),
    fraction: float = typer.Option(default(GPSpec, "fraction"), "--fraction", help="Random fraction of the training run's samples (paper: 0.4)."),
    train_run: int = typer.Option(default(GPSpec, "train_run"), "--train-run", help="Run the GPs are trained on."),
    rk4_substeps: int = typer.Option(default(GPSpec, "rk4_substeps"), "--rk4-substeps", help="RK4 steps of the ideal UKF's model per 0.2 s sample."),
    chunk_size: int = typer.Option(default(GPSpec, "chunk_size"), "--chunk-size", help="Runs per batch, the resumable unit."),
    **kw,
) -> None:
    """GP-UKF vs ideal UKF on simulated REMUS 100 helix runs (gp-ukf.md section 6, Tables 3-4); resumable."""
    from nespm_cli.experiments.gp_ukf import run_gp_experiment

    t0 = time.perf_counter()
    ex = _execution(kw["jobs"], kw["backend"], kw["scheduler"], kw["no_progress"])
    m = run_gp_experiment(out, runs=runs, seed=seed, duration_s=duration, max_points=max_points,
                          n_restarts=restarts, chunk_size=chunk_size, execution=ex, h_inputs=h_inputs,
                          fraction=fraction, train_run=train_run, rk4_substeps=rk4_substeps)
    div = int(m.drop_duplicates(["filter", "run"])["diverged"].sum())
    typer.echo(f"{len(m)} rows in {time.perf_counter() - t0:.1f} s, {div} diverged "
               f"-> {out}/metrics.parquet; next: nespm report {out}")


_REPEATED = ("--filter-plugin", "--sensor-plugin", "--sensor-option")  # options given once per value


def _config_paths(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(config files, argv without them)``: every ``--config FILE`` and ``--config=FILE``, in order."""
    paths, rest, i = [], [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--config":
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                raise NespmError("--config needs a file")
            paths.append(argv[i + 1])
            i += 2
            continue
        if a.startswith("--config="):
            if not a[len("--config="):]:
                raise NespmError("--config needs a file")
            paths.append(a[len("--config="):])
            i += 1
            continue
        rest.append(a)
        i += 1
    return paths, rest


def _config_options(path: Path) -> list[str]:
    """The options of one TOML config file, as command-line words (one-line errors naming the file)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        text = path.read_bytes().decode("utf-8")
        cfg = tomllib.loads(text)
    except OSError as exc:
        raise NespmError(f"--config {path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise NespmError(f"--config {path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset "
                         f"{exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise NespmError(f"--config {path}: not valid TOML ({str(exc).splitlines()[0]})") from None
    except RecursionError:
        raise NespmError(f"--config {path}: nested too deeply") from None
    opts: list[str] = []
    for key, val in cfg.items():
        flag = "--" + key.replace("_", "-")
        if key == "sensors" and isinstance(val, dict):
            opts += _sensor_tables(path, val)
            continue
        if isinstance(val, dict):
            raise NespmError(f"--config {path}: [{key}] is a table; options are top-level keys (runs = 100)")
        if isinstance(val, bool):
            opts += [flag] if val else []
        elif isinstance(val, list) and flag in _REPEATED:
            opts += [x for v in val for x in (flag, str(v))]
        elif isinstance(val, list):
            opts += [flag] + [str(v) for v in val]
        else:
            opts += [flag, str(val)]
    return opts


def _sensor_tables(path: Path, tables: dict) -> list[str]:
    """``[sensors.NAME]`` tables (in file order) as ``--sensors`` and ``--sensor-option`` words."""
    words = ["--sensors", ",".join(tables)]
    for name, table in tables.items():
        if not isinstance(table, dict):
            raise NespmError(f"--config {path}: sensors.{name} must be a table of options ([sensors.{name}])")
        for k, v in table.items():
            if isinstance(v, dict):
                raise NespmError(f"--config {path}: sensors.{name}.{k} is a table; give option values")
            text = ",".join(str(x) for x in v) if isinstance(v, list) else str(v).lower() if isinstance(v, bool) else str(v)
            words += ["--sensor-option", f"{name}.{k}={text}"]
    return words


def _expand_config(argv: list[str]) -> list[str]:
    """Replace every ``--config FILE`` (or ``--config=FILE``) by the options in the TOML file,
    in the order given, placed before the rest of the command line: a later file overrides an
    earlier one, and explicit options override both."""
    paths, rest = _config_paths(argv)
    if not paths:
        return argv
    opts = [w for p in paths for w in _config_options(Path(p))]
    cmd = 1 if rest and not rest[0].startswith("-") else 0
    return rest[:cmd] + opts + rest[cmd:]


def _normalize_argv(argv: list[str]) -> list[str]:
    """Let ``--tracks 5 6`` mean ``--tracks '5 6'`` (click options take one value)."""
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a in ("--tracks", "--test-tracks"):
            vals = []
            i += 1
            while i < len(argv) and (not argv[i].startswith("-") or re.fullmatch(r"-\d+", argv[i])):
                vals.append(argv[i])
                i += 1
            out += [a, " ".join(vals)]
            continue
        out.append(a)
        i += 1
    return out


_INTERRUPTED = "nespm: interrupted; finished chunks are kept, re-run the same command to resume"
_ARGV: list[str] = []  # the command line main() received, for the manifest


MAX_MESSAGE = 400  # characters of an error line


def one_line(text: str) -> str:
    """``text`` as one printable line (:func:`nespm_cli.data.plausibility.printable`: a newline in a
    path becomes a space), at most :data:`MAX_MESSAGE` characters, cut in the middle so that both
    the start and the reason at the end survive a long path."""
    from nespm_cli.data.plausibility import printable

    return printable(str(text), MAX_MESSAGE, cut="middle")


def os_error_line(exc: OSError) -> str:
    """``PATH: what failed`` of an OSError (permission denied, not a directory, read-only ...)."""
    path = exc.filename if exc.filename is not None else ""
    what = exc.strerror or exc.__class__.__name__
    if exc.filename2 is not None:
        path = f"{path} -> {exc.filename2}"
    return one_line(f"{path}: {what}" if path else f"{what} ({exc})")


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings print as one line ``nespm: warning: ...`` (NumPy's RuntimeWarnings not at all:
    the checks that matter raise their own one-line errors)."""
    if issubclass(category, RuntimeWarning):
        return
    typer.echo(f"nespm: warning: {one_line(str(message))}", err=True)


def main(argv: list[str] | None = None) -> int:
    global _ARGV
    import warnings

    warnings.showwarning = _show_warning
    for stream in (sys.stdout, sys.stderr):  # an ASCII locale (LC_ALL=C) prints '?' for ±, σ, ², never fails
        if hasattr(stream, "reconfigure") and (stream.encoding or "").lower().replace("-", "") != "utf8":
            stream.reconfigure(errors="replace")
    try:
        argv = list(sys.argv[1:] if argv is None else [str(a) for a in argv])
        _ARGV = list(argv)
        if not argv:
            argv = ["--help"]
        argv = _normalize_argv(_expand_config(argv))
        rv = typer.main.get_command(app).main(args=argv, prog_name="nespm", standalone_mode=False)
        if rv == 130:  # typer turns Ctrl-C into a returned exit code 130
            typer.echo(_INTERRUPTED, err=True)
        return rv if isinstance(rv, int) else 0
    except NespmError as exc:
        typer.echo(f"nespm: error: {one_line(str(exc))}", err=True)
        return exc.exit_code
    except OSError as exc:  # the file system said no: name the path and what failed
        typer.echo(f"nespm: error: {os_error_line(exc)}", err=True)
        return 2
    except Exit as exc:
        return exc.exit_code
    except Abort:
        typer.echo("nespm: aborted", err=True)
        return 130
    except TyperException as exc:
        msg = exc.format_message().splitlines()
        typer.echo(f"nespm: error: {msg[0] if msg else exc}", err=True)
        return 2
    except KeyboardInterrupt:
        typer.echo(_INTERRUPTED, err=True)
        return 130


if __name__ == "__main__":
    sys.exit(main())
