"""``nespm export``: a results folder's tables for people who analyse elsewhere (CSV, MATLAB).

What is exported is exactly what the folder's last assembly recorded in its manifest
(:mod:`nespm_cli.experiments.snapshot`), read under a shared lock on the folder (an ``mc`` extending
it is refused while export reads, and export is refused while one writes): ``metrics.parquet`` (one
row per track, filter and run) and ``epochs.parquet`` (per epoch, across runs), each checked against
the SHA-256 the assembly recorded and against the manifest's runs, and with ``--series`` the per-run
per-epoch errors of the series chunks the assembly read, in its order, each verified (identity and
content hash); no other file of ``chunks/`` is read. A finished folder of an older version (no
record) exports its tables after the run-count check; ``--series`` needs the record. Beside the tables: every column's unit
(:mod:`nespm_cli.reports.schema`, the one copy of docs/results-schema.md's units) and the study's
metadata (:func:`study_meta`: command, experiment, versions, seed, tracks, runs, filters, sensors
with their resolved options, every option). Formats:

* ``csv``: one ``<table>.csv`` per table, full precision (``%.17g``), NaN as ``NaN``, booleans as
  ``True``/``False``; ``units.csv`` (``table, column, unit``) and ``meta.json`` beside them;
* ``mat``: one ``<folder name>.mat`` (``scipy.io.savemat``, MATLAB 5 format) holding one struct per
  table whose fields are its columns as column vectors (numbers as double, booleans as logical,
  text as a cellstr: an N x 1 cell of char row vectors, ``''`` for an empty text), and ``meta``: the
  study's metadata (texts as char, lists of texts as cellstr, lists of numbers as double vectors,
  JSON null as ``[]``) with ``meta.units.<table>.<field>`` the unit of every field (char, ``''``
  for a count, ratio or text). ``S = load('x.mat'); S.metrics.vrmse; S.meta.units.metrics.vrmse``.

Nothing in the folder is changed; an existing output file is refused unless ``overwrite``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError

FORMATS = ("csv", "mat")
MAT_NAME_MAX = 31  # MATLAB's field-name length limit
#: manifest keys copied into the exported metadata (the rest: timings and per-chunk records)
META_KEYS = ("experiment", "command", "seed", "data_dir", "git_commit", "started", "finished", "wall_seconds",
             "versions", "run_blocks", "sensors", "filter_config", "inputs")


def export_tables(folder: Path, series: bool = False) -> tuple[dict[str, pd.DataFrame], dict]:
    """``({table: DataFrame}, manifest)`` of the folder's exportable tables, read as one consistent state
    (module docstring); one-line errors naming what is missing, changed or being written."""
    from nespm_cli.experiments.snapshot import ReadLock, finished_state, recorded_chunks
    from nespm_cli.reports.results import check_complete, read_manifest_file, read_parquet

    folder = Path(folder)
    if not (folder / "metrics.parquet").is_file():
        raise NespmError(f"{folder}: no metrics.parquet (not a finished nespm mc/sweep folder)")
    with ReadLock(folder, "export"):
        manifest = read_manifest_file(folder / "manifest.json")
        rec = finished_state(folder, manifest, "export", need_record=series)  # --series: the chunks it names
        tables = {}
        for name in ("metrics", "epochs"):
            p = folder / f"{name}.parquet"
            if p.is_file():
                tables[name] = read_parquet(p)
        check_complete(tables["metrics"], manifest, folder / "metrics.parquet")
        if series:
            files = recorded_chunks(folder, rec, "series")
            if not files:
                raise NespmError(f"{folder}: --series asks for the per-run series, but the folder's assembly read "
                                 "no series chunk")
            tables["series"] = pd.concat([read_parquet(f) for f in files], ignore_index=True)
    return tables, manifest


def study_meta(manifest: dict) -> dict:
    """The study's metadata for the export: the manifest's essentials (:data:`META_KEYS`) and every option."""
    meta = {k: manifest[k] for k in META_KEYS if k in manifest}
    if isinstance(meta.get("command"), list):
        meta["command"] = " ".join(str(a) for a in meta["command"])
    opts = manifest.get("options") or {}
    meta.setdefault("experiment", "sweep" if "sweep" in opts else "mc")
    meta["options"] = opts
    if isinstance(meta.get("inputs"), dict):  # {path: sha256} -> two lists (a path is no field name)
        meta["inputs"] = {"path": list(meta["inputs"]), "sha256": list(meta["inputs"].values())}
    return meta


def column_units(tables: dict[str, pd.DataFrame]) -> dict[str, dict[str, str]]:
    """``{table: {column: unit}}`` of the exported columns (:func:`nespm_cli.reports.schema.unit_of`;
    ``"?"`` for a column the schema does not define)."""
    from nespm_cli.reports.schema import unit_of

    out = {}
    for name, df in tables.items():
        out[name] = {}
        for col in df.columns:
            u = unit_of(name, str(col))
            out[name][str(col)] = "?" if u is None else u
    return out


def mat_name(col) -> str:
    """A valid MATLAB field name for ``col`` (letters, digits, ``_``; at most 31 characters)."""
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in str(col))
    return (name if name[:1].isalpha() else f"c_{name}")[:MAT_NAME_MAX]


def cellstr(values) -> np.ndarray:
    """An (N, 1) object array of str: a MATLAB cellstr (missing values as ``''``)."""
    out = np.empty((len(values), 1), dtype=object)
    for i, v in enumerate(values):
        out[i, 0] = "" if v is None or (isinstance(v, float) and np.isnan(v)) or v is pd.NA else str(v)
    return out


def mat_struct(df: pd.DataFrame) -> dict:
    """A table as a MATLAB struct: ``{field: (rows, 1) double, logical or cellstr}`` (:func:`mat_name`)."""
    out = {}
    for col in df.columns:
        s = df[col]
        if pd.api.types.is_bool_dtype(s):
            out[mat_name(col)] = s.to_numpy(dtype=bool).reshape(-1, 1)
        elif pd.api.types.is_numeric_dtype(s):
            out[mat_name(col)] = s.to_numpy(dtype=float).reshape(-1, 1)
        else:
            out[mat_name(col)] = cellstr(s.tolist())
    return out


def mat_value(v):
    """A JSON value as MATLAB data: dict -> struct, str -> char, bool -> logical, number -> double,
    a list of str -> cellstr, a list of numbers -> double vector, other lists -> cell, None -> ``[]``."""
    if isinstance(v, dict):
        return {mat_name(k): mat_value(x) for k, x in v.items()} if v else np.zeros((0, 0))
    if isinstance(v, str):
        return v
    if isinstance(v, (bool, np.bool_)):
        return np.array([[bool(v)]])
    if isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    if v is None:
        return np.zeros((0, 0))
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(x, str) for x in v):
            return cellstr(v).T
        if v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            return np.asarray(v, dtype=float).reshape(1, -1)
        cell = np.empty((1, len(v)), dtype=object)
        for i, x in enumerate(v):
            cell[0, i] = mat_value(x)
        return cell if v else np.zeros((0, 0))
    return str(v)


def export_folder(folder: Path, fmt: str = "csv", out: Path | None = None, series: bool = False,
                  overwrite: bool = False) -> list[Path]:
    """Write the folder's tables as ``fmt`` into ``out`` (default ``folder/export``); return the paths."""
    if fmt not in FORMATS:
        raise NespmError(f"--format: choose {' or '.join(FORMATS)}, got {fmt!r}")
    folder = Path(folder)
    tables, manifest = export_tables(folder, series)
    units, meta = column_units(tables), study_meta(manifest)
    out = Path(out) if out is not None else folder / "export"
    out.mkdir(parents=True, exist_ok=True)
    targets = ([out / f"{t}.csv" for t in tables] + [out / "units.csv", out / "meta.json"] if fmt == "csv"
               else [out / f"{folder.resolve().name or 'results'}.mat"])
    existing = [p for p in targets if p.exists()]
    if existing and not overwrite:
        raise NespmError(f"{existing[0]}: exists; use --overwrite or another --out")
    if fmt == "csv":
        for (name, df), path in zip(tables.items(), targets):
            write_text_atomic(path, df.to_csv(index=False, float_format="%.17g", na_rep="NaN"))
        rows = [(t, c, u) for t, cols in units.items() for c, u in cols.items()]
        write_text_atomic(targets[-2], pd.DataFrame(rows, columns=["table", "column", "unit"]).to_csv(index=False))
        write_text_atomic(targets[-1], json.dumps({**meta, "units": units}, indent=2, default=str))
        return targets
    from scipy.io import savemat

    data = {name: mat_struct(df) for name, df in tables.items()}
    data["meta"] = mat_value({**meta, "units": {t: {mat_name(c): u for c, u in cols.items()} for t, cols in units.items()}})
    tmp = targets[0].with_suffix(".mat.tmp")
    savemat(tmp, data, do_compression=True, oned_as="column")
    tmp.replace(targets[0])
    return targets


__all__ = ["FORMATS", "META_KEYS", "cellstr", "column_units", "export_folder", "export_tables", "mat_struct",
           "mat_value", "study_meta"]
