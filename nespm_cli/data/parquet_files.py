"""How nespm writes Parquet: which columns get a dictionary, and a data frame written atomically.

Every Parquet file nespm writes (results chunks and their assembled tables, realizations, single runs,
tuning trials) goes through :func:`dictionary_columns`, so the rule is made once.
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
    to plain pages once it grows, and the attempt was ~70 % of writing a results chunk (UKF-NESPM's writing
    per extra run 1.14 -> 0.45 ms CPU; the main job's chunks 24.6 -> 21.4 MB; benchmarks/README.md). The
    values read back are the same.
    """
    import pyarrow as pa

    return [f.name for f in schema if not pa.types.is_floating(f.type)]


def write_parquet_atomic(df: "pd.DataFrame", path: str | Path) -> None:
    """``df`` to ``path`` as Parquet (no index), atomically (:func:`~nespm_cli.data.atomic.write_atomic`),
    the floats without a dictionary (:func:`dictionary_columns`)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    write_atomic(path, lambda tmp: pq.write_table(table, tmp, use_dictionary=dictionary_columns(table.schema)))


__all__ = ["dictionary_columns", "write_parquet_atomic"]
