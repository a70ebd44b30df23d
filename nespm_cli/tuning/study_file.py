"""The file that holds a tuning's studies in ``OUT`` and its check before anything opens it
(docs/tuning.md, "Resumable, shareable").

* ``study.journal`` (:data:`JOURNAL_FILE`): Optuna's journal storage, one JSON operation per line,
  appended under a lock file and fsync'd; what ``nespm tune`` writes.
* ``study.db`` (:data:`SQLITE_FILE`): the SQLite database ``nespm tune`` wrote before the journal
  (folders tuned before 2026-12-07): still read and continued where it is the folder's only study file.

A file that cannot be a study (empty, another file, damaged or cut short) is one line naming it
(:func:`check_study_file`), never a traceback and never an empty study.
"""
from __future__ import annotations

import json
from pathlib import Path

from nespm_cli.errors import NespmError

JOURNAL_FILE = "study.journal"
SQLITE_FILE = "study.db"
SQLITE_MAGIC = b"SQLite format 3\x00"
FRESH = " delete it to start afresh or use another --out"


def study_path(out: Path) -> Path:
    """The study file of the tuning folder ``out``: its ``study.db`` where that is the only one (a tuning
    written before the journal, continued in its own format), else ``study.journal``."""
    out = Path(out)
    if (out / SQLITE_FILE).exists() and not (out / JOURNAL_FILE).exists():
        return out / SQLITE_FILE
    return out / JOURNAL_FILE


def read_head(path: Path) -> bytes | None:
    """The file's bytes up to the SQLite magic's length (None: no such file); an unreadable one is one line."""
    try:
        if not path.exists():
            return None
        with open(path, "rb") as fh:
            return fh.read(len(SQLITE_MAGIC))
    except OSError as exc:
        raise NespmError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def check_journal(path: Path) -> None:
    """One line (NespmError) unless every line of ``path`` is one journal operation (a JSON object with an
    ``op_code``) and the file ends with a whole line (a file cut short does not)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise NespmError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data.endswith(b"\n"):
        raise NespmError(f"{path}: damaged (its last line is cut short, a write cut off or a truncated copy); remove "
                         "that line to keep the trials before it, or delete the file to start afresh or use another --out")
    for number, line in enumerate(data.splitlines(), start=1):
        try:
            op = json.loads(line)
        except ValueError:
            op = None
        if not isinstance(op, dict) or "op_code" not in op:
            raise NespmError(f"{path}: line {number} is not a study journal operation (corrupt or another file);"
                             f"{FRESH}")


def check_sqlite(path: Path, head: bytes) -> None:
    """One line unless ``path`` (whose first bytes are ``head``) is an SQLite file that passes SQLite's quick
    check, read as an immutable file (no lock, no journal or WAL file written beside it)."""
    if head != SQLITE_MAGIC:
        raise NespmError(f"{path}: not an SQLite study database (corrupt or another file);{FRESH}")
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{path.resolve()}?immutable=1", uri=True)
        try:
            got = con.execute("PRAGMA quick_check").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error as exc:
        got = str(exc)
    if got != "ok":
        raise NespmError(f"{path}: a damaged study database ({got});{FRESH}")


def check_study_file(path: Path) -> None:
    """One line (NespmError) when ``path`` exists but cannot be a study file: empty (0 bytes: not taken as an
    empty study), or not (or no longer) what its name says (:func:`check_journal`, :func:`check_sqlite`).
    Run once, before anything opens the file: other workers may be writing it later (an SQLite write-ahead
    log not yet checkpointed reads as damaged to the immutable read)."""
    head = read_head(path)
    if head is None:
        return
    if not head:
        raise NespmError(f"{path}: empty (0 bytes), not a study file;{FRESH}")
    if path.name == SQLITE_FILE:
        check_sqlite(path, head)
    else:
        check_journal(path)


__all__ = ["JOURNAL_FILE", "SQLITE_FILE", "SQLITE_MAGIC", "check_journal", "check_sqlite", "check_study_file",
           "read_head", "study_path"]
