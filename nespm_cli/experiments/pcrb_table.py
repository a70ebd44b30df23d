"""The posterior Cramér–Rao bound of a Monte Carlo study's realizations, and each filter's efficiency.

:func:`track_bound` gives the PCRB (:func:`nespm_cli.filters.pcrb.pcrb`) of the runs of one track
from the truth and the *true* statistics of the realizations, whatever the filters were told:

* initial error: the corruption's std (velocity, misalignment and heading, position), the biases'
  std times the run's first schedule factor; the biases are random constants (no process noise),
  scaled at a segment boundary by the ratio of the factors with ``--dynamic-bias segment``;
* IMU white noise: the corruption's per-sample std times the segment's factor, as the filters'
  PSD ``std² dt_imu`` added once per span (``--time-update imu``: once per IMU step);
* each sensor of the suite: its synthetic noise std (``std``, never its ``r_std``), times the factor
  of its ``noise_schedule`` at each measurement (:meth:`Sensor.noise_factor`, a dynamic one per run
  from the run's own stream: R(t), passed to ``pcrb(r_factors=)``), and its times, outages, dropouts
  and lost components, from the same streams as the runs (``build_channel``). Outliers are left out:
  the bound is that of the Gaussian part.

**What is averaged.** The runs may differ in what the bound depends on (dropouts, the dynamic
schedule's factors). The bound is computed per run, conditioned on that run's pattern, and the
bound of the study's mean square error is the mean of the runs' bounds: ``E[J(pattern)⁻¹]``, not
``(E[J])⁻¹`` (the information averaged first, Hernandez et al.'s information-reduction form),
which by Jensen is lower still. Conditioning on the pattern can only lower a Bayesian bound, so
both are valid; ours is the tighter one, and it pairs with the RMSE over the same runs. Identical
patterns are computed once (with the constant schedule and no dropout: one Riccati recursion).

**Left out (the bound stays valid, only looser).** A sensor's constant ``bias`` and ``scale``
errors are treated as known (an estimator told them can only do better). The position block is
bounded only where the layout holds it.

**Unknown.** A recorded IMU or a recorded sensor has no known noise statistics: the bound is then
not a number, and :func:`unknown_reason` says why (the tables and the report print that).
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import pandas as pd

from nespm_cli.data.corruption import draw, segment_index
from nespm_cli.data.tracks import resolve_data_dir
from nespm_cli.experiments.spec import Spec, track_inputs
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters.pcrb import pcrb
from nespm_cli.nav.state import BLOCKS, NavState, parse_layout
from nespm_cli.sensors.channels import build_channel

#: the blocks whose efficiency is reported: (block, error column of the epochs table, components)
EFFICIENCY_BLOCKS = (("vel", "vel_err", None), ("att", "att_err", None), ("hpos", "hpe", ("dpN", "dpE")))
#: the blocks reported from their per-axis RMS (``--save-series axes``)
AXES_BLOCKS = ("pos", "ba", "bg")
#: the blocks averaged only from CONVERGED_S after the first epoch: the biases, whose bound falls by decades in
#: the first seconds (the accelerometer bias's variance to 1/5400 of its prior in 10 s on tracks 5 and 6)
CONVERGED_BLOCKS = ("ba", "bg")
CONVERGED_S = 10.0  # [s]
RUN_BLOCK = 256  # patterns per Riccati batch (memory: RUN_BLOCK x N x n floats of diagonal)
RUNS_PER_PASS = 2000  # runs whose channels are built at once (R x K x m floats per sensor)


def unknown_reason(spec: Spec) -> str | None:
    """Why the bound of ``spec`` is unknown (a recorded IMU or sensor; on the embedded tracks their DVL, generated
    in code with one noise draw for every run), or None when it is computable."""
    if spec.imu == "recorded":
        return "the IMU is recorded: its noise statistics are unknown"
    recorded = [s.name for s in sensor_suite(spec) if s.opt.source == "recorded"]
    if recorded and resolve_data_dir(spec.data_dir) is None:  # the embedded tracks: generated in code
        return (f"{', '.join(recorded)} {'is' if len(recorded) == 1 else 'are'} the embedded track's, generated in code "
                "with one noise draw that every run shares: the runs do not sample its noise")
    if recorded:
        return f"{', '.join(recorded)} {'is' if len(recorded) == 1 else 'are'} recorded: the noise statistics are unknown"
    return None


def bound_layout(spec: Spec):
    """The layout of the bound: the study's, with the bias blocks (random in every realization) added."""
    lay = parse_layout(spec.filter_config.state)
    return parse_layout(",".join(dict.fromkeys(lay.blocks + ("ba", "bg"))))


def true_sensor(sensor):
    """A copy of ``sensor`` whose filter noise is its synthetic noise (``r_std`` unset)."""
    out = type(sensor)(dataclasses.replace(sensor.opt, r_std=None))
    out.name = sensor.name
    return out


def track_bound(spec: Spec, number: int, runs, within_span: bool = True) -> tuple[np.ndarray, list[str]]:
    """``(diag, labels)``: the PCRB's variances (R, N, n) of ``runs`` of track ``number`` at the GT
    epochs [SI units²] and the n component labels (:data:`nespm_cli.nav.state.BLOCKS`).
    ``within_span``: :func:`nespm_cli.filters.pcrb.noise_within_span` (False: the filters' form)."""
    runs = np.asarray(runs, dtype=np.int64)
    lay = bound_layout(spec)
    track, truth = track_inputs(spec, number)
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    c = spec.corruption
    real = draw(spec.seed, number, runs, float(t_rel[-1]), c)
    channels = [build_channel(true_sensor(s), track, truth, spec.seed, number, runs, clean=True)
                for s in sensor_suite(spec)]
    fa, fg = real.acc_factors, real.gyro_factors  # (R, S)
    factors = schedule_factors(channels, spec.seed, number, runs)
    # the patterns: what the bound of a run depends on
    key = ([fa, fg] + [ch.ok for ch in channels] + [np.isnan(ch.z).reshape(len(runs), -1) for ch in channels]
           + [f for f in factors if f is not None])
    _, first, inverse = np.unique(np.concatenate([np.asarray(k, float).reshape(len(runs), -1) for k in key], axis=1),
                                  axis=0, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    S = fa.shape[1]
    mis = np.deg2rad(c.misalignment_deg)
    head = np.deg2rad(c.heading_deg) if c.heading_deg is not None else mis
    dt_imu = float(np.median(truth.dt))
    blocks = {"pos": (np.array([c.pos_h_std, c.pos_h_std, c.pos_v_std]) ** 2, None),
              "vel": (np.array([c.vel_h_std, c.vel_h_std, c.vel_v_std]) ** 2, None),
              "att": (np.array([mis, mis, head]) ** 2, None)}
    nav0 = NavState(truth.pos[e[0]][None], truth.v_n[e[0]][None], truth.C_bn[e[0]][None], np.zeros((1, 3)),
                    np.zeros((1, 3)))
    out = np.empty((len(first), len(e), lay.n))
    for lo in range(0, len(first), RUN_BLOCK):
        idx = first[lo:lo + RUN_BLOCK]
        pa, pg = fa[idx], fg[idx]
        p0 = []
        for b in lay.blocks:
            if b in blocks:
                p0.append(np.broadcast_to(blocks[b][0], (len(idx), 3)))
            elif b == "ba":
                p0.append((c.acc_bias * pa[:, :1]) ** 2 * np.ones(3))
            else:
                p0.append((c.gyro_bias * pg[:, :1]) ** 2 * np.ones(3))
        P0 = np.einsum("bi,ij->bij", np.concatenate(p0, axis=1), np.eye(lay.n))
        process = _process(lay, c, pa, pg, S, dt_imu)
        chs = [dataclasses.replace(ch, z=ch.z[idx], ok=ch.ok[idx]) for ch in channels]
        r_factors = None if all(f is None for f in factors) else [None if f is None else f[idx] for f in factors]
        res = pcrb(lay, nav0, truth.f_b, truth.w_ib_b, truth.dt, e, chs, P0, process,
                   per_step=spec.filter_config.time_update == "imu", within_span=within_span, r_factors=r_factors)
        out[lo:lo + len(idx)] = res.diag
    labels = [lab for b in lay.blocks for lab in BLOCKS[b][2]]
    return out[inverse], labels


def schedule_factors(channels: list, seed: int, number: int, runs: np.ndarray) -> list:
    """Per channel, (R, K) the factor of its sensor's ``noise_schedule`` on the noise std at each of its
    K measurement times in each run (:meth:`nespm_cli.sensors.source.Sensor.noise_factor`: the factor the
    realizations draw with), or None: no schedule (R as the sensor's model gives it) or a recorded sensor."""
    out = []
    for ch in channels:
        opt = ch.sensor.opt
        if getattr(opt, "source", "synthetic") != "synthetic" or not getattr(opt, "noise_schedule", ""):
            out.append(None)
            continue
        f = ch.sensor.noise_factor(ch.t, seed, number, np.asarray(runs, dtype=np.int64))
        out.append(None if f is None else np.asarray(f, dtype=float))
    return out


def _process(lay, c, pa: np.ndarray, pg: np.ndarray, S: int, dt_imu: float):
    """The true ``process(t0, t1)`` of :func:`nespm_cli.filters.pcrb.pcrb` for patterns with factors
    ``pa``, ``pg`` (B, S): white noise per segment, bias steps with ``dynamic_bias segment``."""
    vel, att = lay.slice("vel"), lay.slice("att")
    ba, bg = lay.slice("ba"), lay.slice("bg")
    T = c.segment_s
    edges = np.arange(S + 1) * T
    edges[-1] = np.inf
    qa, qg = (c.acc_noise * pa) ** 2 * dt_imu, (c.gyro_noise * pg) ** 2 * dt_imu  # PSD per segment (B, S)
    B, n = pa.shape[0], lay.n

    def process(t0: float, t1: float):
        w = np.clip(np.minimum(edges[1:], t1) - np.maximum(edges[:-1], t0), 0.0, None)  # (S,) time per segment
        q = np.zeros((B, n))
        q[:, vel] = (qa @ w)[:, None]
        q[:, att] = (qg @ w)[:, None]
        D = None
        if c.dynamic_bias == "segment":
            s0, s1 = segment_index(np.array([t0, t1]), T, S)
            if s0 != s1:
                D = np.ones((B, n))
                D[:, ba] = (pa[:, s1] / pa[:, s0])[:, None]
                D[:, bg] = (pg[:, s1] / pg[:, s0])[:, None]
        return q, D

    return process


def unknown_columns(spec: Spec, number: int) -> pd.DataFrame:
    """:func:`bound_columns` where the bound is unknown: every ``pcrb_<label>`` NaN."""
    N = len(track_inputs(spec, number)[1].epoch_index)
    labels = [lab for b in bound_layout(spec).blocks for lab in BLOCKS[b][2]]
    return pd.DataFrame({"epoch": np.arange(N), **{f"pcrb_{lab}": np.full(N, np.nan) for lab in labels}})


def bound_columns(spec: Spec, number: int, runs) -> pd.DataFrame:
    """Per GT epoch of track ``number``: ``pcrb_<label>`` the runs' mean PCRB variance of each
    component [SI units²] (NaN, every one, where :func:`unknown_reason` says the bound is unknown)."""
    if unknown_reason(spec) is not None:
        return unknown_columns(spec, number)
    runs = np.asarray(runs, dtype=np.int64)
    total, labels = 0.0, []
    for lo in range(0, len(runs), RUNS_PER_PASS):  # the channels of RUNS_PER_PASS runs in memory at a time
        diag, labels = track_bound(spec, number, runs[lo:lo + RUNS_PER_PASS])
        total = total + diag.sum(axis=0)
    mean = total / len(runs)
    return pd.DataFrame({"epoch": np.arange(mean.shape[0]), **{f"pcrb_{lab}": mean[:, i] for i, lab in enumerate(labels)}})


def add_pcrb(epochs: pd.DataFrame, cells: list, keys: tuple = ()) -> tuple[pd.DataFrame, dict]:
    """``epochs`` with the ``pcrb_<label>`` columns of every cell and track (the same in every
    filter's rows; runs 0 .. runs-1) and ``{"status", "reason", "seconds"}`` for the manifest."""
    t0 = time.perf_counter()
    parts = []
    reasons = set()
    for cell in cells:
        spec = cell.spec
        why = unknown_reason(spec)
        if why:
            reasons.add(why)
        kv = dict(cell.columns)
        for n in spec.tracks:
            try:
                df = bound_columns(spec, int(n), np.arange(spec.runs))
            except Exception as exc:  # e.g. a plugin sensor's model: the study's results stay, the bound says why
                if os.environ.get("NESPM_DEBUG"):
                    raise
                why = f"the bound could not be computed on track {n} ({exc.__class__.__name__}: {' '.join(str(exc).split())[:120]})"
                reasons.add(why)
                df = unknown_columns(spec, int(n))
            df["track"] = n
            for k in keys:
                df[k] = kv[k]
            parts.append(df)
    table = pd.concat(parts, ignore_index=True)
    on = [*keys, "track", "epoch"]
    for k in on:
        table[k] = table[k].astype(epochs[k].dtype)
    out = epochs.merge(table, on=on, how="left")
    status = {"status": "unknown" if reasons else "computed", "reason": "; ".join(sorted(reasons)) or None,
              "seconds": round(time.perf_counter() - t0, 3)}
    return out, status


def window_mask(t: np.ndarray, epoch: np.ndarray, block: str, converged_s: float = CONVERGED_S) -> np.ndarray:
    """The epochs a block's efficiency averages over (docs/pcrb.md, "Efficiency in the report"): every GT
    epoch after t = 0 (``epoch > 0``, the t = 0 rule of docs/report.md), and for a bias block
    (:data:`CONVERGED_BLOCKS`) only those at least ``converged_s`` [s] after the first epoch ``t`` [s]."""
    t, epoch = np.asarray(t, float), np.asarray(epoch)
    mask = epoch > 0
    if block in CONVERGED_BLOCKS and mask.any():
        mask &= t - t[np.argmin(epoch)] >= converged_s - 1e-9
    return mask


def window_text(block: str, converged_s: float = CONVERGED_S) -> str:
    """The window of :func:`window_mask` in words, for the tables: ``t > 0`` or ``t ≥ 10 s``."""
    return f"t ≥ {converged_s:g} s" if block in CONVERGED_BLOCKS else "t > 0"


def efficiency(epochs: pd.DataFrame, keys: tuple = (), runs: pd.DataFrame | None = None,
               converged_s: float = CONVERGED_S) -> pd.DataFrame:
    """Per (keys, track, filter, block): the efficiency over the epochs of :func:`window_mask` (after t = 0;
    a bias block from ``converged_s`` on: its bound falls by decades in the first seconds, and an average
    over them is the prior's, not the filter's).

    ``rmse`` the root of the block's mean square error over the runs (not lost) and the window's epochs
    (the velocity error norm as eq 50, the attitude's Euler-angle norm, the horizontal position; with
    ``--save-series axes`` also the bias and 3-D position blocks from their per-axis RMS), ``root_pcrb``
    the root of the bound's trace of that block averaged over the same epochs, ``efficiency`` =
    rmse / root_pcrb (1: the filter reaches the bound; below 1 only by sampling, or for a smoothed
    ``-rts`` result, which the filtering bound does not bound); NaN where the bound is unknown or the
    block absent. ``window`` says which epochs (:func:`window_text`), ``epochs`` how many.

    The sampling interval: ``runs`` holds per (keys, track, filter, run) ``mse_<block>``, each run's mean
    square error of the block over the same window (:func:`nespm_cli.reports.efficiency_runs.run_mse`);
    the runs are independent, so the MSE's standard error is their sample std / √R and, to first order,
    ``rmse_3sigma`` = 3 · se / (2 · rmse) [the block's SI unit], ``efficiency_lo`` / ``efficiency_hi`` =
    (rmse ∓ rmse_3sigma) / root_pcrb; NaN without ``runs`` or with fewer than 2 runs."""
    rows = []
    blocks = list(EFFICIENCY_BLOCKS) + [(b, None, BLOCKS[b][2]) for b in AXES_BLOCKS]
    group = [*keys, "track", "filter"]
    spread = {}
    if runs is not None and not runs.empty:
        for key, g in runs.groupby(group, sort=False):
            spread[key if isinstance(key, tuple) else (key,)] = g
    for key, g in epochs.groupby(group, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        g = g.sort_values("epoch")
        for block, col, comps in blocks:
            labels = comps or BLOCKS[block][2]
            cols = [f"pcrb_{lab}" for lab in labels]
            if col is not None:
                if f"{col}_std" not in g:
                    continue
                ms = g[f"{col}_mean"] ** 2 + g[f"{col}_std"] ** 2  # population std: the mean square over runs
            elif all(f"rms_{lab}" in g for lab in labels):
                ms = sum(g[f"rms_{lab}"] ** 2 for lab in labels)
            else:
                continue
            w = window_mask(g["t"].to_numpy(), g["epoch"].to_numpy(), block, converged_s)
            mse = float(ms.to_numpy(float)[w].mean()) if w.any() else np.nan
            bound = (float(g[cols].sum(axis=1, min_count=len(cols)).to_numpy(float)[w].mean())
                     if w.any() and all(c in g for c in cols) else np.nan)
            rmse = float(np.sqrt(mse))
            root = float(np.sqrt(bound)) if np.isfinite(bound) else np.nan
            eff = rmse / root if root and np.isfinite(root) else np.nan
            half = _rmse_3sigma(spread.get(key), block, rmse)
            rows.append({**dict(zip(group, key)), "block": block, "window": window_text(block, converged_s),
                         "epochs": int(w.sum()), "rmse": rmse, "rmse_3sigma": half, "root_pcrb": root,
                         "efficiency": eff, "efficiency_lo": (rmse - half) / root if np.isfinite(eff) else np.nan,
                         "efficiency_hi": (rmse + half) / root if np.isfinite(eff) else np.nan})
    return pd.DataFrame(rows, columns=[*group, "block", "window", "epochs", "rmse", "rmse_3sigma", "root_pcrb",
                                       "efficiency", "efficiency_lo", "efficiency_hi"])


def _rmse_3sigma(runs: pd.DataFrame | None, block: str, rmse: float) -> float:
    """3 standard errors of ``rmse`` from the runs' own mean square errors ``mse_<block>`` (NaN: none)."""
    col = f"mse_{block}"
    if runs is None or col not in runs or not np.isfinite(rmse) or rmse <= 0:
        return np.nan
    x = runs[col].to_numpy(float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return np.nan
    return float(3.0 * x.std(ddof=1) / np.sqrt(x.size) / (2.0 * rmse))


__all__ = ["CONVERGED_BLOCKS", "CONVERGED_S", "EFFICIENCY_BLOCKS", "add_pcrb", "bound_columns", "bound_layout",
           "efficiency", "schedule_factors", "track_bound", "true_sensor", "unknown_columns", "unknown_reason",
           "window_mask", "window_text"]
