"""Reading a results folder (``docs/results-schema.md``): ``manifest.json``, ``metrics.parquet``,
``epochs.parquet``; column checks; facts of the results (filters, RTS-smoother floors, scenario,
runs per track, the sensors' measurement sizes)."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.filters.smoother import smoothed_of


METRICS_COLUMNS: tuple[str, ...] = (
    "track", "filter", "run", "sse_vel", "sse_att", "n_samples", "nees", "diverged",
)


EPOCHS_COLUMNS: tuple[str, ...] = (
    "track", "filter", "t", "vel_err_mean", "vel_err_std", "att_err_mean", "att_err_std",
    "north_err_mean", "east_err_mean", "north_true", "east_true", "dvl_used",
)


#: metrics.parquet columns of the horizontal position error (absent in folders written before them).
HPE_COLUMNS: tuple[str, ...] = ("sse_hpe", "hpe_final", "hpe_rms", "hpe_final_pct", "distance")


def read_results_folder(out_dir: Path, command: str = "mc",
                        experiment: str | None = None) -> tuple[pd.DataFrame, dict]:
    """Read ``manifest.json`` (optional) and ``metrics.parquet`` (required, unvalidated) of a
    results folder written by ``nespm <command>``; one-line :class:`NespmError` otherwise.

    With ``experiment``, the manifest must exist and name it (checked before the metrics).
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise NespmError(f"results folder not found: {out_dir}")
    manifest_path = out_dir / "manifest.json"
    manifest: dict = read_manifest_file(manifest_path) if manifest_path.is_file() else {}
    if experiment is not None and manifest.get("experiment") != experiment:
        raise NespmError(f"{manifest_path}: not a {experiment.upper()} experiment folder "
                         f"(experiment = {manifest.get('experiment')!r}); run `nespm {command} --out {out_dir}`")
    metrics_path = out_dir / "metrics.parquet"
    if not metrics_path.is_file():
        raise NespmError(f"{metrics_path} not found: run `nespm {command} ... --out {out_dir}` first")
    return read_parquet(metrics_path), manifest


def read_manifest_file(path: Path) -> dict:
    """``manifest.json`` at ``path`` as a dict whose ``options`` is an object (one-line NespmError for a
    missing or unreadable file, text that is not JSON, or JSON that is not such an object)."""
    path = Path(path)
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise NespmError(f"{path}: not found (not a results folder of nespm)") from None
    except (OSError, ValueError, RecursionError) as exc:
        raise NespmError(f"{path}: not valid JSON ({one_line(exc)})") from None
    if not isinstance(manifest, dict):
        raise NespmError(f"{path}: expected a JSON object (a nespm manifest), got {type(manifest).__name__}")
    if not isinstance(manifest.get("options", {}), dict):
        raise NespmError(f"{path}: 'options' is not an object (not a nespm manifest)")
    return manifest


def check_figures_dir(out_dir: Path) -> Path:
    """``out_dir/figures``, where a report draws: refused in one line when it is a symbolic link (figures
    are never written through a link into another folder) or not a folder."""
    fig = Path(out_dir) / "figures"
    if fig.is_symlink():
        raise NespmError(f"{fig}: is a symbolic link (to {os.path.realpath(fig)}); the report does not write its "
                         "figures through it: remove the link, or report into a copy of the folder")
    if fig.exists() and not fig.is_dir():
        raise NespmError(f"{fig}: exists and is not a folder; remove it to let the report draw its figures")
    return fig


def check_n_boot(n_boot: int) -> int:
    """``--n-boot``: a number of bootstrap resamples, at least 1 (0 would give no interval, silently)."""
    if isinstance(n_boot, bool) or not isinstance(n_boot, (int,)) or n_boot < 1:
        raise NespmError(f"--n-boot must be a number of bootstrap resamples, at least 1 (2000 by default), got {n_boot}")
    return n_boot


def check_complete(metrics: pd.DataFrame, manifest: dict, where: object) -> None:
    """One line unless ``metrics`` holds every run the manifest's options ask for: ``runs`` runs
    (0 .. runs-1) of every track of ``tracks`` for every filter of ``filters`` (and ``smooth``'s
    ``<filter>-rts``), per swept value in a sweep. A folder whose manifest does not say is not checked."""
    from nespm_cli.filters.smoother import smoothed_name

    opts = manifest.get("options") or {}
    runs, tracks, filters = opts.get("runs"), opts.get("tracks"), opts.get("filters")
    if not isinstance(runs, int) or isinstance(runs, bool) or not {"track", "filter", "run"} <= set(metrics.columns):
        return
    keys = [k for k in ("param", "value") if k in metrics.columns] + ["track", "filter"]
    per = metrics.groupby(keys, sort=False)["run"].agg(["nunique", "min", "max"])
    short = per[(per["nunique"] != runs) | (per["min"] != 0) | (per["max"] != runs - 1)]
    if len(short):
        key, row = short.index[0], short.iloc[0]
        raise NespmError(f"{where}: holds {int(row['nunique'])} runs of {key} where its manifest asks for {runs} "
                         "(an incomplete or replaced table); re-run the same command to assemble it again")
    if isinstance(tracks, list):
        gone = [t for t in tracks if t not in set(metrics["track"].tolist())]
        if gone:
            raise NespmError(f"{where}: holds no row of track {gone[0]} of its manifest's tracks; re-run the same "
                             "command to assemble it again")
    if isinstance(filters, list):
        want = list(filters) + [smoothed_name(f) for f in (opts.get("smooth") or []) if isinstance(f, str)]
        gone = [f for f in want if f not in set(metrics["filter"].astype(str))]
        if gone:
            raise NespmError(f"{where}: holds no row of filter {gone[0]} of its manifest's filters; re-run the same "
                             "command to assemble it again")


def load_results(out_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame | None, dict]:
    """Read ``metrics.parquet`` (required), ``epochs.parquet`` and ``manifest.json``.

    Returns ``(metrics, epochs or None, manifest or {})``. Raises :class:`NespmError`
    for a missing folder, a missing/unreadable metrics file or missing columns.
    """
    out_dir = Path(out_dir)
    metrics, manifest = read_results_folder(out_dir, "mc")
    check_metrics(metrics, out_dir / "metrics.parquet")
    epochs_path = out_dir / "epochs.parquet"
    epochs = read_parquet(epochs_path) if epochs_path.is_file() else None
    if epochs is not None:
        require_columns(epochs, EPOCHS_COLUMNS, epochs_path)
    return metrics, epochs, manifest


def read_parquet(path: Path) -> pd.DataFrame:
    """Read one Parquet file, turning reader errors into a one-line NespmError."""
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises many types for a damaged file
        raise NespmError(f"{path}: cannot read Parquet ({one_line(exc)})") from exc


def one_line(exc: BaseException) -> str:
    """First line of an exception message."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def require_columns(df: pd.DataFrame, columns: Iterable[str], where: object) -> None:
    """Raise NespmError naming the columns of ``columns`` that ``df`` lacks."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise NespmError(f"{where}: missing column(s) {', '.join(missing)}")


def check_metrics(metrics: pd.DataFrame, where: object = "metrics") -> None:
    """Validate the columns, non-emptiness and (track, filter, run) uniqueness."""
    require_columns(metrics, METRICS_COLUMNS, where)
    if metrics.empty:
        raise NespmError(f"{where}: no rows")
    dup = metrics.duplicated(["track", "filter", "run"])
    if dup.any():
        row = metrics.loc[dup].iloc[0]
        raise NespmError(
            f"{where}: duplicate row for track {row['track']}, filter {row['filter']}, run {row['run']}"
        )


def filters_in_order(metrics: pd.DataFrame) -> list[str]:
    """Filter names in their order of first appearance."""
    return [str(f) for f in pd.unique(metrics["filter"])]


def has_hpe(metrics: pd.DataFrame) -> bool:
    """Whether ``metrics`` holds the horizontal-position columns (:data:`HPE_COLUMNS`)."""
    return all(c in metrics.columns for c in HPE_COLUMNS)


def unique_text(values: Iterable[Any]) -> str:
    """Distinct values joined by commas, in order of appearance."""
    return ", ".join(str(v) for v in pd.unique(pd.Series(list(values))))


def runs_per_track(metrics: pd.DataFrame) -> str:
    """Distinct run indices per track: one number, or ``min–max`` when tracks differ."""
    n = metrics.groupby("track")["run"].nunique()
    return str(int(n.min())) if n.min() == n.max() else f"{int(n.min())}–{int(n.max())}"


def scenario_of(metrics: pd.DataFrame, manifest: dict) -> str | None:
    """The single scenario of the results (metrics column, else manifest option), or None."""
    if "scenario" in metrics.columns:
        vals = pd.unique(metrics["scenario"].dropna())
        return str(vals[0]) if len(vals) == 1 else None
    return (manifest.get("options") or {}).get("scenario")


def is_smoother(name: Any) -> bool:
    """Whether ``name`` is an RTS-smoother floor (``<filter>-rts``, :mod:`nespm_cli.filters.smoother`):
    a hindsight solution, shown beside the filters but never the best of a verdict or the reference."""
    return smoothed_of(str(name)) is not None


def smoother_label(name: str) -> str:
    """A table's name cell: ``ekf-rts (RTS smoother floor)`` for a smoother floor, else ``name``."""
    return f"{name} (RTS smoother floor)" if is_smoother(name) else name


def checked_filter(metrics: pd.DataFrame, name: str, role: str = "reference") -> str:
    """``name`` (``--baseline``) if it is a causal filter of ``metrics``; one line otherwise (an unknown
    filter, or an RTS-smoother floor: hindsight is no ``role`` for a causal filter)."""
    names = filters_in_order(metrics)
    if name not in names:
        raise NespmError(f"--baseline: unknown filter '{name}': the results hold {', '.join(names)}")
    if is_smoother(name):
        causal = [n for n in names if not is_smoother(n)]
        raise NespmError(f"--baseline: '{name}' is an RTS-smoother floor (hindsight), not a {role}; "
                         f"choose one of {', '.join(causal)}")
    return name


def causal_only(metrics: pd.DataFrame) -> pd.DataFrame:
    """The rows of the causal filters (every filter but the RTS-smoother floors)."""
    return metrics[~metrics["filter"].astype(str).map(is_smoother).to_numpy(bool)]


def sensor_dims(manifest: dict, sensors: Iterable[str]) -> dict[str, int | None]:
    """Measurement size m of each sensor (the dof of its NIS): as the manifest records it (``dim``), else
    from the sensor class registered under
    its name with the options the manifest recorded (``sensors``, per cell; the first cell that holds
    it), else with its default options; None for a sensor not registered here (a plugin not loaded)
    or with conflicting sizes across cells."""
    from nespm_cli.experiments.suite import recorded_dim
    from nespm_cli.sensors.registry import get_sensor
    from nespm_cli.sensors.source import options_of

    cells = [c for c in (manifest.get("sensors") or {}).values() if isinstance(c, dict)]
    out: dict[str, int | None] = {}
    for name in sensors:
        if recorded_dim(manifest, name) is not None:  # recorded at mc time: no plugin needed
            out[name] = recorded_dim(manifest, name)
            continue
        try:
            cls = get_sensor(name)
        except NespmError:
            out[name] = None
            continue
        sizes = set()
        for raw in [c[name] for c in cells if isinstance(c.get(name), dict)] or [{}]:
            known = {k: v for k, v in raw.items() if k in cls.Options.__dataclass_fields__ and v is not None}
            try:
                sizes.add(int(cls(options_of(cls, known)).dim))
            except (NespmError, TypeError, ValueError):
                sizes.add(None)
        out[name] = sizes.pop() if len(sizes) == 1 else None
    return out
