"""Assembling a Monte Carlo folder's tables from exactly the chunks its manifest expects.

``metrics.parquet`` is the expected metrics chunks concatenated in key order, one chunk in
memory at a time (:func:`nespm_cli.experiments.chunks.concat_parquet`). ``epochs.parquet``
holds, per (keys, track, filter, epoch), the mean and population std across the runs that did
not diverge; it is formed chunk by chunk: each series chunk (one track and filter, R runs x N
epochs, run-major) gives its count, mean and sum of squared deviations per epoch and column,
and chunks are merged with the pairwise update of Chan, Golub & LeVeque (1979), so memory stays
that of one chunk whatever the number of runs (docs/results-schema.md).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

#: columns of a series chunk averaged across runs: (column, also its std)
MEAN_COLUMNS = (("vel_err", True), ("att_err", True), ("nees", False), ("north_err", False),
                ("east_err", False), ("hpe", True), ("nees_vel", False), ("nees_att", False), ("nees_pos", False))
COVERAGE = tuple(f"cover{k}_{b}" for b in ("vel", "att", "pos") for k in (1, 2, 3))
MEAN_COLUMNS = MEAN_COLUMNS + tuple((c, False) for c in COVERAGE)
BLOCK_COLUMNS = ("nees_vel", "nees_att", "nees_pos") + COVERAGE  # per-block columns (NaN in older chunk files)


class Moments:
    """Running count, mean and sum of squared deviations (N,) of one column across runs (NaN skipped)."""

    def __init__(self, n_epochs: int) -> None:
        self.n = np.zeros(n_epochs)
        self.mean = np.zeros(n_epochs)
        self.m2 = np.zeros(n_epochs)

    def add(self, X: np.ndarray) -> None:
        """Merge the runs ``X`` (R, N) of one chunk (NaN: a run left out at that epoch)."""
        ok = ~np.isnan(X)
        nb = ok.sum(axis=0).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            mb = np.where(ok, X, 0.0).sum(axis=0) / nb
            m2b = np.where(ok, (X - mb) ** 2, 0.0).sum(axis=0)
            n = self.n + nb
            delta = mb - self.mean
            mean = np.where(nb > 0, self.mean + delta * nb / n, self.mean)
            m2 = np.where(nb > 0, self.m2 + m2b + delta**2 * self.n * nb / n, self.m2)
        self.n, self.mean, self.m2 = n, np.where(n > 0, mean, 0.0), np.where(n > 0, m2, 0.0)

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, population std)`` (N,), NaN where no run counted."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.n > 0, self.mean, np.nan), np.where(self.n > 0, np.sqrt(self.m2 / self.n), np.nan)


def epoch_table(series: list[tuple[tuple, Path]], keys: tuple[str, ...] = ()) -> pd.DataFrame:
    """``epochs.parquet`` from series chunk files: ``series`` is ``[(key values, path)]`` where the
    key values are ``(*keys, track, filter)`` of the chunk; diverged runs count in no mean."""
    groups: dict[tuple, dict] = {}
    for key, path in series:
        s = pd.read_parquet(path)
        N = int(s["epoch"].max()) + 1
        R = len(s) // N
        g = groups.get(key)
        nis_cols = sorted(c for c in s.columns if c.startswith("nis_"))  # one per sensor (a chunk's own)
        if g is None:
            g = groups[key] = {"t": s["t"].to_numpy()[:N], "dvl_used": s["dvl_used"].to_numpy()[:N],
                               "ok": np.zeros(N, dtype=np.int64),
                               "moments": {c: Moments(N) for c, _ in MEAN_COLUMNS},
                               "nis": {c: Moments(N) for c in nis_cols}}
        bad = s["diverged"].to_numpy().reshape(R, N)
        g["ok"] += (~bad).sum(axis=0)
        cols = {c: s[c].to_numpy(float).reshape(R, N) for c in ("vel_err", "att_err", "nees", "north_err",
                                                               "east_err")}
        for c in BLOCK_COLUMNS:
            cols[c] = s[c].to_numpy(float).reshape(R, N) if c in s.columns else np.full((R, N), np.nan)
        cols["hpe"] = np.hypot(cols["north_err"], cols["east_err"])  # horizontal position error [m]
        for c, _ in MEAN_COLUMNS:
            g["moments"][c].add(np.where(bad, np.nan, cols[c]))
        for c in g["nis"]:
            x = s[c].to_numpy(float).reshape(R, N) if c in s.columns else np.full((R, N), np.nan)
            g["nis"][c].add(np.where(bad, np.nan, x))
    rows = []
    for key in sorted(groups):
        g = groups[key]
        N = len(g["t"])
        row = {k: [v] * N for k, v in zip((*keys, "track", "filter"), key)}
        row.update(epoch=np.arange(N), t=g["t"])
        for c, with_std in MEAN_COLUMNS:
            mean, std = g["moments"][c].result()
            row[f"{c}_mean"] = mean
            if with_std:
                row[f"{c}_std"] = std
        nis = {}
        for c, mom in g["nis"].items():
            nis[f"{c}_mean"], nis[f"{c}_n"] = mom.result()[0], mom.n.astype(np.int64)
        row.update(dvl_used=g["dvl_used"], n_runs=g["ok"], **nis)
        rows.append(pd.DataFrame(row))
    order = [*keys, "track", "filter", "epoch", "t", "vel_err_mean", "vel_err_std", "att_err_mean", "att_err_std",
             "nees_mean", "north_err_mean", "east_err_mean", "hpe_mean", "hpe_std", "nees_vel_mean", "nees_att_mean",
             "nees_pos_mean", *(f"{c}_mean" for c in COVERAGE), "dvl_used", "n_runs"]
    table = pd.concat(rows, ignore_index=True)
    return table[order + sorted(c for c in table.columns if c.startswith("nis_"))]


__all__ = ["MEAN_COLUMNS", "Moments", "epoch_table"]
