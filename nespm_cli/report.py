"""Summary report of a Monte Carlo results folder: tables, paired bootstrap, figures.

Reads the files described in ``docs/results-schema.md`` (``metrics.parquet``, optionally
``epochs.parquet`` and ``manifest.json``) and writes ``report.md`` plus PNG figures.

Metric definitions (anukf.md eqs 50-53), repeated in the report text:

* per track and filter, ``VRMSE = sqrt(sum(sse_vel) / sum(n_samples))`` over the
  non-diverged runs (eq 50); ``MRMSE`` likewise with ``sse_att`` (eq 52);
* track average: ``sqrt(mean over tracks of VRMSE_track**2)`` (eq 51);
* improvement of a row over the reference filter F: ``100 * (m_row - m_F) / m_row``
  (the papers' "ANUKF Imprv." column);
* 95 % interval of the improvement: paired bootstrap over run indices, resampled per track.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError

__all__ = [
    "PUBLISHED",
    "load_results",
    "filter_table",
    "track_table",
    "published_tables",
    "default_reference",
    "plot_track_figures",
    "render_report",
    "write_report",
]

#: Published track-averaged results (real Snapir tracks 5 and 6, authors' recorded IMU).
#: ``values`` maps our filter name to ``{"vrmse": m/s, "mrmse": rad}`` (table order);
#: ``reference`` is the table's proposed method, whose 'Imprv.' over each row is shown.
PUBLISHED: dict[str, dict[str, Any]] = {
    "anukf-table1": {
        "source": "anukf.md Table I",
        "scenario": "nominal",
        "reference": "anukf",
        "values": {
            "ukf": {"vrmse": 0.1172, "mrmse": 0.0112},
            "anekf": {"vrmse": 0.1004, "mrmse": 0.0156},
            "anukf": {"vrmse": 0.0922, "mrmse": 0.0106},
        },
    },
    "anukf-table2": {
        "source": "anukf.md Table II (20 s DVL outage from t = 180 s)",
        "scenario": "outage",
        "reference": "anukf",
        "values": {
            "anekf": {"vrmse": 0.222, "mrmse": 0.0156},
            "anukf": {"vrmse": 0.1183, "mrmse": 0.0106},
        },
    },
    "ukf-nespm-table1": {
        "source": "ukf-nespm.md Table I",
        "scenario": "nominal",
        "reference": "anukf-nespm",
        "values": {
            "anukf-nespm": {"vrmse": 0.073, "mrmse": 0.0065},
            "anukf": {"vrmse": 0.08, "mrmse": 0.0079},
        },
    },
}

METRICS_COLUMNS: tuple[str, ...] = (
    "track", "filter", "run", "sse_vel", "sse_att", "n_samples", "nees", "diverged",
)
EPOCHS_COLUMNS: tuple[str, ...] = (
    "track", "filter", "t", "vel_err_mean", "vel_err_std", "att_err_mean", "att_err_std",
    "north_err_mean", "east_err_mean", "north_true", "east_true", "dvl_used",
)
DEFAULT_REFERENCE = "ukf-nespm"
FIG_DPI = 150
DASH = "—"

# metric key -> (sse column, display name, unit)
_METRICS: dict[str, tuple[str, str, str]] = {
    "vrmse": ("sse_vel", "VRMSE", "m/s"),
    "mrmse": ("sse_att", "MRMSE", "rad"),
}


# ----------------------------------------------------------------------------- loading


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
    manifest: dict = {}
    if manifest_path.is_file():
        try:
            manifest = json.loads(manifest_path.read_text())
        except (OSError, ValueError) as exc:
            raise NespmError(f"{manifest_path}: not valid JSON ({_one_line(exc)})") from exc
        if not isinstance(manifest, dict):
            raise NespmError(f"{manifest_path}: expected a JSON object")
    if experiment is not None and manifest.get("experiment") != experiment:
        raise NespmError(f"{manifest_path}: not a {experiment.upper()} experiment folder "
                         f"(experiment = {manifest.get('experiment')!r}); run `nespm {command} --out {out_dir}`")
    metrics_path = out_dir / "metrics.parquet"
    if not metrics_path.is_file():
        raise NespmError(f"{metrics_path} not found: run `nespm {command} ... --out {out_dir}` first")
    return _read_parquet(metrics_path), manifest


def load_results(out_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame | None, dict]:
    """Read ``metrics.parquet`` (required), ``epochs.parquet`` and ``manifest.json``.

    Returns ``(metrics, epochs or None, manifest or {})``. Raises :class:`NespmError`
    for a missing folder, a missing/unreadable metrics file or missing columns.
    """
    out_dir = Path(out_dir)
    metrics, manifest = read_results_folder(out_dir, "mc")
    _check_metrics(metrics, out_dir / "metrics.parquet")
    epochs_path = out_dir / "epochs.parquet"
    epochs = _read_parquet(epochs_path) if epochs_path.is_file() else None
    if epochs is not None:
        _require_columns(epochs, EPOCHS_COLUMNS, epochs_path)
    return metrics, epochs, manifest


def _read_parquet(path: Path) -> pd.DataFrame:
    """Read one Parquet file, turning reader errors into a one-line NespmError."""
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises many types for a damaged file
        raise NespmError(f"{path}: cannot read Parquet ({_one_line(exc)})") from exc


def _one_line(exc: BaseException) -> str:
    """First line of an exception message."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _require_columns(df: pd.DataFrame, columns: Iterable[str], where: object) -> None:
    """Raise NespmError naming the columns of ``columns`` that ``df`` lacks."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise NespmError(f"{where}: missing column(s) {', '.join(missing)}")


def _check_metrics(metrics: pd.DataFrame, where: object = "metrics") -> None:
    """Validate the columns, non-emptiness and (track, filter, run) uniqueness."""
    _require_columns(metrics, METRICS_COLUMNS, where)
    if metrics.empty:
        raise NespmError(f"{where}: no rows")
    dup = metrics.duplicated(["track", "filter", "run"])
    if dup.any():
        row = metrics.loc[dup].iloc[0]
        raise NespmError(
            f"{where}: duplicate row for track {row['track']}, filter {row['filter']}, run {row['run']}"
        )


# ----------------------------------------------------------------------------- tables


def filters_in_order(metrics: pd.DataFrame) -> list[str]:
    """Filter names in their order of first appearance."""
    return [str(f) for f in pd.unique(metrics["filter"])]


def default_reference(metrics: pd.DataFrame, reference: str | None = None) -> str:
    """The reference filter: ``reference`` if given, else ``ukf-nespm`` if present, else the
    last filter that is not the free-inertial ``ins``.

    Raises NespmError if ``reference`` is not one of the filters in ``metrics``.
    """
    names = filters_in_order(metrics)
    if reference:
        if reference not in names:
            raise NespmError(
                f"--baseline: unknown filter '{reference}': the results hold {', '.join(names)}"
            )
        return reference
    if DEFAULT_REFERENCE in names:
        return DEFAULT_REFERENCE
    aided = [n for n in names if n != "ins"]
    return aided[-1] if aided else names[-1]


def _sums(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per (track, filter): error sums over non-diverged runs, NEES mean and run counts."""
    df = metrics.assign(
        diverged=metrics["diverged"].astype(bool),
        ok=~metrics["diverged"].astype(bool),
    )
    ok = df[df["ok"]]
    grouped = ok.groupby(["track", "filter"], sort=False)
    sums = grouped[["sse_vel", "sse_att", "n_samples"]].sum()
    sums["nees"] = grouped["nees"].mean()
    counts = df.groupby(["track", "filter"], sort=False).agg(
        runs=("run", "size"), diverged=("diverged", "sum")
    )
    out = counts.join(sums, how="left")
    out["n_samples"] = out["n_samples"].fillna(0.0)
    return out


def _rmse(sse: pd.Series | np.ndarray, n: pd.Series | np.ndarray) -> np.ndarray:
    """sqrt(sse / n), NaN where n == 0 (every run diverged)."""
    sse = np.asarray(sse, dtype=float)
    n = np.asarray(n, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(n > 0, np.sqrt(sse / np.where(n > 0, n, 1.0)), np.nan)


def track_table(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per (track, filter): VRMSE, MRMSE (eqs 50, 52), mean NEES, diverged count and runs.

    Rows are sorted by track, filters in order of appearance; the NEES is the mean of the
    per-run ``nees`` over the non-diverged runs.
    """
    _check_metrics(metrics)
    s = _sums(metrics).reset_index()
    order = {f: i for i, f in enumerate(filters_in_order(metrics))}
    s = s.assign(_o=s["filter"].map(order)).sort_values(["track", "_o"]).drop(columns="_o")
    return pd.DataFrame(
        {
            "track": s["track"].to_numpy(),
            "filter": s["filter"].astype(str).to_numpy(),
            "vrmse": _rmse(s["sse_vel"], s["n_samples"]),
            "mrmse": _rmse(s["sse_att"], s["n_samples"]),
            "nees": s["nees"].to_numpy(dtype=float),
            "diverged": s["diverged"].to_numpy(dtype=int),
            "runs": s["runs"].to_numpy(dtype=int),
        }
    )


def _track_average(per_track: np.ndarray | pd.Series) -> float:
    """Eq 51: sqrt of the mean over tracks of the squared per-track RMSE (NaN if any is NaN)."""
    x = np.asarray(per_track, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def improvement(value: float | np.ndarray, ref: float | np.ndarray) -> float | np.ndarray:
    """Papers' improvement of the reference over a row, percent: 100 * (value - ref) / value."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * (np.asarray(value) - np.asarray(ref)) / np.asarray(value)


def _bootstrap_counts(n_runs: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """(n_boot, n_runs) multiplicities of each run in each with-replacement resample."""
    idx = rng.integers(0, n_runs, size=(n_boot, n_runs))
    flat = idx + (np.arange(n_boot, dtype=np.int64) * n_runs)[:, None]
    return np.bincount(flat.ravel(), minlength=n_boot * n_runs).reshape(n_boot, n_runs).astype(float)


def _paired_runs(metrics: pd.DataFrame, track: Any, a: str, b: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rows of filters ``a`` and ``b`` on ``track`` for the runs diverged in neither, aligned by run."""
    sub = metrics[metrics["track"] == track]
    A = sub[sub["filter"] == a].set_index("run")
    B = sub[sub["filter"] == b].set_index("run")
    common = A.index.intersection(B.index).sort_values()
    keep = ~(A.loc[common, "diverged"].to_numpy(bool) | B.loc[common, "diverged"].to_numpy(bool))
    runs = common[keep]
    return A.loc[runs], B.loc[runs]


def paired_bootstrap(
    metrics: pd.DataFrame, row: str, ref: str, n_boot: int = 2000, seed: int = 0
) -> dict[str, np.ndarray]:
    """Bootstrap replicates of the improvement of ``ref`` over ``row`` for VRMSE and MRMSE.

    Per track, run indices (of the runs diverged in neither filter) are resampled with
    replacement; both filters use the same resample (paired). Each replicate recomputes
    eq 50/52 per track from the resampled error sums and the track average (eq 51) of
    both filters, then the improvement. The resamples of a track depend only on
    ``(seed, track)`` and the number of paired runs. Returns ``{"vrmse": (n_boot,),
    "mrmse": (n_boot,)}``; all NaN if some shared track has no paired run.
    """
    tracks = sorted(
        set(metrics.loc[metrics["filter"] == row, "track"])
        & set(metrics.loc[metrics["filter"] == ref, "track"])
    )
    nan = {k: np.full(n_boot, np.nan) for k in _METRICS}
    if not tracks or n_boot < 1:
        return nan
    ms: dict[str, dict[str, list[np.ndarray]]] = {k: {"row": [], "ref": []} for k in _METRICS}
    for track in tracks:
        A, B = _paired_runs(metrics, track, row, ref)
        if len(A) == 0:
            return nan
        rng = np.random.default_rng([int(seed), int(track)])
        counts = _bootstrap_counts(len(A), n_boot, rng)
        for key, (sse_col, _, _) in _METRICS.items():
            for side, T in (("row", A), ("ref", B)):
                num = counts @ T[sse_col].to_numpy(float)
                den = counts @ T["n_samples"].to_numpy(float)
                ms[key][side].append(num / den)
    out = {}
    for key in _METRICS:
        avg_row = np.sqrt(np.mean(ms[key]["row"], axis=0))
        avg_ref = np.sqrt(np.mean(ms[key]["ref"], axis=0))
        out[key] = improvement(avg_row, avg_ref)
    return out


def paired_improvement(metrics: pd.DataFrame, row: str, ref: str) -> dict[str, float]:
    """Improvement of ``ref`` over ``row`` (percent) for VRMSE and MRMSE, on the runs that
    diverged in neither filter: the point estimate that :func:`paired_bootstrap`'s interval
    belongs to (with no divergence it equals the improvement of the two track averages)."""
    tracks = sorted(set(metrics.loc[metrics["filter"] == row, "track"])
                    & set(metrics.loc[metrics["filter"] == ref, "track"]))
    out = {}
    for key, (sse_col, _, _) in _METRICS.items():
        ms = {"row": [], "ref": []}
        for track in tracks:
            A, B = _paired_runs(metrics, track, row, ref)
            for side, T in (("row", A), ("ref", B)):
                n = T["n_samples"].to_numpy(float).sum()
                ms[side].append(T[sse_col].to_numpy(float).sum() / n if n else np.nan)
        with np.errstate(all="ignore"):
            out[key] = float(improvement(np.sqrt(np.mean(ms["row"])), np.sqrt(np.mean(ms["ref"])))) if tracks \
                else math.nan
    return out


def filter_table(
    metrics: pd.DataFrame, reference: str | None, n_boot: int = 2000, seed: int = 0
) -> pd.DataFrame:
    """One row per filter (order of appearance): track-averaged metrics and improvements.

    Columns: ``filter``, ``vrmse``, ``vrmse_imprv``, ``vrmse_ci_lo``, ``vrmse_ci_hi``,
    ``vrmse_ci_excludes_0`` and the same for ``mrmse``; ``nees`` (mean per-run NEES over
    the non-diverged runs of all tracks), ``diverged``, ``runs``, ``tracks``,
    ``is_reference``. Improvements are percent, NaN on the reference row; the interval is
    the 2.5/97.5 percentile of :func:`paired_bootstrap`. ``attrs["reference"]`` names
    the reference filter.
    """
    _check_metrics(metrics)
    if n_boot < 0:
        raise NespmError(f"n_boot must be >= 0, got {n_boot}")
    ref = default_reference(metrics, reference)
    tt = track_table(metrics)
    ok = metrics[~metrics["diverged"].astype(bool)]
    rows = []
    for name in filters_in_order(metrics):
        t = tt[tt["filter"] == name]
        rows.append(
            {
                "filter": name,
                "vrmse": _track_average(t["vrmse"]),
                "mrmse": _track_average(t["mrmse"]),
                "nees": float(ok.loc[ok["filter"] == name, "nees"].mean()),
                "diverged": int(t["diverged"].sum()),
                "runs": int(t["runs"].sum()),
                "tracks": int(len(t)),
                "is_reference": name == ref,
            }
        )
    table = pd.DataFrame(rows)
    for key in _METRICS:
        table[f"{key}_imprv"] = np.nan
        table[f"{key}_ci_lo"] = np.nan
        table[f"{key}_ci_hi"] = np.nan
    for i, name in enumerate(table["filter"]):
        if name == ref:
            continue
        for key, v in paired_improvement(metrics, name, ref).items():  # the point of its paired interval
            table.loc[i, f"{key}_imprv"] = v
        boot = paired_bootstrap(metrics, name, ref, n_boot=n_boot, seed=seed)
        for key, reps in boot.items():
            if np.all(np.isfinite(reps)) and reps.size:
                lo, hi = np.percentile(reps, [2.5, 97.5])
                table.loc[i, [f"{key}_ci_lo", f"{key}_ci_hi"]] = [lo, hi]
    for key in _METRICS:
        lo, hi = table[f"{key}_ci_lo"], table[f"{key}_ci_hi"]
        table[f"{key}_ci_excludes_0"] = ((lo > 0) | (hi < 0)).to_numpy(bool)
    columns = ["filter"]
    for key in _METRICS:
        columns += [key, f"{key}_imprv", f"{key}_ci_lo", f"{key}_ci_hi", f"{key}_ci_excludes_0"]
    columns += ["nees", "diverged", "runs", "tracks", "is_reference"]
    table = table[columns]
    table.attrs["reference"] = ref
    return table


def published_tables(filters: Sequence[str], scenario: str | None) -> list[dict[str, Any]]:
    """The entries of :data:`PUBLISHED` for ``scenario`` that share at least one filter."""
    return [
        entry
        for entry in PUBLISHED.values()
        if entry["scenario"] == scenario and set(entry["values"]) & set(filters)
    ]


# ----------------------------------------------------------------------------- formatting


def _fmt(x: Any, spec: str = ".4g") -> str:
    """Format a number, or an em dash for None/NaN."""
    if x is None or (isinstance(x, (float, np.floating)) and not np.isfinite(x)):
        return DASH
    return format(x, spec)


def _pct(x: float) -> str:
    """One decimal like the papers (21.3), more where that would print 0.0 or -0.0."""
    if abs(x) >= 0.05 or x == 0.0:
        return f"{x:.1f}"
    return f"{x:.2g}" if abs(x) >= 1e-4 else f"{x:.1e}"


def _fmt_pct(x: Any) -> str:
    """Improvement in percent, e.g. ``21.3 %`` (small values keep two significant digits)."""
    return DASH if x is None or not np.isfinite(x) else f"{_pct(x)} %"


def _fmt_ci(lo: float, hi: float, excludes_0: bool) -> str:
    """``[lo, hi] %`` with a trailing ``*`` when the interval excludes zero."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return DASH
    return f"[{_pct(lo)}, {_pct(hi)}] %" + (" *" if excludes_0 else "")


def _md_table(headers: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(" --- " for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _unique_text(values: Iterable[Any]) -> str:
    """Distinct values joined by commas, in order of appearance."""
    return ", ".join(str(v) for v in pd.unique(pd.Series(list(values))))


def _runs_per_track(metrics: pd.DataFrame) -> str:
    """Distinct run indices per track: one number, or ``min–max`` when tracks differ."""
    n = metrics.groupby("track")["run"].nunique()
    return str(int(n.min())) if n.min() == n.max() else f"{int(n.min())}–{int(n.max())}"


def _scenario(metrics: pd.DataFrame, manifest: dict) -> str | None:
    """The single scenario of the results (metrics column, else manifest option), or None."""
    if "scenario" in metrics.columns:
        vals = pd.unique(metrics["scenario"].dropna())
        return str(vals[0]) if len(vals) == 1 else None
    return (manifest.get("options") or {}).get("scenario")


def _header_line(metrics: pd.DataFrame, manifest: dict) -> str:
    """The run summary line: tracks, runs per track, filters, scenario, schedule, seed, data, time."""
    options = manifest.get("options") or {}

    def field(col: str) -> str:
        if col in metrics.columns:
            return _unique_text(metrics[col])
        return str(options.get(col, manifest.get(col, DASH)))

    seed = manifest.get("seed", None)
    seed_text = str(seed) if seed is not None else field("seed")
    wall = manifest.get("wall_seconds")
    wall_text = f"{float(wall):.1f} s" if isinstance(wall, (int, float)) else DASH
    parts = [
        f"tracks {', '.join(str(t) for t in sorted(pd.unique(metrics['track'])))}",
        f"runs per track {_runs_per_track(metrics)}",
        f"filters {', '.join(filters_in_order(metrics))}",
        f"scenario {field('scenario')}",
        f"schedule {field('schedule')}",
        f"seed {seed_text}",
        f"data dir {manifest.get('data_dir') or DASH}",
        f"wall time {wall_text}",
    ]
    return "**Run:** " + "; ".join(parts) + "."


def _definitions(ref: str, n_boot: int, seed: int) -> str:
    """The report's definitions section (every number in the tables)."""
    return f"""## Definitions

- **VRMSE** (anukf.md eq 50), per track and filter: `sqrt(sum(sse_vel) / sum(n_samples))` over
  the runs that did not diverge, where `sse_vel` is a run's sum over the ground-truth epochs of
  the squared velocity-error norm. **MRMSE** (eq 52) likewise with `sse_att`, the squared norm of
  the misalignment Euler angles of `C_b^n C_n^b,GT` (eq 53).
- **Track average** (eq 51), used in the main table: `sqrt(mean over tracks of VRMSE_track²)`,
  and the same for MRMSE.
- **{ref} Imprv.**: improvement of the reference filter `{ref}` over each other row, as in the
  papers' "ANUKF Imprv." column: `100 · (metric_row − metric_{ref}) / metric_row`. Positive
  means `{ref}` has the smaller error; the reference row shows "{DASH}".
- **95 % CI**: paired bootstrap percentile interval (2.5 %, 97.5 %) of that improvement. The same
  run index is the same realization for every filter, so per track the run indices that diverged in
  neither filter of the pair are resampled with replacement (the same resample for both filters),
  eqs 50–51 are recomputed for both and the improvement taken; {n_boot} resamples, seed {seed}.
  `*` marks an interval that excludes 0. The point estimate uses every non-diverged run of each
  filter, the interval only the pairs.
- **mean NEES**: mean over the non-diverged runs of each run's epoch-averaged 6-DOF NEES of
  `[δv, δψ]` (6 for a consistent filter; {DASH} for `ins`).
- **diverged**: runs whose covariance became non-finite or not positive definite or whose
  velocity error exceeded the divergence limit, out of all runs; they are left out of every
  error number.
"""


def _main_table(table: pd.DataFrame) -> str:
    """Markdown of :func:`filter_table`."""
    ref = table.attrs["reference"]
    headers = [
        "Method", "VRMSE [m/s]", f"{ref} Imprv.", "95 % CI",
        "MRMSE [rad]", f"{ref} Imprv.", "95 % CI", "mean NEES", "diverged",
    ]
    rows = []
    for r in table.itertuples(index=False):
        rows.append(
            [
                r.filter + (" (reference)" if r.is_reference else ""),
                _fmt(r.vrmse), _fmt_pct(r.vrmse_imprv),
                _fmt_ci(r.vrmse_ci_lo, r.vrmse_ci_hi, r.vrmse_ci_excludes_0),
                _fmt(r.mrmse), _fmt_pct(r.mrmse_imprv),
                _fmt_ci(r.mrmse_ci_lo, r.mrmse_ci_hi, r.mrmse_ci_excludes_0),
                _fmt(r.nees, ".2f"), f"{r.diverged} / {r.runs}",
            ]
        )
    return _md_table(headers, rows)


def _track_md(tt: pd.DataFrame) -> str:
    """Markdown of :func:`track_table`."""
    headers = ["Track", "Method", "VRMSE [m/s]", "MRMSE [rad]", "mean NEES", "diverged"]
    rows = [
        [str(r.track), r.filter, _fmt(r.vrmse), _fmt(r.mrmse), _fmt(r.nees, ".2f"),
         f"{r.diverged} / {r.runs}"]
        for r in tt.itertuples(index=False)
    ]
    return _md_table(headers, rows)


def _published_md(metrics: pd.DataFrame, table: pd.DataFrame, scenario: str | None, n_boot: int,
                  seed: int) -> str:
    """Each matching published table beside ours: the table's methods in its order, our
    track-averaged VRMSE/MRMSE, the improvement of the table's proposed method over each row
    (ours with its paired 95 % interval, and the published one)."""
    entries = published_tables(list(table["filter"]), scenario)
    intro = (
        "The published numbers come from the real Snapir AUV data (test tracks 5 and 6) with the "
        "authors' recorded IMU and their trained networks; our values on other tracks or data, "
        "or with a synthesized IMU, are not expected to match them closely. Methods we did not "
        f"run show \"{DASH}\". Imprv. is the improvement of the table's proposed method over the "
        "row, 100 (row - proposed) / row, with our paired bootstrap 95 % interval (* = excludes 0)."
    )
    if not entries:
        return intro + f"\n\nNo published table covers these filters in scenario `{scenario}`."
    parts = [intro]
    ours = {r.filter: r for r in table.itertuples(index=False)}
    for entry in entries:
        ref = entry["reference"]
        pub_ref = entry["values"][ref]
        rows = []
        for name, pub in entry["values"].items():
            r = ours.get(name)
            cells = [name]
            boot = (paired_bootstrap(metrics, name, ref, n_boot=n_boot, seed=seed)
                    if r is not None and ref in ours and name != ref else None)
            for key in _METRICS:
                mine = getattr(r, key) if r is not None else None
                cells += [_fmt(mine), _fmt(pub[key])]
                if name == ref:
                    cells += [DASH, DASH]
                    continue
                if boot is not None:
                    imp = paired_improvement(metrics, name, ref)[key]
                    reps = boot[key]
                    ci = (np.percentile(reps, [2.5, 97.5]) if reps.size and np.all(np.isfinite(reps))
                          else (np.nan, np.nan))
                    cells.append(f"{_fmt_pct(float(imp))} {_fmt_ci(ci[0], ci[1], bool(ci[0] > 0 or ci[1] < 0))}")
                else:
                    cells.append(DASH)
                cells.append(_fmt_pct(float(improvement(pub[key], pub_ref[key]))))
            rows.append(cells)
        parts.append(
            f"**{entry['source']}** (scenario `{entry['scenario']}`; Imprv. of {ref})\n\n"
            + _md_table(["Method", "VRMSE ours [m/s]", "VRMSE published [m/s]", "Imprv. ours [95 % CI]",
                         "Imprv. published", "MRMSE ours [rad]", "MRMSE published [rad]",
                         "Imprv. ours [95 % CI]", "Imprv. published"], rows)
        )
    return "\n\n".join(parts)


def render_report(
    metrics: pd.DataFrame,
    manifest: dict,
    table: pd.DataFrame,
    tt: pd.DataFrame,
    figures: Sequence[Path],
    out_dir: Path,
    n_boot: int,
    seed: int,
) -> str:
    """The full markdown text of ``report.md``."""
    scenario = _scenario(metrics, manifest)
    ref = table.attrs["reference"]
    diverged = ", ".join(f"{r.filter} {r.diverged}" for r in table.itertuples(index=False))
    fig_text = (
        "\n".join(f"![{p.stem}]({p.relative_to(out_dir).as_posix()})" for p in figures)
        if figures
        else "No figures: `epochs.parquet` is absent."
    )
    return "\n\n".join(
        [
            "# nespm Monte Carlo report",
            _header_line(metrics, manifest),
            _definitions(ref, n_boot, seed).rstrip(),
            "## Track-averaged results (eq 51)\n\n" + _main_table(table),
            f"Diverged runs per filter: {diverged}.",
            "## Per-track results (eqs 50, 52)\n\n" + _track_md(tt),
            "## Comparison with the published tables\n\n" + _published_md(metrics, table, scenario, n_boot, seed),
            "## Figures\n\nPer track: velocity-error norm and misalignment norm, mean ± 1 std "
            "across the non-diverged runs (band clipped at 0), grey = epochs without a DVL "
            "update (outage); and the true vs mean estimated horizontal track.\n\n" + fig_text,
        ]
    ) + "\n"


# ----------------------------------------------------------------------------- figures


def save_figure(fig, path: Path, dpi: int = FIG_DPI) -> Path:
    """Lay out, write ``path`` (PNG) and close ``fig``; return ``path``. Every report figure ends here."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


def _outage_spans(t: np.ndarray, dvl_used: np.ndarray) -> list[tuple[float, float]]:
    """Time spans of consecutive epochs with t > 0 and no DVL update (half-epoch padded)."""
    mask = (~dvl_used) & (t > 0)
    spans = []
    i, n = 0, len(t)
    while i < n:
        if not mask[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and mask[j + 1]:
            j += 1
        lo = 0.5 * (t[i - 1] + t[i]) if i > 0 else t[i]
        hi = 0.5 * (t[j] + t[j + 1]) if j + 1 < n else t[j]
        spans.append((float(lo), float(hi)))
        i = j + 1
    return spans


def _colors(filters: Sequence[str]) -> dict[str, Any]:
    """One tab10 colour per filter, stable across figures."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {f: cmap(i % 10) for i, f in enumerate(filters)}


def _error_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], kind: str, title: str, path: Path
) -> Path:
    """Plot mean ± 1 std of an error norm over time per filter with outage shading."""
    import matplotlib.pyplot as plt

    col, label = {"vel": ("vel_err", "velocity error norm [m/s]"),
                  "att": ("att_err", "misalignment norm [rad]")}[kind]
    fig, ax = plt.subplots(figsize=(9, 4.8))
    for f in filters:
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        t = d["t"].to_numpy(float)
        m = d[f"{col}_mean"].to_numpy(float)
        s = d[f"{col}_std"].to_numpy(float)
        ax.plot(t, m, color=colors[f], lw=1.4, label=f)
        ax.fill_between(t, np.clip(m - s, 0.0, None), m + s, color=colors[f], alpha=0.2, lw=0)
    grid = ep.groupby("t", sort=True)["dvl_used"].any()
    for k, (lo, hi) in enumerate(_outage_spans(grid.index.to_numpy(float), grid.to_numpy(bool))):
        ax.axvspan(lo, hi, color="0.6", alpha=0.3, lw=0, label="DVL outage" if k == 0 else None)
    ax.set_xlabel("time since first epoch [s]")
    ax.set_ylabel(label)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    return save_figure(fig, path)


def _track_figure(
    ep: pd.DataFrame, filters: Sequence[str], colors: dict[str, Any], title: str, path: Path
) -> Path:
    """True vs mean estimated horizontal track (east, north) per filter, equal aspect."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7))
    first = ep[ep["filter"] == filters[0]].sort_values("t")
    ax.plot(first["east_true"], first["north_true"], color="k", lw=2.0, label="truth")
    for f in filters:
        d = ep[ep["filter"] == f].sort_values("t")
        if d.empty:
            continue
        ax.plot(d["east_true"] + d["east_err_mean"], d["north_true"] + d["north_err_mean"],
                color=colors[f], lw=1.2, ls="--", label=f"{f} (mean estimate)")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return save_figure(fig, path)


def plot_track_figures(
    epochs: pd.DataFrame, metrics: pd.DataFrame, fig_dir: Path, scenario: str | None = None
) -> list[Path]:
    """Write three PNGs per track into ``fig_dir``; return their paths in track order.

    ``vel_track<N>.png`` and ``att_track<N>.png``: mean ± 1 std of the error norms over time
    per filter, shading epochs (t > 0) where no filter applied a DVL update;
    ``path_track<N>.png``: true and mean estimated horizontal track.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (after selecting the backend)

    fig_dir.mkdir(parents=True, exist_ok=True)
    order = filters_in_order(metrics)
    filters = order + [f for f in (str(x) for x in pd.unique(epochs["filter"])) if f not in order]
    colors = _colors(filters)
    runs = metrics.groupby("track")["run"].nunique()
    paths: list[Path] = []
    for track in sorted(pd.unique(epochs["track"])):
        ep = epochs[epochs["track"] == track]
        present = [f for f in filters if (ep["filter"] == f).any()]
        n = int(runs.get(track, 0))
        tail = f"track {track}, {n} runs, scenario {scenario or DASH}"
        paths.append(_error_figure(ep, present, colors, "vel",
                                   f"Velocity error, mean ± 1 std — {tail}",
                                   fig_dir / f"vel_track{track}.png"))
        paths.append(_error_figure(ep, present, colors, "att",
                                   f"Misalignment, mean ± 1 std — {tail}",
                                   fig_dir / f"att_track{track}.png"))
        paths.append(_track_figure(ep, present, colors,
                                   f"Horizontal track — {tail}",
                                   fig_dir / f"path_track{track}.png"))
    return paths


# ----------------------------------------------------------------------------- entry point


def _write_atomic(path: Path, text: str) -> None:
    """Write text to ``path`` through a temporary file and a rename."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_report(out_dir: Path, reference: str | None = None, n_boot: int = 2000) -> Path:
    """Write ``out_dir/report.md`` and ``out_dir/figures/*.png``; return the report path.

    Figures are skipped when ``epochs.parquet`` is absent. The bootstrap seed is 0. A sweep
    folder (metrics with a ``param`` column) goes to :func:`sweep_report.write_sweep_report`
    with ``reference`` as its baseline.
    """
    out_dir = Path(out_dir)
    try:
        experiment = json.loads((out_dir / "manifest.json").read_text()).get("experiment")
    except (OSError, ValueError, AttributeError):
        experiment = None  # load_results reports a missing or unreadable manifest
    if experiment == "gp-ukf":
        from nespm_cli.gp_report import write_gp_report

        return write_gp_report(out_dir, n_boot=n_boot)  # --baseline does not apply
    try:  # schema only; an unreadable file is reported by load_results below
        import pyarrow.parquet as pq

        is_sweep = "param" in pq.read_schema(out_dir / "metrics.parquet").names
    except Exception:
        is_sweep = False
    if is_sweep:
        from nespm_cli.sweep_report import write_sweep_report

        return write_sweep_report(out_dir, reference, n_boot=n_boot)
    metrics, epochs, manifest = load_results(out_dir)
    seed = 0
    table = filter_table(metrics, reference, n_boot=n_boot, seed=seed)
    tt = track_table(metrics)
    figures: list[Path] = []
    if epochs is not None and not epochs.empty:
        figures = plot_track_figures(epochs, metrics, out_dir / "figures", _scenario(metrics, manifest))
    text = render_report(metrics, manifest, table, tt, figures, out_dir, n_boot, seed)
    path = out_dir / "report.md"
    _write_atomic(path, text)
    return path
