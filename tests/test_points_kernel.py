"""The points in SIMD lanes (filters/points_kernel.py): the same bits as the scalar point kernel."""
import numpy as np
import pytest

from nespm_cli.filters import kernels

pk = pytest.importorskip("nespm_cli.filters.points_kernel")
tk = pytest.importorskip("nespm_cli.filters.transition_kernel")


def _inputs(R=6, n=12, M=40, seed=3):
    rng = np.random.default_rng(seed)
    pos = np.column_stack([0.55 + 0.01 * rng.standard_normal(R), 0.6 + 0.01 * rng.standard_normal(R),
                           -20 + rng.standard_normal(R)])
    v = rng.standard_normal((R, 3))
    C = np.linalg.qr(rng.standard_normal((R, 3, 3)))[0]
    ba, bg = 1e-3 * rng.standard_normal((R, 3)), 1e-4 * rng.standard_normal((R, 3))
    X = 1e-2 * rng.standard_normal((R, 2 * n, n))
    X[:2, :3, 6:9] = 0.3  # attitude offsets above 0.01 rad: the Rodrigues branch of the start
    f = rng.standard_normal((R, M, 3)) + [0.0, 0.0, -9.8]
    w = 0.1 * rng.standard_normal((R, M, 3))
    w[:2, :5] = 3.0  # rotation per step above 0.01 rad: the Rodrigues branch in the cycle
    return pos, v, C, ba, bg, X, f, w, np.full(M, 0.01)


def _run(kernel, args, S):
    R, M = args[0].shape[0], args[6].shape[1]
    out = np.empty((R, S, 3)), np.empty((R, S, 3)), np.empty((R, S, 3, 3))
    kernel(*args, 0, M, *out, kernels.LAYOUT_12.offsets())
    return out


def test_soa_points_bit_identical_to_scalar_kernel():
    """Every point's state after 40 IMU steps equals the scalar kernel's to the bit (the cycle's operations
    in the same order), on both branches of the SO(3) exponential."""
    if not kernels.compiled_enabled():
        pytest.skip("numba not installed")
    args = _inputs()
    a, b = _run(tk.points_span, args, 25), _run(pk.points_span_soa, args, 25)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert np.all(np.isfinite(b[0]))
