"""``nespm import BAG --spec SPEC --out DIR``: a ROS 1 / ROS 2 bag as an A-KIT track folder
(:mod:`nespm_cli.data.rosbag.importer`, docs/rosbags.md); ``nespm import BAG --list``: its topics."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

import typer

from nespm_cli.experiments.progress import Status


def import_cmd(
    bag: Path = typer.Argument(..., metavar="BAG",
                               help="A ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml; sqlite3 or mcap)."),
    spec: Optional[Path] = typer.Option(None, "--spec", help="TOML import spec: topics -> GT, IMU, DVL, depth, fix; "
                                        "frames; origin; track number (docs/rosbags.md). Required unless --list."),
    out: Optional[Path] = typer.Option(None, "--out", help="Data folder to write TrajectoryN into (usable as "
                                       "--data-dir). Required unless --list."),
    track: Optional[int] = typer.Option(None, "--track", help="Track number N to write (default: the spec's track)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing TrajectoryN folder of that number."),
    list_: bool = typer.Option(False, "--list", help="List the bag's topics (type, messages, rate, frame_id of the "
                               "first message) and write nothing."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say what is being done (a status on a terminal; nothing off one)."),
) -> None:
    """Import a ROS bag (rosbags, no ROS install) as a track: GT from Odometry (or pose + twist), IMU,
    DVL, depth (FluidPressure or a depth field) and fixes (NavSatFix), converted to NED / body FRD, with
    the spec and IMPORT.md beside the files; the bag is only read. --list shows what the bag holds."""
    from nespm_cli.errors import NespmError

    if list_:
        if spec is not None or out is not None or track is not None or overwrite:
            raise NespmError("--list writes nothing: give the bag alone (without --spec, --out, --track, --overwrite)")
        from nespm_cli.data.rosbag.inspect_bag import list_bag, list_text
        from nespm_cli.data.rosbag.messages import bag_kind, open_bag

        path, kind = bag_kind(bag.expanduser())
        reader = open_bag(path, None, {})
        try:
            rows = list_bag(reader)
        finally:
            reader.close()
        typer.echo(list_text(path, kind, rows))
        return
    for name, value in (("--spec", spec), ("--out", out)):
        if value is None:
            raise NespmError(f"{name} is required (or --list to see the bag's topics)")
    with Status("nespm import", enabled=not no_progress, plain=False) as status:
        status(f"reading {bag.name} and converting its messages (spec {spec.name})")
        from nespm_cli.data.plausibility import DataWarning
        from nespm_cli.data.rosbag.importer import NOTE_MD, import_bag

        result = import_bag(bag, spec, out, track=track, overwrite=overwrite)
    for text in result.warnings:
        warnings.warn(text, DataWarning, stacklevel=1)
    gt, *rest = result.record["channels"]
    span = gt["span_s"]
    rows = ", ".join(f"{c['channel']} {c['written']}" for c in rest)
    typer.echo(f"track {result.record['track']} from {bag}: {gt['written']} GT epochs ({span[0]:.10g}-{span[1]:.10g} "
               f"s), {rows} -> {result.track_dir} ({NOTE_MD}); next: nespm tracks --data-dir {out}")
