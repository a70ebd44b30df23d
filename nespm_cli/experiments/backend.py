"""Where the Monte Carlo chunks run: local loky processes (default) or a Dask cluster.

``parallel_map`` is the one place the runner asks for parallelism; results never depend on
the backend, because every chunk is seeded per (track, run), never per worker, and every
chunk writes its own files (deterministic names, atomic rename) from the worker.

``parallel_map`` is a plain function: it validates the backend, and for Dask connects to
(or starts) the cluster, before it returns the iterator of results. Every configuration
error is therefore a one-line :class:`NespmError` raised before any progress bar starts.

Dask backend (docs/cluster.md): the chunks are submitted directly with
``Client.submit`` and collected with ``distributed.as_completed`` (not through joblib's
Dask backend), so that

* a worker lost mid-chunk is handled by the scheduler, which re-runs that chunk on another
  worker (the chunk's files are rewritten whole, so nothing is duplicated);
* an error in a chunk (a :class:`NespmError` such as a missing data folder on a worker)
  reaches the client as that exception, with the worker's host name appended, and the
  remaining chunks are cancelled;
* results arrive in completion order, one per chunk, with no joblib batching.

The scheduler is ``--scheduler``, else ``$NESPM_DASK_SCHEDULER`` (an address or a scheduler
file), else a local cluster of ``jobs`` single-threaded worker processes (``LOCAL_CONFIG``).
"""
from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import os
import socket
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from nespm_cli.errors import NespmError

BACKENDS = ("loky", "dask")
ENV_SCHEDULER = "NESPM_DASK_SCHEDULER"
ENV_TIMEOUT = "NESPM_DASK_TIMEOUT"  # seconds to reach the scheduler (default 10)
ENV_WAIT = "NESPM_DASK_WAIT"  # seconds to wait for a first worker on an empty cluster (default 60)
INSTALL_HINT = "pip install 'nespm[dask]'"
# Settings of the local cluster nespm starts (docs/cluster.md explains how to give them to
# workers you start yourself), measured on 50-run chunks on the 2-core VM:
# * Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which turns off glibc's
#   adaptive mmap threshold: every large NumPy temporary is mmap'ed and page-faulted anew
#   (ukf-nespm chunk: 1.95 M minor faults instead of 6 k, +26 % CPU time);
# * the worker's statistical profiler samples the task thread every 10 ms, which costs
#   ~15-20 % CPU on the filters' many small NumPy calls (ekf chunk: 17.1-19.6 s instead of
#   ~15.5 s), and only feeds a dashboard;
# * worker-saturation 1.0: a worker gets its next chunk only when it is free; chunks are few
#   and long, and one queued behind a busy worker would wait for work stealing.
LOCAL_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                "distributed.worker.profile.enabled": False,
                "distributed.scheduler.worker-saturation": 1.0}


@dataclass(frozen=True)
class Execution:
    """Where and how an experiment's chunks run; none of it changes a number.

    ``jobs`` local worker processes (loky, or the local Dask cluster); ``backend`` ``loky`` or
    ``dask``; ``scheduler`` a Dask scheduler address or file (dask only); ``progress`` a progress
    display; ``argv`` the command line recorded in the manifest (None: the Python API).
    """

    jobs: int = 2
    backend: str = "loky"
    scheduler: str | None = None
    progress: bool = True
    argv: tuple | None = None

    @property
    def local(self) -> bool:
        """Whether the chunks run in processes on this machine (loky, or the local Dask cluster),
        which share this machine's compiled-kernel cache and memory."""
        return not (self.backend == "dask" and (self.scheduler or os.environ.get(ENV_SCHEDULER, "").strip()))

    def check(self) -> "Execution":
        """One-line errors for a bad ``jobs``, backend or scheduler (before any folder is made)."""
        if not isinstance(self.jobs, int) or self.jobs < 1:
            raise NespmError(f"--jobs must be at least 1, got {self.jobs}")
        check_backend(self.backend)
        check_scheduler(self.backend, self.scheduler)
        return self

    @classmethod
    def of(cls, execution: "Execution | None" = None, **legacy) -> "Execution":
        """``execution``, or one built from the keyword arguments the API took before
        (``jobs``, ``backend``, ``scheduler``, ``progress``, ``argv``; None: the default)."""
        base = execution if execution is not None else cls()
        given = {k: (tuple(v) if k == "argv" and v is not None else v) for k, v in legacy.items() if v is not None}
        unknown = set(given) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise NespmError(f"unknown execution option(s): {', '.join(sorted(unknown))}")
        return dataclasses.replace(base, **given)


def check_backend(backend: str) -> None:
    """Raise :class:`NespmError` unless ``backend`` is known and usable here (nothing is started)."""
    if backend not in BACKENDS:
        raise NespmError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend == "dask":
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise NespmError(f"--backend dask needs the 'distributed' package: {INSTALL_HINT}") from None


def check_scheduler(backend: str, scheduler: str | None) -> None:
    """A scheduler address only means something to the dask backend: refuse it with loky."""
    if scheduler and backend != "dask":
        raise NespmError(f"--scheduler {scheduler}: only the dask backend uses a scheduler; add --backend dask "
                         "or drop --scheduler")


def parallel_map(fn: Callable, args: list[tuple], jobs: int, backend: str = "loky",
                 scheduler: str | None = None) -> Iterator:
    """Return an iterator of ``fn(*a)`` for every ``a`` in ``args``, in completion order.

    ``jobs`` is the number of local worker processes (loky, or the local Dask cluster started
    when no scheduler is given); ``scheduler`` the address of a Dask scheduler (dask backend;
    default ``$NESPM_DASK_SCHEDULER``, else a local cluster).

    Validation and the connection happen now; the work starts when the iterator is consumed.
    Exhausting, closing or dropping the iterator closes what was opened.
    """
    check_backend(backend)
    args = [tuple(a) for a in args]
    if backend == "loky":
        return _loky_map(fn, args, jobs)
    client, cluster = _connect(scheduler, jobs, len(args))
    it = _dask_map(client, cluster, fn, args)
    next(it)  # enter its try/finally: closing or collecting the iterator now closes the client
    return it


# --- loky ------------------------------------------------------------------------------

def _loky_map(fn: Callable, args: list[tuple], jobs: int) -> Iterator:
    from joblib import Parallel, delayed

    par = Parallel(n_jobs=min(jobs, max(len(args), 1)), backend="loky", return_as="generator_unordered")
    parent = os.getpid()
    yield from par(delayed(in_worker)(parent, fn, a) for a in args)


_WATCHING: list[int] = []  # the parent pid a worker process watches (set once per process)
PARENT_POLL_S = 0.5  # [s] how often a worker checks that its parent still lives


def in_worker(parent: int, fn: Callable, args: tuple):
    """Run ``fn(*args)`` in a loky worker that dies with the ``nespm`` process that started it.

    On the first call a daemon thread starts that ends the worker (``os._exit``) within
    :data:`PARENT_POLL_S` once ``parent`` is gone (kill -9 leaves no chance to stop the pool).
    NumPy's RuntimeWarnings stay quiet:
    the chunk's own checks report what matters, in one line.
    """
    if not _WATCHING and os.getpid() != parent:
        _WATCHING.append(parent)
        _die_with_parent(parent)
        warnings.filterwarnings("ignore", category=RuntimeWarning)
        from nespm_cli.data.plausibility import DataWarning

        warnings.filterwarnings("ignore", category=DataWarning)  # the parent said it once, before the run
        warnings.filterwarnings("ignore", message="numba cannot cache")  # the parent says it (nav.kernels)
    return fn(*args)


def worker_died(exc: BaseException) -> bool:
    """Whether ``exc`` says a worker process died under a chunk (killed by the system, e.g. the
    OOM killer): loky's ``TerminatedWorkerError`` / a broken pool, Dask's ``KilledWorker``."""
    names = {c.__name__ for c in type(exc).__mro__}
    return bool(names & {"TerminatedWorkerError", "BrokenProcessPool", "KilledWorker"})


def _die_with_parent(parent: int) -> None:
    def watch() -> None:
        while os.getppid() == parent:  # a worker whose parent died is re-parented (to init or a subreaper)
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="nespm-parent-watch", daemon=True).start()


# --- dask ------------------------------------------------------------------------------

def _env_seconds(name: str, default: float) -> float:
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        raise NespmError(f"${name}: expected a number of seconds, got {text!r}") from None
    if value <= 0:
        raise NespmError(f"${name}: must be positive, got {text!r}")
    return value


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{exc.__class__.__name__}: {text[0]}" if text else exc.__class__.__name__


def _probe(address: str, timeout: float) -> None:
    """Check that ``address`` answers as a Dask scheduler within ``timeout`` seconds.

    Done with a bare comm so that a failure leaves no half-built ``Client`` behind (whose
    finalizer would block and print to stderr).
    """
    from distributed.comm import connect, parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address)
        if scheme in ("tcp", "tls"):  # fail at once on a refused port or an unknown host
            socket.create_connection(parse_host_port(loc), timeout=timeout).close()
    except socket.timeout:
        raise NespmError(f"--scheduler {address}: no answer within {timeout:g} s "
                         f"(is 'dask scheduler' running there? ${ENV_TIMEOUT} sets the wait)") from None
    except Exception as exc:
        raise NespmError(f"--scheduler {address}: cannot reach a Dask scheduler ({_one_line(exc)})") from None

    async def identity() -> dict:
        comm = await connect(address, timeout=timeout)
        try:
            await asyncio.wait_for(comm.write({"op": "identity", "reply": True}), timeout)
            return await asyncio.wait_for(comm.read(), timeout)
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(identity(), timeout + 1))
    except (asyncio.TimeoutError, TimeoutError):
        raise NespmError(f"--scheduler {address}: no answer within {timeout:g} s "
                         f"(is 'dask scheduler' running there? ${ENV_TIMEOUT} sets the wait)") from None
    except MemoryError:  # a non-Dask service: its first bytes read as an absurd frame length
        raise NespmError(f"--scheduler {address}: something answers there, but not the Dask protocol "
                         "(wrong port?)") from None
    except Exception as exc:  # OSError, ValueError (bad address), a comm error
        raise NespmError(f"--scheduler {address}: cannot reach a Dask scheduler ({_one_line(exc)})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise NespmError(f"--scheduler {address}: answers, but as {kind or 'something else'}, "
                         "not as a Dask scheduler")


def _worker_env() -> dict:
    """What must match between the client and every worker for identical results."""
    import numpy
    import scipy

    from nespm_cli import __version__

    return {"nespm": __version__, "numpy": numpy.__version__, "scipy": scipy.__version__}


def _check_workers(client, address: str, wait: float) -> None:
    """Wait for a first worker; check every present worker runs the client's nespm/numpy/scipy."""
    try:
        client.wait_for_workers(1, timeout=wait)
    except (asyncio.TimeoutError, TimeoutError):
        raise NespmError(f"--scheduler {address}: no Dask worker joined within {wait:g} s "
                         f"(start 'dask worker {address}' on the compute hosts; ${ENV_WAIT} sets the wait)") from None
    try:
        envs = client.run(_worker_env)
    except Exception as exc:
        raise NespmError(f"--scheduler {address}: a worker cannot run nespm ({_one_line(exc)}); "
                         "install this nespm in every worker's environment") from None
    mine = _worker_env()
    for worker, env in sorted(envs.items()):
        diff = [f"{k} {env.get(k)} (client {v})" for k, v in mine.items() if env.get(k) != v]
        if diff:
            raise NespmError(f"--scheduler {address}: worker {worker} has {', '.join(diff)}; "
                             "results are only identical with the same versions everywhere")


def _connect(scheduler: str | None, jobs: int, n_tasks: int):
    """Return ``(client, cluster)``: a client of ``scheduler`` (``cluster`` None), or of a new
    local cluster of ``min(jobs, n_tasks)`` single-threaded worker processes."""
    from distributed import Client, LocalCluster

    timeout = _env_seconds(ENV_TIMEOUT, 10.0)
    address = (scheduler or "").strip() or os.environ.get(ENV_SCHEDULER, "").strip() or None
    if address is None:
        if jobs < 1:
            raise NespmError(f"--jobs must be at least 1, got {jobs}")
        import dask

        try:
            with dask.config.set(LOCAL_CONFIG):
                cluster = LocalCluster(n_workers=max(1, min(jobs, n_tasks)), threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address=":0", silence_logs=logging.CRITICAL)
        except Exception as exc:
            raise NespmError(f"--backend dask: could not start a local Dask cluster ({_one_line(exc)})") from None
        try:
            client = Client(cluster, set_as_default=False, timeout=timeout)
            client.register_plugin(_ignore_sigint_plugin())
            return client, cluster
        except BaseException:
            with _quiet_distributed():
                cluster.close()
            raise
    if "://" not in address and os.path.isfile(address):  # a scheduler file (dask scheduler --scheduler-file)
        import json

        try:
            address = json.loads(Path(address).read_text(encoding="utf-8"))["address"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise NespmError(f"--scheduler {scheduler or address}: not a readable Dask scheduler file "
                             f"({_one_line(exc)})") from None
    _probe(address, timeout)
    try:
        client = Client(address, set_as_default=False, timeout=timeout)
    except Exception as exc:
        raise NespmError(f"--scheduler {address}: cannot connect ({_one_line(exc)})") from None
    try:
        _check_workers(client, address, _env_seconds(ENV_WAIT, 60.0))
    except BaseException:
        client.close()
        raise
    return client, None


def _ignore_sigint_plugin():
    """A worker plugin for the local cluster's workers: ignore SIGINT. A Ctrl-C in the terminal
    reaches the whole process group; the nespm process handles it and stops the cluster, the
    workers would only print KeyboardInterrupt tracebacks."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        name = "nespm-ignore-sigint"

        def setup(self, worker):
            import signal
            import threading

            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreSigint()


def _call(fn: Callable, args: tuple):
    """Run one chunk on a worker; name the worker's host in the errors the user must act on."""
    from nespm_cli.data.atomic import WriteError
    from nespm_cli.errors import NespmError as _NespmError

    try:
        return fn(*args)
    except WriteError as exc:  # typically the --out folder is not shared with this worker
        raise _NespmError(f"{exc} (on Dask worker host {socket.gethostname()}; --out and --data-dir must be on a "
                          "filesystem every worker sees at the same path)") from None
    except _NespmError as exc:
        first = str(exc).splitlines()[0] if str(exc) else repr(exc)
        raise _NespmError(f"{first} (on Dask worker host {socket.gethostname()})") from None
    except OSError as exc:  # typically the --out folder is not shared with this worker
        raise _NespmError(f"{_one_line(exc)} (on Dask worker host {socket.gethostname()}; --out and --data-dir "
                          "must be on a filesystem every worker sees at the same path)") from None


def _dask_map(client, cluster, fn: Callable, args: list[tuple]) -> Iterator:
    from concurrent.futures import CancelledError

    from distributed import KilledWorker, as_completed
    from distributed.client import FutureCancelledError

    futures = []
    try:
        yield None  # primed by parallel_map
        token = uuid.uuid4().hex[:8]
        name = getattr(fn, "__name__", "task")
        futures = [client.submit(_call, fn, a, key=f"nespm-{name}-{i}-{token}", pure=False)
                   for i, a in enumerate(args)]
        for fut in as_completed(futures, loop=client.loop):
            try:
                result = fut.result()
            except KilledWorker as exc:
                raise NespmError(f"a chunk killed every Dask worker that ran it ({_one_line(exc)}); "
                                 "check the workers' memory; re-run the same command to resume") from None
            except (FutureCancelledError, CancelledError) as exc:
                raise NespmError(f"Dask cancelled a chunk ({_one_line(exc)}); finished chunks are kept, "
                                 "re-run the same command to resume") from None
            fut.release()
            yield result
    finally:  # never let a failing clean-up hide the error that got us here, nor log tracebacks
        with _quiet_distributed():
            with contextlib.suppress(Exception):
                pending = [f for f in futures if not f.done()]
                if pending:
                    client.cancel(pending)
            with contextlib.suppress(Exception):
                client.close()
            if cluster is not None:
                with contextlib.suppress(Exception):
                    cluster.close()


@contextlib.contextmanager
def _quiet_distributed():
    """Silence distributed's loggers in this process (e.g. the traceback it logs when a client
    that lost its scheduler is closed mid-reconnect); the error itself is already raised."""
    names = ["distributed"] + [n for n in logging.root.manager.loggerDict if n.startswith("distributed.")]
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)
