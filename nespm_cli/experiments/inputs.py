"""The input files of an experiment: tracks read once per process, hashed as they were read.

A results folder's numbers depend on its input files (each track's GT, DVL and, with
``--imu recorded``, IMU file; the ProcessNet weights; the corrections file; the plugins' code).
The manifest records a SHA-256 of each. To make that record true for every chunk, a file's hash
is taken when it is *read*: :func:`prepared` hashes a track's files before and after parsing
them (a file edited during the read is refused) and keeps the hashes in :data:`READ_HASHES`;
the parent writes the manifest from them, and every worker compares the hashes of what it read
with the manifest before it computes a chunk (:func:`verify_read`). A file edited while an
experiment runs therefore stops it with one line, instead of mixing two datasets under one hash.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from nespm_cli.data.corrections import Corrections, apply_corrections
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.synthesis_cache import synthesized
from nespm_cli.data.track import Track
from nespm_cli.data.tracks import load_track, track_files
from nespm_cli.errors import NespmError
from nespm_cli.experiments.store import file_hashes
from nespm_cli.nav.synthesis import DEFAULT_IMU_RATE, ImuTruth, from_recorded

#: ``{absolute path: sha256}`` of every file this process has read through :func:`prepared`
READ_HASHES: dict[str, str] = {}


def read_track(number: int, data_dir: str | None, imu: str, accept_residual: bool | None = None) -> Track:
    """Track ``number`` from ``data_dir`` (None: the embedded default), its files hashed around the
    read into :data:`READ_HASHES`; a file that changes during the read is a one-line error.
    ``accept_residual``: :func:`~nespm_cli.data.tracks.load_track`'s (None: the track spec's key decides)."""
    if data_dir is None:
        return embedded_track(number)
    files = track_files(number, data_dir, imu == "recorded")
    before = file_hashes(files)
    track = load_track(number, data_dir, accept_residual=accept_residual)
    after = file_hashes(files)
    for path, digest in after.items():
        if before[path] != digest:
            raise NespmError(f"{path}: changed while it was read; wait until it is written, then run again")
    READ_HASHES.update(after)
    return track


def prepared(number: int, data_dir: str | None, imu: str,
             corrections: Corrections = Corrections(), imu_rate: float = DEFAULT_IMU_RATE,
             accept_residual: bool | None = None) -> tuple[Track, ImuTruth]:
    """Track (corrected) and its IMU-rate truth/IMU, computed once per process and file version:
    the cache key holds the files' size, modification time and inode, so a file changed since it
    was read is read (and hashed) again. ``imu_rate`` [Hz]: the synthesized IMU's rate
    (:func:`substeps_for`; a recorded IMU keeps its own). ``accept_residual``: as :func:`read_track`."""
    # None is the embedded default here (validate resolved $NESPM_DATA_DIR on the client), never
    # the worker's own $NESPM_DATA_DIR
    stamp = () if data_dir is None else tuple(file_stamp(p) for p in track_files(number, data_dir, imu == "recorded"))
    return prepared_version(number, data_dir, imu, corrections, stamp, float(imu_rate), accept_residual)


def file_stamp(path: Path) -> tuple:
    """``(size, mtime_ns, inode)`` of ``path`` (``()`` if it cannot be read: the read then says why)."""
    try:
        st = Path(path).stat()
    except OSError:
        return ()
    return (st.st_size, st.st_mtime_ns, st.st_ino)


@lru_cache(maxsize=16)
def prepared_version(number: int, data_dir: str | None, imu: str, corrections: Corrections,
                     stamp: tuple, imu_rate: float = DEFAULT_IMU_RATE,
                     accept_residual: bool | None = None) -> tuple[Track, ImuTruth]:
    """:func:`prepared` of one version (``stamp``) of the track's files. A track without ground truth keeps
    its first epoch (its initial state): a ``--window`` or time offset that drops it is one line."""
    track = read_track(number, data_dir, imu, accept_residual)
    try:
        track = apply_corrections(track, corrections)
    except ValueError:  # Track: a track without truth lost the epoch of its initial state
        if track.truth:
            raise
        raise NespmError(f"track {number}: --window or a time offset drops its first epoch ({float(track.t[0])!r} s), "
                         "where its initial state ([init]) is given and no ground truth after it; start the window "
                         "at or before it") from None
    if imu == "synthetic":
        return track, synthesized(track, substeps_for(track, imu_rate))  # from the per-user cache where kept
    return track, from_recorded(track)


def substeps_for(track: Track, imu_rate: float) -> int:
    """IMU steps per GT interval of a synthesized IMU at about ``imu_rate`` Hz: ``round(imu_rate x the
    median GT step)``, at least 1 (the Snapir GT step of 400/399 s at 100 Hz: 100 steps of 10.025 ms)."""
    import numpy as np

    return max(1, int(round(float(imu_rate) * float(np.median(np.diff(track.t))))))


def verify_read(expected: dict[str, str], paths) -> None:
    """Compare what this process read of ``paths`` (:data:`READ_HASHES`, else the file now) with the
    manifest's ``expected`` hashes; a difference is a one-line error naming the file."""
    for p in paths:
        p = str(Path(p).resolve())
        if p not in expected:
            continue
        got = READ_HASHES.get(p) or file_hashes([p])[p]
        if got != expected[p]:
            raise NespmError(f"{p}: changed while the experiment ran (sha256 {expected[p][:12]}... when it started, "
                             f"{got[:12]}... now); its results would mix two datasets: restore the file and re-run "
                             "the same command, or use a new --out folder")


__all__ = ["DEFAULT_IMU_RATE", "READ_HASHES", "file_stamp", "substeps_for", "prepared", "prepared_version", "read_track", "verify_read"]
