"""Assembling a Monte Carlo folder's tables from exactly the chunks its manifest expects.

``metrics.parquet`` is the expected metrics chunks concatenated in key order, one chunk in
memory at a time (:func:`nespm_cli.experiments.chunks.concat_parquet`). ``epochs.parquet``
holds, per (keys, track, filter, epoch), the mean and population std across the runs that did
not diverge (``dvl_used``: whether a DVL update was applied at the epoch in any run; the series chunks
hold it per run); it is formed chunk by chunk: each series chunk (one track and filter, R runs x N
epochs, run-major) gives its count, mean and sum of squared deviations per epoch and column,
and chunks are merged with the pairwise update of Chan, Golub & LeVeque (1979), so memory stays
that of one chunk whatever the number of runs (docs/results-schema.md).
"""
from __future__ import annotations

from pathlib import Path

import warnings

import numpy as np
import pandas as pd

#: the blocks with a NEES and a coverage in the series (metrics.STAT_BLOCKS)
BLOCKS = ("vel", "att", "pos", "ba", "bg")
COVERAGE = tuple(f"cover{k}_{b}" for b in BLOCKS for k in (1, 2, 3))
BLOCK_COLUMNS = tuple(f"nees_{b}" for b in BLOCKS) + COVERAGE  # per-block columns (NaN in older chunk files)
#: columns of a series chunk averaged across runs: (column, also its std)
MEAN_COLUMNS = (("vel_err", True), ("att_err", True), ("nees", False), ("north_err", False),
                ("east_err", False), ("hpe", True)) + tuple((c, False) for c in BLOCK_COLUMNS)


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


class Credibility:
    """Li and Zhao's noncredibility index of one block per epoch, over the runs of every chunk.

    ``NCI = (10/n) Σ_i log10(ε_i / ε*_i)`` [dB] with ``ε_i = eᵢᵀ P_i⁻¹ eᵢ`` the filter's NEES of
    run i and ``ε*_i = eᵢᵀ Σ⁻¹ eᵢ`` the NEES under the actual mean-square error matrix
    ``Σ = (1/n) Σ_i eᵢ eᵢᵀ`` over the n runs (X. R. Li, Z. Zhao, "Measuring estimator's credibility:
    noncredibility index", FUSION 2006). 0 dB: credible; > 0 optimistic (P too small); < 0
    pessimistic. Σ needs every run first: :meth:`add_mse` over the chunks, then :meth:`add_ratio`.
    """

    def __init__(self, n_epochs: int) -> None:
        self.mse = np.zeros((n_epochs, 3, 3))
        self.n = np.zeros(n_epochs)
        self.ratio = Moments(n_epochs)

    def add_mse(self, E: np.ndarray) -> None:
        """Sum the outer products of the errors ``E`` (R, N, 3) (NaN rows: left out)."""
        ok = np.isfinite(E).all(axis=-1)
        Z = np.where(ok[..., None], E, 0.0)
        self.mse += np.einsum("rni,rnj->nij", Z, Z)
        self.n += ok.sum(axis=0)

    def add_ratio(self, E: np.ndarray, nees: np.ndarray) -> None:
        """Merge ``10 log10(ε / ε*)`` (R, N) of one chunk (after every :meth:`add_mse`)."""
        with np.errstate(all="ignore"):
            S = self.mse / self.n[:, None, None]
            # an epoch whose errors do not span 3 dimensions (all zero at a known start) has no index
            scale = np.einsum("nii->n", S) / 3.0
            full = np.isfinite(S).all(axis=(-2, -1)) & (scale > 0)
            full &= np.abs(np.linalg.det(np.where(full[:, None, None], S, np.eye(3)))) > 1e-12 * np.where(full, scale, 1.0) ** 3
            ok = np.isfinite(E).all(axis=-1) & np.isfinite(nees) & (self.n > 0) & full
            S = np.where(full[:, None, None], S, np.eye(3))
            sol = np.linalg.solve(np.broadcast_to(S, E.shape[:2] + (3, 3)), np.where(ok[..., None], E, 1.0)[..., None])
            star = (np.where(ok[..., None], E, 1.0) * sol[..., 0]).sum(axis=-1)
            self.ratio.add(np.where(ok, 10.0 * np.log10(nees / star), np.nan))

    def result(self) -> np.ndarray:
        """(N,) the index [dB], NaN where no run counted."""
        return self.ratio.result()[0]


def _read_columns(s: pd.DataFrame, cols, R: int, N: int) -> dict[str, np.ndarray]:
    return {c: s[c].to_numpy(float).reshape(R, N) if c in s.columns else np.full((R, N), np.nan) for c in cols}


def epoch_table(series: list[tuple[tuple, Path]], keys: tuple[str, ...] = ()) -> pd.DataFrame:
    """``epochs.parquet`` from series chunk files: ``series`` is ``[(key values, path)]`` where the
    key values are ``(*keys, track, filter)`` of the chunk; diverged runs count in no mean.

    Chunks saved with ``--save-series axes`` (columns ``e_<label>``, ``s_<label>``) also give per
    component ``rms_<label>`` (RMS error over the runs) and ``sig_<label>`` (RMS of the filter's
    std), and per block with its three components the noncredibility index ``nci_<block>``
    (:class:`Credibility`; the series are read twice)."""
    from nespm_cli.nav.state import BLOCKS as STATE_BLOCKS

    groups: dict[tuple, dict] = {}
    axes_paths = []
    for key, path in series:
        s = pd.read_parquet(path)
        N = int(s["epoch"].max()) + 1
        R = len(s) // N
        g = groups.get(key)
        nis_cols = sorted(c for c in s.columns if c.startswith("nis_"))  # one per sensor (a chunk's own)
        labels = [c[2:] for c in s.columns if c.startswith("e_")]
        if g is None:
            g = groups[key] = {"t": s["t"].to_numpy()[:N], "dvl_used": np.zeros(N, dtype=bool),
                               "ok": np.zeros(N, dtype=np.int64),
                               "moments": {c: Moments(N) for c, _ in MEAN_COLUMNS},
                               "nis": {c: Moments(N) for c in nis_cols},
                               "axes": {lab: (Moments(N), Moments(N)) for lab in labels}, "hpe_runs": [],
                               "nci": {b: Credibility(N) for b, (_, _, labs) in STATE_BLOCKS.items()
                                       if all(lab in labels for lab in labs)}}
        bad = s["diverged"].to_numpy().reshape(R, N)
        g["ok"] += (~bad).sum(axis=0)
        g["dvl_used"] |= s["dvl_used"].to_numpy(bool).reshape(R, N).any(axis=0)  # per run in the series: any run
        cols = _read_columns(s, ("vel_err", "att_err", "nees", "north_err", "east_err") + BLOCK_COLUMNS, R, N)
        cols["hpe"] = np.hypot(cols["north_err"], cols["east_err"])  # horizontal position error [m]
        for c, _ in MEAN_COLUMNS:
            g["moments"][c].add(np.where(bad, np.nan, cols[c]))
        g["hpe_runs"].append(np.where(bad, np.nan, cols["hpe"]).astype(np.float32))  # (R, N): CEP over the runs
        for c in g["nis"]:
            g["nis"][c].add(np.where(bad, np.nan, _read_columns(s, (c,), R, N)[c]))
        for lab, (me, ms) in g["axes"].items():
            ax = _read_columns(s, (f"e_{lab}", f"s_{lab}"), R, N)
            me.add(np.where(bad, np.nan, ax[f"e_{lab}"] ** 2))
            ms.add(np.where(bad, np.nan, ax[f"s_{lab}"] ** 2))
        for b, cred in g["nci"].items():
            cred.add_mse(_block_errors(s, STATE_BLOCKS[b][2], bad, R, N))
        if g["nci"]:
            axes_paths.append((key, path))
    for key, path in axes_paths:  # the second pass of the noncredibility index
        s = pd.read_parquet(path)
        N = len(groups[key]["t"])
        R = len(s) // N
        bad = s["diverged"].to_numpy().reshape(R, N)
        for b, cred in groups[key]["nci"].items():
            cred.add_ratio(_block_errors(s, STATE_BLOCKS[b][2], bad, R, N),
                           _read_columns(s, (f"nees_{b}",), R, N)[f"nees_{b}"])
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
        row["hpe_cep50"], row["hpe_r95"] = epoch_cep(np.concatenate(g["hpe_runs"], axis=0))
        for lab, (me, ms) in g["axes"].items():
            row[f"rms_{lab}"], row[f"sig_{lab}"] = np.sqrt(me.result()[0]), np.sqrt(ms.result()[0])
        for b, cred in g["nci"].items():
            row[f"nci_{b}"] = cred.result()
        rows.append(pd.DataFrame(row))
    order = [*keys, "track", "filter", "epoch", "t", "vel_err_mean", "vel_err_std", "att_err_mean", "att_err_std",
             "nees_mean", "north_err_mean", "east_err_mean", "hpe_mean", "hpe_std",
             "hpe_cep50", "hpe_r95", *(f"nees_{b}_mean" for b in BLOCKS), *(f"{c}_mean" for c in COVERAGE),
             "dvl_used", "n_runs"]
    table = pd.concat(rows, ignore_index=True)
    extra = sorted(c for c in table.columns if c.startswith("nis_"))
    extra += [c for c in table.columns if c.startswith(("rms_", "sig_", "nci_"))]
    return table[order + extra]


def epoch_cep(hpe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(CEP50, R95)`` (N,) [m] per epoch: the 50 % and 95 % quantiles (linear interpolation, as
    :func:`nespm_cli.experiments.metrics.cep`) of the horizontal errors ``hpe`` (R, N) of the runs not
    lost (NaN: left out; NaN where no run counts). The runs' errors are kept as float32 (4 bytes per
    run and epoch of one track and filter) until the quantiles are taken."""
    x = np.asarray(hpe, dtype=float)
    if not x.size:
        return np.full(x.shape[1], np.nan), np.full(x.shape[1], np.nan)
    q = np.quantile(x, [0.5, 0.95], axis=0)  # NumPy's nanquantile takes the epochs one by one (apply_along_axis)
    lost = np.isnan(x).any(axis=0)  # ... so only the epochs where a run was lost go through it
    if lost.any():
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an epoch without a run: NaN
            q[:, lost] = np.nanquantile(x[:, lost], [0.5, 0.95], axis=0)
    return q[0], q[1]


def _block_errors(s: pd.DataFrame, labels, bad: np.ndarray, R: int, N: int) -> np.ndarray:
    """(R, N, 3) one block's error components of a series chunk, NaN for the lost runs."""
    E = np.stack([s[f"e_{lab}"].to_numpy(float).reshape(R, N) for lab in labels], axis=-1)
    return np.where(bad[..., None], np.nan, E)


__all__ = ["BLOCK_COLUMNS", "COVERAGE", "Credibility", "MEAN_COLUMNS", "Moments", "epoch_cep", "epoch_table"]
