"""Each run's mean square error of a state block over the efficiency's window: the input of the
efficiency's sampling interval (:func:`nespm_cli.experiments.pcrb_table.efficiency`, docs/pcrb.md).

The runs of a study are independent realizations, so the standard error of the study's mean square
error is the sample std of the runs' own over √R. Where each run's own comes from:

* velocity, attitude, horizontal position (window ``t > 0``): the posterior sums of
  ``metrics.parquet``, ``sse_vel_post / n_post`` [(m/s)²], ``sse_att_post / n_post`` [rad²] and
  ``sse_hpe_post / n_post`` [m²] (the same errors as the epochs table's ``vel_err``, ``att_err``,
  ``hpe``, over the same epochs);
* 3-D position and the bias blocks (``--save-series axes``): the per-run series chunks the folder's
  assembly recorded (``e_<label>``, :func:`series_files`), over :func:`pcrb_table.window_mask`'s
  epochs (the bias blocks from 10 s on). A run lost in the window counts as no run.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import POSTERIOR_COLUMNS
from nespm_cli.experiments.pcrb_table import AXES_BLOCKS, window_mask
from nespm_cli.nav.state import BLOCKS

#: block of the efficiency -> its posterior sum in metrics.parquet (over n_post epochs)
METRICS_SUMS = {"vel": "sse_vel", "att": "sse_att", "hpos": "sse_hpe"}


def metrics_mse(metrics: pd.DataFrame, keys: tuple = ()) -> pd.DataFrame:
    """Per (keys, track, filter, run): ``mse_vel``, ``mse_att``, ``mse_hpos``, each run's mean square error
    over the epochs after t = 0 (NaN for a lost run, or a folder without the posterior sums)."""
    group = [*keys, "track", "filter", "run"]
    out = metrics[group].copy()
    post = POSTERIOR_COLUMNS
    n = metrics[post["n_samples"]].to_numpy(float) if post["n_samples"] in metrics else np.full(len(metrics), np.nan)
    for block, col in METRICS_SUMS.items():
        sse = metrics[post[col]].to_numpy(float) if post[col] in metrics else np.full(len(metrics), np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[f"mse_{block}"] = np.where(n > 0, sse / np.where(n > 0, n, 1.0), np.nan)
    return out.reset_index(drop=True)


def needs_series(epochs: pd.DataFrame | None) -> bool:
    """The epochs hold a block whose per-run errors only the series have (``rms_<label>`` of
    :data:`AXES_BLOCKS`, ``--save-series axes``)."""
    labels = [lab for b in AXES_BLOCKS for lab in BLOCKS[b][2]]
    return epochs is not None and any(f"rms_{lab}" in epochs.columns for lab in labels)


def series_files(folder: Path, manifest: dict) -> list[Path]:
    """The series chunks the folder's last assembly recorded, verified; [] for a folder without that
    record (an older nespm) or whose chunks are gone or changed (the interval then reads "—")."""
    from nespm_cli.experiments.snapshot import finished_state, recorded_chunks

    try:
        rec = finished_state(Path(folder), manifest or {}, "report")
        return recorded_chunks(Path(folder), rec, "series") if rec is not None else []
    except NespmError:
        return []


def series_mse(files: list[Path], keys: tuple = ()) -> pd.DataFrame:
    """Per (keys, track, filter, run): ``mse_<block>`` for the blocks of :data:`AXES_BLOCKS` whose per-axis
    errors ``e_<label>`` the series hold, over :func:`window_mask`'s epochs (empty without such series).
    Each chunk holds whole runs, so it is reduced on its own (one chunk in memory at a time)."""
    import pyarrow.parquet as pq

    group = [*keys, "track", "filter", "run"]
    parts = []
    for f in files:
        names = set(pq.read_schema(f).names)
        blocks = [b for b in AXES_BLOCKS if all(f"e_{lab}" in names for lab in BLOCKS[b][2])]
        if not blocks or not {*group, "epoch", "t"} <= names:
            continue
        cols = [*group, "epoch", "t", *(["diverged"] if "diverged" in names else []),
                *(f"e_{lab}" for b in blocks for lab in BLOCKS[b][2])]
        s = pd.read_parquet(f, columns=cols)
        lost = s["diverged"].to_numpy(bool) if "diverged" in s else np.zeros(len(s), bool)
        out = s[group].drop_duplicates().reset_index(drop=True)
        for b in blocks:
            sq = sum(s[f"e_{lab}"].to_numpy(float) ** 2 for lab in BLOCKS[b][2])
            sq = np.where(lost, np.nan, sq)
            mask = np.zeros(len(s), bool)
            for _, idx in s.groupby([*keys, "track"], sort=False).indices.items():
                mask[idx] = window_mask(s["t"].to_numpy(float)[idx], s["epoch"].to_numpy()[idx], b)
            d = s.loc[mask, group].assign(sq=sq[mask])
            per = d.groupby(group, sort=False)["sq"].agg(["mean", "count", "size"])
            per = per["mean"].where(per["count"] == per["size"])  # a run lost in the window: no run
            out[f"mse_{b}"] = out.set_index(group).index.map(per).to_numpy(float)
        parts.append(out)
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=group)


def run_mse(metrics: pd.DataFrame | None, files: list[Path] = (), keys: tuple = ()) -> pd.DataFrame | None:
    """:func:`metrics_mse` and :func:`series_mse` side by side per (keys, track, filter, run); None without
    metrics."""
    if metrics is None or metrics.empty:
        return None
    out = metrics_mse(metrics, keys)
    axes = series_mse(list(files), keys)
    if axes.empty or len(axes.columns) <= len(keys) + 3:
        return out
    group = [*keys, "track", "filter", "run"]
    for k in group:
        axes[k] = axes[k].astype(out[k].dtype)
    return out.merge(axes, on=group, how="left")


__all__ = ["METRICS_SUMS", "metrics_mse", "needs_series", "run_mse", "series_files", "series_mse"]
