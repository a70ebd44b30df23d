"""Atomic file writes, written once for every layer that saves files.

Lives in ``data`` (below vehicles, filters, experiments and reports) so every writer can
use it; ``nav`` and ``errors`` write no files.
"""
from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Callable
from pathlib import Path


def write_atomic(path: str | Path, write: Callable[[Path], object]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it onto ``path``.

    Readers never see a partial file. The temporary name holds host, process and a random
    part, so workers of several hosts writing into one shared folder never collide; a failed
    write leaves no temporary behind (and the exception propagates).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (:func:`write_atomic`)."""
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding=encoding))
