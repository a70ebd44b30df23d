"""``nespm run``: one realization of one filter on one track, with its full time series."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.data.parquet_files import write_parquet_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import NO_TRUTH, Spec, filter_config_of, track_inputs, validate
from nespm_cli.experiments.metrics import divergence, run_metrics, sensor_nis, sensor_rejections, truth_free_metrics
from nespm_cli.nav.rotations import dcm_to_euler
from nespm_cli.nav.state import parse_layout


def run_single(spec: Spec, track: int, filt: str, run: int, clean: bool = False, out: str | None = None,
               status: Callable[[str], None] | None = None) -> dict:
    """Run realization ``run`` (or the clean case) and return its summary metrics.

    ``status(text)``, if given, is told what is being done (loading, IMU, every 10 % of the filter).

    ``out`` (optional): per-epoch time series as Parquet (CSV if it ends in .csv) with
    true and estimated velocity and attitude, errors, covariance diagonal and biases.

    On a track without ground truth (a track spec without ``[gt]``) the summary holds the innovation
    statistics only (:func:`nespm_cli.experiments.metrics.truth_free_metrics`: NIS and likelihood per
    sensor) and ``note`` says so; the series has no truth and no error column.
    """
    from nespm_cli.experiments.spec import load_filters
    from nespm_cli.filters.registry import filter_names
    from nespm_cli.data.tracks import available_tracks, resolve_data_dir

    if run < 0:
        raise NespmError(f"--run must be >= 0, got {run}")
    spec = load_filters(spec)
    if filt not in filter_names():
        raise NespmError(f"--filter: unknown filter {filt!r}; choose from {', '.join(filter_names())}")
    have = available_tracks(resolve_data_dir(spec.data_dir))
    if track not in have:
        raise NespmError(f"--track: no track {track}; available: {', '.join(map(str, have))}")
    say = status or (lambda text: None)
    spec = validate(spec)  # before any progress line: a bad input's message is the only line
    imu = "synthesizing the 100 Hz IMU from the GT" if spec.imu == "synthetic" else "reading the recorded IMU"
    say(f"track {track}: {imu}")
    _, truth0 = track_inputs(spec, track)
    from nespm_cli.experiments.progress import COMPILING, kernels_for
    from nespm_cli.filters.kernels import kernels_cached, warm_up

    need = kernels_for([filt], spec.filter_config.layout)
    if kernels_cached(need) is False:  # the first run on a machine: its own phase, not the filter's epochs
        say(COMPILING)
        warm_up(need)
    n = len(truth0.epoch_index) - 1
    tenth = max(n // 10, 1)

    def progress(k: int) -> None:
        if k % tenth == 0 or k == n:
            say(f"{filt} on track {track}, run {run}: epoch {k}/{n}")
    results, truth, real = simulate(spec, track, np.array([run]), [filt], clean=clean, progress=progress)
    o, err, secs = results[filt]
    e0 = truth.epoch_index
    if err is None:  # no ground truth: the innovations only
        m = truth_free_metrics(o)
        why, inconsistent = m.pop("diverged_reason"), m.pop("inconsistent")
    else:
        div, why, inconsistent = divergence(err, o.diverged, truth.t[e0] - truth.t[e0[0]], spec.divergence)
        if o.lost_reason is not None:  # the engine's own reason ("noise-model")
            why = np.where(o.lost_reason != "", o.lost_reason, why).astype(object)
        m = run_metrics(err, div)
        m.update(sensor_nis(o))
    if filter_config_of(spec, filt).robust_update()[0] != "none":  # its rejected, applied, downweighted samples
        m.update(sensor_rejections(o))
    summary = {"track": track, "filter": filt, "run": run, "clean": clean, "scenario": spec.scenario,
               "schedule": spec.corruption.schedule,
               **{k: (bool(v[0]) if k == "diverged" else (int(v[0]) if np.asarray(v).dtype.kind == "i" else float(v[0])))
                                             for k, v in m.items()}}
    summary = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in summary.items()}
    summary["diverged_reason"] = str(why[0])
    summary["inconsistent"] = bool(inconsistent[0])
    if err is None:
        summary["note"] = NO_TRUTH
    if out:
        e = truth.epoch_index
        ts = pd.DataFrame({"t": truth.t[e] - truth.t[e[0]], "dvl_used": o.dvl_used[0]})  # this run's
        if err is not None:
            ts["vel_err"], ts["att_err"], ts["nees"] = err.vel[0], err.att[0], err.nees[0]
        eu_t, eu_e = dcm_to_euler(truth.C_bn[e]), dcm_to_euler(o.C_bn[0])
        for i, c in enumerate("NED"):
            if err is not None:
                ts[f"v{c}_true"] = truth.v_n[e][:, i]
            ts[f"v{c}_est"] = o.v_n[0, :, i]
        for i, c in enumerate(("roll", "pitch", "yaw")):
            if err is not None:
                ts[f"{c}_true"] = eu_t[:, i]
            ts[f"{c}_est"] = eu_e[:, i]
        for i, c in enumerate("xyz"):
            ts[f"ba_{c}_est"] = o.b_a[0, :, i]
            ts[f"bg_{c}_est"] = o.b_g[0, :, i]
            if not clean and err is not None:
                ts[f"ba_{c}_true"] = real.b_a[0, i]
                ts[f"bg_{c}_true"] = real.b_g[0, i]
        for i, c in enumerate(parse_layout(o.layout).labels):  # dvN ... bgZ, with dpN, dpE, dpD first for 15 states
            ts[f"sigma_{c}"] = np.sqrt(o.P_diag[0, :, i])
        if err is not None:
            ts["north_err"], ts["east_err"], ts["down_err"] = err.ne[0, :, 0], err.ne[0, :, 1], err.down[0]
        for name, rec in o.sensors.items():  # per sensor: measurements applied and their NIS, per epoch interval
            ts[f"{name}_count"] = np.bincount(np.searchsorted(ts["t"].to_numpy(), rec.t[rec.used[0]], side="left"),
                                              minlength=len(ts))[: len(ts)]
        if o.noise_std is not None:  # adaptive filters: the network std of the interval ending at the epoch
            for key, arr in (("acc", o.noise_std[0]), ("gyro", o.noise_std[1])):
                for i, c in enumerate("xyz"):
                    ts[f"net_std_{key}_{c}"] = np.concatenate([[np.nan], arr[0, :, i]])
        p = Path(out)
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.suffix == ".csv":
            ts.to_csv(p, index=False)
        else:
            write_parquet_atomic(ts, p)
    return summary
