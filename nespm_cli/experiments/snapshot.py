"""Reading a finished results folder as one consistent state (``export``, ``compare``).

A reader takes a shared lock on ``OUT/.lock`` (:class:`ReadLock`): refused in one line while a
writer holds it (an ``mc`` extending the folder), and while it is held a writer is told the folder
is busy. It reads exactly what the last assembly recorded in the manifest (``assembled``, written
by :class:`nespm_cli.experiments.store.ResultsFolder`): the chunk files in their order, each
verified by its identity and content hash, and the tables, whose SHA-256 must match
(:func:`assembled_record`, :func:`recorded_chunks`). Nothing else in ``chunks/`` is read.
"""
from __future__ import annotations

import os
from pathlib import Path

from nespm_cli.errors import NespmError
from nespm_cli.experiments.chunks import chunk_problem
from nespm_cli.experiments.store import LOCK_FILE, file_hashes


class ReadLock:
    """A shared lock on a finished results folder while a command reads it (``export``, ``compare``):
    refused in one line while a writer holds ``OUT/.lock`` (an ``mc`` extending it: the folder is
    half-written), and while it is held a writer is told the folder is busy, so what is read is one
    consistent state. A folder without ``.lock`` (copied, read-only) is read without a lock.
    Use as a context manager."""

    def __init__(self, out: Path, what: str) -> None:
        import fcntl

        self.fd = None
        path = Path(out) / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            return  # no lock file (or a link, which the writer refuses): nobody can be writing through it
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.read(fd, 32).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise NespmError(f"{out}: another nespm process (pid {pid}) is writing this folder now; {what} would "
                             "read a half-written state; wait for it to finish") from None
        except OSError:
            os.close(fd)
            return
        self.fd = fd

    def __enter__(self) -> "ReadLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def assembled_record(out: Path, manifest: dict, what: str) -> dict:
    """The manifest's record of the last assembly (``assembled``: the chunk experiment digest, the
    chunk files in the order assembled, the SHA-256 of each table), after checking that the folder's
    last run finished and that its tables are the ones assembled (one line otherwise)."""
    out = Path(out)
    if manifest.get("finished") is None:
        raise NespmError(f"{out}: its last run did not finish (interrupted, or still running); {what} reads only "
                         "finished folders: re-run the same command to complete it")
    rec = manifest.get("assembled")
    if not isinstance(rec, dict) or not isinstance(rec.get("chunks"), list) or not isinstance(rec.get("tables"), dict):
        raise NespmError(f"{out}/manifest.json: no record of the assembled chunks (a folder of an older nespm); "
                         f"re-run the same command on it (it computes nothing new) to record them, then {what}")
    for name, digest in rec["tables"].items():
        p = out / str(name)
        try:
            now = file_hashes([p])[str(p.resolve())]
        except NespmError:
            now = None
        if now != digest:
            raise NespmError(f"{p}: is not the table nespm assembled into this folder (changed or missing since; "
                             "sha256 differs); re-run the same command to assemble it again")
    return rec


def finished_state(out: Path, manifest: dict, what: str, need_record: bool = False) -> dict | None:
    """The :func:`assembled_record` of a finished folder, or None for a finished folder of an older nespm
    (no record; refused when ``need_record``, e.g. to read its chunks); one line for an unfinished run."""
    if "assembled" in manifest or need_record:
        return assembled_record(out, manifest, what)
    if manifest.get("finished") is None:
        raise NespmError(f"{out}: its last run did not finish (interrupted, or still running); {what} reads only "
                         "finished folders: re-run the same command to complete it")
    return None


def recorded_chunks(out: Path, rec: dict, kind: str) -> list[Path]:
    """The ``kind`` (``metrics``, ``series``) chunk files of an :func:`assembled_record`, in assembly order,
    each verified (identity and content hash); one line naming a missing or changed one. Other files in
    ``chunks/`` are never read."""
    out = Path(out)
    paths = []
    for name in rec["chunks"]:
        if not (isinstance(name, str) and name.startswith(f"{kind}-")) or "/" in name or name.startswith("."):
            continue
        problem = chunk_problem(out / "chunks" / name, str(rec.get("experiment")))
        if problem is not None:
            raise NespmError(f"{out / 'chunks' / name}: {problem}; re-run the same command to compute it again")
        paths.append(out / "chunks" / name)
    return paths


__all__ = ["ReadLock", "assembled_record", "finished_state", "recorded_chunks"]
