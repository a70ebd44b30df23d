"""The experiment commands: ``nespm run`` (one realization), ``mc`` and ``sweep`` (many, resumable),
``gp-ukf`` (the GP-UKF experiment, resumable)."""
from __future__ import annotations

import json
import time
from typing import Optional

import typer

from nespm_cli.cli.options import COMMON, KERNELS, PARALLEL, RUNNER, default, with_options
from nespm_cli.cli.parsing import build_spec, execution, parse_filters, parse_tracks
from nespm_cli.experiments.gp_ukf.spec import GPSpec
from nespm_cli.filters import FILTERS


@with_options(COMMON, [KERNELS])
def run(
    track: int = typer.Option(..., "--track", help="Track number."),
    filt: str = typer.Option("ukf-nespm", "--filter", help=f"{', '.join(FILTERS[:-1])} or {FILTERS[-1]} (docs/filters.md), or a plugin's."),
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

    spec = build_spec(tracks=(track,), runs=run + 1, filters=(filt.lower(),), **kw)
    t0 = time.perf_counter()
    with Status("nespm run", enabled=not no_progress) as status:
        summary = run_single(spec, track, filt.lower(), run, clean=clean, out=out, status=status)
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    if as_json:
        typer.echo(json.dumps(summary))
    else:
        for k, v in summary.items():
            typer.echo(f"{k:>12}: {v}")


def _run_many(tracks_: str, runs: int, filters_: str, jobs: int, chunk_size: Optional[int],
              no_progress: bool, backend: str, scheduler: Optional[str], **kw):
    """Shared body of mc and sweep: build the spec, run, print the summary line."""
    kw.pop("config")  # always None: --config is expanded before parsing (config.expand_config); declared for --help
    spec = build_spec(tracks=parse_tracks(tracks_), runs=runs, filters=parse_filters(filters_), chunk_size=chunk_size, **kw)
    t0 = time.perf_counter()
    return spec, t0, execution(jobs, backend, scheduler, no_progress)


def _summary(m, t0: float, out: str) -> None:
    div = int(m["diverged"].sum())
    typer.echo(f"{len(m)} rows in {time.perf_counter() - t0:.1f} s, {div} diverged "
               f"-> {out}/metrics.parquet; next: nespm report {out}")


@with_options(RUNNER, COMMON)
def mc(
    out: str = typer.Option("results/mc", "--out", help="Output folder."),
    **kw,
) -> None:
    """Monte Carlo: every filter on the same realizations; metrics/epochs Parquet, manifest; resumable."""
    from nespm_cli.experiments.mc import run_mc

    spec, t0, ex = _run_many(**kw)
    _summary(run_mc(spec, out, ex), t0, out)


@with_options(RUNNER, COMMON)
def sweep(
    param: str = typer.Option(..., "--param", help="Parameter to sweep: misalignment-deg, heading-deg, vel-std, acc-bias, gyro-bias, acc-noise, gyro-noise, dvl-noise (with --dvl synthetic), outage-length, alpha; a sensor's: fix-interval, fix-std, depth-std, heading-std, beam-loss-length, or any numeric sensor option SENSOR.KEY (e.g. fix.vertical_std; the sensor in --sensors)."),
    values: str = typer.Option(..., "--values", help="Comma-separated values, e.g. 0.01,0.1,1,10."),
    out: str = typer.Option("results/sweep", "--out", help="Output folder."),
    **kw,
) -> None:
    """Paired Monte Carlo per value of one parameter (same seeds across values and filters); resumable."""
    from nespm_cli.experiments.sweep import parse_values, run_sweep

    spec, t0, ex = _run_many(**kw)
    _summary(run_sweep(spec, param, parse_values(values), out, ex), t0, out)


@with_options(PARALLEL)
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
    ex = execution(kw["jobs"], kw["backend"], kw["scheduler"], kw["no_progress"])
    m = run_gp_experiment(out, runs=runs, seed=seed, duration_s=duration, max_points=max_points,
                          n_restarts=restarts, chunk_size=chunk_size, execution=ex, h_inputs=h_inputs,
                          fraction=fraction, train_run=train_run, rk4_substeps=rk4_substeps)
    div = int(m.drop_duplicates(["filter", "run"])["diverged"].sum())
    typer.echo(f"{len(m)} rows in {time.perf_counter() - t0:.1f} s, {div} diverged "
               f"-> {out}/metrics.parquet; next: nespm report {out}")
