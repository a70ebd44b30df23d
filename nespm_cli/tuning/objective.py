"""The objectives of ``nespm tune``: one trial's settings of one filter run on the training
realizations, scored (lower is better; docs/tuning.md).

A trial runs the library's batched Monte Carlo in-process (:func:`nespm_cli.experiments.mc.simulate`,
every run of a track in one batch), on the same realizations for every trial and every filter
(common random numbers). Its statistics, over every run of every tuning track:

* ``rmse``: the velocity RMSE [m/s] (eq 50 over the runs not lost) with the papers' 12 states; with
  position in the state the horizontal RMS position error [m];
* ``anees_<block>`` (N,) per epoch, the mean over runs of each block's 3-dof NEES; ``anis_<sensor>``
  the mean NIS of each sensor (expectation: its dimension m);
* ``lost``: the fraction of runs lost (:func:`nespm_cli.experiments.metrics.divergence`).

The objectives (:data:`OBJECTIVES`):

* ``rmse``: the RMSE;
* ``consistency``: the mean over blocks and sensors, and over epochs after the first, of
  ``log(ANEES / 3)²`` (``log(ANIS / m)²``): 0 for a consistent filter, a factor too large and the
  same factor too small count alike;
* ``rmse-consistent`` (the default): the RMSE x ``(1 + 100 d)``, ``d`` the log-distance of the
  filter's ANEES (the report's: velocity and attitude, 6 dof, over all epochs and runs) outside
  its 95 % band ``χ²(6R)/R`` (:func:`nespm_cli.experiments.metrics.nees_band`): the most accurate
  settings whose ANEES lies in its band (1 % outside doubles the score); outside it the penalty
  grows smoothly, so the search finds the band;
* ``innovation``: no truth read: the filter's innovation likelihood (:mod:`nespm_cli.tuning.innovation`;
  the NIS per sensor against its χ² band is kept beside it, not scored), from ``innovation`` (each sensor's sums of NIS,
  log det S and rows over the runs the engine did not flag) and ``lost_numeric`` alone.

The level (``--level``, :data:`LEVELS`): scaling every variance of Q, R and P0 by one factor ``c``
leaves an EKF's gain, estimates and errors unchanged and divides its NEES by ``c`` (the Kalman
recursion is homogeneous in (P0, Q, R)); a sigma-point filter changes only through its spread
(``√c`` wider), negligibly at the papers' alpha. So with ``rmse-consistent`` the default ``tracks``
searches the *shape* of the noise (the ratios of the factors) for accuracy and sets its *level* in
closed form (:func:`fit_level`): ``c`` puts the geometric mean over the training tracks of each
track's ANEES (6 dof) at its expectation 6 — every track counts alike, a track a factor too
overconfident and one the same factor too conservative cancel (the log rule of ``consistency``),
so a few turn-rich tracks do not set the level for all. The trial's score is then its RMSE, and
its written values are its factors x ``√c`` (:func:`leveled`; kept within the noise-scale limits 1e-3
to 1e3 that ``--config tuned.toml`` accepts, a clipped factor said in ``tuned.toml`` and the tune
report). ``off``: the band penalty above on the factors as searched.

A trial that loses a run scores ``LOST + lost fraction`` (above every trial that loses none: lost
runs are ranked worst, and fewer lost is better); with ``innovation`` a run is lost when the engine
flags it (``lost_numeric``: the attitude rule needs the truth).

On tracks without ground truth (a track spec without ``[gt]``, docs/data.md) only ``innovation`` scores:
:func:`trial_statistics` then holds the filter's outputs alone (``truth`` False: no RMSE, NEES or truth-based
loss), and :func:`summary` keeps only the innovation statistics.
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from nespm_cli.data.corruption import true_biases
from nespm_cli.experiments.metrics import (STAT_BLOCKS, block_statistics, divergence, epoch_nis, nees_band,
                                          run_metrics)
from nespm_cli.experiments.spec import Spec
from nespm_cli.filters.options import SCALE_LIMITS
from nespm_cli.tuning.innovation import add_sums, innovation_score, innovation_summary, outside, sensor_sums

OBJECTIVES = ("rmse-consistent", "rmse", "consistency", "innovation")
LEVELS = ("tracks", "off")  # rmse-consistent: the level fitted over the tracks (default), or searched as the factors
LOST = 1e6  # the score of a trial that lost runs: LOST + the fraction lost
BAND_PENALTY = 100.0  # rmse-consistent: x (1 + BAND_PENALTY x the log-distance outside the band)


def trial_spec(spec: Spec, name: str, values: dict) -> Spec:
    """``spec`` running filter ``name`` alone with the options ``values`` ({key: value}) over its own
    (the study's other options of that filter stay unless a value replaces them)."""
    keep = tuple(o for o in spec.filter_options if o[0] == name and o[1] not in values)
    opts = keep + tuple((name, k, float(v)) for k, v in values.items())
    return dataclasses.replace(spec, filters=(name,), smooth=(), filter_options=opts)


REUSE_RUNS = 200  # trials keep their inputs in memory up to this many runs x tracks (~40 MB per 20 runs of 400 s)


def trial_statistics(spec: Spec, name: str, values: dict, reuse: dict | None = None) -> dict:
    """Run filter ``name`` with the options ``values`` on every run of every track of ``spec``
    (validated); return the statistics the objectives use: ``rmse``, ``lost`` (fractions),
    ``anees`` ({block: (N,) per epoch over every track's epochs}), ``anis`` ({sensor: (N,)}),
    ``mean_anees`` ({block: float}), ``runs`` (total), and from the filter's outputs alone (no truth):
    ``innovation`` ({sensor: (4,)}, :func:`nespm_cli.tuning.innovation.sensor_sums` over the runs the
    engine did not flag) and ``lost_numeric`` (the fraction it flagged). ``reuse``: a dict kept across the trials of one
    training spec (:func:`nespm_cli.experiments.mc.simulate`): the realizations are built once, not
    per trial (the same arrays: bit-identical scores). ``truth``: whether the tracks have a ground truth;
    without one (:func:`nespm_cli.experiments.spec.has_truth`) only ``innovation``, ``lost_numeric``,
    ``anis``, ``dims``, ``runs_per_track`` and ``truth`` are given."""
    from nespm_cli.experiments.mc import simulate

    s = trial_spec(spec, name, values)
    runs = np.arange(spec.runs)
    sse, n, lost, total = 0.0, 0, 0, 0
    nees: dict = {b: [] for b in STAT_BLOCKS}
    nees6 = []  # the report's NEES (velocity and attitude, 6 dof) of the runs kept, per run
    tracks6 = []  # each track's ANEES (6 dof): mean over its runs kept and its epochs
    nis: dict = {}
    dims: dict = {}
    inn: dict = {}  # the innovation objective's sums: the filter's outputs only
    flagged = 0
    for number in spec.tracks:
        results, truth, real = simulate(s, number, runs, (name,), reuse=reuse)
        out, err, _ = results[name]
        numeric = np.asarray(out.diverged, dtype=bool)
        inn = add_sums(inn, sensor_sums(out, ~numeric))
        flagged += int(numeric.sum())
        e = truth.epoch_index
        t_rel = truth.t[e] - truth.t[e[0]]
        if err is None:  # no ground truth: the filter's outputs alone (the NIS per epoch of the runs kept)
            for k, v in epoch_nis(out, t_rel).items():
                nis.setdefault(k[len("nis_"):], []).append(np.where(numeric[:, None], np.nan, v)[:, 1:])
            dims.update({sname: rec.nu.shape[-1] for sname, rec in out.sensors.items()})
            continue
        lost_runs, _, _ = divergence(err, out.diverged, t_rel, spec.divergence)
        m = run_metrics(err, lost_runs)
        col = "sse_hpe" if spec.filter_config.layout.has("pos") else "sse_vel"
        ok = ~lost_runs
        sse += float(np.sum(m[col][ok]))
        n += int(np.sum(m["n_samples"][ok]))
        lost += int(lost_runs.sum())
        total += len(runs)
        bias = true_biases(real, truth.t[e] - truth.t[0]) if spec.imu == "synthetic" else None
        stats = block_statistics(out, truth.v_n[e], truth.C_bn[e], truth.pos[e], bias)
        nees6.append(np.asarray(err.nees, float)[ok])
        with np.errstate(all="ignore"):
            tracks6.append(float(np.nanmean(nees6[-1])) if nees6[-1].size else float("nan"))
        for b in STAT_BLOCKS:
            nees[b].append(np.where(ok[:, None], stats[f"nees_{b}"], np.nan)[:, 1:])
        for k, v in epoch_nis(out, t_rel).items():
            nis.setdefault(k[len("nis_"):], []).append(np.where(ok[:, None], v, np.nan)[:, 1:])
        for sname, rec in out.sensors.items():
            dims[sname] = rec.nu.shape[-1]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        # an epoch no kept run reaches (or no update of a sensor) is NaN, the scores skip it: no warning
        warnings.simplefilter("ignore", RuntimeWarning)
        anees = {b: np.nanmean(np.concatenate(v, axis=1), axis=0) for b, v in nees.items()
                 if v and np.isfinite(np.concatenate(v, axis=1)).any()}
        mean_anees = {b: float(np.nanmean(np.concatenate(nees[b], axis=1))) for b in anees}
        anis = {k: np.nanmean(np.concatenate(v, axis=1), axis=0) for k, v in nis.items()
                if np.isfinite(np.concatenate(v, axis=1)).any()}
    if total == 0:  # no ground truth (simulate gave no errors): no truth statistic at all
        return {"truth": False, "anis": anis, "dims": dims, "runs_per_track": len(runs), "innovation": inn,
                "lost_numeric": flagged / max(len(runs) * len(spec.tracks), 1)}
    return {"truth": True, "rmse": float(np.sqrt(sse / n)) if n else float("nan"), "lost": lost / max(total, 1), "anees": anees,
            "mean_anees": mean_anees, "anis": anis, "dims": dims, "runs": total - lost,
            "runs_per_track": len(runs), "anees6_tracks": tracks6, "innovation": inn,
            "lost_numeric": flagged / max(total, 1),
            "anees6": float(np.nanmean(np.concatenate([x.ravel() for x in nees6]))) if n else float("nan")}


def consistency(stats: dict) -> float:
    """Mean over blocks and sensors, and over their epochs, of ``log(ANEES/3)²`` and ``log(ANIS/m)²``."""
    parts = []
    for v in stats["anees"].values():
        parts.append(np.nanmean(np.log(np.asarray(v) / 3.0) ** 2))
    for k, v in stats["anis"].items():
        parts.append(np.nanmean(np.log(np.asarray(v) / stats["dims"][k]) ** 2))
    parts = [p for p in parts if np.isfinite(p)]
    return float(np.mean(parts)) if parts else float("inf")


def band_distance(stats: dict) -> float:
    """Log-distance of the 6-dof ANEES (over the runs kept and every epoch) outside its 95 % band (0: inside;
    inf without a covariance)."""
    a = stats["anees6"]
    if not np.isfinite(a):
        return float("inf")
    return outside(a, *nees_band(6, max(int(stats["runs"]), 1)))


def fit_level(stats: dict) -> float:
    """The variance factor ``c`` on every Q, R and P0 that puts the geometric mean over the tracks of
    each track's ANEES (6 dof, ``stats["anees6_tracks"]``) at 6: ``c = (Π aᵢ)^(1/n) / 6``; 1.0 where a
    track has no finite positive ANEES (no covariance, or every run lost)."""
    a = np.asarray(stats.get("anees6_tracks", ()), float)
    if a.size == 0 or not np.all(np.isfinite(a) & (a > 0)):
        return 1.0
    return float(np.exp(np.mean(np.log(a))) / 6.0)


def leveled(values: dict, bases: dict, c: float) -> dict:
    """``values`` ({key: std factor}) with every key of ``bases`` ({key: the factor it has when not
    searched}) multiplied by ``√c`` (a std factor; ``c`` scales the variances) and kept within
    :data:`~nespm_cli.filters.options.SCALE_LIMITS`, the factors ``--filter-option`` and so ``--config tuned.toml``
    accept (a factor the level pushes past a limit is run and written at it: :func:`beyond_limits` names it);
    other keys as given."""
    s = float(np.sqrt(c))
    lo, hi = SCALE_LIMITS
    out = {k: float(v) for k, v in values.items()}
    for k, base in bases.items():
        out[k] = min(max(float(out.get(k, base)) * s, lo), hi)
    return out


def beyond_limits(values: dict, bases: dict, c: float) -> dict:
    """``{key: factor x √c}`` of the keys :func:`leveled` clipped to ``SCALE_LIMITS`` ({} for none)."""
    s = float(np.sqrt(c))
    lo, hi = SCALE_LIMITS
    raw = {k: float(values.get(k, base)) * s for k, base in bases.items()}
    return {k: v for k, v in raw.items() if not lo <= v <= hi}


def score(stats: dict, objective: str, level: str = "off") -> float:
    """The trial's score under ``objective`` (:data:`OBJECTIVES`) and ``level`` (:data:`LEVELS`; it acts
    on ``rmse-consistent`` only); lower is better. ``innovation`` reads ``innovation`` and
    ``lost_numeric`` only; another objective without a ground truth (``stats["truth"]`` False) is a
    ValueError (:func:`nespm_cli.tuning.spec.check` refuses it first, in one line)."""
    if objective != "innovation" and not stats.get("truth", True):
        raise ValueError(f"objective {objective!r} needs the ground truth; these tracks have none")
    if objective == "innovation":
        lost = float(stats["lost_numeric"])
        return LOST + lost if lost > 0 else innovation_score(stats["innovation"])
    if stats["lost"] > 0 or not np.isfinite(stats["rmse"]):
        return LOST + float(stats["lost"])
    if objective == "rmse" or (objective == "rmse-consistent" and level == "tracks"):
        return stats["rmse"]
    if objective == "consistency":
        return consistency(stats)
    return stats["rmse"] * (1.0 + BAND_PENALTY * band_distance(stats))


def summary(stats: dict) -> dict:
    """The trial's numbers kept beside its score (trials.parquet): ``rmse``, ``lost``, ``consistency``,
    ``band_distance``, ``level`` (:func:`fit_level`), ``anees_<block>`` (mean over runs and epochs), ``in_band_<block>`` (the
    fraction of epochs whose ANEES lies in its per-epoch band χ²(3R)/R), ``anis_<sensor>``, and the
    innovation objective's (:func:`nespm_cli.tuning.innovation.innovation_summary`, ``lost_numeric``). Without a
    ground truth: the innovation objective's numbers and ``anis_<sensor>`` only."""
    if not stats.get("truth", True):
        out = {"lost_numeric": stats["lost_numeric"], **innovation_summary(stats["innovation"]),
               **{f"anis_{k}": float(np.nanmean(v)) for k, v in stats["anis"].items()}}
        return {k: float(v) for k, v in out.items()}
    out = {"rmse": stats["rmse"], "lost": stats["lost"], "consistency": consistency(stats),
           "anees": stats["anees6"], "band_distance": band_distance(stats), "level": fit_level(stats),
           "lost_numeric": stats["lost_numeric"], **innovation_summary(stats["innovation"])}
    lo, hi = nees_band(3, max(int(stats["runs_per_track"]), 1))  # each epoch's ANEES: one track's runs
    for b, v in stats["anees"].items():
        out[f"anees_{b}"] = stats["mean_anees"][b]
        out[f"in_band_{b}"] = float(np.mean((v >= lo) & (v <= hi)))
    for k, v in stats["anis"].items():
        out[f"anis_{k}"] = float(np.nanmean(v))
    return {k: float(v) for k, v in out.items()}


__all__ = ["BAND_PENALTY", "LEVELS", "LOST", "REUSE_RUNS", "OBJECTIVES", "band_distance", "beyond_limits", "consistency",
           "fit_level", "leveled", "score", "summary", "trial_spec", "trial_statistics"]
