"""A track's synthesized truth and IMU kept on disk, so that a process reads it instead of synthesizing
it again (:func:`nespm_cli.nav.synthesis.synthesize`: about 0.4 CPU-s for a 400 s track, the splines,
the position integral and the inverse strapdown; reading it back about 15 ms). An ``mc`` synthesizes
each track in the parent (to check the study) and in every worker that runs one of its chunks.

A file per track and substeps, ``cache_base()/synth-<source key>/<content key>.npz``
(:func:`nespm_cli.nav.user_cache.cache_base`): the source key is a hash of the text of the modules the
synthesis runs (:data:`SOURCES`) and of NumPy's and SciPy's versions; the content key a hash of what
the synthesis reads of the track (``t``, ``v_n``, ``euler``, the first position) and of the substeps.
So an edited track, another NumPy or SciPy, or an edit to the synthesis synthesizes afresh. The file
holds the very bits the synthesis gave (tests/test_synthesis_cache.py). At most :data:`MAX_BYTES` per
folder: a save removes the least recently used files beyond them (every load marks its file used), so
the many tracks of a test suite do not pile up. Never raises: a folder that cannot be written, or
a file that cannot be read (truncated, foreign), only means the track is synthesized as before.
"""
from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numpy as np

from nespm_cli.nav.synthesis import ImuTruth, synthesize
from nespm_cli.nav.user_cache import cache_base, sources_digest

#: the modules (relative to the package) whose text the synthesized arrays depend on
SOURCES = ("nav/synthesis.py", "nav/earth.py", "nav/trig.py", "nav/rotations.py", "nav/strapdown.py", "nav/products.py")
ARRAYS = ("t", "dt", "pos", "v_n", "C_bn", "f_b", "w_ib_b", "epoch_index")
MAX_BYTES = 256 * 2**20  # per folder: about 35 tracks of 400 s at 100 Hz (7.4 MB each)


@functools.lru_cache(maxsize=None)
def source_key() -> str:
    """16 hex digits of SHA-256 over :data:`SOURCES`' text and NumPy's and SciPy's versions."""
    import scipy

    return sources_digest(f"numpy {np.__version__} scipy {scipy.__version__}", SOURCES)


def content_key(track, substeps: int) -> str:
    """32 hex digits of SHA-256 over what :func:`~nespm_cli.nav.synthesis.synthesize` reads of ``track`` and
    ``substeps``: each array's dtype, shape and bytes."""
    h = hashlib.sha256(f"substeps {int(substeps)}".encode())
    for name, a in (("t", track.t), ("v_n", track.v_n), ("euler", track.euler), ("pos0", np.asarray(track.pos)[:1])):
        a = np.ascontiguousarray(a, dtype=float)
        h.update(f"{name} {a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:32]


def cache_file(track, substeps: int) -> Path:
    """Where the synthesis of ``track`` with ``substeps`` is kept."""
    return cache_base() / f"synth-{source_key()}" / f"{content_key(track, substeps)}.npz"


def load(path: Path) -> ImuTruth | None:
    """The synthesis kept in ``path`` (marked used); None where there is none or it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: np.array(z[k]) for k in ARRAYS}
        os.utime(path)
    except Exception:  # noqa: BLE001 - any unreadable file is only a cache miss
        return None
    return ImuTruth(**arrays, exact=True)


def save(path: Path, imu: ImuTruth) -> None:
    """Write ``imu``'s arrays (:data:`ARRAYS`) to ``path`` atomically, then keep the folder's most recently used
    files within :data:`MAX_BYTES` (``path`` always); silent on failure."""
    from nespm_cli.data.atomic import write_atomic

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: np.asarray(getattr(imu, k)) for k in ARRAYS})

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, write)
        kept = 0
        for f in sorted(path.parent.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True):
            kept += f.stat().st_size
            if kept > MAX_BYTES and f != path:
                f.unlink(missing_ok=True)
    except Exception:  # noqa: BLE001 - a cache that cannot be written is no error
        pass


def synthesized(track, substeps: int) -> ImuTruth:
    """:func:`~nespm_cli.nav.synthesis.synthesize` of ``track`` with ``substeps``, read from the cache where a
    process before kept it, else computed and kept."""
    if not getattr(track, "truth", True):
        return synthesize(track, substeps)  # refused there, in one line
    try:
        path = cache_file(track, substeps)
    except Exception:  # noqa: BLE001 - no cache folder: synthesize as before
        return synthesize(track, substeps)
    got = load(path)
    if got is not None:
        return got
    imu = synthesize(track, substeps)
    save(path, imu)
    return imu


__all__ = ["ARRAYS", "MAX_BYTES", "SOURCES", "cache_file", "content_key", "load", "save", "source_key",
           "synthesized"]
