"""A sensor's channel on one track: its times on the IMU grid, the truth there, and its values in R runs.

:func:`build_channel` is what an experiment calls per sensor and chunk of runs:

* **times**: a recorded channel's own stamps (file time minus the first GT epoch), or a synthetic
  schedule: the GT epochs (a sensor with no interval, the papers' DVL) or every ``interval``
  seconds from the first epoch, moved by ``jitter`` (one draw per track);
* **place on the grid** (:func:`locate`): the IMU sample at or before each time and the fraction
  of the following step (0 on a sample; the engine splits the step there);
* **truth there** (:func:`truth_at`): the grid's truth, or, inside a step, the truth carried over
  the part of the step by ``na_cycle`` with the step's clean IMU, exactly what a perfect filter
  computes over the split step;
* **values**: the recorded ones (NaN: none), or :meth:`Sensor.synthesize` (``clean``: the
  error-free values); then the components the sensor loses on its own set to NaN
  (:meth:`Sensor.lose_components`, e.g. a DVL's lost beams) and a row kept where
  :meth:`Sensor.present` says (default: every component finite; NaN components of a kept row
  are masked by the sensor's ``Measurement``);
* **availability** (:func:`nespm_cli.sensors.source.availability`): never at t = 0, not in an
  outage window, not where the sensor's own rule or a dropout says no.

A track without ground truth (``ImuTruth.known`` False) takes recorded channels only: a synthetic
source, and an availability rule that reads the truth (``fix.surface_only``), are refused in one line
(:func:`truth_free_check`); its channels carry no truth (``where`` None: no rule consulted).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import body_rate_step
from nespm_cli.nav.strapdown import na_cycle
from nespm_cli.nav.synthesis import ImuTruth
from nespm_cli.sensors.guard import checked_values, sensor_call
from nespm_cli.sensors.source import Channel, Sensor, TrackInfo, Truth, availability, jittered

ON_SAMPLE = 1e-9  # a time within this fraction of a step from a sample is at the sample
STAMP_TOL = 1e-6  # [s] a recorded stamp this far outside the GT span is still inside it


def grid_time(truth: ImuTruth) -> np.ndarray:
    """(M+1,) IMU sample times [s since the first GT epoch]."""
    return np.asarray(truth.t, dtype=float) - float(truth.t[truth.epoch_index[0]])


def locate(truth: ImuTruth, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(index, frac)`` (K,) of times ``t`` [s since the first epoch] on the grid of ``truth``:
    the sample at or before and the fraction of the next step (0 on a sample)."""
    tg = grid_time(truth)
    t = np.asarray(t, dtype=float)
    j = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, len(tg) - 1)
    step = np.asarray(truth.dt, dtype=float)[np.minimum(j, len(truth.dt) - 1)]
    frac = np.where(j < len(tg) - 1, (t - tg[j]) / step, 0.0)
    up = frac > 1.0 - ON_SAMPLE
    j, frac = np.where(up, j + 1, j), np.where(up, 0.0, frac)
    frac = np.where(frac < ON_SAMPLE, 0.0, frac)
    return j.astype(np.int64), frac


def track_info(truth: ImuTruth, number: int) -> TrackInfo:
    """The :class:`TrackInfo` of track ``number``: the truth's position and file time at the first epoch."""
    e0 = int(truth.epoch_index[0])
    return TrackInfo(int(number), np.array(truth.pos[e0], dtype=float), float(truth.t[e0]))


def truth_at(truth: ImuTruth, index: np.ndarray, frac: np.ndarray, track: TrackInfo | None = None) -> Truth:
    """The truth at grid places ``(index, frac)`` (K,): on a sample the grid's values, inside a step
    ``na_cycle`` over ``frac`` of it with the step's clean IMU; ``w_nb_b`` from the (part-)step
    ending there (eq 31 inverted)."""
    index, frac = np.asarray(index, dtype=np.int64), np.asarray(frac, dtype=float)
    dt = np.asarray(truth.dt, dtype=float)
    M = len(dt)
    inside = frac > 0
    j = np.minimum(index, M - 1)
    pos, v, C = truth.pos[index].copy(), truth.v_n[index].copy(), truth.C_bn[index].copy()
    if inside.any():
        d = frac[inside] * dt[j[inside]]
        p1, v1, C1 = na_cycle(truth.pos[j[inside]], truth.v_n[j[inside]], truth.C_bn[j[inside]],
                              truth.f_b[j[inside]], truth.w_ib_b[j[inside]], d)
        pos[inside], v[inside], C[inside] = p1, v1, C1
    # body rate of the step (or part) ending at each place; the first sample takes the first step's
    prev = np.maximum(index - 1, 0)
    w = body_rate_step(truth.C_bn[prev], truth.C_bn[np.maximum(index, 1)], dt[prev])
    if inside.any():
        w[inside] = body_rate_step(truth.C_bn[j[inside]], C[inside], frac[inside] * dt[j[inside]])
    t = grid_time(truth)[index] + frac * dt[j]
    return Truth(t=t, pos=pos, v_n=v, C_bn=C, w_nb_b=w, track=track)


def schedule(sensor: Sensor, truth: ImuTruth, seed: int, track: int) -> np.ndarray:
    """A synthetic channel's times (K,) [s since the first epoch]: the GT epochs (``interval`` None);
    or every ``interval`` seconds up to the last epoch, each at the IMU sample nearest to
    ``k x interval`` (a sensor sampled on the IMU's clock: at most half an IMU step, 5 ms at
    100 Hz, from the nominal time, and no IMU step is split); with ``jitter``, the nominal times
    moved by the jitter draw (one per track) and kept exactly, off the IMU grid, inside the span."""
    tg = grid_time(truth)
    epochs = tg[truth.epoch_index]
    every = sensor.interval()
    if every is None:
        return epochs
    end = float(epochs[-1])
    t = np.arange(1, int(np.floor(end / every + 1e-9)) + 1) * every
    if sensor.opt.jitter:
        t = jittered(sensor, t, seed, track)
        return np.sort(t[(t > 0) & (t <= end)])
    j = np.clip(np.searchsorted(tg, t), 1, len(tg) - 1)
    nearest = np.where(t - tg[j - 1] <= tg[j] - t, j - 1, j)
    return np.unique(tg[nearest[tg[nearest] > 0]])


def recorded_times(sensor: Sensor, track, truth: ImuTruth) -> tuple[np.ndarray, np.ndarray]:
    """``(t, z)`` of the track's recorded channel: times [s since the first epoch] inside the GT span.
    A file without a measurement there, or with another number of value columns than the sensor
    measures, is refused in one line naming the track and the sensor."""
    rec = sensor_call(sensor, "recorded", sensor.recorded, track)
    if rec is None:
        raise NespmError(f"--sensors {sensor.name}: source recorded, but track {track.number} has no "
                         f"{sensor.name} file (docs/data-format.md)")
    t_file, z = (np.asarray(a, dtype=float) for a in rec)
    if z.ndim == 1:
        z = z[:, None]
    if z.shape[-1] != sensor.dim:
        raise NespmError(f"--sensors {sensor.name}: track {track.number}'s recorded {sensor.name} file has "
                         f"{z.shape[-1]} value column(s), but {sensor.name} measures {sensor.dim} "
                         f"({', '.join(sensor.labels[:sensor.dim])}) with its --sensor-option values")
    t0, t_end = float(track.t[0]), float(track.t[-1])
    keep = (t_file >= t0 - STAMP_TOL) & (t_file <= t_end + STAMP_TOL)
    if not np.isfinite(z[keep]).any(axis=-1).sum():
        raise NespmError(f"--sensors {sensor.name}: track {track.number}'s recorded {sensor.name} file has no "
                         f"measurement inside the track's span ({len(t_file)} rows, {int(keep.sum())} inside, none "
                         f"finite there); use --sensor-option {sensor.name}.source=synthetic or drop {sensor.name}")
    return np.clip(t_file[keep] - t0, 0.0, t_end - t0), z[keep]


def synthetic_times(sensor: Sensor, truth: ImuTruth, seed: int, number: int) -> np.ndarray:
    """:func:`schedule`, refused in one line where it cannot be a sensor's: an ``interval`` shorter
    than the IMU step (a sensor on the IMU clock measures at most once per step) or a schedule
    without a time in the track's span (a given interval longer than the track, or a ``jitter`` that
    moves every stamp out of it; a sensor's default interval longer than a short ``--window`` is
    not refused: the sensor then has no measurement there, as its record shows)."""
    every, o = sensor.interval(), sensor.opt
    step = float(np.min(truth.dt))
    if every is not None and every < step * (1 - 1e-9):
        raise NespmError(f"--sensor-option {sensor.name}.interval={every:g}: shorter than track {number}'s IMU "
                         f"step ({step:g} s); a sensor measures at most once per IMU step")
    t = schedule(sensor, truth, seed, number)
    if len(t) == 0 and (o.interval is not None or o.jitter):  # a default schedule may miss a short --window
        end = float(grid_time(truth)[truth.epoch_index[-1]])
        if o.jitter:
            raise NespmError(f"--sensor-option {sensor.name}.jitter={o.jitter:g}: moves every stamp of track "
                             f"{number} out of its span (0-{end:g} s), so {sensor.name} would have no measurement; "
                             f"use a jitter well below the interval ({every:g} s)")
        raise NespmError(f"--sensor-option {sensor.name}.interval={every:g}: longer than track {number} "
                         f"({end:g} s), so {sensor.name} would have no measurement")
    return t


def truth_free_check(sensor: Sensor, truth: ImuTruth, number: int) -> None:
    """On a track without ground truth (``truth.known`` False) refuse, in one line naming the option, a
    synthetic source (drawn from the truth) and a sensor whose own availability rule reads the truth."""
    if truth.known:
        return
    name = sensor.name
    if sensor.opt.source != "recorded":
        flag, use = (("--dvl synthetic", "--dvl recorded") if name == "dvl" else
                     (f"--sensors {name} (source synthetic)", f"--sensor-option {name}.source=recorded"))
        raise NespmError(f"{flag}: a synthetic {name} is drawn from the ground truth, and track {number} has none "
                         f"(its track spec has no [gt]); use the recorded one ({use})")
    e0 = np.zeros(1, dtype=np.int64) + int(truth.epoch_index[0])
    probe_truth = truth_at(truth, np.r_[e0, e0 + 1], np.zeros(2), track_info(truth, number))
    with np.errstate(invalid="ignore"):
        rule = sensor_call(sensor, "available_extra", sensor.available_extra, probe_truth)
    if rule is not None:
        raise NespmError(f"--sensor-option {name}: its availability rule (e.g. {name}.surface_only) reads the ground "
                         f"truth, and track {number} has none (its track spec has no [gt]); turn the rule off")


def channel_times(sensor: Sensor, track, truth: ImuTruth, seed: int, number: int):
    """``(t, z)``: a recorded channel's times and values (:func:`recorded_times`), or a synthetic
    one's times (:func:`synthetic_times`) and None; a track without truth: :func:`truth_free_check` first."""
    truth_free_check(sensor, truth, number)
    if sensor.opt.source == "recorded":
        return recorded_times(sensor, track, truth)
    return synthetic_times(sensor, truth, seed, number), None


def probe(sensor: Sensor, track, truth: ImuTruth, seed: int, number: int) -> None:
    """Check ``sensor`` on a track before anything runs: its times (:func:`channel_times`) and, for a
    synthetic source, its ``true_values`` (K, dim) there (a plugin's failure one line naming it)."""
    t, z = channel_times(sensor, track, truth, seed, number)
    if z is None:
        where = truth_at(truth, *locate(truth, t), track_info(truth, number))
        values = sensor_call(sensor, "true_values", sensor.true_values, where)
        checked_values(sensor, "true_values", values, (len(t), sensor.dim))


def build_channel(sensor: Sensor, track, truth: ImuTruth, seed: int, number: int, runs: np.ndarray,
                  clean: bool = False) -> Channel:
    """The channel of ``sensor`` on track ``number`` for runs ``runs`` (see the module docstring)."""
    runs = np.asarray(runs, dtype=np.int64)
    info = track_info(truth, number)
    t, z = channel_times(sensor, track, truth, seed, number)
    index, frac = locate(truth, t)
    where = truth_at(truth, index, frac, info) if truth.known else None
    m = sensor.dim
    if z is not None:
        values = np.broadcast_to(z, (len(runs),) + z.shape)
    elif clean:
        v = checked_values(sensor, "true_values", sensor_call(sensor, "true_values", sensor.true_values, where),
                           (len(t), m))
        values = np.broadcast_to(v, (len(runs),) + v.shape)
    else:
        values = sensor_call(sensor, "synthesize", sensor.synthesize, where, seed, number, runs)
        values = checked_values(sensor, "synthesize", values, (len(runs), len(t), m), finite=False)
    values = sensor_call(sensor, "lose_components", sensor.lose_components, values, t, seed, number, runs)
    ok = np.asarray(sensor_call(sensor, "present", sensor.present, values), dtype=bool)
    values = np.where(ok[..., None], values, 0.0)  # NaN stays only in the components a Measurement masks
    ok = ok & sensor_call(sensor, "available_extra", availability, sensor, t, where, seed, number, runs)
    return Channel(sensor, index, t, values, ok, frac, info)


__all__ = ["build_channel", "channel_times", "grid_time", "locate", "probe", "recorded_times", "schedule",
           "synthetic_times", "track_info", "truth_at", "truth_free_check"]
