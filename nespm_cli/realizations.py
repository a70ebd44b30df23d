"""``nespm corrupt``: write the realizations of an experiment as data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .corruption import CorruptionConfig, draw, imu_errors
from .errors import NespmError
from .experiment import prepared, write_parquet_atomic
from .tracks import available_tracks, resolve_data_dir


def write_realizations(tracks, runs: int, seed: int, config: CorruptionConfig, out: str | Path,
                       data_dir: str | None = None, materialize: bool = False) -> Path:
    """Write ``out/realizations.parquet`` (one row per track x run, docs/results-schema.md).

    With ``materialize`` also ``out/imu_errors-<track>.parquet``: the additive IMU errors
    (run, step, e_fx..e_fz [m/s²], e_wx..e_wz [rad/s]) regenerated from the stored seeds.
    """
    if runs < 1:
        raise NespmError(f"--runs must be at least 1, got {runs}")
    d = resolve_data_dir(data_dir)
    have = available_tracks(d)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in tracks:
        if n not in have:
            raise NespmError(f"--tracks: no track {n}; available: {', '.join(map(str, have))}")
        _, truth = prepared(n, str(d) if d else None, "synthetic")
        duration = float(truth.t[-1] - truth.t[0])
        real = draw(seed, n, np.arange(runs), duration, config)
        from .corruption import to_rows

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
    path = out / "realizations.parquet"
    write_parquet_atomic(pd.DataFrame(rows), path)
    return path
