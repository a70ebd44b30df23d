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
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from nespm_cli import __version__
from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.experiments.chunks import chunk_problem, experiment_digest
from nespm_cli.experiments.folder_kind import refuse_other_kind
from nespm_cli.experiments.progress import PROGRESS_DIR, Poller, Progress, read_reports

LOCK_FILE = ".lock"  # OUT/.lock: held (flock) by the process writing the folder
SAVE_EVERY_S = 2.0  # [s] the manifest's timings are saved at most this often while chunks finish


class ChunkWarning(UserWarning):
    """A file in ``chunks/`` that is not used (printed as one ``nespm: warning:`` line)."""


# --- atomic files (nespm_cli.data.atomic) ---------------------------------------------------

def write_json_atomic(obj, path: Path) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2))


# --- provenance --------------------------------------------------------------------------

def versions() -> dict:
    """Versions of Python, nespm and the numeric stack, for the manifest (with onnx and onnxruntime
    where installed: an ONNX noise model's numbers depend on onnxruntime's kernels)."""
    import joblib
    import pandas as pd
    import pyarrow
    import scipy

    from nespm_cli.filters.kernels import kernel_backend

    out = {"python": platform.python_version(), "nespm": __version__, "numpy": np.__version__,
           "scipy": scipy.__version__, "pandas": pd.__version__, "pyarrow": pyarrow.__version__,
           "joblib": joblib.__version__, "kernels": kernel_backend()}
    if out["kernels"] == "numba":
        from nespm_cli.nav.kernel_cache import numba_version

        out["numba"] = numba_version()  # the package's metadata: the parent of an mc does not import numba
    from importlib.metadata import PackageNotFoundError, version
    from importlib.util import find_spec

    for name in ("onnx", "onnxruntime"):  # the optional extra of ONNX noise models: metadata only, never imported
        try:
            if find_spec(name) is not None:
                out[name] = version(name)
        except (PackageNotFoundError, ValueError, ImportError):
            pass
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
    or the process ends (the system releases it on kill -9 too).

    The lock file is opened without following a symbolic link and must be a regular file: a
    ``.lock`` that points elsewhere is refused, never written through.
    """

    def __init__(self, out: Path) -> None:
        import fcntl
        import stat

        out.mkdir(parents=True, exist_ok=True)
        self.path = out / LOCK_FILE
        flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except OSError as exc:
            if self.path.is_symlink():
                raise NespmError(f"{self.path}: is a symbolic link; nespm's lock must be a regular file "
                                 "(remove it, or use another --out)") from None
            raise NespmError(f"{self.path}: cannot open the folder lock ({exc.strerror or exc})") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise NespmError(f"{self.path}: is not a regular file; nespm's lock must be one (remove it, or use "
                             "another --out)")
        self.handle = os.fdopen(fd, "r+")
        try:
            fcntl.flock(self.handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.handle.seek(0)
            pid = self.handle.read(32).strip() or "?"
            self.handle.close()
            raise NespmError(f"{out}: busy: another nespm process is writing or reading this folder (pid {pid} "
                             "wrote it last); wait for it to finish, or use another --out") from None
        self.handle.seek(0)
        self.handle.truncate()
        self.handle.write(str(os.getpid()))
        self.handle.flush()

    def release(self) -> None:
        if not self.handle.closed:
            self.handle.close()


def writer_pid(out: Path) -> str | None:
    """The pid of a process holding ``out``'s lock now (it is being written), else None. Takes no lock."""
    import fcntl

    path = Path(out) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return os.read(fd, 32).decode("ascii", "replace").strip() or "?"
        except OSError:
            return None
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def check_out_link(out: Path) -> None:
    """Refuse an ``--out`` that is a symbolic link to a non-empty folder holding no nespm results (a
    link set to the wrong place must not get a study written into someone's folder); a link to an
    empty folder or to a results folder is followed."""
    if not out.is_symlink() or not out.is_dir():
        return
    try:
        entries = [p.name for p in out.iterdir()
                   if p.name != LOCK_FILE and not (p.name == "chunks" and p.is_dir() and not any(p.iterdir()))]
    except OSError:
        return  # the lock reports an unreadable folder
    if entries and not (out / "manifest.json").is_file() and not has_results(out):
        raise NespmError(f"--out {out}: is a symbolic link to {os.path.realpath(out)}, a non-empty folder holding no "
                         f"nespm results ({entries[0]}, ...); give a new or empty folder, or the folder itself")


#: what an experiment writes into its folder besides the manifest: never overwritten without one
OUTPUT_NAMES = ("metrics.parquet", "epochs.parquet", "report.md", "figures", "chunks", "models.npz")


def read_manifest(path: Path) -> dict:
    """The manifest at ``path``, checked for the structure nespm relies on (one-line NespmError)."""
    try:
        old = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:
        raise NespmError(f"{path}: unreadable manifest ({exc.__class__.__name__}); use a new --out folder") from None
    if not isinstance(old, dict) or not isinstance(old.get("options"), dict):
        raise NespmError(f"{path}: not a nespm manifest (expected an object with an 'options' object); "
                         "use a new --out folder")
    blocks = old.get("run_blocks")
    if blocks is not None:
        ok = isinstance(blocks, list) and blocks and all(
            isinstance(b, list) and len(b) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in b)
            and 0 <= b[0] < b[1] for b in blocks)
        ok = ok and all(a[1] == b[0] for a, b in zip(blocks, blocks[1:])) and blocks[0][0] == 0
        if not ok:
            raise NespmError(f"{path}: bad run_blocks {json.dumps(blocks)[:80]} (expected consecutive "
                             "[start, end] run ranges from 0); use a new --out folder")
    for key in ("chunk_seconds", "inputs"):
        if key in old and not isinstance(old[key], dict):
            raise NespmError(f"{path}: bad '{key}' (expected an object); use a new --out folder")
    return old


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
        held = [n for n in OUTPUT_NAMES if (out / n).exists() and (n != "chunks" or any((out / n).iterdir()))]
        if held:
            raise NespmError(f"{out}: holds {held[0]} but no manifest.json (results of an unknown experiment); "
                             "use a new --out folder")
        return None
    old = read_manifest(mf)
    before = old.get("options", {})
    diff = sorted(k for k in set(before) | set(options) if before.get(k) != options.get(k))
    grown = [k for k in diff if k in extendable and isinstance(before.get(k), int) and options.get(k, 0) > before[k]]
    shrunk = [k for k in diff if k in extendable and isinstance(before.get(k), int) and options.get(k, 0) < before[k]]
    if shrunk:
        k = shrunk[0]
        raise NespmError(f"{out}: holds {before[k]} {k}; --{k} {options[k]} would drop finished work "
                         f"(give --{k} {before[k]} or more, or use a new --out folder)")
    grown += check_grown_lists(out, before, options, sorted((k for k in diff if k in extendable and k not in grown),
                                                           key=lambda k: ("filters", "smooth").index(k)
                                                           if k in ("filters", "smooth") else 2))
    if set(diff) - set(grown):
        diff = sorted(set(diff) - set(grown))
        raise NespmError(f"{out}: holds results of a different experiment (differs in: {', '.join(diff)}); "
                         "use a new --out folder or the same options to resume")
    return old


def _entries(value) -> list[str]:
    return [json.dumps(v, sort_keys=True) for v in (value or [])]


def check_grown_lists(out: Path, before: dict, options: dict, keys: list[str]) -> list[str]:
    """The list options of ``keys`` that only grew (every old entry kept: ``filters``, ``smooth``, and
    ``filter_options`` of filters the folder did not hold); one line for one that lost an entry."""
    grown = []
    old_filters = set(before.get("filters") or [])
    for k in keys:
        b, a = before.get(k), options.get(k)
        if not all(v is None or isinstance(v, list) for v in (b, a)):
            continue  # not a list option: a plain difference
        lost = [e for e in _entries(b) if e not in _entries(a)]
        if k == "filter_options":
            added = [json.loads(e) for e in _entries(a) if e not in _entries(b)]
            touched = sorted({e[0] for e in added if e[0] in old_filters} | {json.loads(e)[0] for e in lost})
            if touched:
                raise NespmError(f"{out}: holds results of filter {touched[0]} made with other --filter-option "
                                 "values; use a new --out folder (or the same values to resume)")
        elif lost:
            gone = ", ".join(json.loads(e) if isinstance(json.loads(e), str) else e for e in lost)
            raise NespmError(f"{out}: holds --{k.replace('_', '-')} {gone}; give it too (a study may grow, not "
                             "shrink), or use a new --out folder")
        grown.append(k)
    return grown


def run_blocks(old: dict | None, runs: int) -> list[tuple[int, int]]:
    """The run blocks ``[start, end)`` of a folder asked for ``runs`` runs, given its old manifest.

    One block per ``--runs`` extension; each is cut into chunks from its own start, so
    extending a folder never changes a finished chunk.
    """
    if old is None:
        return [(0, runs)]
    default = [(0, old["options"]["runs"])] if isinstance(old["options"].get("runs"), int) else None
    if not old.get("run_blocks") and default is None:
        raise NespmError("manifest.json: neither run_blocks nor an integer options.runs; use a new --out folder")
    blocks = [tuple(b) for b in old.get("run_blocks") or default]
    have = blocks[-1][1]
    return blocks + [(have, runs)] if runs > have else blocks


def chunk_firsts(blocks: Iterable[tuple[int, int]], chunk_size: int) -> list[tuple[int, int]]:
    """``(first, last)`` run ranges of every chunk of ``blocks`` (runs ``first .. last-1``)."""
    return [(f0, min(f0 + chunk_size, end)) for start, end in blocks for f0 in range(start, end, chunk_size)]


#: the identity scheme of a new folder (manifest ``identity``): its chunks' digest leaves out the
#: options that may grow (:data:`GROWABLE`), so a study takes more runs, filters and smoothed filters
#: without touching a finished chunk; folders made before it grow in runs only
IDENTITY = 2
GROWABLE = ("runs", "filters", "smooth", "filter_options")


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
        if not str(out).strip():
            raise NespmError("--out: an empty path (it would write into the current folder); name a folder")
        self.out = Path(out)
        self.chunks = self.out / "chunks"
        self.options = options
        self.argv = list(argv or sys.argv)
        self.extendable = extendable
        self.old: dict | None = None
        self.manifest: dict = {}
        self.t0 = time.perf_counter()
        self.lock: FolderLock | None = None
        self._saved = 0.0
        self._warned: set[str] = set()
        self._assembling = False

    def open(self, inputs: dict[str, str] | None = None, **extra) -> "ResultsFolder":
        """Lock the folder, check it against ``options`` and the ``inputs`` hashes
        (:func:`file_hashes`), write the manifest."""
        if self.out.exists() and not self.out.is_dir():
            raise NespmError(f"--out {self.out}: exists and is not a folder")
        check_out_link(self.out)
        refuse_other_kind(self.out, "mc")  # a tune study's folder is not one of these
        self.lock = FolderLock(self.out)
        mf = self.out / "manifest.json"
        if mf.exists() and has_results(self.out) and read_manifest(mf).get("identity") != IDENTITY:
            # a folder made before studies could grow: its chunks' identity leaves out the runs only
            self.extendable = tuple(k for k in self.extendable if k == "runs")
        self.old = check_existing(self.out, self.options, self.extendable)
        check_inputs(self.out, self.old, inputs or {})
        self.chunks.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(self.chunks / PROGRESS_DIR, ignore_errors=True)  # a killed run's stale reports
        old = self.old or {}
        identity = {"identity": IDENTITY} if set(self.extendable) - {"runs"} else {}
        self.manifest = {"command": self.argv, "options": self.options, **identity, **extra, "inputs": inputs or {},
                         "versions": versions(), "git_commit": git_commit(),
                         "started": old.get("started", now()), "finished": None,
                         "chunk_seconds": old.get("chunk_seconds", {})}
        for k, v in old.items():  # what the experiment recorded before (e.g. training) survives a resume
            self.manifest.setdefault(k, v)
        self.save()
        self.t0 = time.perf_counter()
        return self

    def save(self, every_s: float = 0.0) -> None:
        """Write the manifest (atomically); with ``every_s``, only if the last write is older
        (a study of thousands of chunks must not rewrite it thousands of times)."""
        if every_s and time.monotonic() - self._saved < every_s:
            return
        write_json_atomic(self.manifest, self.out / "manifest.json")
        self._saved = time.monotonic()

    @property
    def experiment(self) -> str:
        """The digest every chunk file of this experiment carries (:func:`chunks.experiment_digest`)."""
        return experiment_digest(self.options, self.extendable)

    def path(self, name: str) -> Path:
        """The chunk file ``chunks/name``."""
        return self.chunks / name

    def done(self, name: str) -> bool:
        """Whether ``chunks/name`` is a finished chunk of this experiment. A file there that is
        not (truncated, of another experiment, a copy) is named in a warning and computed again."""
        problem = chunk_problem(self.path(name), self.experiment)
        if problem is not None and problem != "missing" and name not in self._warned:
            self._warned.add(name)
            warnings.warn(f"{self.path(name)}: {problem}; computing it again", ChunkWarning, stacklevel=2)
        return problem is None

    def ignore_strays(self, expected: set[str]) -> list[str]:
        """Warn once about files in ``chunks/`` that this experiment does not expect (leftovers of
        another experiment, copies, foreign files); they are never read. Returns their names."""
        strays = sorted(p.name for p in self.chunks.iterdir() if not p.name.startswith(".") and p.name not in expected)
        if strays:
            more = f" and {len(strays) - 3} more" if len(strays) > 3 else ""
            warnings.warn(f"{self.chunks}: ignored {len(strays)} file(s) this experiment does not expect: "
                          f"{', '.join(strays[:3])}{more}", ChunkWarning, stacklevel=2)
        return strays

    def verified(self, names: list[str]) -> list[Path]:
        """The chunk files ``names`` (in order), each verified as a finished chunk of this
        experiment; a missing or bad one is a one-line NespmError naming it."""
        out = []
        for name in names:
            problem = chunk_problem(self.path(name), self.experiment)
            if problem is not None:
                raise NespmError(f"{self.path(name)}: {problem} (changed while this command ran?); re-run the "
                                 "same command to compute it again")
            out.append(self.path(name))
        if not self._assembling:  # the first assembly call of this process replaces the last assembly's record
            self._assembling = True
            self.manifest["assembled"] = {"experiment": self.experiment, "chunks": [], "tables": {}}
        self.manifest["assembled"]["chunks"] += [p.name for p in out]
        return out

    def run(self, fn: Callable, tasks: list[Task], execution, label: str, unit: str = "filter-epochs",
            detail: str = "") -> None:
        """Compute ``tasks`` (``fn(*task.args) -> (key, timings)``) where ``execution`` (an
        :class:`nespm_cli.experiments.backend.Execution`) says, with a progress display fed by the
        workers' reports (:mod:`nespm_cli.experiments.progress`; ``detail`` describes a chunk there).

        A worker process that dies (killed by the system, e.g. out of memory) ends the command
        with one line naming the chunks it was computing; finished chunks are kept."""
        from nespm_cli.experiments.backend import parallel_map, worker_died

        if not tasks:
            return
        units = {t.key: t.units for t in tasks}
        finished: set[str] = set()
        ex = execution
        results = parallel_map(fn, [t.args for t in tasks], ex.jobs, ex.backend, ex.scheduler)
        try:
            with Progress(label, sum(units.values()), len(tasks), unit=unit, enabled=ex.progress,
                          detail=detail) as bar, \
                    Poller(bar, self.chunks) as poller:
                for key, timings in results:
                    finished.add(key)
                    self.manifest["chunk_seconds"].update(timings)
                    self.save(every_s=SAVE_EVERY_S)  # a killed run's timings come back from its chunks
                    poller.finish(key)
                    bar.chunk_done(units.get(key, 0))
                    poller.poll()
        except Exception as exc:
            if not worker_died(exc):
                raise
            running = sorted(set(read_reports(self.chunks)) - finished) or sorted(set(units) - finished)
            more = f" (and {len(running) - 2} more)" if len(running) > 2 else ""
            raise NespmError(f"a worker process died while computing chunk {', '.join(running[:2])}{more} "
                             "(killed by the system: memory may be the cause; try a smaller --chunk-size or "
                             "fewer --jobs); finished chunks are kept, re-run the same command to resume") from None
        finally:
            self.save()

    def finish(self, chunks: int) -> None:
        old = self.old or {}
        rec = self.manifest.get("assembled")
        if self._assembling and isinstance(rec, dict):  # the tables as assembled: export/compare verify them
            tables = [self.out / n for n in ("metrics.parquet", "epochs.parquet") if (self.out / n).is_file()]
            rec["tables"] = {p.name: h for p, h in zip(tables, file_hashes(tables).values())}
        self.manifest.update(finished=now(), chunks=chunks,
                             wall_seconds=round(time.perf_counter() - self.t0 + old.get("wall_seconds", 0.0), 3))
        self.save()
        self.lock.release()
