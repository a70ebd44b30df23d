"""``nespm export``: a results folder's tables for people who analyse elsewhere (CSV, MATLAB).

The tables exported are the folder's finished ones (docs/results-schema.md): ``metrics.parquet``
(one row per track, filter and run), ``epochs.parquet`` (per epoch, across runs) and, with
``--series``, the per-run per-epoch errors of the chunk series files (verified chunks only, in the
manifest's order; ``series.csv`` or a ``series`` struct). Formats:

* ``csv``: one ``<table>.csv`` per table, full precision (``%.17g``), NaN as ``NaN``;
* ``mat``: one ``<folder name>.mat`` (``scipy.io.savemat``, MATLAB 5 format) holding one struct
  per table whose fields are its columns (numbers as double columns, text as cell arrays of
  char), so ``load('x.mat'); x.metrics.vrmse`` works in MATLAB and Octave.

Nothing in the folder is changed; an existing output file is refused unless ``overwrite``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError

FORMATS = ("csv", "mat")
MAT_NAME_MAX = 31  # MATLAB's field-name length limit


def export_tables(folder: Path, series: bool = False) -> dict[str, pd.DataFrame]:
    """``{table: DataFrame}`` of the folder's exportable tables (one-line errors naming what is missing)."""
    folder = Path(folder)
    tables = {}
    for name in ("metrics", "epochs"):
        p = folder / f"{name}.parquet"
        if not p.is_file():
            if name == "metrics":
                raise NespmError(f"{folder}: no metrics.parquet (not a finished nespm mc/sweep folder)")
            continue
        tables[name] = pd.read_parquet(p)
    if series:
        files = sorted((folder / "chunks").glob("series-*.parquet"))
        if not files:
            raise NespmError(f"{folder}: --series asks for the per-run series, but chunks/ holds no series file")
        tables["series"] = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    return tables


def mat_struct(df: pd.DataFrame) -> dict:
    """A table as a MATLAB struct: ``{column: (rows,) double or cell array of char}``; column names
    made valid MATLAB field names (letters, digits, ``_``; at most 31 characters)."""
    out = {}
    for col in df.columns:
        name = "".join(c if c.isalnum() or c == "_" else "_" for c in str(col))
        name = (name if name[:1].isalpha() else f"c_{name}")[:MAT_NAME_MAX]
        s = df[col]
        if pd.api.types.is_bool_dtype(s) or pd.api.types.is_numeric_dtype(s):
            out[name] = s.to_numpy(dtype=float)
        else:
            out[name] = np.array([str(v) for v in s], dtype=object)
    return out


def export_folder(folder: Path, fmt: str = "csv", out: Path | None = None, series: bool = False,
                  overwrite: bool = False) -> list[Path]:
    """Write the folder's tables as ``fmt`` into ``out`` (default ``folder/export``); return the paths."""
    if fmt not in FORMATS:
        raise NespmError(f"--format: choose {' or '.join(FORMATS)}, got {fmt!r}")
    folder = Path(folder)
    tables = export_tables(folder, series)
    out = Path(out) if out is not None else folder / "export"
    out.mkdir(parents=True, exist_ok=True)
    targets = ([out / f"{t}.csv" for t in tables] if fmt == "csv"
               else [out / f"{folder.resolve().name or 'results'}.mat"])
    existing = [p for p in targets if p.exists()]
    if existing and not overwrite:
        raise NespmError(f"{existing[0]}: exists; use --overwrite or another --out")
    if fmt == "csv":
        for (name, df), path in zip(tables.items(), targets):
            write_text_atomic(path, df.to_csv(index=False, float_format="%.17g", na_rep="NaN"))
        return targets
    from scipy.io import savemat

    tmp = targets[0].with_suffix(".mat.tmp")
    savemat(tmp, {name: mat_struct(df) for name, df in tables.items()}, do_compression=True)
    tmp.replace(targets[0])
    return targets


__all__ = ["FORMATS", "export_folder", "export_tables", "mat_struct"]
