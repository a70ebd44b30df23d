"""One track's consistency check: the IMU and DVL parts, a verdict and the corrections that apply.

:func:`check_track` returns a plain-JSON dict (the ``check.json`` entry of the track):

* ``imu``: None (no IMU file) or the :mod:`imu_gt` results: ``axis_mapping``, ``time_offset``,
  ``stats`` (per sensor and axis), ``windows``, ``attitude_drift``;
* ``dvl``: the :mod:`dvl_gt` fit (lever arm, scale factor, misalignment, time offset, residuals);
* ``corrections``: the :class:`~nespm_cli.data.corrections.Corrections` the data justify, as a
  dict, and ``options``: the same as command-line options;
* ``verdict``: ``consistent``, ``consistent after corrections`` or ``inconsistent``;
  ``verdict_reasons``: why inconsistent, short, with the numbers (empty otherwise); and
  ``findings``: one sentence per thing found (the DVL's reasons first, :mod:`dvl_verdict`);
  ``dvl["judged"]``: the DVL's own noise, the bound, its RMS speed and the frame test.

Rules (each written once here; docs/checking-data.md explains them):

* axis mapping: corrected when the best signed permutation is not the identity and its cost
  is below :data:`AXES_RATIO` times the identity's;
* an IMU clock drift: corrected when the local offsets' line (:func:`imu_gt.clock_drift`) has a
  slope beyond ``DRIFT_SIGMAS`` sigma that moves the offset by ``DRIFT_MIN_S`` over the track;
* a time offset (IMU or DVL): corrected when ``|offset| >= OFFSET_MIN_S`` and beyond
  ``OFFSET_SIGMAS`` of its 1-sigma; an offset at the edge of the search is a finding;
* windows: inconsistent or unresolved windows (:func:`imu_gt.windows`) that touch the first or
  last :data:`TRIM_FRACTION` of the track without a gap are cut by a suggested ``window``;
  any other is a finding, and an inconsistent one makes the verdict ``inconsistent``;
* the DVL: a residual, scale factor, offset at the edge of its search or frame that
  :func:`dvl_verdict.judge_dvl` finds makes the verdict ``inconsistent``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from nespm_cli.checks import dvl_gt, imu_gt
from nespm_cli.checks.dvl_verdict import judge_dvl
from nespm_cli.data.corrections import IDENTITY_AXES, Corrections, apply_corrections
from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
from nespm_cli.data.track import Track
from nespm_cli.errors import NespmError

AXES_RATIO = 0.7
OFFSET_MIN_S = 0.02
OFFSET_SIGMAS = 2.0
TRIM_FRACTION = 0.15


def significant(value: float, std: float) -> bool:
    """Whether a time offset [s] is worth correcting (see the module rules); an undetermined offset (its std
    None or not finite, or the value not finite) is not."""
    if value is None or std is None or not (math.isfinite(value) and math.isfinite(std)):
        return False
    return abs(value) >= OFFSET_MIN_S and abs(value) > OFFSET_SIGMAS * std


def imu_part(track: Track) -> dict:
    """The :mod:`imu_gt` analysis of a track with an IMU, in the order a reader needs it."""
    g = imu_gt.compare_grid(track)
    mapping, offset = imu_gt.search(g)
    A = np.asarray(mapping["matrix"])
    drift = offset["drift"]["drift"]
    rf, rw = imu_gt.residual(g, offset["offset_s"], A, drift)
    stats = imu_gt.axis_stats(g, rf, rw)
    wins = imu_gt.windows(g, *imu_gt.remove_bias_scale(g, rf, rw, stats))
    axes = mapping["axes"] if mapping["cost"] < AXES_RATIO * mapping["identity_cost"] else IDENTITY_AXES
    off = round(offset["offset_s"], 2) if (drift or significant(offset["offset_s"], offset["std_s"])) else 0.0
    drift = round(drift, 6)
    att = imu_gt.attitude_drift(apply_corrections(track, Corrections(imu_axes=axes, imu_time_offset=off,
                                                                     imu_time_drift=drift)))
    series = {"t": g["t"][::10].tolist(), "implied_w": g["imp_w"][::10].tolist(),
              "recorded_w": (g["imp_w"] + rw)[::10].tolist(), "resid_w": rw[::10].tolist(),
              "implied_f": g["imp_f"][::10].tolist(), "recorded_f": (g["imp_f"] + rf)[::10].tolist()}
    return {"axis_mapping": mapping, "time_offset": offset, "stats": stats, "windows": wins,
            "own_noise": imu_gt.own_noise(track),
            "attitude_drift": att, "series": series,
            "applied": {"imu_axes": axes, "imu_time_offset": off, "imu_time_drift": drift}}


def trim_window(track: Track, wins: list[dict]) -> tuple[tuple | None, list[dict]]:
    """A ``window`` cutting the inconsistent windows at the track's ends, and the ones left."""
    t0, t1 = float(track.t[0]), float(track.t[-1])
    span = t1 - t0
    bad = [w for w in wins if w["inconsistent"] or w["unresolved"]]
    start, end = t0, t1
    for w in sorted(bad, key=lambda w: w["start"]):  # from the front, without a gap
        if w["start"] <= max(start, t0 + imu_gt.EDGE_S) + imu_gt.WINDOW_STEP_S + 1e-6 and w["end"] <= t0 + TRIM_FRACTION * span + imu_gt.WINDOW_S:
            start = max(start, w["end"])
    for w in sorted(bad, key=lambda w: -w["end"]):  # from the back
        if w["end"] >= min(end, t1 - imu_gt.EDGE_S) - imu_gt.WINDOW_STEP_S - 1e-6 and w["start"] >= t1 - TRIM_FRACTION * span - imu_gt.WINDOW_S:
            end = min(end, w["start"])
    left = [w for w in bad if w["start"] >= start - 1e-6 and w["end"] <= end + 1e-6]
    if start == t0 and end == t1:
        return None, left
    # snap to GT epochs inside the cut
    t = np.asarray(track.t)
    return (float(t[t >= start - 1e-9][0]), float(t[t <= end + 1e-9][-1])), left


def check_track(track: Track) -> dict:
    """The consistency check of one track (see the module docstring for the keys)."""
    if not getattr(track, "truth", True):  # a track spec without [gt]: nothing to check the sensors against
        raise NespmError(f"track {track.number}: no ground truth ([gt] in the track spec): nespm check compares "
                         "the sensors with it")
    findings: list[str] = []
    dvl = dvl_gt.fit_dvl_to_gt(track)
    corr = Corrections()
    left: list[dict] = []
    imu = None
    if track.imu is None:
        findings.append("no IMU file: the IMU part needs IMU_trajectoryN.csv")
    else:
        imu = imu_part(track)
        m, o = imu["axis_mapping"], imu["time_offset"]
        corr = dataclasses.replace(corr, **imu["applied"])
        if corr.imu_axes != IDENTITY_AXES:
            findings.append(f"IMU axes {corr.imu_axes} fit {m['identity_cost'] / max(m['cost'], 1e-12):.1f}x "
                            f"better than the identity (normalised residual {m['cost']:.3g} vs {m['identity_cost']:.3g})")
        if o["at_edge"]:
            findings.append(f"IMU time offset at the edge of the +-{imu_gt.OFFSETS[-1]:g} s search: not determined")
        elif corr.imu_time_offset:
            findings.append(f"IMU time offset {o['offset_s']:+.2f} +- {o['std_s']:.3f} s")
        if corr.imu_time_drift:
            d = o["drift"]
            findings.append(f"IMU clock drift {d['drift'] * 1e6:+.0f} +- {d['drift_std'] * 1e6:.0f} ppm: the IMU's "
                            f"offset moves {d['drift'] * float(track.duration):+.2f} s over the track "
                            f"({d['windows_used']} local offsets, reduced chi-square {d['chi2_red']:.1f})")
        window, left = trim_window(track, imu["windows"])
        if window is not None:
            corr = dataclasses.replace(corr, window=window)
            findings.append(f"IMU and GT disagree (or the GT cannot resolve the motion) at the track's ends: "
                            f"use {window[0]:g}-{window[1]:g} s")
        for w in left:
            what = "the 1 Hz GT cannot resolve the motion" if w["unresolved"] else "IMU and GT disagree"
            findings.append(f"{what} in {w['start']:.0f}-{w['end']:.0f} s ({'; '.join(w['reasons'])})")
        left = [w for w in left if w["inconsistent"]]
        nz = imu["own_noise"]
        findings.append(f"the recorded IMU's own white noise per sample: acc {max(nz['acc']):.3g} m/s^2, gyro "
                        f"{max(nz['gyro']):.3g} rad/s ({max(nz['acc']) / NOMINAL_ACC_NOISE:.2g}x and "
                        f"{max(nz['gyro']) / NOMINAL_GYRO_NOISE:.2g}x the papers' injected noise, which the filters' "
                        "Q assumes by default)")
        d = imu["attitude_drift"]["final_deg"]
        findings.append("recorded gyros integrate to " + ", ".join(f"{a:+.2f}" for a in d) +
                        " deg (N, E, D axes) from the GT over the track")
    if significant(dvl["time_offset_s"], dvl["time_offset_std_s"]):
        corr = dataclasses.replace(corr, dvl_time_offset=round(dvl["time_offset_s"], 2))
        findings.append(f"DVL time offset {dvl['time_offset_s']:+.2f} +- {dvl['time_offset_std_s']:.2f} s")
    judged = judge_dvl(track, dvl)
    reasons = list(judged["reasons"])
    if imu is not None and imu["time_offset"]["at_edge"]:
        reasons.append(f"IMU offset at the edge of the +-{imu_gt.OFFSETS[-1]:g} s search")
    if left:
        reasons.append("IMU and GT disagree in " + ", ".join(f"{w['start']:.0f}-{w['end']:.0f} s" for w in left))
    if reasons:
        verdict = "inconsistent"
    elif corr.is_identity:
        verdict = "consistent"
    else:
        verdict = "consistent after corrections"
    findings[:0] = judged["findings"]  # the DVL's reasons first: they name the likely cause
    dvl = {**dvl, "judged": {k: v for k, v in judged.items() if k not in ("findings", "reasons")}}
    out = {"track": int(track.number), "source": track.source, "imu": imu, "dvl": dvl,
           "corrections": {**dataclasses.asdict(corr), "window": None if corr.window is None else list(corr.window)},
           "options": corr.options(), "verdict": verdict, "verdict_reasons": reasons, "findings": findings}
    bad = non_finite(out, skip=PLOT_ONLY)
    if bad:
        findings.append(f"{len(bad)} figure(s) not finite (not determined by these data), written as null in "
                        f"check.json: {', '.join(bad[:6])}{' ...' if len(bad) > 6 else ''}")
    return out


#: the keys (dotted paths) of a track's result that only the figures use (not written to check.json)
PLOT_ONLY = ("imu.series", "imu.attitude_drift.t", "imu.attitude_drift.drift_deg")


def non_finite(obj, path: str = "", skip: tuple = ()) -> list[str]:
    """The dotted paths (``imu.time_offset.local.3.std_s``) of every non-finite float in ``obj`` (nested dicts,
    lists, tuples, NumPy floats), the paths in ``skip`` and below them left out."""
    if path in skip:
        return []
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in non_finite(v, f"{path}.{k}" if path else str(k), skip)]
    if isinstance(obj, (list, tuple)):
        return [p for i, v in enumerate(obj) for p in non_finite(v, f"{path}.{i}", skip)]
    if isinstance(obj, (float, np.floating)) and not math.isfinite(obj):
        return [path]
    return []


def json_safe(obj):
    """``obj`` (nested dicts, lists, tuples) with every non-finite float as None: JSON has no inf or NaN, and a
    figure the data do not determine is written as ``null`` (:func:`check_track` says which in a finding)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj
