"""The data commands: ``nespm check`` (against the GT), ``corrupt`` (draw the realizations),
``simulate`` (REMUS 100 runs written as tracks); ``nespm tracks`` lives in :mod:`nespm_cli.cli.tracks_command`
(it must not import the option tables)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from nespm_cli.cli.options import ACCEPT_RESIDUAL, CORRUPTION, DATA_DIR, with_options
from nespm_cli.cli.parsing import corruption_config, parse_tracks, warning_mode
from nespm_cli.errors import NespmError


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

    warning_mode(data_warnings)
    numbers = parse_tracks(tracks_) if tracks_ else None
    with Status("nespm check", enabled=not no_progress) as status:
        result = check_folder(data_dir, numbers, status=status)
        status("writing the report")
        path = write_check_report(result, out, figures=not no_figures)
    typer.echo(summary_table(result))
    for r in result["tracks"]:
        for f in r["findings"]:
            typer.echo(f"track {r['track']}: {f}")
    typer.echo(f"wrote {path} and {Path(out) / 'corrections.json'} (use: --corrections {Path(out) / 'corrections.json'})")


@with_options(CORRUPTION, [ACCEPT_RESIDUAL])
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

    seed, data_dir, accept = kw.pop("seed"), kw.pop("data_dir"), kw.pop("accept_residual")
    path, fresh = write_realizations(parse_tracks(tracks_), runs, seed, corruption_config(kw), out, data_dir=data_dir,
                                     materialize=materialize, accept_residual=True if accept else None)
    typer.echo(f"wrote {path}" if fresh else f"{path} already holds these realizations; nothing written")


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
