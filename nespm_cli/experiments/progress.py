"""Progress of long jobs, on a terminal (a rich bar) and off one (plain lines with an ETA).

Workers of a run folder report how far each running chunk has got by writing a tiny
text file ``DIR/chunks/.progress/<chunk>`` (``done total``, in filter-epochs) at most a few
times a second; the parent polls those files, so the bar moves within a chunk on every
backend that shares the folder (loky, Dask on a shared filesystem). A finished chunk's
file is removed by the parent.

Off a terminal (a log file, CI, a pipe) the parent prints one line every ``interval``
seconds and at the end: ``mc: 45 % (1234/2745 filter-epochs, 2/4 chunks) 62 s elapsed, ETA 75 s``.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Callable, TextIO

PROGRESS_DIR = ".progress"
WRITE_EVERY_S = 0.5  # a worker rewrites its progress file at most this often
PLAIN_EVERY_S = 15.0  # off a terminal: one line this often


def fmt_seconds(s: float) -> str:
    """``75 s``, ``12 min 5 s`` or ``2 h 3 min`` (None or negative: ``?``)."""
    if s is None or s != s or s < 0:
        return "?"
    s = int(round(s))
    if s < 120:
        return f"{s} s"
    if s < 7200:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {(s % 3600) // 60} min"


def epoch_reporter(folder: str | Path, key: str, total: int) -> Callable[[int], None]:
    """A worker's callback ``report(done)`` that writes ``done total`` to ``folder/.progress/key``.

    Throttled to one write per :data:`WRITE_EVERY_S`; ``done == total`` is always written.
    Write errors are ignored: progress must never fail a computation.
    """
    path = Path(folder) / PROGRESS_DIR / key
    last = [0.0]

    def report(done: int) -> None:
        now = time.monotonic()
        if done < total and now - last[0] < WRITE_EVERY_S:
            return
        last[0] = now
        try:
            path.parent.mkdir(exist_ok=True)  # never the folder above: a worker that cannot see --out must fail
            tmp = path.with_name(f".{key}.{os.getpid()}.tmp")
            tmp.write_text(f"{done} {total}", encoding="ascii")
            os.replace(tmp, path)
        except OSError:
            pass
    return report


def read_reports(folder: str | Path) -> dict[str, tuple[int, int]]:
    """``{key: (done, total)}`` of the progress files in ``folder/.progress`` (unreadable ones skipped)."""
    out = {}
    d = Path(folder) / PROGRESS_DIR
    try:
        paths = list(d.iterdir())
    except OSError:
        return out
    for p in paths:
        if p.name.startswith("."):
            continue
        try:
            done, total = (int(x) for x in p.read_text(encoding="ascii").split())
        except (OSError, ValueError):
            continue
        out[p.name] = (done, total)
    return out


def clear_report(folder: str | Path, key: str) -> None:
    try:
        (Path(folder) / PROGRESS_DIR / key).unlink(missing_ok=True)
    except OSError:
        pass


class Progress:
    """A progress display of ``total`` units over ``chunks`` chunks.

    ``label`` names the job (``mc``, ``sweep``); ``enabled=False`` shows nothing. On a terminal
    (``stream.isatty()``) a rich bar, else plain lines every ``interval`` seconds. ``detail``
    describes a chunk (``of 4 runs``), said once at the start. Use as a context manager; call
    :meth:`set_running` with the units done inside unfinished chunks and :meth:`chunk_done` when
    one finishes.
    """

    def __init__(self, label: str, total: int, chunks: int, unit: str = "filter-epochs", enabled: bool = True,
                 stream: TextIO | None = None, interval: float = PLAIN_EVERY_S, detail: str = "") -> None:
        self.label, self.total, self.chunks, self.unit = label, max(int(total), 1), chunks, unit
        self.detail = detail
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.finished_units = 0
        self.running_units = 0
        self.finished_chunks = 0
        self.t0 = time.monotonic()
        self._last_line = self.t0
        self._first: tuple[float, int] | None = None  # (time, units) of the first report with units done
        self._bar = None
        self._lock = threading.Lock()
        tty = getattr(self.stream, "isatty", lambda: False)
        self.tty = bool(tty())

    # --- state -----------------------------------------------------------------------
    @property
    def done(self) -> int:
        return min(self.finished_units + self.running_units, self.total)

    def eta(self) -> float | None:
        """Seconds left at the rate measured since the first unit was reported, so the start-up (the
        workers' imports and the kernels' compilation, before any unit) does not count; None until
        a second report shows a rate."""
        now, done = time.monotonic(), self.done
        if self._first is None:
            return None
        t1, d1 = self._first
        if done <= d1 or now <= t1:
            return None
        return (now - t1) * (self.total - done) / (done - d1)

    def line(self) -> str:
        el = time.monotonic() - self.t0
        pct = 100.0 * self.done / self.total
        if self.done >= self.total:
            when = "done"
        elif self._first is None:  # nothing reported yet: the workers import nespm and load the kernels
            when = "workers starting (imports, compiled kernels), ETA once a rate is measured"
        else:
            when = f"ETA {fmt_seconds(eta)}" if (eta := self.eta()) is not None else "ETA once a rate is measured"
        return (f"{self.label}: {pct:.0f} % ({self.done}/{self.total} {self.unit}, {self.finished_chunks}/{self.chunks} "
                f"chunks) {fmt_seconds(el)} elapsed, {when}")

    # --- updates ---------------------------------------------------------------------
    def set_running(self, units: int) -> None:
        with self._lock:
            self.running_units = int(units)
            self._note_first()
        self._show()

    def chunk_done(self, units: int) -> None:
        with self._lock:
            self.finished_units += int(units)
            self.finished_chunks += 1
            self._note_first()
        self._show()

    def _note_first(self) -> None:
        if self._first is None and self.done > 0:
            self._first = (time.monotonic(), self.done)

    def _show(self, force: bool = False) -> None:
        if not self.enabled:
            return
        if self._bar is not None:
            bar, task = self._bar
            bar.update(task, completed=self.done,
                       description=f"{self.finished_chunks}/{self.chunks} chunks")
            return
        now = time.monotonic()
        if force or now - self._last_line >= self.interval:
            self._last_line = now
            print(self.line(), file=self.stream, flush=True)

    # --- context ---------------------------------------------------------------------
    def __enter__(self) -> "Progress":
        if self.enabled and self.tty:
            from rich.console import Console
            from rich.progress import (BarColumn, Progress as RichProgress, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)

            bar = RichProgress(TextColumn(f"[bold]{self.label}[/] {{task.description}}"), BarColumn(),
                               TextColumn("{task.percentage:>3.0f} %"), TimeElapsedColumn(), TimeRemainingColumn(),
                               console=Console(file=self.stream), transient=False)
            bar.start()
            self._bar = (bar, bar.add_task(f"0/{self.chunks} chunks", total=self.total))
            if self.detail:
                bar.console.print(f"{self.label}: {self.chunks} chunk{'s' if self.chunks != 1 else ''} {self.detail}")
        elif self.enabled:
            what = f"{self.chunks} chunk{'s' if self.chunks != 1 else ''}" + (f" {self.detail}" if self.detail else "")
            print(f"{self.label}: {what}, {self.total} {self.unit} to compute", file=self.stream, flush=True)
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar[0].stop()
            self._bar = None
        elif self.enabled and exc[0] is None:
            self._show(force=True)


class Poller:
    """A thread that feeds :class:`Progress` with the workers' progress files every ``period`` s."""

    def __init__(self, progress: Progress, folder: str | Path, period: float = 0.5) -> None:
        self.progress, self.folder, self.period = progress, Path(folder), period
        self.finished: set[str] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        while not self._stop.wait(self.period):
            self.poll()

    def poll(self) -> None:
        reports = read_reports(self.folder)
        self.progress.set_running(sum(d for k, (d, _) in reports.items() if k not in self.finished))

    def finish(self, key: str) -> None:
        """Chunk ``key`` is complete: its units move to the finished count."""
        self.finished.add(key)
        clear_report(self.folder, key)

    def __enter__(self) -> "Poller":
        if self.progress.enabled:
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)


#: the open :class:`Status` displays, innermost last: where :func:`phase` reports
ACTIVE: list["Status"] = []


def phase(text: str) -> None:
    """Say what a long library call is doing now (``"figure anees.png"``) on the innermost open
    :class:`Status` (the command's, e.g. ``nespm report``); nothing when none is open (the Python API)."""
    if ACTIVE:
        ACTIVE[-1](text)


class Status:
    """Say what a short command is doing: a transient rich status on a terminal, else one
    line per step on ``stream`` (stderr), prefixed with ``label`` (``plain=False``: nothing off a
    terminal, for steps too quick to be worth a log line). ``enabled=False``: silent. While open
    (``with``), the library's :func:`phase` calls report here."""

    def __init__(self, label: str, enabled: bool = True, stream: TextIO | None = None, plain: bool = True) -> None:
        self.label, self.enabled, self.plain = label, enabled, plain
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._status = None
        self.t0 = time.monotonic()

    def __call__(self, text: str) -> None:
        if not self.enabled:
            return
        if self.tty:
            if self._status is None:
                from rich.console import Console

                self._status = Console(file=self.stream).status(f"{self.label}: {text}")
                self._status.start()
            else:
                self._status.update(f"{self.label}: {text}")
        elif self.plain:
            print(f"{self.label}: {text} ({fmt_seconds(time.monotonic() - self.t0)} elapsed)", file=self.stream,
                  flush=True)

    def __enter__(self) -> "Status":
        ACTIVE.append(self)
        return self

    def __exit__(self, *exc) -> None:
        if self in ACTIVE:
            ACTIVE.remove(self)
        if self._status is not None:
            self._status.stop()
            self._status = None


def kernels_for(filters, layout=None, runs: int | None = 1) -> tuple[str, ...]:
    """The kernels (:data:`nespm_cli.filters.kernels.KERNELS`) that running ``filters`` (names) with the error-state ``layout``
    on batches of up to ``runs`` runs uses: the points for the sigma-point NESPM filters, Φ_inv for the
    iekf, the free-inertial loop for ins, and Φ of the common error for every other error-state filter
    (for ``runs`` from ``kernels.lanes_from(layout)``, the 12 or 15 states' with the runs in lanes) and always run by
    run (the PCRB's Φ along the truth). ``runs=None``: any batch (``nespm warm-up``). ``layout``: a
    :class:`~nespm_cli.nav.state.StateLayout` (default the papers' 12 states). A name that is not a
    registered filter adds nothing."""
    from nespm_cli.errors import NespmError
    from nespm_cli.filters.ins import InsFilter
    from nespm_cli.filters.kernels import KERNELS, lanes_from, transition_kernel
    from nespm_cli.filters.protocol import ErrorStateFilter
    from nespm_cli.filters.registry import get_filter
    from nespm_cli.filters.ukf import UKFNespm
    from nespm_cli.nav.state import LAYOUT_12

    layout = LAYOUT_12 if layout is None else layout
    need = {transition_kernel(False, layout)}
    for name in filters:
        try:
            cls = get_filter(name)
        except (NespmError, KeyError):
            continue
        if not isinstance(cls, type) or not issubclass(cls, ErrorStateFilter):
            continue
        if issubclass(cls, UKFNespm):
            need.add("points")
        elif issubclass(cls, InsFilter):
            need.add("strapdown")
        elif getattr(cls, "invariant_error", False):
            need.add(transition_kernel(True, layout))
        else:
            need.add(transition_kernel(False, layout, lanes_from(layout) if runs is None else runs))
    return tuple(k for k in KERNELS if k in need)


COMPILING = "compiling the filters' kernels (once per machine; later runs load them from the disk cache)"


def compile_kernels(label: str, enabled: bool = True, stream: TextIO | None = None,
                    kernels: tuple[str, ...] | None = None) -> float | None:
    """The numba kernels' compilation as its own phase, before the chunks start (and so before any
    ETA): where the compiled kernels are in use and the per-user cache does not hold the ``kernels``
    the command uses (names of :data:`nespm_cli.filters.kernels.KERNELS`, e.g. from
    :func:`~nespm_cli.filters.kernels.kernels_for`; default all), say so (``<label>: compiling ...``,
    a status on a terminal, a line off one) and compile them here
    (:func:`~nespm_cli.filters.kernels.warm_up`); the workers then load them from the cache instead of
    each compiling its own. With the cache warm this is a few file tests: nothing is said or loaded.
    Returns the seconds it took, or None when there was nothing to compile. ``enabled=False``
    compiles without a word."""
    from nespm_cli.filters.kernels import kernels_cached, warm_up

    if (kernels_cached() if kernels is None else kernels_cached(kernels)) is not False:
        return None
    with Status(label, enabled=enabled, stream=stream) as status:
        status(COMPILING)
        seconds = warm_up() if kernels is None else warm_up(kernels)
    if enabled:
        print(f"{label}: kernels compiled in {fmt_seconds(seconds)}", file=status.stream, flush=True)
    return seconds
