"""The points in SIMD lanes (filters/compiled/points.py): the same bits as the scalar point kernel."""
import numpy as np
import pytest

from nespm_cli.filters import kernels

pk = pytest.importorskip("nespm_cli.filters.compiled.points")
cl = pytest.importorskip("nespm_cli.filters.compiled.cycle_lanes")
tk = pytest.importorskip("nespm_cli.filters.compiled.spans")


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


def _run(kernel, args, layout, soa):
    R, M, S = args[0].shape[0], args[6].shape[1], 2 * layout.n + 1
    out = np.empty((R, S, 3)), np.empty((R, S, 3)), np.empty((R, S, 3, 3)), np.full((R, S, 3), -1.0)
    if soa:
        kernel(*args, 0, M, *out, layout.offsets())
    elif layout.has("pos"):
        kernel(*args, 0, M, *out, layout.offsets())
    else:
        kernel(*args, 0, M, *out[:3], layout.offsets())
    return out


@pytest.mark.parametrize("n, R", [(12, 6), (15, 6), (12, 1), (12, 9)])
def test_soa_points_bit_identical_to_scalar_kernel(n, R):
    """Every point's state (and with the position block its position offset) after 40 IMU steps equals
    the scalar kernel's to the bit (the cycle's operations in the same order), on both branches of the
    SO(3) exponential. Without the position block a table's 32 lanes hold the points of up to three runs
    (6 runs: 150 points in five tables, the fourth holding runs 3, 4 and 5, the last 22 lanes; 9 runs: 225,
    the last table one lane); one run's NaN IMU sample stays in its own points (9 runs: run 1, in two tables)."""
    if not kernels.compiled_enabled():
        pytest.skip("numba not installed")
    layout = kernels.LAYOUT_12 if n == 12 else kernels.LAYOUT_15
    args = _inputs(R=R, n=n)
    if R == 9:
        args[6][1, 20, 1] = np.nan
    scalar = tk.points_span_position if layout.has("pos") else tk.points_span
    a, b = _run(scalar, args, layout, False), _run(pk.points_span_soa, args, layout, True)
    for x, y in zip(a, b):
        assert np.array_equal(x, y, equal_nan=True)
    finite = np.isfinite(b[0]).all(axis=(1, 2))
    assert finite.tolist() == [r != 1 for r in range(R)] if R == 9 else finite.all()
    if layout.has("pos"):
        assert np.all(b[3][:, 0] == 0.0) and np.any(b[3][:, 1:] != 0.0)
    else:
        assert np.all(b[3] == -1.0)  # dp untouched without the position block


def test_division_without_divide_is_bit_exact():
    """series_ab's ``th2 / q`` as div_by (two FMAs and a product, no division) equals IEEE division to the
    bit for each of its six constants, on squared angles of the series' range and on magnitudes from
    1e-30 to 1e2, including the neighbours of exact multiples (ties and near-ties of the rounding)."""
    if not kernels.compiled_enabled():
        pytest.skip("numba not installed")
    from nespm_cli.nav.kernels import njit

    @njit
    def mismatches(x, q, r):
        bad = 0
        for i in range(x.size):
            if cl.div_by(x[i], q, r) != x[i] / q:
                bad += 1
        return bad

    rng = np.random.default_rng(7)
    for q in (6.0, 20.0, 42.0, 24.0, 30.0, 56.0):
        m = rng.uniform(0.0, 1e-4, 100_000)
        x = np.concatenate([rng.uniform(0.0, 1e-4, 200_000), 10.0 ** rng.uniform(-30, 2, 200_000), [0.0, 1e-4],
                            m * q, np.nextafter(m * q, 0.0), np.nextafter(m * q, 1.0)])
        assert mismatches(x, q, 1.0 / q) == 0
    assert np.isnan(cl.series_ab(np.nan)[0])
