"""``nespm import BAG --spec SPEC --out DIR``: a ROS 1 / ROS 2 bag as an A-KIT track folder
(:mod:`nespm_cli.data.rosbag_import`, docs/rosbags.md)."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

import typer

from nespm_cli.experiments.progress import Status


def import_cmd(
    bag: Path = typer.Argument(..., metavar="BAG",
                               help="A ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml; sqlite3 or mcap)."),
    spec: Path = typer.Option(..., "--spec", help="TOML import spec: topics -> GT, IMU, DVL, depth, fix; frames; "
                              "origin; track number (docs/rosbags.md)."),
    out: Path = typer.Option(..., "--out", help="Data folder to write TrajectoryN into (usable as --data-dir)."),
    track: Optional[int] = typer.Option(None, "--track", help="Track number N to write (default: the spec's track)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing TrajectoryN folder of that number."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say what is being done (a status on a terminal; nothing off one)."),
) -> None:
    """Import a ROS bag (rosbags, no ROS install) as a track: GT from Odometry (or pose + twist), IMU,
    DVL, depth (FluidPressure or a depth field) and fixes (NavSatFix), converted to NED / body FRD, with
    the spec and IMPORT.md beside the files; the bag is only read."""
    with Status("nespm import", enabled=not no_progress, plain=False) as status:
        status(f"reading {bag.name} and converting its messages (spec {spec.name})")
        from nespm_cli.data.plausibility import DataWarning
        from nespm_cli.data.rosbag_import import NOTE_MD, import_bag

        result = import_bag(bag, spec, out, track=track, overwrite=overwrite)
    for text in result.warnings:
        warnings.warn(text, DataWarning, stacklevel=1)
    gt, *rest = result.record["channels"]
    span = gt["span_s"]
    rows = ", ".join(f"{c['channel']} {c['written']}" for c in rest)
    typer.echo(f"track {result.record['track']} from {bag}: {gt['written']} GT epochs ({span[0]:.10g}-{span[1]:.10g} "
               f"s), {rows} -> {result.track_dir} ({NOTE_MD}); next: nespm tracks --data-dir {out}")
