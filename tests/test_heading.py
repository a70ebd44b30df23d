"""``heading``: compass heading, the yaw of C_bn, options in degrees (docs/sensors.md).

Numbers pinned here (embedded track 5, 16 runs, DVL synthetic; measured values in the comments):

* H on the attitude block, every layout, against central differences of ``h``, pitched and near
  yaw ±π: < 1e-6 (measured 3e-10); the closed form ``[cos ψ tan θ, sin ψ tan θ, 1]``.
* a 10° initial heading error (8 runs), which the DVL alone leaves at a yaw RMS of 5.9° (ekf;
  3.4° iekf) on this track: with the 1° heading at 1 Hz below 1.5° for every filter and layout
  (measured 0.50°, the first epoch's 10° included; ~0.16° without it).
* the heading's NIS mean within the 99.8 % χ² band of its count (1 dof each; measured 0.976).
* adding the heading changes no other sensor's draws, bit for bit.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import chi2

from conftest import assert_one_error_line, nespm, short_track
from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters import FilterConfig
from nespm_cli.nav.rotations import dcm_to_euler, euler_to_dcm
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, NavState, StateLayout, plus
from nespm_cli.sensors.channels import build_channel
from nespm_cli.sensors.heading import Heading, HeadingOptions
from nespm_cli.sensors.source import Context

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

LAYOUTS = {"12": LAYOUT_12, "15": LAYOUT_15, "9": StateLayout(("pos", "vel", "att"))}


def batch(B: int = 8, seed: int = 5):
    rng = np.random.default_rng(seed)
    euler = np.column_stack([rng.uniform(-0.5, 0.5, B), rng.uniform(-0.6, 0.6, B), rng.uniform(-np.pi, np.pi, B)])
    euler[0, 2], euler[1, 2] = np.pi - 1e-7, -np.pi + 1e-7  # at the wrap
    nav = NavState(pos=np.column_stack([rng.uniform(0.3, 0.8, B), rng.uniform(0.3, 0.6, B), rng.uniform(-50, 0, B)]),
                   v_n=rng.normal(0, 1.5, (B, 3)), C_bn=euler_to_dcm(euler),
                   b_a=np.zeros((B, 3)), b_g=np.zeros((B, 3)))
    ctx = Context(np.zeros((B, 3)), np.zeros((B, 3)))
    return nav, ctx, euler, rng


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_H_is_the_finite_difference_jacobian_of_h(layout):
    nav, ctx, euler, _ = batch()
    lay = LAYOUTS[layout]
    m = Heading().measurement(euler[:, 2:3], nav, ctx, lay)
    B, n = nav.v_n.shape[0], lay.n
    eps = 1e-6
    X = np.broadcast_to(np.concatenate([np.eye(n), -np.eye(n)])[None] * eps, (B, 2 * n, n))
    hz = m.h(X, nav)
    fd = np.swapaxes((hz[:, :n] - hz[:, n:]) / (2 * eps), -1, -2)
    H = m.H(nav)
    assert H.shape == (B, 1, n)
    assert np.abs(fd - H).max() < 1e-6, np.abs(fd - H).max()
    a = lay.slice("att")
    pitch, yaw = euler[:, 1], euler[:, 2]
    closed = np.column_stack([np.cos(yaw) * np.tan(pitch), np.sin(yaw) * np.tan(pitch), np.ones(B)])
    assert np.abs(H[:, 0, a] - closed).max() < 1e-12
    assert not np.delete(H, np.arange(a.start, a.stop), axis=-1).any()  # the attitude block only
    assert np.abs(m.innovation(nav)).max() < 1e-12 and np.abs(m.h(np.zeros((B, 1, n)), nav)).max() == 0.0


def test_h_is_the_yaw_of_nav_plus_x_and_the_innovation_wraps():
    nav, ctx, euler, rng = batch()
    x = np.concatenate([rng.normal(0, 1, (8, 3)), rng.normal(0, 0.1, (8, 3)), rng.normal(0, 0.05, (8, 3)),
                        np.zeros((8, 6))], axis=-1)
    moved = nav.copy()
    plus(moved, x, LAYOUT_15)
    z = dcm_to_euler(moved.C_bn)[:, 2:3]  # crosses ±π for the first two runs
    m = Heading().measurement(z, nav, ctx, LAYOUT_15)
    nu = m.innovation(nav)
    assert np.all(np.abs(nu) < 0.3)  # wrapped: never near 2π
    assert np.abs(nu - m.h(x[:, None], nav)[:, 0]).max() < 1e-12  # h is exactly the yaw change
    z = np.array([[np.pi - 0.01]])
    one = NavState(pos=nav.pos[:1], v_n=nav.v_n[:1], C_bn=euler_to_dcm(np.array([[0.0, 0.0, -np.pi + 0.01]])),
                   b_a=nav.b_a[:1], b_g=nav.b_g[:1])
    assert abs(Heading().measurement(z, one, ctx, LAYOUT_12).innovation(one)[0, 0] + 0.02) < 1e-12


def test_options_are_in_degrees():
    s = Heading()
    assert s.noise_std() == math.radians(1.0) and s.interval() == 1.0
    assert np.allclose(s.measurement(np.zeros((2, 1)), batch(2)[0], None, LAYOUT_12).R, math.radians(1.0) ** 2)
    s = Heading(HeadingOptions(std=2.0, r_std=3.0))
    assert s.noise_std() == math.radians(2.0) and s.r_std() == math.radians(3.0)


# ----------------------------------------------------------------------------- synthesis


def spec_of(sensors=("dvl", "heading"), opts=(), runs=16, **kw) -> Spec:
    return validate(Spec(tracks=(5,), runs=runs, filters=kw.pop("filters", ("ekf",)), dvl="synthetic",
                         sensors=sensors, sensor_options=opts, **kw))


def channels(spec: Spec, runs=np.arange(3)) -> dict:
    track, truth = track_inputs(spec, 5)
    return {s.name: build_channel(s, track, truth, spec.seed, 5, runs) for s in sensor_suite(spec)}


def test_noise_bias_and_outage_of_the_synthetic_heading():
    """1° white noise (degrees on the command line, radians in the values), a constant bias per run of
    std 2° on top of the very same noise draws, and no heading inside the outage window."""
    from nespm_cli.sensors.channels import truth_at

    runs = np.arange(64)
    ch = channels(spec_of(opts=(("heading", "bias", "2"), ("heading", "outage", "100:200"))), runs)["heading"]
    nobias = channels(spec_of(), runs)["heading"]
    _, truth = track_inputs(spec_of(), 5)
    yaw = Heading().true_values(truth_at(truth, ch.index, ch.frac))[:, 0]
    assert np.allclose(np.diff(ch.t), 1.0, atol=0.011)  # every 1 s on the IMU clock
    ok = ch.ok
    assert not ok[:, (ch.t >= 100) & (ch.t < 200)].any() and ok[:, (ch.t > 0) & ((ch.t < 100) | (ch.t >= 200))].all()
    wrap_deg = lambda a: np.degrees(np.angle(np.exp(1j * a)))  # noqa: E731
    err, err0 = wrap_deg(ch.z[..., 0] - yaw), wrap_deg(nobias.z[..., 0] - yaw)
    assert abs(err0[ok].std() - 1.0) < 0.02, err0[ok].std()  # 1° white noise, ~22,000 draws
    bias = (err - err0)[:, 1]
    assert np.abs(err - err0 - bias[:, None]).max() < 1e-9  # a constant per run, the noise untouched
    assert 1.5 < bias.std() < 2.6, bias.std()


def test_adding_the_heading_leaves_the_other_draws_alone():
    base = spec_of(("dvl", "dvl-beams"), (("dvl-beams", "beam_dropout", "0.2"),))
    more = spec_of(("heading", "dvl", "dvl-beams"),
                   (("dvl-beams", "beam_dropout", "0.2"), ("heading", "dropout", "0.3"), ("heading", "bias", "1")))
    a, b = channels(base), channels(more)
    for name in ("dvl", "dvl-beams"):
        assert np.array_equal(a[name].z, b[name].z, equal_nan=True) and np.array_equal(a[name].ok, b[name].ok), name
    alone = channels(spec_of(("heading",), (("heading", "dropout", "0.3"), ("heading", "bias", "1"))))["heading"]
    assert np.array_equal(alone.z, b["heading"].z) and np.array_equal(alone.ok, b["heading"].ok)
    assert 0.6 < b["heading"].ok.mean() < 0.8


# ----------------------------------------------------------------------------- filters


@pytest.mark.parametrize("state,filters", [("12", ("ekf", "ukf", "iekf")), ("15", ("ekf", "ukf-nespm"))])
def test_heading_bounds_a_poorly_observed_yaw(state, filters):
    """10° initial heading error (P0 follows it): DVL alone leaves the yaw error large, the 1° heading
    brings its RMS (every epoch, the first included) below 1.5°."""
    cfg = FilterConfig(state=state)
    corr = CorruptionConfig(heading_deg=10.0)
    runs = np.arange(8)

    def yaw_rms(sensors):
        res, truth, _ = simulate(spec_of(sensors, filters=filters, filter_config=cfg, corruption=corr), 5, runs)
        e = truth.epoch_index
        out = {}
        for f in filters:
            o = res[f][0]
            yaw = dcm_to_euler(o.C_bn @ np.swapaxes(truth.C_bn[e], -1, -2))[..., 2]
            out[f] = (math.degrees(float(np.sqrt((yaw**2).mean()))), o)
        return out

    with_h, without = yaw_rms(("dvl", "heading")), yaw_rms(("dvl",))
    for f in filters:
        rms, out = with_h[f]
        assert rms < 1.5, (f, rms)  # measured 0.50°
        assert without[f][0] > 2.5, (f, without[f][0])  # measured 3.4 (iekf) to 5.9° (ekf)
        rec = out.sensors["heading"]
        nis = rec.nis()[rec.used]
        k = nis.size
        assert k > 8 * 390 and chi2.ppf(0.001, k) / k < nis.mean() < chi2.ppf(0.999, k) / k, (f, nis.mean())


# ----------------------------------------------------------------------------- inputs and files


@pytest.mark.parametrize("key,value,needle", [
    ("std", "0", "heading.std"), ("std", "-1", "heading.std"), ("r_std", "0", "heading.r_std"),
    ("scale", "0.01", "heading.scale"), ("bias", "-1", "heading.bias"),
])
def test_bad_heading_options_raise_naming_the_option(key, value, needle):
    with pytest.raises(NespmError) as ei:
        sensor_suite(Spec(tracks=(5,), sensors=("dvl", "heading"), sensor_options=(("heading", key, value),)))
    assert needle in str(ei.value) and "\n" not in str(ei.value), str(ei.value)


def test_bad_heading_std_on_the_command_line_is_one_line(tmp_path):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--sensors", "dvl,heading", "--sensor-option",
                         "heading.std=0", "--out", tmp_path / "x", "--no-progress")
    assert_one_error_line(rc, out, err, "heading.std", "positive")
    assert not (tmp_path / "x").exists()


def test_recorded_heading_file(tmp_path):
    """HEADING_ file at its own stamps: round trip, NaN rows skipped, the values applied (a constant
    0.05 rad offset from the truth moves the solution's heading to it), degrees refused in one line."""
    tr = short_track(5, 61)
    spec0 = validate(Spec(tracks=(5,), runs=1, window="0:60"))
    _, truth = track_inputs(spec0, 5)
    from nespm_cli.sensors.channels import locate, truth_at
    t_h = tr.t[0] + np.arange(0.3, 60.0, 0.7)
    at = truth_at(truth, *locate(truth, t_h - tr.t[0]))
    h = dcm_to_euler(at.C_bn)[:, 2:3] + 0.05
    h[[4, 9]] = np.nan
    folder = tmp_path / "data"
    tdir = write_akit(dataclasses.replace(tr, channels={"heading": (t_h, h)}), folder)
    assert np.array_equal(load_track(5, folder).channels["heading"][1], h, equal_nan=True)
    spec = validate(Spec(tracks=(5,), runs=2, filters=("ekf",), data_dir=str(folder), sensors=("dvl", "heading"),
                         sensor_options=(("heading", "source", "recorded"), ("heading", "std", "0.1")),
                         corruption=CorruptionConfig(heading_deg=5.0)))  # P0 admits the 2.9° offset
    res, tru, _ = simulate(spec, 5, np.arange(2))
    out = res["ekf"][0]
    assert out.sensors["heading"].used.sum(axis=1).tolist() == [len(t_h) - 2] * 2
    e = tru.epoch_index
    dyaw = dcm_to_euler(out.C_bn)[..., 2] - dcm_to_euler(tru.C_bn[e])[..., 2]  # heading, not eq 53's yaw
    assert abs(dyaw[:, -10:].mean() - 0.05) < 0.005, dyaw[:, -10:].mean()
    (tdir / "HEADING_trajectory5.csv").write_text(f"Time [s],Heading [rad]\n{float(tr.t[1])!r},270\n")
    with pytest.raises(NespmError, match=r"HEADING_trajectory5.csv: data row 1, column 'Heading \[rad\]'.*radians"):
        load_track(5, folder)
