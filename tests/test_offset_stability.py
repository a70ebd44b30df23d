"""The time-offset estimator of ``nespm check`` (``imu_gt.parabola_minimum``) is stable to round-off: a
last-bit change of its inputs moves an offset by at most 1 µs (issue 30: a parabola re-centred on a grid
minimum with near ties moved local offsets by ~30 µs)."""
from __future__ import annotations

import dataclasses

import numpy as np

from conftest import exact_imu_table, short_track
from nespm_cli.checks import imu_gt

GRID = np.round(np.arange(-2.0, 2.0 + 1e-9, 0.01), 2)


def _old_style(offsets, cost):
    """The former estimator: an unweighted parabola through the 11 points about the grid minimum."""
    k = int(np.argmin(cost))
    c2, c1, _ = np.polyfit(offsets[k - 5:k + 6] - offsets[k], cost[k - 5:k + 6], 2)
    return offsets[k] - c1 / (2 * c2)


def test_near_tied_grid_minima_give_the_same_offset():
    x = GRID - 0.005  # the true minimum halfway between two grid points: their costs tie
    cost = 0.02 * x**2 + np.abs(x) ** 3 + 0.5 * x**3  # not a parabola, skewed
    k = int(np.flatnonzero(GRID == 0.0)[0])
    cost[k + 1] = cost[k]  # an exact tie
    a, b = cost.copy(), cost.copy()
    a[k] = np.nextafter(a[k], -np.inf)  # grid minimum at 0.00 ...
    b[k + 1] = np.nextafter(b[k + 1], -np.inf)  # ... or at 0.01, by one last bit
    assert np.argmin(a) != np.argmin(b)
    assert abs(_old_style(GRID, a) - _old_style(GRID, b)) > 1e-5  # the failure this guards against
    (oa, sa, ea), (ob, sb, eb) = (imu_gt.parabola_minimum(GRID, c, 100.0) for c in (a, b))
    assert abs(oa - ob) <= 1e-6 and not ea and not eb
    assert abs(oa - 0.005) < 0.01  # within a grid step of the true minimum (the skew biases a parabola)
    assert np.isfinite(sa) and abs(sa - sb) <= 1e-3 * sa


def test_local_offsets_move_by_round_off_only():
    tr = short_track(1, 200)
    imu = exact_imu_table(tr)
    imu[:, 0] += 0.137  # an offset between grid points
    g = imu_gt.compare_grid(dataclasses.replace(tr, imu=imu))
    base = imu_gt.local_offsets(g, np.eye(3))
    assert len(base) >= 3 and all(abs(w["offset_s"] - 0.137) < 0.02 for w in base)
    rng = np.random.default_rng(3)
    for _ in range(2):
        x = g["rec_w"].copy()
        m = rng.random(x.shape) < 0.5
        x[m] = np.nextafter(x[m], np.where(rng.random(int(m.sum())) < 0.5, np.inf, -np.inf))
        got = imu_gt.local_offsets({**g, "rec_w": x}, np.eye(3))
        assert max(abs(p["offset_s"] - q["offset_s"]) for p, q in zip(base, got)) <= 1e-6
