"""The innovation objective of ``nespm tune`` (``--objective innovation``): a trial scored from the
filter's own innovations alone, no truth read (docs/tuning.md, "Tuning without ground truth").

Every sensor's channel records, at each of its K measurements and in each of R runs, the innovation
ν (m,) and its covariance S (m, m) as the filter predicted it
(:class:`nespm_cli.filters.engine.SensorRecord`). For a filter whose noise model is right the
innovations are white, zero-mean and of covariance S, so

* the **likelihood**: the negative log-likelihood of the recorded measurements under the filter,
  ``½ Σ (νᵀ S⁻¹ ν + log det S)`` (without the constant ``½ m log 2π``), is smallest, in
  expectation, at the true noise (the prediction-error decomposition of the likelihood: the
  maximum-likelihood estimate of Q and R). Per row of measurement (a masked row, e.g. a lost DVL
  beam, enters with ν = 0 and a unit, uncoupled S: it adds 0 to both terms and no row);
* the **NIS**: ``Σ νᵀ S⁻¹ ν / Σ rows`` has the expectation 1 per row, its 95 % band ``χ²(D)/D`` for
  D rows (:func:`nespm_cli.experiments.metrics.nees_band`).

The NIS alone does not identify a noise level: a Q too large with an R too small can give the same
NIS (it constrains one combination of them), whereas ``log det S`` penalises every S larger than
the innovations need, so the likelihood separates them wherever S depends on them differently.

The score (:func:`innovation_score`, lower is better): ``exp(L)``, ``L`` the mean over the sensors of
each one's negative log-likelihood per row. ``exp(L)`` is a std-like quantity (for one scalar
sensor ``√S x exp(NIS/2)``) whose relative change is the change of ``L`` in nats per row, whatever
the sensors' units: the profile's relative flatness rule applies as it does to the RMSE. Each
sensor counts alike (as in the consistency objective), not by its rate.

The NIS is kept beside the score, per sensor with its distance from its band (:func:`nis_distance`),
not in it: where the space holds the level of the noise (an EKF's S scales with one factor on every
Q, R and P0), the likelihood is stationary only where ``Σ NIS = Σ rows``, so its optimum has the
NIS at its expectation already; a band penalty in the score (measured: x (1 + 100 d)) made the
search stop at settings in the band far from the likelihood's optimum (the accelerometer noise x9
on the recovery world) and the NIS alone cannot tell Q from R (docs/tuning.md, "Tuning without
ground truth").

Lost runs: without the truth only the engine's numeric flag (a non-finite state or covariance, a
speed above 50 m/s: ``FilterOutput.diverged``) can say a run is lost; the attitude rule of
:class:`nespm_cli.experiments.metrics.DivergenceRule` needs the truth and is not used here.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.experiments.metrics import innovation_terms, nees_band

SUM_KEYS = ("nis", "logdet", "rows", "count")  # each sensor's sums over the runs kept and its measurements


def sensor_sums(out, keep: np.ndarray) -> dict[str, np.ndarray]:
    """``{sensor: (4,) [Σ NIS, Σ log det S, Σ rows, measurements]}`` over the runs ``keep`` (R,) bool of
    ``out`` (a :class:`nespm_cli.filters.engine.FilterOutput`) and the measurements applied with a finite,
    positive-definite S; a filter that reports no innovation (NaN S) has zeros. Reads ``out.sensors``
    only (:func:`nespm_cli.experiments.metrics.innovation_terms`: the rule a run's ``nll_<sensor>`` uses)."""
    res = {}
    keep = np.asarray(keep, dtype=bool)
    for name, rec in getattr(out, "sensors", {}).items():
        nis, logdet, rows, ok = innovation_terms(rec)
        ok = ok & keep[:, None]
        res[name] = np.array([np.sum(nis[ok]), np.sum(logdet[ok]), np.sum(rows[ok]), np.sum(ok)], dtype=float)
    return res


def add_sums(total: dict, more: dict) -> dict:
    """``total`` with each sensor's sums of ``more`` added (both ``{sensor: (4,)}``, :func:`sensor_sums`)."""
    out = {k: np.array(v, dtype=float) for k, v in total.items()}
    for k, v in more.items():
        out[k] = out.get(k, np.zeros(len(SUM_KEYS))) + np.asarray(v, dtype=float)
    return out


def per_sensor(sums: dict) -> dict[str, dict[str, float]]:
    """``{sensor: {"nll", "nis", "logdet", "rows"}}`` per row of measurement: the negative log-likelihood
    ``½ (Σ NIS + Σ log det S) / Σ rows``, the NIS and the log det S per row; the sensors with rows only."""
    res = {}
    for k, (nis, logdet, rows, _) in sums.items():
        if rows > 0:
            res[k] = {"nll": 0.5 * (nis + logdet) / rows, "nis": nis / rows, "logdet": logdet / rows, "rows": rows}
    return res


def likelihood(sums: dict) -> float:
    """``L``: the mean over the sensors of their negative log-likelihood per row (:func:`per_sensor`); inf
    without any innovation."""
    p = per_sensor(sums)
    return float(np.mean([v["nll"] for v in p.values()])) if p else float("inf")


def outside(a: float, lo: float, hi: float) -> float:
    """The log-distance of ``a`` (> 0) outside the band ``[lo, hi]``: ``log(a/hi)`` above, ``log(lo/a)``
    below, 0 inside (the NEES and NIS bands' one rule)."""
    return float(np.log(a / hi)) if a > hi else float(np.log(lo / a)) if a < lo else 0.0


def nis_distance(sums: dict) -> float:
    """The mean over the sensors of the log-distance of the NIS per row outside its 95 % band ``χ²(D)/D``
    (D the sensor's rows; 0 inside); inf without any innovation."""
    p = per_sensor(sums)
    if not p:
        return float("inf")
    return float(np.mean([outside(v["nis"], *nees_band(1, int(v["rows"]))) for v in p.values()]))


def innovation_score(sums: dict) -> float:
    """``exp(L)`` (:func:`likelihood`); inf without any innovation (a filter with no covariance). Lower
    is better."""
    L = likelihood(sums)
    return float(np.exp(L)) if np.isfinite(L) else float("inf")


def innovation_summary(sums: dict) -> dict[str, float]:
    """The numbers kept beside a trial's score: ``innovation_nll`` (L), ``nis_distance`` (d) and each
    sensor's ``nis_<sensor>`` (per row: 1 when consistent) and ``nll_<sensor>``."""
    out = {"innovation_nll": likelihood(sums), "nis_distance": nis_distance(sums)}
    for k, v in per_sensor(sums).items():
        out[f"nis_{k}"] = v["nis"]
        out[f"nll_{k}"] = v["nll"]
    return out


__all__ = ["SUM_KEYS", "add_sums", "innovation_score", "innovation_summary", "likelihood",
           "nis_distance", "outside", "per_sensor", "sensor_sums"]
