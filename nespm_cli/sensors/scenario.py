"""Sensor noise scenarios: a noise schedule (the white noise std varying in time) and an outlier
model (a fraction of samples with heavy-tailed errors), the ``noise_schedule`` and ``outliers``
options of every sensor that uses the common synthesis (docs/sensors.md, "Noise scenarios").

Schedules (``noise_schedule``; times in seconds since the first epoch, factors > 0 multiplying
the sensor's ``std``):

* ``step:T0=F0,T1=F1,...``: factor ``Fi`` from ``Ti`` until the next knot (before ``T0``: ``F0``);
* ``ramp:T0=F0,T1=F1,...``: linear between the knots, held constant outside them;
* ``dynamic:SEG:LO:HI``: segments of ``SEG`` s from t = 0, each with a factor drawn U[LO, HI] per
  run (as the IMU's ``--schedule dynamic``), from the sensor's :data:`SCHEDULE_SUB` sub-stream.

Outliers (``outliers``; drawn from the sensor's :data:`OUTLIER_SUB` sub-stream, an extra error
added to a sample's white noise on every component):

* ``FRACTION:SCALE`` or ``gauss:FRACTION:SCALE``: a contaminated Gaussian, N(0, (SCALE std)²);
* ``t:NU:FRACTION[:SCALE]``: a Student-t with NU degrees of freedom times SCALE std (SCALE 1);
* a trailing ``:burst=L``: outliers come in bursts of L consecutive samples; a burst starts at a
  sample with probability ``1 - (1 - FRACTION)^(1/L)``, so a sample is an outlier with probability
  FRACTION (away from the first L - 1 samples).

The functions are pure: given the parsed model, the times and one generator per run (the run's own
stream, so the draws are the same whatever the chunk of runs), they return batched arrays.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nespm_cli.errors import NespmError

SCHEDULE_SUB = 11  # the sub-stream of a sensor's dynamic-schedule factors
OUTLIER_SUB = 12  # the sub-stream of a sensor's outlier draws
SCHEDULE_KINDS = ("step", "ramp", "dynamic")
OUTLIER_KINDS = ("gauss", "t")


@dataclass(frozen=True)
class NoiseSchedule:
    """A parsed ``noise_schedule``: ``kind`` (step, ramp, dynamic); ``times`` [s] and ``factors``
    the knots of step/ramp; ``segment`` [s], ``low``, ``high`` of a dynamic schedule."""

    kind: str
    times: tuple = ()
    factors: tuple = ()
    segment: float = 0.0
    low: float = 1.0
    high: float = 1.0


@dataclass(frozen=True)
class OutlierModel:
    """A parsed ``outliers``: ``kind`` (gauss, t), ``fraction`` of samples, ``scale`` (x the
    sensor's std), ``nu`` (Student-t dof), ``burst`` (consecutive samples per outlier event)."""

    kind: str
    fraction: float
    scale: float
    nu: float = math.inf
    burst: int = 1


def _number(text: str, where: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise NespmError(f"{where}: {what} must be a number, got {text.strip()!r}") from None
    if not math.isfinite(v):
        raise NespmError(f"{where}: {what} must be finite, got {text.strip()!r}")
    return v


def parse_schedule(text: str, where: str) -> NoiseSchedule | None:
    """``noise_schedule`` text -> :class:`NoiseSchedule` (None for ""); ``where`` names the option
    in the one-line error (unknown kind, bad knots, a factor <= 0, times not increasing)."""
    text = str(text or "").strip()
    if not text:
        return None
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind not in SCHEDULE_KINDS:
        raise NespmError(f"{where}: unknown schedule {kind!r}; choose step:T=F,..., ramp:T=F,... or dynamic:SEG:LO:HI")
    if kind == "dynamic":
        parts = rest.split(":")
        if len(parts) != 3:
            raise NespmError(f"{where}: expected dynamic:SEG:LO:HI (segment seconds, factor range), got {text!r}")
        seg, lo, hi = (_number(p, where, w) for p, w in zip(parts, ("SEG", "LO", "HI")))
        if seg <= 0:
            raise NespmError(f"{where}: the segment length SEG must be > 0 s, got {seg:g}")
        if not 0 < lo <= hi:
            raise NespmError(f"{where}: dynamic factors need 0 < LO <= HI, got {lo:g}, {hi:g}")
        return NoiseSchedule(kind, segment=seg, low=lo, high=hi)
    times, factors = [], []
    for knot in rest.split(","):
        if not knot.strip():
            continue
        t, eq, f = knot.partition("=")
        if not eq:
            raise NespmError(f"{where}: expected {kind}:T=F[,T=F...] (seconds=factor), got {knot.strip()!r}")
        times.append(_number(t, where, "a knot time"))
        factors.append(_number(f, where, "a factor"))
    if not times:
        raise NespmError(f"{where}: {kind} needs at least one knot T=F, got {text!r}")
    if min(times) < 0 or any(b <= a for a, b in zip(times, times[1:])):
        raise NespmError(f"{where}: knot times must be >= 0 and increasing, got {times}")
    if min(factors) <= 0:
        raise NespmError(f"{where}: factors must be > 0, got {min(factors):g}")
    return NoiseSchedule(kind, times=tuple(times), factors=tuple(factors))


def parse_outliers(text: str, where: str) -> OutlierModel | None:
    """``outliers`` text -> :class:`OutlierModel` (None for ""); one-line error naming ``where``
    for an unknown kind, a fraction outside [0, 1], a scale or dof <= 0, a burst < 1."""
    text = str(text or "").strip()
    if not text:
        return None
    parts = [p.strip() for p in text.split(":")]
    burst = 1
    if parts and parts[-1].lower().startswith("burst="):
        b = _number(parts.pop()[6:], where, "burst")
        if b < 1 or b != int(b):
            raise NespmError(f"{where}: burst must be a whole number of samples >= 1, got {b:g}")
        burst = int(b)
    head = parts[0].lower() if parts else ""
    if head in OUTLIER_KINDS:
        kind, args = head, parts[1:]
    else:
        try:
            float(head)
        except ValueError:
            raise NespmError(f"{where}: unknown outlier model {parts[0] if parts else ''!r}; choose FRACTION:SCALE, "
                             "gauss:FRACTION:SCALE or t:NU:FRACTION[:SCALE], optionally :burst=L") from None
        kind, args = "gauss", parts
    nu = math.inf
    if kind == "t":
        if len(args) not in (2, 3):
            raise NespmError(f"{where}: expected t:NU:FRACTION[:SCALE][:burst=L], got {text!r}")
        nu = _number(args[0], where, "NU")
        if nu <= 0:
            raise NespmError(f"{where}: the Student-t dof NU must be > 0, got {nu:g}")
        fraction = _number(args[1], where, "FRACTION")
        scale = _number(args[2], where, "SCALE") if len(args) == 3 else 1.0
    else:
        if len(args) != 2:
            raise NespmError(f"{where}: expected [gauss:]FRACTION:SCALE[:burst=L], got {text!r}")
        fraction, scale = _number(args[0], where, "FRACTION"), _number(args[1], where, "SCALE")
    if not 0 <= fraction <= 1:
        raise NespmError(f"{where}: FRACTION must be a probability in [0, 1], got {fraction:g}")
    if scale <= 0:
        raise NespmError(f"{where}: SCALE must be > 0 (x the sensor's std), got {scale:g}")
    return OutlierModel(kind, fraction, scale, nu, burst)


def n_segments(t: np.ndarray, segment: float) -> int:
    """Number of dynamic segments covering times ``t`` (K,) [s] from 0 (at least 1)."""
    end = float(np.max(t)) if np.size(t) else 0.0
    return int(np.floor(max(end, 0.0) / segment + 1e-9)) + 1


def schedule_factor(schedule: NoiseSchedule | None, t: np.ndarray, gens: Sequence[np.random.Generator]) -> np.ndarray:
    """(R, K) the factor on the white noise std at times ``t`` (K,) [s since the first epoch] in
    each of R = ``len(gens)`` runs (ones for None; a step or ramp takes None entries). Only a dynamic schedule draws: S uniforms per
    run from that run's generator (its schedule sub-stream), S = :func:`n_segments`."""
    t = np.asarray(t, dtype=float)
    R, K = len(gens), len(t)
    if schedule is None:
        return np.ones((R, K))
    if schedule.kind == "dynamic":
        S = n_segments(t, schedule.segment)
        u = np.stack([g.uniform(schedule.low, schedule.high, S) for g in gens]) if R else np.empty((0, S))
        seg = np.clip(np.floor(t / schedule.segment + 1e-9).astype(np.int64), 0, S - 1)
        return u[:, seg]
    times, factors = np.asarray(schedule.times), np.asarray(schedule.factors)
    if schedule.kind == "ramp":
        f = np.interp(t, times, factors)
    else:
        f = factors[np.clip(np.searchsorted(times, t + 1e-9, side="right") - 1, 0, len(times) - 1)]
    return np.broadcast_to(f, (R, K)).copy()


def burst_mask(starts: np.ndarray, burst: int) -> np.ndarray:
    """(R, K) bool: a sample is in a burst if a start (R, K) lies within the ``burst`` samples
    ending at it."""
    c = np.cumsum(starts, axis=-1)
    back = np.zeros_like(c)
    if burst < c.shape[-1]:
        back[:, burst:] = c[:, :-burst]
    return (c - back) > 0


def outlier_errors(model: OutlierModel | None, K: int, m: int, std: float,
                   gens: Sequence[np.random.Generator]) -> tuple[np.ndarray, np.ndarray]:
    """``(errors (R, K, m), mask (R, K))``: the extra errors of K samples of m components in R =
    ``len(gens)`` runs and which samples are outliers. Per run, from its outlier sub-stream: K
    uniforms (burst starts), then K x m standard normal (gauss) or Student-t (t) draws; an
    outlier's error is ``scale x std x draw``, zero elsewhere. ``std`` the sensor's base noise std
    (the schedule does not scale outliers). None (or fraction 0): zeros and no draw."""
    R = len(gens)
    if model is None or model.fraction == 0 or R == 0:
        return np.zeros((R, K, m)), np.zeros((R, K), dtype=bool)
    q = 1.0 - (1.0 - model.fraction) ** (1.0 / model.burst)
    u = np.empty((R, K))
    e = np.empty((R, K, m))
    for i, g in enumerate(gens):  # one generator per run: its own stream
        u[i] = g.random(K)
        e[i] = g.standard_normal((K, m)) if model.kind == "gauss" else g.standard_t(model.nu, (K, m))
    mask = burst_mask(u < q, model.burst)
    return np.where(mask[..., None], e * (model.scale * std), 0.0), mask


__all__ = ["NoiseSchedule", "OUTLIER_KINDS", "OUTLIER_SUB", "OutlierModel", "SCHEDULE_KINDS", "SCHEDULE_SUB",
           "burst_mask", "n_segments", "outlier_errors", "parse_outliers", "parse_schedule", "schedule_factor"]
