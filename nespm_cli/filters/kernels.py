"""The compiled time loop of the built-in filters, and the switch between it and NumPy.

What is compiled (numba, :mod:`nespm_cli.nav.kernels`) is the part that runs at the IMU
rate, the loop over the IMU steps of one time-update span, for every run (and sigma point)
of a batch:

* :func:`strapdown` — free inertial steps (``ins``; ``ErrorStateFilter.strapdown``);
* :func:`transition` — the navigation cycle plus the accumulation of Φ = Π (I + F dt), F the
  error-state matrix of :func:`nespm_cli.filters.model.system_matrix` on the solution before
  each step (``ekf``, ``ukf``, the adaptive twins and every plugin that calls
  ``ErrorStateFilter.transition``), or the right-invariant F_inv of
  :func:`nespm_cli.filters.model.invariant_system_matrix` (``iekf``, 12 or 15 states);
* :func:`points_through_cycle` — error-state points (sigma or cubature offsets) added to the
  solution (ukf-nespm.md eqs 35-37) and each carried through the navigation cycle with its
  own bias compensation (eq 38) (``ukf-nespm``, ``anukf-nespm``).

What stays NumPy is what runs once per span or per DVL epoch (Cholesky factors, unscented
moments, ``Φ P Φᵀ + Q``, the measurement update): at 100 IMU steps per DVL interval it is
a few per cent of a run (benchmarks/README.md gives the split). The NumPy functions remain
the reference; tests/test_kernels.py runs both on the same realizations.

The switch, :func:`kernel_mode`: ``auto`` (default) uses the compiled loop where numba is
installed, ``numba`` requires it, ``numpy`` never uses it. It is read from the context set by
:func:`use_kernels`, else from the environment variable ``NESPM_KERNELS`` (which the CLI's
``--kernels`` sets, so that worker processes inherit it). It never changes a result beyond
round-off (tests: 1e-9), so it is not part of an experiment's identity (like ``--jobs``).

Compiled once per user, machine and kernel text (:func:`nespm_cli.nav.kernel_cache.cache_folder`), and
only what is used: each kernel (:data:`KERNELS`) compiles on its first call, the first process to
need it holding a lock in the cache folder so that concurrent workers do not compile it twice, and
is then marked ready there, so :func:`kernels_cached` is a few file tests. A command compiles what
its filters need up front (:func:`warm_up` with :func:`nespm_cli.experiments.progress.kernels_for`),
saying so; ``nespm warm-up`` does it ahead of time (CI images).
"""
from __future__ import annotations

import importlib.util
import os
from contextlib import contextmanager
from typing import Iterator

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, StateLayout

MODES = ("auto", "numba", "numpy")
ENV = "NESPM_KERNELS"
_override: list[str] = []


def numba_installed() -> bool:
    """Whether numba can be imported (without importing it: that costs ~0.4 s)."""
    return importlib.util.find_spec("numba") is not None


def checked_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else a one-line NespmError."""
    if mode not in MODES:
        raise NespmError(f"--kernels / {ENV}: unknown mode {mode!r}; choose {', '.join(MODES)}")
    return mode


def kernel_mode() -> str:
    """The requested mode: the innermost :func:`use_kernels`, else ``$NESPM_KERNELS``, else ``auto``."""
    return checked_mode(_override[-1] if _override else os.environ.get(ENV, "auto") or "auto")


def compiled_enabled() -> bool:
    """Whether the filters use the compiled loop now (see :func:`kernel_mode`)."""
    mode = kernel_mode()
    if mode == "numpy":
        return False
    if not numba_installed():
        if mode == "numba":
            raise NespmError("--kernels numba: numba is not installed (pip install numba), or use --kernels numpy")
        return False
    return True


def kernel_backend() -> str:
    """``numba`` or ``numpy``: what :func:`compiled_enabled` resolves to (for manifests)."""
    return "numba" if compiled_enabled() else "numpy"


def set_kernel_mode(mode: str) -> None:
    """Set ``$NESPM_KERNELS`` (this process and the worker processes it starts); checks ``mode``
    and, for ``numba``, that numba is installed."""
    os.environ[ENV] = checked_mode(mode)
    compiled_enabled()


@contextmanager
def use_kernels(mode: str) -> Iterator[None]:
    """Run the enclosed filters with ``mode`` (one of :data:`MODES`) in this process."""
    _override.append(checked_mode(mode))
    try:
        yield
    finally:
        _override.pop()


def _f64(a: np.ndarray) -> np.ndarray:
    """Float64 view or copy; broadcast (zero-stride) views pass through uncopied."""
    return a if a.dtype == np.float64 else a.astype(np.float64)


#: the compiled kernels by name (what :func:`warm_up`, :func:`kernels_cached` and the ready marks in
#: the cache folder speak of): the free-inertial loop, Φ of the common error (the papers' 12 states
#: unrolled, run by run, or from :data:`LANES_MIN` runs in SIMD lanes; the 15 states with F's zeros
#: skipped, likewise; any other layout, a plugin's, in the generic loop), Φ_inv of the iekf (12 / 15 states), the
#: sigma/cubature points
KERNELS = ("strapdown", "transition", "transition-lanes", "transition-position", "transition-position-lanes",
           "transition-generic", "transition-invariant", "transition-invariant-position", "points")
#: runs from which the papers' 12-state Φ runs with the runs in SIMD lanes ("transition-lanes",
#: filters/compiled/lanes_12.py), fewer run by run ("transition"): a block of lanes costs 32 runs'
#: cycles whatever it holds; at 8 runs the two cost the same per run-step, from 24 the lanes about 0.3x
#: (benchmarks/README.md). The same bits either way, so no number depends on the chunk size.
LANES_MIN = 8
#: ... and for the 15 states' Φ ("transition-position-lanes", filters/compiled/lanes_15.py), whose block costs
#: more: at 8 runs the lanes cost 1.3x per run-step, at 10 1.05x, at 12 0.87x, from 24 about 0.5x
LANES_MIN_15 = 12
#: a layout that only the generic Φ loop runs (what warm_up compiles "transition-generic" on)
GENERIC_LAYOUT = StateLayout(("pos", "vel", "att"))


def run_kernel(name: str, kernel, *args):
    """``kernel(*args)``: the first call of kernel ``name`` in a process that finds it not yet compiled
    holds its lock in the cache folder, so concurrent workers compile it once (the others wait, then
    load it), and marks it ready (:func:`nespm_cli.nav.kernel_cache.first_use`); later calls go straight in."""
    from nespm_cli.nav.kernel_cache import READY, first_use

    if name in READY:
        return kernel(*args)
    with first_use(name):
        return kernel(*args)


def strapdown(pos, v_n, C_bn, b_a, b_g, f, w, dt, j0: int, j1: int) -> None:
    """Free-inertial steps ``[j0, j1)`` of R runs, in place on ``pos``, ``v_n`` (R, 3), ``C_bn``
    (R, 3, 3) (C-contiguous float64); IMU ``f``, ``w`` (R, M, 3) minus ``b_a``, ``b_g`` (R, 3);
    ``dt`` (M,) [s]. Same numbers as :func:`nespm_cli.nav.strapdown.na_cycle` step by step."""
    from nespm_cli.nav import kernels as nk

    run_kernel("strapdown", nk.strapdown_span, pos, v_n, C_bn, b_a, b_g, _f64(f), _f64(w), _f64(dt), j0, j1)


def lanes_from(layout: StateLayout) -> int:
    """The runs from which ``layout``'s common-error Φ runs with the runs in SIMD lanes: :data:`LANES_MIN`,
    :data:`LANES_MIN_15` for the 15 states (any other layout never: the generic loop)."""
    return LANES_MIN_15 if layout.blocks == LAYOUT_15.blocks else LANES_MIN


def transition_kernel(invariant: bool, layout: StateLayout, runs: int = 1) -> str:
    """The name (:data:`KERNELS`) of the kernel :func:`transition` runs for ``invariant``, ``layout`` and
    a batch of ``runs`` runs."""
    if invariant:
        return "transition-invariant-position" if layout.has("pos") else "transition-invariant"
    lanes = runs >= lanes_from(layout)
    if layout.blocks == LAYOUT_12.blocks:
        return "transition-lanes" if lanes else "transition"
    if layout.blocks == LAYOUT_15.blocks:
        return "transition-position-lanes" if lanes else "transition-position"
    return "transition-generic"


def transition(pos, v_n, C_bn, b_a, b_g, f, w, dt, j0: int, j1: int, invariant: bool = False,
               layout: StateLayout = LAYOUT_12, origin: np.ndarray | None = None) -> np.ndarray:
    """Steps ``[j0, j1)`` in place as :func:`strapdown`, returning Φ (R, n, n) = Π (I + F dt) of
    ``layout``, F (:func:`nespm_cli.filters.model.system_matrix`, or with ``invariant`` the
    right-invariant :func:`nespm_cli.filters.model.invariant_system_matrix`) on the solution before
    each step. The invariant error with a position block (the iekf's 15 states) needs ``origin``
    (R, 3) ``[lat, lon, h]``: the group position is the solution's NED offset from it (docs/iekf.md)."""
    from nespm_cli.filters.compiled import spans as tk

    Phi = np.empty((pos.shape[0], layout.n, layout.n))
    name, off = transition_kernel(invariant, layout, pos.shape[0]), layout.offsets()
    args = (pos, v_n, C_bn, b_a, b_g, _f64(f), _f64(w), _f64(dt), j0, j1, Phi)
    if name == "transition-invariant-position":
        if origin is None:
            raise NespmError("kernels.transition: the invariant error with a position block needs the origin")
        run_kernel(name, tk.transition_span_invariant_position, *args, off, np.ascontiguousarray(origin, dtype=np.float64))
    elif name == "transition-position":  # the 15 states: F's zeros skipped
        run_kernel(name, tk.transition_span_position, *args)
    elif name == "transition-position-lanes":  # ... and from LANES_MIN runs, the runs in SIMD lanes (the same bits)
        from nespm_cli.filters.compiled.lanes_15 import transition_lanes_15

        run_kernel(name, transition_lanes_15, *args)
    elif name == "transition-invariant":
        run_kernel(name, tk.transition_span_invariant, *args, off)
    elif name == "transition":  # the papers' 12 states: the generic loop unrolled (the same bits, less to compile)
        from nespm_cli.filters.compiled.unrolled_12 import transition_span_12

        run_kernel(name, transition_span_12, *args)
    elif name == "transition-lanes":  # ... and from LANES_MIN runs, the runs in SIMD lanes (the same bits)
        from nespm_cli.filters.compiled.lanes_12 import transition_lanes_12

        run_kernel(name, transition_lanes_12, *args)
    else:
        run_kernel(name, tk.transition_span_common, *args, off)
    return Phi


def points_through_cycle(pos, v_n, C_bn, b_a, b_g, X, f, w, dt, j0: int, j1: int,
                         layout: StateLayout = LAYOUT_12):
    """The mean (point 0) and the offsets ``X`` (R, S-1, n) of each run through steps ``[j0, j1)``.

    Point s starts at ``pos ⊕ dp`` (``pos`` without a position block), ``v_n + dv``,
    ``exp([dpsi x]) C_bn`` (eqs 35-37) and uses the IMU minus ``b_a + δb_a``, ``b_g + δb_g`` (eq 38).
    Returns ``(pos, v, C, dp)`` (R, S, 3), (R, S, 3), (R, S, 3, 3), (R, S, 3): ``dp`` each point's
    position offset from point 0, NED [m] (its ``dp`` plus the integral of its velocity offset);
    nothing is modified in place.
    """
    from nespm_cli.filters.compiled import points as pk
    from nespm_cli.filters.compiled import spans as tk

    R, S = X.shape[0], X.shape[1] + 1
    out = np.empty((R, S, 3)), np.empty((R, S, 3)), np.empty((R, S, 3, 3))
    args = (pos, v_n, C_bn, b_a, b_g, np.ascontiguousarray(X, dtype=float), _f64(f), _f64(w), _f64(dt), j0, j1)
    dp = np.zeros((R, S, 3))
    if S <= pk.L:  # the points in SIMD lanes; the same bits as the scalar kernels below
        run_kernel("points", pk.points_span_soa, *args, *out, dp, layout.offsets())
    elif not layout.has("pos"):  # more than 32 points (a plugin's layout): compiled where first used
        tk.points_span(*args, *out, layout.offsets())
    else:
        tk.points_span_position(*args, *out, dp, layout.offsets())
    return (*out, dp)


def warm_up(names=None) -> float:
    """Compile (or load from the on-disk cache) the kernels ``names`` (default: all of :data:`KERNELS`)
    on a tiny input; returns seconds. Each is marked ready in the cache folder.

    The first call on a machine compiles (benchmarks/README.md gives the cost); later processes
    load the cached machine code. Nothing needs to call it: the kernels compile on first use.
    """
    import time

    t0 = time.perf_counter()
    R, M = 1, 2
    pos, v = np.array([[0.5, 0.1, -10.0]]), np.array([[1.0, 0.0, 0.0]])
    C, b = np.eye(3)[None].copy(), np.zeros((R, 3))
    f, w, dt = np.tile([0.0, 0.0, -9.8], (R, M, 1)), np.zeros((R, M, 3)), np.full(M, 0.01)
    for name in KERNELS if names is None else names:
        if name == "strapdown":
            strapdown(pos.copy(), v.copy(), C.copy(), b, b, f, w, dt, 0, M)
        elif name == "points":
            points_through_cycle(pos, v, C, b, b, np.zeros((R, 24, 12)), f, w, dt, 0, M, LAYOUT_12)
        elif name.endswith("lanes"):
            layout = LAYOUT_15 if "position" in name else LAYOUT_12
            n = lanes_from(layout)
            transition(np.repeat(pos, n, 0), np.repeat(v, n, 0), np.repeat(C, n, 0), np.repeat(b, n, 0),
                       np.repeat(b, n, 0), np.repeat(f, n, 0), np.repeat(w, n, 0), dt, 0, M, layout=layout)
        elif name.startswith("transition"):
            layout = LAYOUT_15 if name.endswith("position") else GENERIC_LAYOUT if name.endswith("generic") else LAYOUT_12
            transition(pos.copy(), v.copy(), C.copy(), b, b, f, w, dt, 0, M, "invariant" in name, layout, pos)
        else:
            raise NespmError(f"warm_up: unknown kernel {name!r}; choose from {', '.join(KERNELS)}")
    return time.perf_counter() - t0


def kernels_cached(names=None) -> bool | None:
    """Whether the kernels ``names`` (default: all of :data:`KERNELS`) are compiled into the per-user
    cache folder for this CPU (their ready marks, :func:`nespm_cli.nav.kernel_cache.is_ready`): True,
    False, or None where the compiled kernels are not in use or cannot be cached here (then every
    process compiles its own). Does not import numba (the mc parent leaves it to its workers), compiles
    nothing, reads no cache index: a few file tests.
    """
    if not compiled_enabled():
        return None
    from nespm_cli.nav.kernel_cache import is_ready

    marks = [is_ready(name) for name in (KERNELS if names is None else names)]
    if any(m is None for m in marks):
        return None
    return all(marks)
