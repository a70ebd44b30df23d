"""Atomic file writes, written once for every layer that saves files.

Lives in ``data`` (below vehicles, filters, experiments and reports) so every writer can
use it; ``nav`` and ``errors`` write no files.
"""
from __future__ import annotations

import errno
import os
import socket
import uuid
from collections.abc import Callable
from pathlib import Path

from nespm_cli.errors import NespmError


def write_atomic(path: str | Path, write: Callable[[Path], object]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it onto ``path``.

    Any OSError (a full disk, a read-only folder) becomes one line naming ``path``
    (:func:`write_error`). Readers never see a partial file, and after a crash (power loss included: the data is
    synced before the rename) the file is either the old one or the whole new one. The temporary name holds host, process and a random
    part, so workers of several hosts writing into one shared folder never collide; a failed
    write leaves no temporary behind (and the exception propagates).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        write(tmp)
        sync_file(tmp)  # the data is on disk before the name points at it: a crash leaves no empty file
        os.replace(tmp, path)
        sync_dir(path.parent)
    except OSError as exc:
        raise write_error(path, exc) from None
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass


class WriteError(NespmError):
    """A file could not be written (one line naming it; ``errno`` the system's reason)."""

    def __init__(self, message: str, errno_: int | None = None):
        super().__init__(message)
        self.errno = errno_


def write_error(path: Path, exc: OSError) -> WriteError:
    """One line for a failed write of ``path``: the path and the reason (a full disk said so)."""
    if exc.errno == errno.ENOSPC:
        return WriteError(f"{path}: cannot write: no space left on the device (is the disk full?)", exc.errno)
    if exc.errno == errno.ENOENT and not path.parent.exists():
        return WriteError(f"{path}: cannot write: its folder {path.parent} does not exist here", exc.errno)
    reason = exc.strerror or " ".join(str(exc).split()) or exc.__class__.__name__
    return WriteError(f"{path}: cannot write ({reason})", exc.errno)


def sync_file(path: Path) -> None:
    """``fsync`` the file ``path`` (its data, before a rename makes it visible)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sync_dir(folder: Path) -> None:
    """``fsync`` a folder (its entries, after a rename); a file system that cannot is skipped."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_text_atomic(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (:func:`write_atomic`)."""
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding=encoding))
