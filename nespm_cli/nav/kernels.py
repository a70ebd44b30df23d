"""Compiled (numba, ``nopython``) twins of the navigation cycle, one state at a time.

The NumPy functions of :mod:`.earth`, :mod:`.rotations` and :mod:`.strapdown` are the
reference; the functions here compute the same formulas, in the same order and with the
same branches, on the scalars of one state, so a compiled loop over runs, sigma points and
IMU steps agrees with the reference: bit for bit for the cycle itself (the reference's 3x3
products are elementwise sums in the same order, :mod:`.products`), and to 1e-9 on whole
filter runs (tests/test_kernels.py; measured 0 for the sigma-point filters, ~1e-14 for the
Φ-based ones). Each compiled function is cached on disk (``cache=True``) in a per-user folder,
:func:`~nespm_cli.nav.kernel_cache.cache_folder` (``$NESPM_CACHE_DIR``, else ``$NUMBA_CACHE_DIR``, else the platform's cache
folder: ``$XDG_CACHE_HOME/nespm`` or ``~/.cache/nespm``), in a subfolder named by a hash of the
kernels' source text (:data:`~nespm_cli.nav.kernel_cache.KERNEL_SOURCES`), so every install and clone of the same kernels on
the machine shares one compile, and an edit to any of them (a constant, an inlined helper)
compiles afresh; numba's own locations are the fallback where that folder is not writable.

Why numba: it compiles this plain-Python arithmetic to machine code without a second
language or a build step, it is maintained on PyPI with wheels for every platform NumPy has,
and its on-disk cache makes the compile a one-time cost. Without numba the filters run
the NumPy reference (:func:`nespm_cli.filters.kernels.compiled_enabled` is False).

A state travels through the loops as a 25-tuple of floats (kept in registers):
``(lat, lon, h)`` [rad, rad, m], ``v_n`` (3) [m/s], ``C_bn`` (9, row-major) and its earth
quantities (10, :func:`earth_t`); :func:`load_t` / :func:`store_t` convert from and to arrays
``pos`` (3,), ``v`` (3,), ``C`` (3, 3). IMU ``f`` [m/s²], ``w`` [rad/s] per step, ``dt`` [s].
"""
from __future__ import annotations

import functools
import math
import os
import warnings
from pathlib import Path

import numpy as np

from nespm_cli.nav.earth import A, B, E2, F, GAMMA_E, K_SOMIGLIANA, MU, OMEGA_IE
from nespm_cli.nav.kernel_cache import NO_CACHE, cache_folder, source_key
from nespm_cli.nav.trig import sin_cos_core

try:  # numba is a dependency; without it the filters run the NumPy reference (filters.kernels)
    import numba
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    numba = None

class KernelCacheWarning(UserWarning):
    """numba found no writable place to cache the compiled kernels (printed as one warning line)."""


class FolderLocator:
    """A numba cache locator (the interface of ``numba.core.caching``'s locators) that puts a kernel of
    ``<dir>/<module>.py`` in ``cache_folder()/<dir>``, stamped with :func:`source_key` instead of the
    file's own hash: a clone at another path with the same kernels finds it."""

    def __init__(self, py_func, folder: Path, py_file: str) -> None:
        self._lineno = py_func.__code__.co_firstlineno
        self._path = str(folder / Path(py_file).parent.name)

    def ensure_cache_path(self) -> None:
        os.makedirs(self._path, exist_ok=True)

    def get_cache_path(self) -> str:
        return self._path

    def get_source_stamp(self) -> str:
        return source_key()

    def get_disambiguator(self) -> str:
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file: str):
        folder = cache_folder()
        if folder is None or not os.path.isfile(py_file):
            return None
        locator = cls(py_func, folder, py_file)
        try:
            locator.ensure_cache_path()
        except OSError:
            return None
        return locator


@functools.lru_cache(maxsize=None)
def folder_cache_class():
    """numba's ``FunctionCache`` with :class:`FolderLocator` as its only locator (None: numba's
    internals are not what this was written against; its default cache is kept)."""
    try:
        from numba.core import caching

        impl = type("FolderCacheImpl", (caching.CompileResultCacheImpl,), {"_locator_classes": [FolderLocator]})
        return type("FolderFunctionCache", (caching.FunctionCache,), {"_impl_class": impl})
    except (ImportError, AttributeError, TypeError):  # pragma: no cover - another numba
        return None


def use_folder_cache(dispatcher) -> bool:
    """Point a ``cache=True`` dispatcher's on-disk cache at :func:`cache_folder` (what
    ``Dispatcher.enable_caching`` does with numba's locators); False where that folder or numba's
    internals are not available (the dispatcher keeps numba's default locations)."""
    cls = folder_cache_class()
    if cls is None or cache_folder() is None:
        return False
    try:
        dispatcher._cache = cls(dispatcher.py_func)
    except (RuntimeError, AttributeError, OSError):  # no locator, or another numba
        return False
    return True


def njit(*args, **kwargs):
    """``numba.njit``, with ``cache=True`` cached in :func:`cache_folder` (numba's default locations
    where it is not writable). Falls back to ``cache=False`` when numba finds no writable cache
    location at all (a read-only install and no writable ``NUMBA_CACHE_DIR``): the kernels then compile
    in every process instead of failing (:data:`NO_CACHE` says why). Without numba: the plain function."""
    if numba is None:  # pragma: no cover
        return args[0] if args and callable(args[0]) else (lambda f: f)

    def deco(f):
        try:
            dispatcher = numba.njit(**kwargs)(f)
            if kwargs.get("cache"):
                use_folder_cache(dispatcher)
            return dispatcher
        except RuntimeError as exc:
            if not kwargs.get("cache") or "cannot cache" not in str(exc):
                raise
            if not NO_CACHE:
                NO_CACHE.append(str(exc))
                warnings.warn("numba cannot cache the compiled kernels here (no writable cache location; set "
                              "NESPM_CACHE_DIR or NUMBA_CACHE_DIR to a writable folder): they compile in every process "
                              "(seconds each)",
                              KernelCacheWarning, stacklevel=3)
            return numba.njit(**{**kwargs, "cache": False})(f)
    return deco(args[0]) if args and callable(args[0]) else deco


def helper(f=None, *, python: bool = False):
    """A function the kernels call (``@helper``, or ``@helper(python=True)``): ``njit(cache=True,
    error_model="numpy")`` compiled once per process and signature and inlined by LLVM into every kernel
    that calls it (``forceinline``: the ``alwaysinline`` attribute), not by numba. numba's own inlining
    (``inline="always"``, what these were) copies and types the helper's IR again at every call site
    (``exp_t`` twice per ``cycle_t``, ``load_t`` and ``earth_t`` in every kernel), and kernels sharing a
    helper each paid for it. The machine code is the same: the same operations in the same order (no
    fast-math), every helper inlined. Without ``python`` no Python wrapper is built (a helper is called
    from kernels only, and the wrapper was most of its own compile); ``python=True`` keeps it callable
    from Python (tests). Measured: the default ``mc``'s two kernels 4.3 → 3.4 CPU-s to compile
    (benchmarks/README.md, the compile section)."""
    opts = dict(cache=True, error_model="numpy", forceinline=True)
    if not python:
        opts.update(no_cpython_wrapper=True, no_cfunc_wrapper=True)
    return njit(**opts) if f is None else njit(**opts)(f)


#: ``(sin x, cos x)`` of a latitude, compiled from :func:`nespm_cli.nav.trig.sin_cos_core` (the same bits; arithmetic
#: only, so it vectorises in a loop over points)
sin_cos_t = helper(python=True)(sin_cos_core)

SERIES2 = 1e-4  # rotations._SERIES2: squared angle below which the exp series is used
GRAV_M = OMEGA_IE**2 * A**2 * B / MU  # gravity_n's m


@helper
def exp_t(p0, p1, p2):
    """``exp([p x])`` as a 9-tuple, row-major (rotations.exp_so3: series below 0.01 rad, Rodrigues above)."""
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 >= SERIES2:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / (th * th)
    else:  # also for NaN, as the reference
        a = 1.0 - th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0))
        b = 0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0))
    return exp_from(p0, p1, p2, th2, a, b)


@helper
def exp_from(p0, p1, p2, th2, a, b):
    """exp_t's 9-tuple from the angle ``p``, its square ``th2`` and the coefficients ``a`` (sin θ/θ) and
    ``b`` ((1 − cos θ)/θ²): ``(1 − b θ²) I + a [p×] + b p pᵀ``, in one order (the points kernel's too)."""
    d = 1.0 - b * th2
    return (b * (p0 * p0) + d, -(p2 * a) + b * (p0 * p1), p1 * a + b * (p0 * p2),
            p2 * a + b * (p1 * p0), b * (p1 * p1) + d, -(p0 * a) + b * (p1 * p2),
            -(p1 * a) + b * (p2 * p0), p0 * a + b * (p2 * p1), b * (p2 * p2) + d)


@helper
def mul_t(X, Y):
    """``X @ Y`` of two row-major 9-tuples, summed as products.mat_mul: ``(x0 y0 + x1 y1) + x2 y2``."""
    return ((X[0] * Y[0] + X[1] * Y[3]) + X[2] * Y[6], (X[0] * Y[1] + X[1] * Y[4]) + X[2] * Y[7],
            (X[0] * Y[2] + X[1] * Y[5]) + X[2] * Y[8],
            (X[3] * Y[0] + X[4] * Y[3]) + X[5] * Y[6], (X[3] * Y[1] + X[4] * Y[4]) + X[5] * Y[7],
            (X[3] * Y[2] + X[4] * Y[5]) + X[5] * Y[8],
            (X[6] * Y[0] + X[7] * Y[3]) + X[8] * Y[6], (X[6] * Y[1] + X[7] * Y[4]) + X[8] * Y[7],
            (X[6] * Y[2] + X[7] * Y[5]) + X[8] * Y[8])


@helper
def earth_t(lat, h, vN, vE):
    """The earth quantities of a state, a 10-tuple ``(sin L, cos L, R_N, R_E, w_ie^n (3), w_en^n (3))``.

    A cycle ends by evaluating them at the new state (eq 32), which is where the next cycle
    starts (eq 25): :func:`cycle_t` hands them on instead of computing them twice (the
    reference computes them twice, from the same inputs, so to the same bits).
    """
    sl, cl = sin_cos_t(lat)
    den = 1.0 - E2 * (sl * sl)
    R_N = A * (1.0 - E2) / (den * math.sqrt(den))
    R_E = A / math.sqrt(den)
    return (sl, cl, R_N, R_E, OMEGA_IE * cl, 0.0, -OMEGA_IE * sl,
            vE / (R_E + h), -vN / (R_N + h), -vE * sl / cl / (R_E + h))


@helper
def gravity_t(h, sl, cl):
    """``(g_N, g_D)`` [m/s²] of earth.gravity_n at height ``h`` [m] and latitude ``L`` (``sl``, ``cl`` = sin L, cos L)."""
    s2 = sl * sl
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    gN = -8.08e-9 * h * (2.0 * sl * cl)
    gD = g0 * (1.0 - 2.0 / A * (1.0 + F + GRAV_M - 2.0 * F * s2) * h + 3.0 * h * h / A**2)
    return gN, gD


@helper
def cycle_t(x, f0, f1, f2, w0, w1, w2, dt):
    """One navigation cycle, ukf-nespm.md eqs 24-32 (strapdown.na_cycle), on scalars.

    ``x`` is the 25-tuple ``(lat, lon, h, v (3), C (9, row-major), earth cache (10))`` of a
    state (:func:`earth_t`); returns that of the next state. Kept in registers: the loops over
    IMU steps carry ``x`` from one cycle to the next.
    """
    lat, lon, h = x[0], x[1], x[2]
    v0, v1, v2 = x[3], x[4], x[5]
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = x[6], x[7], x[8], x[9], x[10], x[11], x[12], x[13], x[14]
    sl, cl, R_N, R_E = x[15], x[16], x[17], x[18]
    ie0, ie1, ie2, en0, en1, en2 = x[19], x[20], x[21], x[22], x[23], x[24]
    u0, u1, u2 = ie0 + en0, ie1 + en1, ie2 + en2
    half = 0.5 * dt
    # eq 25: w_nb* = w_ib - C^T (w_ie + w_en); eq 24: C* = C exp(w_nb* dt/2)
    p0 = (w0 - ((c00 * u0 + c10 * u1) + c20 * u2)) * half
    p1 = (w1 - ((c01 * u0 + c11 * u1) + c21 * u2)) * half
    p2 = (w2 - ((c02 * u0 + c12 * u1) + c22 * u2)) * half
    C = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
    s00, s01, s02, s10, s11, s12, s20, s21, s22 = mul_t(C, exp_t(p0, p1, p2))
    gN, gD = gravity_t(h, sl, cl)
    # eqs 26-27: v_dot = C* f + g - (w_en + 2 w_ie) x v
    a0, a1, a2 = en0 + 2.0 * ie0, en1 + 2.0 * ie1, en2 + 2.0 * ie2
    vd0 = (((s00 * f0 + s01 * f1) + s02 * f2) + gN) - (a1 * v2 - a2 * v1)
    vd1 = (((s10 * f0 + s11 * f1) + s12 * f2) + 0.0) - (a2 * v0 - a0 * v2)
    vd2 = (((s20 * f0 + s21 * f1) + s22 * f2) + gD) - (a0 * v1 - a1 * v0)
    n0, n1, n2 = v0 + vd0 * dt, v1 + vd1 * dt, v2 + vd2 * dt
    # eqs 28-30: position (strapdown.update_position)
    h1 = h + (-n2 + -v2) * half
    lat1 = lat + (v0 / (R_N + h) + n0 / (R_N + h1)) * half
    e = earth_t(lat1, h1, n0, n1)
    lon1 = lon + (v1 / ((R_E + h) * cl) + n1 / ((e[3] + h1) * e[1])) * half
    # eq 32: w_nb with the updated position and velocity; eq 31: C_{k+1} = C exp(w_nb dt)
    u0, u1, u2 = e[4] + e[7], e[5] + e[8], e[6] + e[9]
    p0 = (w0 - ((c00 * u0 + c10 * u1) + c20 * u2)) * dt
    p1 = (w1 - ((c01 * u0 + c11 * u1) + c21 * u2)) * dt
    p2 = (w2 - ((c02 * u0 + c12 * u1) + c22 * u2)) * dt
    return (lat1, lon1, h1, n0, n1, n2) + mul_t(C, exp_t(p0, p1, p2)) + e


@helper
def load_t(pos, v, C):
    """The 25-tuple of :func:`cycle_t` from arrays ``pos``, ``v`` (3,), ``C`` (3, 3)."""
    return state_t(pos[0], pos[1], pos[2], v[0], v[1], v[2], matrix_t(C))


@helper
def matrix_t(C):
    """A (3, 3) array as a row-major 9-tuple."""
    return (C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2])


@helper
def state_t(lat, lon, h, v0, v1, v2, C):
    """The 25-tuple of :func:`cycle_t` of a state (``C`` a row-major 9-tuple)."""
    return (lat, lon, h, v0, v1, v2) + C + earth_t(lat, h, v0, v1)


@helper
def store_t(x, pos, v, C):
    """Write the state of a 25-tuple into ``pos``, ``v`` (3,) and ``C`` (3, 3)."""
    pos[0], pos[1], pos[2] = x[0], x[1], x[2]
    v[0], v[1], v[2] = x[3], x[4], x[5]
    C[0, 0], C[0, 1], C[0, 2] = x[6], x[7], x[8]
    C[1, 0], C[1, 1], C[1, 2] = x[9], x[10], x[11]
    C[2, 0], C[2, 1], C[2, 2] = x[12], x[13], x[14]


@njit(cache=True, error_model="numpy")
def na_cycle_batch(pos, v, C, f, w, dt, pos_out, v_out, C_out):
    """:func:`cycle_t` over a flat batch: ``pos``, ``v``, ``f``, ``w`` (B, 3), ``C`` (B, 3, 3), ``dt`` (B,)."""
    for b in range(pos.shape[0]):
        x = cycle_t(load_t(pos[b], v[b], C[b]), f[b, 0], f[b, 1], f[b, 2], w[b, 0], w[b, 1], w[b, 2], dt[b])
        store_t(x, pos_out[b], v_out[b], C_out[b])


@njit(cache=True, error_model="numpy")
def strapdown_span(pos, v, C, b_a, b_g, f, w, dt, j0, j1):
    """Free-inertial steps ``[j0, j1)`` of R runs in place: ``pos``, ``v``, ``b_a``, ``b_g`` (R, 3),
    ``C`` (R, 3, 3); IMU ``f``, ``w`` (R, M, 3) compensated by the run's biases; ``dt`` (M,)."""
    for r in range(pos.shape[0]):
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            x = cycle_t(x, f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2,
                        w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
        store_t(x, pos[r], v[r], C[r])


def na_cycle_compiled(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, f_b: np.ndarray,
                      w_ib_b: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`nespm_cli.nav.strapdown.na_cycle` through the compiled kernel (same shapes, broadcast)."""
    batch = np.broadcast_shapes(pos.shape[:-1], v_n.shape[:-1], C_bn.shape[:-2], f_b.shape[:-1],
                                w_ib_b.shape[:-1], np.shape(dt))
    flat = lambda a, tail: np.ascontiguousarray(np.broadcast_to(a, batch + tail), dtype=float).reshape((-1,) + tail)  # noqa: E731
    p, v, C = flat(pos, (3,)), flat(v_n, (3,)), flat(C_bn, (3, 3))
    outs = np.empty_like(p), np.empty_like(v), np.empty_like(C)
    na_cycle_batch(p, v, C, flat(f_b, (3,)), flat(w_ib_b, (3,)), flat(np.asarray(dt, float), ()), *outs)
    return outs[0].reshape(batch + (3,)), outs[1].reshape(batch + (3,)), outs[2].reshape(batch + (3, 3))
