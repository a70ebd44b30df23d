"""Where the Monte Carlo chunks run: local loky processes (default) or a Dask cluster.

``parallel_map`` is the one place the runner asks for parallelism; results never depend on
the backend, because every chunk is seeded per (track, run), never per worker.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from .errors import NespmError

BACKENDS = ("loky", "dask")


def parallel_map(fn: Callable, args: list[tuple], jobs: int, backend: str = "loky",
                 scheduler: str | None = None) -> Iterator:
    """Yield ``fn(*a)`` for every ``a`` in ``args``, in completion order.

    ``jobs`` is the number of local worker processes (loky); ``scheduler`` the address of a
    Dask scheduler (dask backend).
    """
    from joblib import Parallel, delayed

    if backend not in BACKENDS:
        raise NespmError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend == "dask":
        raise NespmError("--backend dask is not available yet")
    calls: Iterable = (delayed(fn)(*a) for a in args)
    par = Parallel(n_jobs=min(jobs, max(len(args), 1)), backend="loky", return_as="generator_unordered")
    yield from par(calls)
