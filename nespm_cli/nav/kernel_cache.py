"""Where the compiled kernels are cached, and whether they are: the per-user cache folder named by the
kernels' source text (:data:`KERNEL_SOURCES`, :func:`source_key`), one readiness mark per kernel and CPU
(:func:`is_ready`), and the lock that lets one process compile a kernel while the others wait
(:func:`first_use`). The standard library only, numba not imported (its version read from the package
metadata): the parent of an ``mc`` checks the cache in a few file tests and leaves numba (~0.2 s to
import) to the workers that run the kernels (:mod:`nespm_cli.nav.kernels` compiles them).
"""
from __future__ import annotations

import functools
import hashlib
import platform
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from nespm_cli.nav.user_cache import cache_base, sources_digest


@functools.lru_cache(maxsize=None)
def numba_version() -> str:
    """The installed numba's version (its package metadata, without importing it); '' without numba."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("numba")
    except (PackageNotFoundError, ValueError):
        return ""


#: why compiled kernels are not cached on disk in this process (empty: they are)
NO_CACHE: list[str] = []


#: the files (relative to the package) whose text the compiled kernels depend on: their code, what
#: they inline, the earth constants they freeze. A new kernel module must be listed here.
KERNEL_SOURCES = ("nav/earth.py", "nav/trig.py", "nav/kernels.py", "filters/compiled/spans.py",
                  "filters/compiled/unrolled_12.py", "filters/compiled/lanes_12.py", "filters/compiled/lanes_15.py",
                  "filters/compiled/points.py", "filters/compiled/cycle_lanes.py", "filters/compiled/entries.py")
#: the kernels (filters.kernels names) this process has already used: no cache check on later calls
READY: set[str] = set()
_folders: dict[tuple[str, str], Path | None] = {}


@functools.lru_cache(maxsize=None)
def source_key() -> str:
    """16 hex digits of SHA-256 over :data:`KERNEL_SOURCES` (their text, not their path or mtime), the
    Python minor version and numba's version: the name of the cache subfolder and numba's source stamp."""
    seed = f"py{sys.version_info[0]}.{sys.version_info[1]} numba {numba_version()}"
    return sources_digest(seed, KERNEL_SOURCES)


def cache_folder() -> Path | None:
    """The kernels' cache folder, ``cache_base()/kernels-<source_key()>``, created on the first call
    (the first kernel module's import) and checked writable; None where it cannot be (numba's own
    locations then, or no cache: :func:`njit`). Never raises."""
    key = (str(cache_base()), source_key())
    if key not in _folders:
        folder = cache_base() / f"kernels-{key[1]}"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            tempfile.TemporaryFile(dir=folder).close()
        except (OSError, ValueError):
            folder = None
        _folders[key] = folder
    return _folders[key]


@functools.lru_cache(maxsize=None)
def cpu_tag() -> str:
    """8 hex digits naming this machine's CPU (architecture, model and flags where /proc/cpuinfo tells):
    numba keys its machine code by the CPU, so a cache folder shared by two machines keeps one
    readiness mark per CPU."""
    text = f"{platform.system()} {platform.machine()} {platform.processor()}"
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            seen = set()
            for line in fh:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part") and key not in seen:
                    seen.add(key)
                    text += line
    except OSError:
        pass
    return hashlib.sha256(text.encode()).hexdigest()[:8]


def ready_mark(name: str) -> Path | None:
    """The file that says kernel ``name`` (a filters.kernels name) is compiled into the cache folder
    for this CPU; None where kernels are not cached in the folder (then nothing is marked)."""
    folder = cache_folder()
    if folder is None or NO_CACHE:
        return None
    return folder / "ready" / f"{name}-{cpu_tag()}"


def is_ready(name: str) -> bool | None:
    """Whether kernel ``name`` is compiled and cached here (a file test, no numba call); None: no cache."""
    mark = ready_mark(name)
    return None if mark is None else (name in READY or mark.exists())


@contextmanager
def first_use(name: str) -> Iterator[None]:
    """Around a call of kernel ``name``: the first in this process whose kernel is not marked ready
    holds a lock file in the cache folder (other processes wait instead of compiling the same
    kernel at the same time, then load it) and marks the kernel ready after the call. Later calls,
    and calls where the kernel is marked, pass straight through."""
    mark = None if name in READY else ready_mark(name)
    if mark is None or mark.exists():
        yield
        READY.add(name)
        return
    with _lock(mark.parent.parent / "locks" / f"{name}.lock"):
        yield
        try:
            mark.parent.mkdir(exist_ok=True)
            mark.touch()
        except OSError:
            pass
    READY.add(name)


@contextmanager
def _lock(path: Path) -> Iterator[None]:
    """An exclusive advisory lock on ``path`` (fcntl; no lock where there is none, or on an OS error)."""
    try:
        import fcntl

        path.parent.mkdir(exist_ok=True)
        fh = open(path, "a")
    except (ImportError, OSError):
        yield
        return
    try:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield
    finally:
        fh.close()  # releases the lock
