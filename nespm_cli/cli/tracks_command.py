"""``nespm tracks``: list the tracks (duration, distance, speed, depth, DVL residual, lever arm).

Its own module, importing only light ones (typer, :mod:`nespm_cli.cli.data_options`,
:mod:`nespm_cli.cli.parsing`) before it runs: not the option tables of :mod:`nespm_cli.cli.options`,
whose defaults pull the experiment spec, the filter engine and the sensors (tests/test_startup.py)."""
from __future__ import annotations

import sys
from typing import Optional

import typer

from nespm_cli.cli.data_options import ACCEPT_RESIDUAL_FLAG, ACCEPT_RESIDUAL_HELP, DATA_DIR
from nespm_cli.cli.parsing import warning_mode


def tracks(data_dir: Optional[str] = DATA_DIR,
           no_progress: bool = typer.Option(False, "--no-progress", help="Do not say which track is being read."),
           data_warnings: str = typer.Option("warn", "--data-warnings", help="warn, ignore or error on data that looks wrong but may be legitimate."),
           accept_residual: bool = typer.Option(False, ACCEPT_RESIDUAL_FLAG, help=ACCEPT_RESIDUAL_HELP)) -> None:
    """List the tracks: duration, distance, speed, yaw rate, depth, DVL residual and lever arm."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from nespm_cli.data.tracks import available_tracks, load_track, resolve_data_dir, track_summary
    from nespm_cli.experiments.progress import Status

    warning_mode(data_warnings)
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
            s = track_summary(load_track(n, d, accept_residual=True if accept_residual else None))
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
