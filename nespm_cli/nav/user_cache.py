"""The per-user cache folder: where nespm keeps what it computes once per machine (the compiled
kernels, :mod:`nespm_cli.nav.kernels`; the embedded tracks' arrays, :mod:`nespm_cli.data.embedded_cache`).

A light module (the standard library only), so that a command which needs the folder and not the
kernels (``nespm tracks``) does not import numba.
"""
from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

ENV_CACHE = "NESPM_CACHE_DIR"


def cache_base() -> Path:
    """Where the per-user cache lives: ``$NESPM_CACHE_DIR``, else ``$NUMBA_CACHE_DIR``, else the
    platform's per-user cache folder (``$XDG_CACHE_HOME/nespm`` or ``~/.cache/nespm``; macOS
    ``~/Library/Caches/nespm``; Windows ``%LOCALAPPDATA%\\nespm\\Cache``)."""
    for var in (ENV_CACHE, "NUMBA_CACHE_DIR"):
        if os.environ.get(var):
            return Path(os.environ[var]).expanduser()
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA") or "~/AppData/Local").expanduser() / "nespm" / "Cache"
    if sys.platform == "darwin":
        return Path("~/Library/Caches/nespm").expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    return (Path(xdg) if os.path.isabs(xdg) else Path("~/.cache").expanduser()) / "nespm"


def sources_digest(seed: str, sources: tuple[str, ...]) -> str:
    """16 hex digits of SHA-256 over ``seed`` (the versions the cached thing also depends on) and the
    text (not the path or mtime) of each of ``sources`` (paths relative to the package): the name of a
    cache subfolder, which any edit to one of them changes."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256(seed.encode())
    for rel in sources:
        h.update(rel.encode() + b"\0")
        h.update((root / rel).read_bytes())
    return h.hexdigest()[:16]


__all__ = ["ENV_CACHE", "cache_base", "sources_digest"]
