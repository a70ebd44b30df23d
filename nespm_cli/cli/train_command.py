"""``nespm train``: the ProcessNets of the adaptive filters, with a progress bar per sensor."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from nespm_cli.cli.options import ACCEPT_RESIDUAL, DATA_DIR, IMU, RECORDED, with_options
from nespm_cli.cli.parsing import parse_tracks
from nespm_cli.errors import NespmError


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


@with_options(IMU, RECORDED, [ACCEPT_RESIDUAL])
def train(
    tracks_: str = typer.Option("1 2 3 4", "--tracks", help="Training tracks, e.g. '1 2 3 4'."),
    test_tracks: str = typer.Option("5 6", "--test-tracks", help="Held-out tracks for the Spearman check."),
    out: Path = typer.Option(..., "--out", help="Weights file (.npz); a loss-curve PNG is written beside it."),
    runs: int = typer.Option(24, "--runs", help="Dynamic-schedule realizations per training track."),
    epochs: int = typer.Option(12, "--epochs", help="Maximum epochs (early stopping on the validation loss)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the realizations, the split and the initial weights."),
    data_dir: Optional[str] = DATA_DIR,
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
    export: Optional[str] = typer.Option(None, "--export", help="onnx: also write the trained ProcessNet as ONNX beside --out (<out>.onnx; pip install 'nespm[onnx]'; docs/learned.md)."),
    **kw,
) -> None:
    """Train the accelerometer and gyro ProcessNets (anukf.md eqs 34-42) on dynamic-schedule windows."""
    from nespm_cli.learn.training import train_processnet

    train_t, test_t = parse_tracks(tracks_), parse_tracks(test_tracks)
    if not str(out).endswith(".npz"):
        raise NespmError(f"--out {out}: the weights file name must end in .npz")
    if export is not None:
        if export != "onnx":
            raise NespmError(f"--export: choose onnx, got {export!r}")
        from nespm_cli.learn.onnx_model import require_extra

        require_extra("onnx", "--export onnx")  # before the training, not after
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
                             imu=imu, corrections=corr, accept_residual=True if kw["accept_residual"] else None)
    finally:
        if bar is not None:
            bar.stop()
    typer.echo(f"Spearman (predicted vs injected noise std, tracks {' '.join(map(str, test_t))}): "
               f"acc {s['spearman']['acc']:.3f}, gyro {s['spearman']['gyro']:.3f}")
    from nespm_cli.reports.training import plot_history

    plot = plot_history(s["history"], Path(s["path"]).with_suffix(".png"), s["test"])
    typer.echo(f"trained in {s['seconds']:.1f} s -> {s['path']} (loss curves {plot})")
    if export == "onnx":
        from nespm_cli.learn.noise_models import export_processnet

        typer.echo(f"ONNX -> {export_processnet(s['path'], Path(s['path']).with_suffix('.onnx'))}")
