"""Chunk files of a results folder: written with their identity, verified before they are used.

A chunk file (``OUT/chunks/<kind>-<...>.parquet``) is one filter's results for a block of
runs. Each carries, in its Parquet key-value metadata under :data:`IDENTITY_KEY`, a small JSON
record: the *experiment digest* (a SHA-256 of the folder's options without the options that may
grow, :func:`experiment_digest`), the file's own name, its row count and ``sha256``, the SHA-256 of
the file's bytes before its footer (every data page: the content; the footer that holds the record
cannot hash itself). A file counts as a finished chunk of an experiment only when it reads as
Parquet, that record matches and its bytes hash to ``sha256`` (:func:`chunk_problem`); anything
else — a zero-byte or truncated file, a file of another experiment, a renamed or copied one, a
"(conflicted copy)", a hand-edited one — is named and never mixed into the results. The bytes are
hashed once as they are written and once per process when verified (a file unchanged since, by
size, time and inode, is not hashed again). Chunks of older nespm versions carry no ``sha256`` and
are verified without it. Files are written atomically and synced first (:func:`nespm_cli.data.atomic.write_atomic`),
so a crash cannot leave a partial chunk under a final name.

Assembly reads exactly the chunks a folder expects, one at a time
(:func:`concat_parquet`), so a table of any size is written with the memory of one chunk.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import struct
from pathlib import Path

from nespm_cli.data.atomic import write_atomic
from nespm_cli.data.parquet_files import parquet_writer
from nespm_cli.errors import NespmError

IDENTITY_KEY = b"nespm.chunk"


def experiment_digest(options: dict, extendable: tuple[str, ...] = ()) -> str:
    """SHA-256 (hex) of ``options`` without the ``extendable`` keys (canonical JSON)."""
    core = {k: v for k, v in options.items() if k not in extendable}
    text = json.dumps(core, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class _HashingSink(io.RawIOBase):
    """A writable file that hashes (SHA-256) every byte written through it."""

    def __init__(self, f) -> None:
        super().__init__()
        self.f, self.sha = f, hashlib.sha256()

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        self.sha.update(b)
        return self.f.write(b)


def write_chunk(df: pd.DataFrame, path: Path, experiment: str) -> None:
    """Write ``df`` to ``path`` atomically, with its identity (``experiment`` digest, name, rows and the
    SHA-256 of the data bytes, taken as they are written)."""
    import pyarrow as pa

    path = Path(path)
    table = pa.Table.from_pandas(df, preserve_index=False)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            sink = _HashingSink(f)
            writer = parquet_writer(sink, table.schema)
            try:
                writer.write_table(table)  # every data page reaches the sink here; the footer at close
                ident = {"experiment": experiment, "name": path.name, "rows": len(df), "sha256": sink.sha.hexdigest()}
                writer.add_key_value_metadata({IDENTITY_KEY: json.dumps(ident).encode()})
            finally:
                writer.close()

    write_atomic(path, write)


_HASHED: dict[tuple, str] = {}  # (path, size, mtime_ns, inode) -> sha256 of the data bytes: hashed once per process


def data_sha256(path: Path) -> str:
    """SHA-256 (hex) of a Parquet file's bytes before its footer (what :func:`write_chunk` hashes)."""
    st = os.stat(path)
    key = (str(path), st.st_size, st.st_mtime_ns, st.st_ino)
    if key not in _HASHED:
        with open(path, "rb") as f:
            f.seek(-8, os.SEEK_END)
            footer = struct.unpack("<I", f.read(4))[0]
            end = st.st_size - 8 - footer
            f.seek(0)
            sha, left = hashlib.sha256(), end
            while left > 0:
                block = f.read(min(left, 1 << 22))
                if not block:
                    break
                sha.update(block)
                left -= len(block)
        if len(_HASHED) > 100_000:
            _HASHED.clear()
        _HASHED[key] = sha.hexdigest()
    return _HASHED[key]


def chunk_problem(path: Path, experiment: str) -> str | None:
    """None when ``path`` is a complete chunk file of ``experiment``, else what is wrong with it
    (``missing``, ``unreadable (...)``, ``written by another experiment``, ``edited after it was
    written``, ...)."""
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.exists():
        return "missing"
    if not path.is_file():
        return "not a regular file"
    try:
        pf = pq.ParquetFile(path)
        meta = pf.metadata.metadata or {}
        rows = pf.metadata.num_rows
    except Exception as exc:  # zero bytes, truncated, not Parquet
        return f"unreadable ({exc.__class__.__name__}: {' '.join(str(exc).split())[:80]})"
    raw = meta.get(IDENTITY_KEY)
    if raw is None:
        return "has no nespm chunk identity (written by another program or an older nespm)"
    try:
        ident = json.loads(raw)
        exp, name, n = ident["experiment"], ident["name"], int(ident["rows"])
        sha = ident.get("sha256")
    except (ValueError, KeyError, TypeError):
        return "has an unreadable chunk identity"
    if exp != experiment:
        return "was written by a different experiment"
    if name != path.name:
        return f"is a copy of chunk {name}"
    if n != rows:
        return f"holds {rows} rows where its writer wrote {n}"
    if sha is not None:
        try:
            now = data_sha256(path)
        except (OSError, struct.error) as exc:
            return f"unreadable ({exc.__class__.__name__})"
        if now != sha:
            return "was edited after it was written (its content hash does not match)"
    return None


def concat_parquet(paths: list[Path], out: Path) -> int:
    """Write the rows of ``paths`` (in order, equal schemas) into ``out`` atomically, one file in
    memory at a time; return the row count. The chunks' identities are not copied."""
    import pyarrow.parquet as pq

    total = 0

    def write(tmp: Path) -> None:
        nonlocal total
        writer = None
        try:
            for p in paths:
                table = pq.read_table(p)
                table = table.replace_schema_metadata({k: v for k, v in (table.schema.metadata or {}).items()
                                                       if k != IDENTITY_KEY})
                if writer is None:
                    writer = parquet_writer(tmp, table.schema)
                elif table.schema != writer.schema:
                    table = table.cast(writer.schema)
                writer.write_table(table)
                total += table.num_rows
        finally:
            if writer is not None:
                writer.close()

    if not paths:
        raise NespmError(f"{out}: no chunk to assemble")
    write_atomic(out, write)
    return total


__all__ = ["IDENTITY_KEY", "chunk_problem", "concat_parquet", "data_sha256", "experiment_digest", "write_chunk"]
