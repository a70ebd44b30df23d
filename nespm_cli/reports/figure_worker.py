"""A second process that draws some tracks' figures while the report's own process computes its tables and
draws the other tracks (``nespm report`` on a folder of two tracks or more, on a machine of two cores or more).

Why a process: Matplotlib's drawing is Python under the GIL (a thread gains nothing), and it is most of a
report's time (the main job's 16 figures: about 3.5 of its 6 s). Why a fork server: the report process holds
pyarrow's threads once it has read the Parquet files, and a process forked from a threaded one can hang; the
fork server is a fresh interpreter, and the worker forked from it imports the figure modules while the
report computes its tables. Everything starts in a background thread, so the report never waits for it;
where it cannot start (no fork server: Windows), fails, or dies, its tracks are drawn in this process after
all. The files are the same either way (the same code on the same data; tests/test_figure_worker.py).
Like every multiprocessing child, the worker imports the script that called the report as ``__mp_main__``:
the Python API draws in one process unless asked (``figure_jobs``), and ``nespm report`` asks.
"""
from __future__ import annotations

import os
import threading
from typing import Any, Callable


def figure_processes(jobs: int | None, tracks: int) -> int:
    """How many processes draw the figures of ``tracks`` tracks, 1 or 2 (this one and a :class:`FigureWorker`; a
    track is the unit of work, so 1 for a single track): ``jobs`` if given, else 2 where the machine has two
    cores or more."""
    wanted = int(jobs) if jobs is not None else (os.cpu_count() or 1)
    return 2 if wanted >= 2 and tracks >= 2 else 1


class FigureWorker:
    """``fn(*args)`` in a fork-server child, started in a background thread at construction;
    :meth:`result` is its return value, or None when it could not run there (then the caller runs it)."""

    def __init__(self, fn: Callable, *args: Any) -> None:
        self._future = None
        self._pool = None
        self._thread = threading.Thread(target=self._start, args=(fn, args), daemon=True)
        self._thread.start()

    def _start(self, fn: Callable, args: tuple) -> None:
        try:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            ctx = multiprocessing.get_context("forkserver")
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx)
            self._future = self._pool.submit(fn, *args)
        except (ValueError, OSError, RuntimeError, ImportError):  # no fork server here, or no process
            self._future = None

    def result(self) -> Any:
        """The child's return value, or None if it could not start or failed (any error: the caller draws
        those figures itself, where a real error says what it is)."""
        self._thread.join()
        try:
            return None if self._future is None else self._future.result()
        except Exception:  # noqa: BLE001 - a broken pool or the child's error: drawn again in this process
            return None
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)


__all__ = ["FigureWorker", "figure_processes"]
