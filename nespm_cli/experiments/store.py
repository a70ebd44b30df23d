"""The results store: one run folder of any experiment (``mc``, ``sweep``, ``gp-ukf``).

A folder ``OUT`` holds ``manifest.json`` (command, options, input-file hashes, versions,
timings; written first, updated after every chunk and at the end), ``.lock`` (taken by the
process writing the folder: a second one is told the folder is busy), ``chunks/`` (one Parquet file per finished chunk and filter,
written atomically: a file exists only once complete, so an interrupted run resumes by
computing only what is missing), and the assembled ``metrics.parquet`` / ``epochs.parquet``
(docs/results-schema.md). The experiment modules say what a chunk computes; this module
owns the lifecycle: refusing a folder of another experiment, extending one to more runs,
the progress display, running the chunks where the backend says, collecting timings.
"""
from __future__ import annotations

import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import pandas as pd

from nespm_cli import __version__
from nespm_cli.data.atomic import write_atomic, write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.progress import PROGRESS_DIR, Poller, Progress

LOCK_FILE = ".lock"  # OUT/.lock: held (flock) by the process writing the folder


# --- atomic files (nespm_cli.data.atomic) ---------------------------------------------------

def write_parquet_atomic(df: pd.DataFrame, path: Path) -> None:
    write_atomic(path, lambda tmp: df.to_parquet(tmp, index=False))


def write_json_atomic(obj, path: Path) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2))


# --- provenance --------------------------------------------------------------------------

def versions() -> dict:
    """Versions of Python, nespm and the numeric stack, for the manifest."""
    import joblib
    import pyarrow
    import scipy

    from nespm_cli.filters.kernels import kernel_backend

    out = {"python": platform.python_version(), "nespm": __version__, "numpy": np.__version__,
           "scipy": scipy.__version__, "pandas": pd.__version__, "pyarrow": pyarrow.__version__,
           "joblib": joblib.__version__, "kernels": kernel_backend()}
    if out["kernels"] == "numba":
        import numba

        out["numba"] = numba.__version__
    return out


def git_commit() -> str | None:
    """The commit of the installed source tree, or None outside a git checkout."""
    try:
        r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                           text=True, timeout=5)
        return r.stdout.strip() or None if r.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


# --- the folder --------------------------------------------------------------------------

def file_hashes(paths) -> dict[str, str]:
    """``{absolute path: sha256 hex}`` of every file in ``paths`` (the inputs of an experiment)."""
    out = {}
    for p in paths:
        p = Path(p).resolve()
        h = hashlib.sha256()
        try:
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        except OSError as exc:
            raise NespmError(f"{p}: cannot read ({exc.strerror or exc.__class__.__name__})") from None
        out[str(p)] = h.hexdigest()
    return out


def check_inputs(out: Path, old: dict | None, inputs: dict[str, str]) -> None:
    """Refuse to resume ``out`` when an input file changed since it was started (one line)."""
    before = (old or {}).get("inputs") or {}
    for path, digest in inputs.items():
        if path in before and before[path] != digest:
            raise NespmError(f"{path}: changed since {out} was started (sha256 {before[path][:12]}... now "
                             f"{digest[:12]}...); restore the file or use a new --out folder")
    gone = sorted(set(before) - set(inputs))
    if gone and set(inputs):
        raise NespmError(f"{gone[0]}: an input of {out} is no longer used or found; use a new --out folder")


def has_results(out: Path) -> bool:
    """Whether ``out`` holds any finished chunk or assembled table."""
    return (out / "metrics.parquet").exists() or any((out / "chunks").glob("metrics-*.parquet"))


class FolderLock:
    """An exclusive lock on a results folder (``OUT/.lock``, ``flock``), held until :meth:`release`
    or the process ends (the system releases it on kill -9 too)."""

    def __init__(self, out: Path) -> None:
        import fcntl

        out.mkdir(parents=True, exist_ok=True)
        self.path = out / LOCK_FILE
        self.handle = open(self.path, "a+")
        try:
            fcntl.flock(self.handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.handle.seek(0)
            pid = self.handle.read().strip() or "?"
            self.handle.close()
            raise NespmError(f"{out}: busy: another nespm process (pid {pid}) is writing this folder; wait "
                             "for it to finish, or use another --out") from None
        self.handle.seek(0)
        self.handle.truncate()
        self.handle.write(str(os.getpid()))
        self.handle.flush()

    def release(self) -> None:
        if not self.handle.closed:
            self.handle.close()


def check_existing(out: Path, options: dict, extendable: tuple[str, ...] = ()) -> dict | None:
    """The old manifest of ``out`` (None for a new folder); refuse another experiment's folder.

    ``extendable``: integer options that may grow (``runs``: more runs extend the folder)
    but never shrink. A manifest without any result (a start that failed before its first
    chunk) is no experiment: the folder counts as new.
    """
    mf = out / "manifest.json"
    if mf.exists() and not has_results(out):
        return None
    if not mf.exists():
        if (out / "chunks").exists() and any((out / "chunks").iterdir()):
            raise NespmError(f"{out}: has chunk files but no manifest.json; use a new --out folder")
        return None
    try:
        old = json.loads(mf.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise NespmError(f"{mf}: unreadable manifest ({exc.__class__.__name__}); use a new --out folder") from None
    before = old.get("options", {})
    diff = sorted(k for k in set(before) | set(options) if before.get(k) != options.get(k))
    grown = [k for k in diff if k in extendable and isinstance(before.get(k), int) and options.get(k, 0) > before[k]]
    shrunk = [k for k in diff if k in extendable and isinstance(before.get(k), int) and options.get(k, 0) < before[k]]
    if shrunk:
        k = shrunk[0]
        raise NespmError(f"{out}: holds {before[k]} {k}; --{k} {options[k]} would drop finished work "
                         f"(give --{k} {before[k]} or more, or use a new --out folder)")
    if set(diff) - set(grown):
        diff = sorted(set(diff) - set(grown))
        raise NespmError(f"{out}: holds results of a different experiment (differs in: {', '.join(diff)}); "
                         "use a new --out folder or the same options to resume")
    return old


def run_blocks(old: dict | None, runs: int) -> list[tuple[int, int]]:
    """The run blocks ``[start, end)`` of a folder asked for ``runs`` runs, given its old manifest.

    One block per ``--runs`` extension; each is cut into chunks from its own start, so
    extending a folder never changes a finished chunk.
    """
    if old is None:
        return [(0, runs)]
    blocks = [tuple(b) for b in old.get("run_blocks") or [(0, int(old["options"]["runs"]))]]
    have = blocks[-1][1]
    return blocks + [(have, runs)] if runs > have else blocks


def chunk_firsts(blocks: Iterable[tuple[int, int]], chunk_size: int) -> list[tuple[int, int]]:
    """``(first, last)`` run ranges of every chunk of ``blocks`` (runs ``first .. last-1``)."""
    return [(f0, min(f0 + chunk_size, end)) for start, end in blocks for f0 in range(start, end, chunk_size)]


@dataclass(frozen=True)
class Task:
    """One chunk to compute: ``fn(*args)`` returns ``(key, timings)``; ``units`` of progress."""

    key: str
    args: tuple
    units: int = 1


class ResultsFolder:
    """The run folder ``out`` of one experiment, identified by ``options``.

    ``open()`` validates the folder (a new one, or one of the same experiment; ``extendable``
    options may grow) and writes the manifest; ``run(...)`` computes the missing chunks;
    ``finish()`` records the end. ``manifest`` can be added to by the experiment.
    """

    def __init__(self, out: str | Path, options: dict, argv: list[str] | None = None,
                 extendable: tuple[str, ...] = ()) -> None:
        self.out = Path(out)
        self.chunks = self.out / "chunks"
        self.options = options
        self.argv = list(argv or sys.argv)
        self.extendable = extendable
        self.old: dict | None = None
        self.manifest: dict = {}
        self.t0 = time.perf_counter()
        self.lock: FolderLock | None = None

    def open(self, inputs: dict[str, str] | None = None, **extra) -> "ResultsFolder":
        """Lock the folder, check it against ``options`` and the ``inputs`` hashes
        (:func:`file_hashes`), write the manifest."""
        if self.out.exists() and not self.out.is_dir():
            raise NespmError(f"--out {self.out}: exists and is not a folder")
        self.lock = FolderLock(self.out)
        self.old = check_existing(self.out, self.options, self.extendable)
        check_inputs(self.out, self.old, inputs or {})
        self.chunks.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self.chunks / PROGRESS_DIR, ignore_errors=True)  # a killed run's stale reports
        old = self.old or {}
        self.manifest = {"command": self.argv, "options": self.options, **extra, "inputs": inputs or {},
                         "versions": versions(), "git_commit": git_commit(),
                         "started": old.get("started", now()), "finished": None,
                         "chunk_seconds": old.get("chunk_seconds", {})}
        for k, v in old.items():  # what the experiment recorded before (e.g. training) survives a resume
            self.manifest.setdefault(k, v)
        self.save()
        self.t0 = time.perf_counter()
        return self

    def save(self) -> None:
        write_json_atomic(self.manifest, self.out / "manifest.json")

    def path(self, name: str) -> Path:
        """The chunk file ``chunks/name``."""
        return self.chunks / name

    def done(self, name: str) -> bool:
        return self.path(name).exists()

    def run(self, fn: Callable, tasks: list[Task], jobs: int, backend: str, scheduler: str | None,
            label: str, progress: bool = True, unit: str = "filter-epochs") -> None:
        """Compute ``tasks`` (``fn(*task.args) -> (key, timings)``) where the backend says, with
        a progress display fed by the workers' reports (:mod:`nespm_cli.experiments.progress`)."""
        from nespm_cli.experiments.backend import parallel_map

        if not tasks:
            return
        units = {t.key: t.units for t in tasks}
        results = parallel_map(fn, [t.args for t in tasks], jobs, backend, scheduler)
        with Progress(label, sum(units.values()), len(tasks), unit=unit, enabled=progress) as bar, \
                Poller(bar, self.chunks) as poller:
            for key, timings in results:
                self.manifest["chunk_seconds"].update(timings)
                self.save()  # a killed run's finished chunks keep their timings
                poller.finish(key)
                bar.chunk_done(units.get(key, 0))
                poller.poll()

    def read(self, kind: str) -> pd.DataFrame:
        """All chunk files ``chunks/<kind>-*.parquet``, concatenated in file-name order."""
        return pd.concat([pd.read_parquet(p) for p in sorted(self.chunks.glob(f"{kind}-*.parquet"))],
                         ignore_index=True)

    def finish(self, chunks: int) -> None:
        old = self.old or {}
        self.manifest.update(finished=now(), chunks=chunks,
                             wall_seconds=round(time.perf_counter() - self.t0 + old.get("wall_seconds", 0.0), 3))
        self.save()
        self.lock.release()
