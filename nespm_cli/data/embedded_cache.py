"""The embedded tracks' arrays kept on disk, so that a process reads them instead of building them
(building the six takes about 0.09 CPU-s, a fifth of ``nespm tracks``; reading them about 3 ms).

A track's arrays (``t``, ``pos``, ``v_n``, ``euler``, ``dvl``) are written once, atomically, to
``cache_base()/embedded-<key>/track<N>.npz`` (:func:`nespm_cli.nav.user_cache.cache_base`), where the
key is a hash of the text of the modules that compute them (:data:`SOURCES`) and of NumPy's version:
an edit to any of them, or another NumPy, builds afresh. The file holds the very bits the build gave
(tests/test_embedded.py compares them). Never raises: a folder that cannot be written, or a file that
cannot be read (truncated, foreign), only means the track is built as before.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from nespm_cli.nav.user_cache import cache_base, sources_digest

#: the modules (relative to the package) whose text the embedded tracks' arrays depend on
SOURCES = ("data/embedded.py", "nav/dvl.py", "nav/earth.py", "nav/trig.py", "nav/rotations.py", "nav/strapdown.py", "nav/products.py")
ARRAYS = ("t", "pos", "v_n", "euler", "dvl")


@functools.lru_cache(maxsize=None)
def source_key() -> str:
    """16 hex digits of SHA-256 over :data:`SOURCES`' text and NumPy's version."""
    return sources_digest(f"numpy {np.__version__}", SOURCES)


def cache_file(number: int) -> Path:
    """Where track ``number``'s arrays are kept."""
    return cache_base() / f"embedded-{source_key()}" / f"track{int(number)}.npz"


def load(number: int) -> dict[str, np.ndarray] | None:
    """Track ``number``'s arrays from its cache file; None where there is none or it cannot be read."""
    try:
        with np.load(cache_file(number), allow_pickle=False) as z:
            out = {k: np.array(z[k]) for k in ARRAYS}
    except Exception:  # noqa: BLE001 - any unreadable file is only a cache miss
        return None
    return out


def save(number: int, arrays: dict[str, np.ndarray]) -> None:
    """Write track ``number``'s arrays (:data:`ARRAYS`) to its cache file, atomically; silent on failure."""
    from nespm_cli.data.atomic import write_atomic

    path = cache_file(number)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: np.asarray(arrays[k]) for k in ARRAYS})

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, write)
    except Exception:  # noqa: BLE001 - a cache that cannot be written is no error
        pass


__all__ = ["ARRAYS", "SOURCES", "cache_file", "load", "save", "source_key"]
