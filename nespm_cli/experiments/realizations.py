"""``nespm corrupt``: write the realizations of an experiment as data; :func:`oracle_noise`: the true noise
of a chunk's realizations, what an oracle filter is told (:mod:`nespm_cli.filters.oracle`)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.corruption import check_seed, CorruptionConfig, draw, imu_errors, Realization, segment_index
from nespm_cli.data.parquet_files import write_parquet_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.inputs import prepared
from nespm_cli.experiments.store import write_json_atomic
from nespm_cli.data.tracks import available_tracks, load_track, resolve_data_dir
from nespm_cli.filters.oracle import OracleNoise
from nespm_cli.nav.synthesis import ImuTruth


def write_realizations(tracks, runs: int, seed: int, config: CorruptionConfig, out: str | Path,
                       data_dir: str | None = None, materialize: bool = False,
                       accept_residual: bool | None = None) -> tuple[Path, bool]:
    """Write ``out/realizations.parquet`` (one row per track x run, docs/results-schema.md) and
    ``out/realizations.json`` (the options that drew them).

    With ``materialize`` also ``out/imu_errors-<track>.parquet``: the additive IMU errors
    (run, step, e_fx..e_fz [m/s²], e_wx..e_wz [rad/s]) regenerated from the stored seeds.

    ``accept_residual``: :func:`~nespm_cli.data.tracks.load_track`'s (``--accept-residual``: True; None: each
    track spec's ``gt.accept_residual`` decides).

    Returns ``(path, written)``. A folder that already holds realizations of the same options
    is left as it is (``written`` False); one holding others is refused (never overwritten).
    """
    if runs < 1:
        raise NespmError(f"--runs must be at least 1, got {runs}")
    check_seed(seed)
    if len(set(tracks)) != len(tuple(tracks)) or any(n < 1 for n in tracks):
        raise NespmError(f"--tracks: give each positive track number once, got {' '.join(map(str, tracks))}")
    d = resolve_data_dir(data_dir)
    have = available_tracks(d)
    for n in tracks:
        if n not in have:
            raise NespmError(f"--tracks: no track {n}; available: {', '.join(map(str, have))}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NespmError(f"--out {out}: exists and is not a folder")
    path = out / "realizations.parquet"
    options = {"tracks": [int(n) for n in tracks], "runs": int(runs), "seed": int(seed),
               "data_dir": str(d.resolve()) if d is not None else "embedded", "materialize": bool(materialize),
               "corruption": json.loads(json.dumps(dataclasses.asdict(config), default=list))}
    meta = out / "realizations.json"
    if path.exists() or meta.exists():
        try:
            old = json.loads(meta.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            old = None
        if old != options:
            what = ("no readable realizations.json" if old is None else "different options: " + ", ".join(
                sorted(k for k in set(old) | set(options) if old.get(k) != options.get(k))))
            raise NespmError(f"--out {out}: already holds realizations ({what}); use a new folder or delete it")
        return path, False
    truths = {}
    for n in tracks:  # every track read (its conventions checked) before anything is written
        # the IMU grid the errors are drawn on: the synthesized one, or a track without ground truth's recorded one
        imu = "synthetic" if d is None or load_track(n, d, accept_residual=accept_residual).truth else "recorded"
        truths[n] = prepared(n, str(d) if d else None, imu, accept_residual=accept_residual)[1]
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in tracks:
        truth = truths[n]
        duration = float(truth.t[-1] - truth.t[0])
        real = draw(seed, n, np.arange(runs), duration, config)
        from nespm_cli.data.corruption import to_rows

        rows += to_rows(real)
        if materialize:
            ef, ew = imu_errors(real, truth.t)
            R, M, _ = ef.shape
            df = pd.DataFrame({"run": np.repeat(np.arange(R), M), "step": np.tile(np.arange(M), R)})
            for i, c in enumerate("xyz"):
                df[f"e_f{c}"] = ef[..., i].ravel()
            for i, c in enumerate("xyz"):
                df[f"e_w{c}"] = ew[..., i].ravel()
            write_parquet_atomic(df, out / f"imu_errors-{n}.parquet")
    write_parquet_atomic(pd.DataFrame(rows), path)
    write_json_atomic(options, meta)
    return path, True


def oracle_noise(real: Realization, truth: ImuTruth, channels: list) -> OracleNoise:
    """The true noise of the runs of ``real`` (:class:`nespm_cli.data.corruption.Realization`) on the IMU
    grid of ``truth`` with the sensor ``channels`` (as built for ``run_filter``): the IMU's per-sample
    white-noise std per schedule segment (the corruption's std times each run's factors, the segment of
    each IMU step as :func:`nespm_cli.data.corruption.imu_errors` draws it) and, per synthetic sensor,
    :meth:`nespm_cli.sensors.source.Sensor.true_std` at its measurement times (None for a recorded one:
    its noise is unknown). Outliers are not noise of a known variance and stay out (docs/adapting.md).
    Batched over the runs; the factors are the realization's own draws, so no stream is touched."""
    cfg = real.config
    t = np.asarray(truth.t, dtype=float)
    segment = segment_index(t[1:] - t[0], cfg.segment_s, real.acc_factors.shape[1])
    runs = np.asarray(real.runs, dtype=np.int64)
    std = [None if ch.sensor.opt.source != "synthetic"
           else np.asarray(ch.sensor.true_std(ch.t, real.seed, real.track, runs), dtype=float) for ch in channels]
    return OracleNoise(acc_std=cfg.acc_noise * real.acc_factors, gyro_std=cfg.gyro_noise * real.gyro_factors,
                       segment=segment, dt=np.asarray(truth.dt, dtype=float),
                       epoch_index=np.asarray(truth.epoch_index, dtype=np.int64), channels=list(channels),
                       sensor_std=std)
