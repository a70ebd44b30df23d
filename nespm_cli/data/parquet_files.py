"""How nespm writes Parquet: which columns get a dictionary, and a data frame written atomically.

Every Parquet file nespm writes (results chunks and their assembled tables, realizations, single runs,
tuning trials) is written through :func:`parquet_writer`, so the encoding rule is made once.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from nespm_cli.data.atomic import write_atomic

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd


def dictionary_columns(schema) -> list[str]:
    """The columns of a pyarrow ``schema`` stored with a dictionary: all but the floating-point ones.

    Names, ids, epochs and flags repeat, and a dictionary stores them in a few bytes. Floats (errors,
    NEES, IMU samples) rarely repeat: pyarrow's default attempts a dictionary for them too and falls back
    to plain pages once it grows, and the attempt was about 60 % of writing a results chunk (UKF-NESPM's
    writing per extra run 1.14 -> 0.45 ms CPU; the main job's chunks 24.6 -> 21.4 MB; benchmarks/README.md).
    The values read back are the same.
    """
    import pyarrow as pa

    return [f.name for f in schema if not pa.types.is_floating(f.type)]


def parquet_writer(where, schema):
    """A ``pyarrow.parquet.ParquetWriter`` on ``where`` (a path or a writable file) for ``schema``, with
    dictionaries for :func:`dictionary_columns` only. The caller writes its tables and closes it."""
    import pyarrow.parquet as pq

    return pq.ParquetWriter(where, schema, use_dictionary=dictionary_columns(schema))


def write_parquet_atomic(df: "pd.DataFrame", path: str | Path) -> None:
    """``df`` to ``path`` as Parquet (no index), atomically (:func:`~nespm_cli.data.atomic.write_atomic`),
    through :func:`parquet_writer`."""
    import pyarrow as pa

    table = pa.Table.from_pandas(df, preserve_index=False)

    def write(tmp: Path) -> None:
        with parquet_writer(tmp, table.schema) as writer:
            writer.write_table(table)

    write_atomic(path, write)


__all__ = ["dictionary_columns", "parquet_writer", "write_parquet_atomic"]
