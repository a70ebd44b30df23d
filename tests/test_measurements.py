"""The measurement models of the built-in sensors (nespm_cli.sensors): DVL, depth, position fix.

For every sensor and every built-in layout: ``H`` is the Jacobian of ``h`` at x = 0 (central
finite differences, relative 1e-6 of H's largest entry), ``h(0)`` is zero (h is the change from
x = 0), ``h`` is the full model evaluated on ``nav ⊕ x`` minus its value at ``nav`` (so the
error-state convention ``nav ⊕ x = truth`` and the model agree), and the innovation of an exact
measurement of the truth ``nav ⊕ x`` is ``h(x)`` to first order.
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.nav.rotations import exp_so3
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, NavState, plus
from nespm_cli.sensors.depth import Depth, DepthOptions
from nespm_cli.sensors.dvl import Dvl, DvlMeasurement, DvlOptions, body_rate
from nespm_cli.sensors.fix import Fix, FixOptions
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import Context, Truth

LEVER = (0.4, -0.2, 0.7)
SENSORS = {
    "dvl": lambda: Dvl(DvlOptions(lever_arm=LEVER, r_std=0.02)),
    "depth": lambda: Depth(DepthOptions(lever_arm=LEVER)),
    "fix": lambda: Fix(FixOptions(lever_arm=LEVER)),
    "fix3d": lambda: Fix(FixOptions(lever_arm=LEVER, vertical=True, vertical_std=0.5)),
}
LAYOUTS = {"12": LAYOUT_12, "15": LAYOUT_15}


def batch(B: int = 5, seed: int = 3):
    rng = np.random.default_rng(seed)
    nav = NavState(pos=np.column_stack([rng.uniform(0.3, 0.8, B), rng.uniform(0.3, 0.6, B), rng.uniform(-50, 0, B)]),
                   v_n=rng.normal(0, 1.5, (B, 3)), C_bn=exp_so3(rng.normal(0, 1.0, (B, 3))),
                   b_a=rng.normal(0, 0.1, (B, 3)), b_g=rng.normal(0, 1e-4, (B, 3)))
    ctx = Context(rng.normal(0, 0.1, (B, 3)) + [0, 0, -9.8], rng.normal(0, 0.05, (B, 3)))
    return nav, ctx, rng


def truth_of(nav: NavState, ctx: Context) -> Truth:
    return Truth(t=np.arange(len(nav.v_n), dtype=float), pos=nav.pos, v_n=nav.v_n, C_bn=nav.C_bn,
                 w_nb_b=body_rate(nav, ctx.w_ib_b))


def pairs():
    for s in SENSORS:
        for lay in LAYOUTS:
            if s != "dvl" and lay == "12":
                continue  # depth and fixes need the position block (refused: test_sensors_cli)
            yield s, lay


@pytest.mark.parametrize("sensor,layout", list(pairs()))
def test_H_is_finite_difference_jacobian_of_h(sensor, layout):
    nav, ctx, _ = batch()
    lay = LAYOUTS[layout]
    sen = SENSORS[sensor]()
    m = sen.measurement(sen.true_values(truth_of(nav, ctx)), nav, ctx, lay)
    assert isinstance(m, Measurement)
    B, n = nav.v_n.shape[0], lay.n
    eps = 1e-6
    X = np.concatenate([np.eye(n), -np.eye(n)])[None] * eps
    X = np.broadcast_to(X, (B, 2 * n, n))
    hz = m.h(X, nav)
    fd = np.swapaxes((hz[:, :n] - hz[:, n:]) / (2 * eps), -1, -2)
    H = m.H(nav)
    assert H.shape == (B, m.dim, n)
    scale = np.abs(H).max()
    # central differences: truncation ~ eps² |h'''| and round-off ~ 1e-16 |h| / eps; measured
    # below 1e-9 relative for all four sensors. A wrong sign or block is O(1).
    assert np.abs(fd - H).max() < 1e-6 * scale, np.abs(fd - H).max() / scale
    assert np.abs(m.h(np.zeros((B, 1, n)), nav)).max() == 0.0


@pytest.mark.parametrize("sensor,layout", list(pairs()))
def test_h_is_the_model_on_nav_plus_x(sensor, layout):
    """``h(x)`` equals ``y(nav ⊕ x) − y(nav)`` with ``y`` the sensor's error-free value
    (``true_values``); for the DVL with the body rate fixed and b_g entering as ``−b_g × l``."""
    nav, ctx, rng = batch()
    lay = LAYOUTS[layout]
    sen = SENSORS[sensor]()
    scale = {"pos": 2.0, "vel": 0.3, "att": 0.05, "ba": 0.0, "bg": 0.0}
    x = np.concatenate([rng.normal(0, scale[b], (5, 3)) for b in lay.blocks], axis=-1)
    m = sen.measurement(sen.true_values(truth_of(nav, ctx)), nav, ctx, lay)
    moved = nav.copy()
    plus(moved, x, lay)
    w_nb = body_rate(nav, ctx.w_ib_b)
    y0 = sen.true_values(Truth(nav.v_n[:, 0], nav.pos, nav.v_n, nav.C_bn, w_nb))
    y1 = sen.true_values(Truth(nav.v_n[:, 0], moved.pos, moved.v_n, moved.C_bn, w_nb))
    expected = y1 - y0
    if sensor.startswith("fix"):  # angles -> the metres of the model (ned_offset about nav)
        from nespm_cli.nav.earth import ned_offset
        full = lambda y: np.concatenate([y, nav.pos[:, y.shape[1]:]], axis=-1)  # noqa: E731
        expected = (ned_offset(full(y1), nav.pos) - ned_offset(full(y0), nav.pos))[:, : m.dim]
    got = m.h(x[:, None], nav)[:, 0]
    # exact for the DVL and depth; the fix's local-metre approximation of a 2 m offset: ~1e-6 m
    assert np.abs(got - expected).max() < 1e-5, np.abs(got - expected).max()


@pytest.mark.parametrize("sensor", ["depth", "fix", "fix3d"])
def test_innovation_of_the_truth_is_h_of_the_error(sensor):
    """A perfect measurement of the truth ``nav ⊕ x``: ``innovation(nav) ≈ h(x)`` (first order:
    x of 1 m and 1 mrad gives agreement to 1e-5 m)."""
    nav, ctx, rng = batch()
    sen = SENSORS[sensor]()
    x = np.concatenate([rng.normal(0, 1.0, (5, 3)), rng.normal(0, 0.1, (5, 3)), rng.normal(0, 1e-3, (5, 3)),
                        np.zeros((5, 6))], axis=-1)
    truth = nav.copy()
    plus(truth, x, LAYOUT_15)
    z = sen.true_values(truth_of(truth, ctx))
    m = sen.measurement(z, nav, ctx, LAYOUT_15)
    err = np.abs(m.innovation(nav) - m.h(x[:, None], nav)[:, 0]).max()
    assert err < 1e-5, err


def test_dvl_measurement_noise_and_prediction():
    nav, ctx, _ = batch()
    sen = SENSORS["dvl"]()
    m = sen.measurement(np.zeros((5, 3)), nav, ctx, LAYOUT_12)
    assert isinstance(m, DvlMeasurement) and m.dim == 3
    assert np.array_equal(m.R, np.eye(3) * 0.02**2)
    w_nb = body_rate(nav, ctx.w_ib_b)
    pred = np.einsum("bji,bj->bi", nav.C_bn, nav.v_n) + np.cross(w_nb, LEVER)
    assert np.allclose(m.predict(nav), pred, rtol=0, atol=1e-14)
    assert np.array_equal(m.innovation(nav), m.z - m.predict(nav))


def test_dvl_H_is_the_same_in_both_layouts():
    """The DVL's H of the 15-state layout is the 12-state H with a zero position block in front."""
    nav, ctx, _ = batch()
    sen = SENSORS["dvl"]()
    z = np.zeros((5, 3))
    H12 = sen.measurement(z, nav, ctx, LAYOUT_12).H(nav)
    H15 = sen.measurement(z, nav, ctx, LAYOUT_15).H(nav)
    assert np.array_equal(H15[..., 3:], H12) and not H15[..., :3].any()


def test_fix_R_and_dimension():
    assert SENSORS["fix"]().R().shape == (2, 2) and SENSORS["fix3d"]().R().shape == (3, 3)
    assert np.array_equal(np.diag(SENSORS["fix3d"]().R()), [1.0, 1.0, 0.25])
