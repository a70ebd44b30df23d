"""``dvl-beams``: the four Janus beams as scalar measurements, masked rows for lost beams (docs/sensors.md).

Numbers pinned here (embedded track 5, 16 runs unless said; measured values in the comments):

* H of every beam, both layouts, against central differences of ``h``: < 1e-6 (measured 5e-13).
* a masked beam changes nothing: the 4-row update with beams masked equals the update with the
  available rows alone (EKF and UT) to 1e-12, each run with its own mask in one batch.
* at θ = atan √2 the four beams carry the body DVL's information (LS covariance σ_b² (BᵀB)⁻¹ =
  0.02² I): with the same filter R and negligible noise, velocity RMSE equal to the DVL's within
  1 % (measured 6e-6 relative: what is left is the 1e-5 m/s noise of the two sensors' own draws).
* beams 1, 2 lost 180-240 s: velocity RMS in the window 0.101 m/s, against 0.156 with every beam
  lost and 0.165 with the body DVL's outage (the two remaining beams still observe two directions).
* dof-normalised beam NIS with 30 % of the beams dropped within 3 % of the no-loss value
  (measured 0.911 against 0.929), where ``mean NIS / 4`` would read 0.64.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm, short_track
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters.model import joseph_update
from nespm_cli.filters.unscented import UTWeights, moments, sigma_offsets
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.rotations import exp_so3
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, NavState
from nespm_cli.sensors.channels import build_channel, locate, truth_at
from nespm_cli.sensors.dvl import body_rate, invariant_dvl_h
from nespm_cli.sensors.dvl_beams import (BeamMeasurement, BeamOptions, DvlBeams, beam_directions, equivalent_std,
                                         parse_beam_outage)
from nespm_cli.sensors.registry import get_sensor
from nespm_cli.sensors.source import Context, options_of

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

LEVER = (0.4, -0.2, 0.7)
MAGIC = math.degrees(math.atan(math.sqrt(2.0)))  # 54.7356°: B^T B isotropic
LAYOUTS = {"12": LAYOUT_12, "15": LAYOUT_15}


def batch(B: int = 6, seed: int = 3):
    rng = np.random.default_rng(seed)
    nav = NavState(pos=np.column_stack([rng.uniform(0.3, 0.8, B), rng.uniform(0.3, 0.6, B), rng.uniform(-50, 0, B)]),
                   v_n=rng.normal(0, 1.5, (B, 3)), C_bn=exp_so3(rng.normal(0, 1.0, (B, 3))),
                   b_a=rng.normal(0, 0.1, (B, 3)), b_g=rng.normal(0, 1e-4, (B, 3)))
    ctx = Context(rng.normal(0, 0.1, (B, 3)) + [0, 0, -9.8], rng.normal(0, 0.05, (B, 3)))
    return nav, ctx, rng


def beam_values(sensor: DvlBeams, nav: NavState, ctx: Context) -> np.ndarray:
    """(B, 4) the exact beams of ``nav`` with the body rate the measurement uses."""
    return dvl_velocity(nav.C_bn, nav.v_n, body_rate(nav, ctx.w_ib_b), np.asarray(LEVER)) @ sensor.B.T


# ----------------------------------------------------------------------------- geometry and model


def test_beam_directions_are_the_documented_janus_x():
    B = beam_directions(25.0)
    s, c = math.sin(math.radians(25.0)), math.cos(math.radians(25.0))
    a = s / math.sqrt(2.0)
    assert np.allclose(B, [[a, a, c], [-a, a, c], [-a, -a, c], [a, -a, c]], atol=1e-15)
    assert np.allclose(np.linalg.norm(B, axis=1), 1.0, atol=1e-15)
    assert np.allclose(B.T @ B, np.diag([2 * s * s, 2 * s * s, 4 * c * c]), atol=1e-15)
    # the default std: the LS horizontal velocity std is the DVL's 0.02 m/s
    sb = equivalent_std(0.02, 25.0)
    assert abs(sb - 0.0119534) < 1e-7 and DvlBeams().noise_std() == sb
    cov = sb**2 * np.linalg.inv(B.T @ B)
    assert np.allclose(np.sqrt(np.diag(cov))[:2], 0.02, rtol=1e-12)
    Bm = beam_directions(MAGIC)
    assert np.allclose(equivalent_std(0.02, MAGIC) ** 2 * np.linalg.inv(Bm.T @ Bm), 0.02**2 * np.eye(3), rtol=1e-12)


@pytest.mark.parametrize("layout", ["12", "15"])
def test_H_of_every_beam_is_the_finite_difference_jacobian(layout):
    nav, ctx, rng = batch()
    lay = LAYOUTS[layout]
    sen = DvlBeams(BeamOptions(lever_arm=LEVER, beam_angle=23.0))
    z = beam_values(sen, nav, ctx)
    z[1, 2] = z[4, 0] = z[4, 3] = np.nan  # masked rows in some runs
    m = sen.measurement(z, nav, ctx, lay)
    B, n = nav.v_n.shape[0], lay.n
    eps = 1e-6
    X = np.broadcast_to(np.concatenate([np.eye(n), -np.eye(n)])[None] * eps, (B, 2 * n, n))
    hz = m.h(X, nav)
    fd = np.swapaxes((hz[:, :n] - hz[:, n:]) / (2 * eps), -1, -2)  # (B, 4, n)
    H = m.H(nav)
    assert H.shape == (B, 4, n) and m.R.shape == (B, 4, 4)
    assert np.abs(fd - H).max() < 1e-6, np.abs(fd - H).max()
    assert np.abs(H[m.mask]).max() > 0.1  # not trivially zero
    assert not H[1, 2].any() and not H[4, 0].any() and not H[4, 3].any()
    # the unmasked rows are the beam matrix times the DVL's H
    dvl = get_sensor("dvl")(options_of(get_sensor("dvl"), {"lever_arm": ",".join(map(str, LEVER))}))
    Hd = dvl.measurement(np.zeros((B, 3)), nav, ctx, lay).H(nav)
    assert np.allclose(H[0], sen.B @ Hd[0], atol=1e-15)
    # masked rows: zero innovation, unit R; exact measurement: zero innovation elsewhere
    nu = m.innovation(nav)
    assert np.isfinite(nu).all() and np.abs(nu).max() < 1e-12
    assert m.R[1, 2, 2] == 1.0 and m.R[0, 2, 2] == sen.r_std() ** 2
    assert np.count_nonzero(m.R[1] - np.diag(np.diag(m.R[1]))) == 0


def test_invariant_H_is_the_finite_difference_of_the_invariant_model():
    nav, ctx, _ = batch()
    sen = DvlBeams(BeamOptions(lever_arm=LEVER))
    z = beam_values(sen, nav, ctx)
    z[2, 1] = np.nan
    m = sen.measurement(z, nav, ctx, LAYOUT_12)
    Hi = m.H_invariant(nav)
    eps, n, B = 1e-6, 12, nav.v_n.shape[0]
    X = np.broadcast_to(np.concatenate([np.eye(n), -np.eye(n)])[None] * eps, (B, 2 * n, n))
    hz = invariant_dvl_h(X[..., 0:3], X[..., 3:6], X[..., 9:12], nav.C_bn, np.asarray(LEVER)) @ sen.B.T
    fd = np.where(m.mask[:, None, :], hz[:, :n] - hz[:, n:], 0.0) / (2 * eps)
    assert np.abs(np.swapaxes(fd, -1, -2) - Hi).max() < 1e-6
    assert not Hi[2, 1].any() and not Hi[..., 3:6].any()  # no attitude column (right-invariant)


def reduced_update(P, m: BeamMeasurement, nav, run: int):
    """The run's update with only its available beams, as a measurement of that size."""
    keep = m.mask[run]
    H = m.H(nav)[run][keep]
    nu = m.innovation(nav)[run][keep]
    return joseph_update(P[run][None], H[None], nu[None], m.R[run][np.ix_(keep, keep)][None])


def test_a_masked_beam_changes_nothing_in_the_batched_update():
    """Runs missing different beams (none, one, two, three) in one batched 4-row update: each run's
    state correction, covariance and NIS equal those of the update with its available beams alone."""
    nav, ctx, rng = batch(B=4)
    lay = LAYOUT_15
    sen = DvlBeams(BeamOptions(lever_arm=LEVER))
    z = beam_values(sen, nav, ctx) + rng.normal(0, 0.05, (4, 4))
    z[1, 0] = np.nan
    z[2, [1, 2]] = np.nan
    z[3, [0, 1, 3]] = np.nan
    m = sen.measurement(z, nav, ctx, lay)
    A = rng.normal(0, 0.1, (4, lay.n, lay.n))
    P = A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(lay.n)
    x, P1, S = joseph_update(P, m.H(nav), m.innovation(nav), m.R)
    nu = m.innovation(nav)
    nis = (nu * np.linalg.solve(S, nu[..., None])[..., 0]).sum(-1)
    for r in range(4):
        xr, Pr, Sr = reduced_update(P, m, nav, r)
        nur = m.innovation(nav)[r][m.mask[r]]
        assert np.abs(x[r] - xr[0]).max() < 1e-12 and np.abs(P1[r] - Pr[0]).max() < 1e-12, r
        assert abs(nis[r] - nur @ np.linalg.solve(Sr[0], nur)) < 1e-9, r
    # the unscented update (ukf's formulas on the measurement's h): masked rows get zero gain
    ut = UTWeights(lay.n, 0.5, 2.0, 0.0)
    X = sigma_offsets(np.linalg.cholesky(P), ut)
    mx, _, mz, Pzz, Pxz = moments(X, ut, m.h(X, nav))
    S_ut = Pzz + m.R
    K = np.swapaxes(np.linalg.solve(S_ut, np.swapaxes(Pxz, -1, -2)), -1, -2)
    assert np.abs(K[~m.mask[:, None, :].repeat(lay.n, 1)]).max() == 0.0
    assert np.abs((nu - mz)[~m.mask]).max() == 0.0 and np.all(S_ut[3, 0, 1:] == 0.0) and S_ut[3, 0, 0] == 1.0


# ----------------------------------------------------------------------------- synthesis and loss


def spec_of(sensors=("dvl-beams",), opts=(), runs=16, **kw) -> Spec:
    return validate(Spec(tracks=(5,), runs=runs, filters=kw.pop("filters", ("ekf",)), dvl="synthetic",
                         sensors=sensors, sensor_options=opts, **kw))


def channel(spec: Spec, name: str = "dvl-beams", runs=np.arange(4), clean=False):
    track, truth = track_inputs(spec, 5)
    s = next(s for s in sensor_suite(spec) if s.name == name)
    return build_channel(s, track, truth, spec.seed, 5, runs, clean), s, truth


def test_beam_outage_and_dropout_lose_beams_not_noise_draws():
    base, _, _ = channel(spec_of())
    lost, s, _ = channel(spec_of(opts=(("dvl-beams", "beam_outage", "1,2@180:240;4@300:302"),
                                       ("dvl-beams", "beam_dropout", "0.25"))))
    t = lost.t
    win = (t >= 180) & (t < 240)
    gone = np.isnan(lost.z) | ~lost.ok[..., None]  # a row with no beam left is no measurement (zeroed)
    assert gone[:, win, :2].all() and gone[:, (t >= 300) & (t < 302), 3].all()
    keep = ~gone
    assert np.array_equal(lost.z[keep], base.z[keep])  # the noise draws do not move
    out = ~win & ~((t >= 300) & (t < 302))
    rate = np.isnan(lost.z[:, out]).mean()
    assert 0.22 < rate < 0.28, rate
    assert not np.array_equal(np.isnan(lost.z[0]), np.isnan(lost.z[1]))  # per run
    # a row is a measurement while one beam is left; all four lost: none (its values zeroed)
    none = ~np.isnan(lost.z).any(axis=-1) & (lost.z == 0.0).all(axis=-1)
    assert none.any() and not lost.ok[none].any() and lost.ok[~none & (t > 0)].all()
    assert none[:, win].mean() > 0.04  # beams 3 and 4 both dropped: 0.25² of the window


def test_bias_and_scale_are_drawn_per_beam():
    opts = (("dvl-beams", "std", "1e-9"), ("dvl-beams", "bias", "0.05"), ("dvl-beams", "scale", "0.01"))
    ch, s, truth = channel(spec_of(opts=opts), runs=np.arange(6))
    clean, _, _ = channel(spec_of(), runs=np.arange(6), clean=True)
    d = ch.z[:, 1:] - clean.z[:, 1:]  # (R, K, 4) = clean * scale + bias
    A = np.stack([clean.z[0, 1:], np.ones_like(clean.z[0, 1:])], axis=-1)  # per beam: [d, 1]
    fit = np.stack([[np.linalg.lstsq(A[:, b], d[r, :, b], rcond=None)[0] for b in range(4)] for r in range(6)])
    assert np.abs((A[None] * fit[:, None]).sum(-1) - d).max() < 1e-7  # exactly that model
    scale, bias = fit[..., 0], fit[..., 1]
    assert np.ptp(scale, axis=1).min() > 1e-4 and np.ptp(bias, axis=1).min() > 1e-3  # differ between beams
    assert 0.02 < bias.std() < 0.09 and 0.004 < scale.std() < 0.02


# ----------------------------------------------------------------------------- filters


def vel_rmse(res, f, sel=slice(None)):
    return float(np.sqrt((res[f][1].vel[:, sel] ** 2).mean()))


def test_four_beams_carry_the_body_dvl_information():
    """θ = atan √2: the beams' LS covariance is the DVL's 0.02² I. Same filter R, negligible
    synthetic noise (so the two sensors' different noise draws do not matter): equal velocity RMSE."""
    filters = ("ekf", "ukf", "iekf")
    dvl = simulate(spec_of(("dvl",), (("dvl", "std", "1e-5"), ("dvl", "r_std", "0.02")), filters=filters),
                   5, np.arange(16))[0]
    beams = simulate(spec_of(opts=(("dvl-beams", "beam_angle", repr(MAGIC)), ("dvl-beams", "std", "1e-5"),
                                   ("dvl-beams", "r_std", repr(equivalent_std(0.02, MAGIC)))), filters=filters),
                     5, np.arange(16))[0]
    for f in filters:
        a, b = vel_rmse(dvl, f), vel_rmse(beams, f)
        assert abs(b / a - 1) < 0.01, (f, a, b)
        assert abs(b / a - 1) < 1e-4, (f, a, b)  # measured 6e-6


@pytest.fixture(scope="module")
def losses():
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("NESPM_DATA_DIR", raising=False)
        runs = np.arange(16)
        two = simulate(spec_of(opts=(("dvl-beams", "beam_outage", "1,2@180:240"),)), 5, runs)
        allb = simulate(spec_of(opts=(("dvl-beams", "outage", "180:240"),)), 5, runs)
        dvl = simulate(spec_of(("dvl",), (("dvl", "outage", "180:240"),)), 5, runs)
    return two, allb, dvl


def test_two_lost_beams_beat_losing_the_dvl(losses):
    two, allb, dvl = losses
    truth = two[1]
    e = truth.epoch_index
    t = truth.t[e] - truth.t[e[0]]
    win = (t >= 180) & (t < 240)
    a, b, c = vel_rmse(two[0], "ekf", win), vel_rmse(allb[0], "ekf", win), vel_rmse(dvl[0], "ekf", win)
    assert a < 0.8 * b and a < 0.8 * c, (a, b, c)  # measured 0.101, 0.156, 0.165 m/s
    rec = two[0]["ekf"][0].sensors["dvl-beams"]
    inside = (rec.t >= 180) & (rec.t < 240)
    assert rec.used[:, inside].all()  # the two remaining beams are applied
    assert np.all(rec.S[:, inside, 0, 0] == 1.0) and np.all(rec.nu[:, inside, :2] == 0.0)


def test_nis_per_available_beam_is_not_distorted_by_masked_rows():
    def nis_per_dof(opts):
        out = simulate(spec_of(opts=opts, runs=32), 5, np.arange(32))[0]["ekf"][0]
        rec = out.sensors["dvl-beams"]
        masked = (rec.nu == 0.0) & np.all(rec.S == np.eye(4), axis=-1)
        dof = 4 - masked.sum(-1)
        nis = rec.nis()
        # the metrics' per-run NIS is scaled the same way: 4 Σ NIS / Σ dof (experiments.metrics.sensor_nis)
        from nespm_cli.experiments.metrics import sensor_nis
        per_run = np.where(rec.used, nis, 0.0).sum(1) / np.where(rec.used, dof, 0).sum(1)
        np.testing.assert_allclose(sensor_nis(out)["nis_dvl-beams"], 4 * per_run, rtol=1e-12)
        np.testing.assert_array_equal(rec.dof(), np.where(rec.used, dof, 0))
        return float(nis[rec.used].sum() / dof[rec.used].sum()), float(np.nanmean(nis) / 4)

    full, _ = nis_per_dof(())
    drop, naive = nis_per_dof((("dvl-beams", "beam_dropout", "0.3"),))
    assert abs(drop / full - 1) < 0.03, (full, drop)  # measured 0.911 / 0.929
    assert naive < 0.8 * full  # what dividing by 4 would say (0.64)


# ----------------------------------------------------------------------------- recorded file and inputs


def test_recorded_beam_file_with_lost_beams_keeps_the_filter_on_the_truth(tmp_path):
    """A DVLBEAMS file at its own (off-grid) stamps holding the exact beams, NaN cells in some rows
    (one, two, three beams) and one all-NaN row: every row with a beam is applied, the clean filter
    stays on the truth, and the file round-trips bit for bit."""
    tr = short_track(5, 41)
    t_b = tr.t[0] + np.arange(0.25, 40.0, 0.5)
    spec0 = validate(Spec(tracks=(5,), runs=1, window="0:40"))
    _, truth = track_inputs(spec0, 5)
    at = truth_at(truth, *locate(truth, t_b - tr.t[0]))
    z = dvl_velocity(at.C_bn, at.v_n, at.w_nb_b, np.zeros(3)) @ beam_directions(25.0).T
    z[5, 1] = np.nan
    z[9, [0, 3]] = np.nan
    z[20, [0, 1, 2]] = np.nan
    z[30] = np.nan
    folder = tmp_path / "data"
    write_akit(dataclasses.replace(tr, channels={"dvl-beams": (t_b, z)}), folder)
    assert np.array_equal(load_track(5, folder).channels["dvl-beams"][1], z, equal_nan=True)
    from test_sensors import TINY
    spec = validate(Spec(tracks=(5,), runs=1, filters=("ekf", "ukf"), data_dir=str(folder), tell_filter=False,
                         sensors=("dvl-beams",), sensor_options=(("dvl-beams", "source", "recorded"),),
                         filter_config=TINY))
    assert sensor_suite(spec)[0].r_std() == equivalent_std(0.1, 25.0)
    res, _, _ = simulate(spec, 5, np.arange(1), clean=True)
    for f, (out, err, _) in res.items():
        assert out.sensors["dvl-beams"].used.sum() == len(t_b) - 1, f
        assert err.vel.max() < 1e-8 and err.att.max() < 1e-8, (f, err.vel.max(), err.att.max())


def test_a_beam_file_with_three_beams_is_one_line_naming_it(tmp_path):
    tr = short_track(5, 41)
    folder = tmp_path / "data"
    tdir = write_akit(tr, folder)
    p = tdir / "DVLBEAMS_trajectory5.csv"
    p.write_text(f"Time [s],Beam 1 [m/s],Beam 2 [m/s],Beam 3 [m/s]\n{float(tr.t[1])!r},0.1,0.2,0.3\n")
    with pytest.raises(NespmError, match="DVLBEAMS_trajectory5.csv: 3 beam columns") as ei:
        load_track(5, folder)
    assert "\n" not in str(ei.value)
    rc, out, err = nespm("mc", "--data-dir", folder, "--tracks", "5", "--runs", "1", "--sensors", "dvl-beams",
                         "--sensor-option", "dvl-beams.source=recorded", "--out", tmp_path / "x", "--no-progress")
    assert_one_error_line(rc, out, err, "DVLBEAMS_trajectory5.csv", "3 beam columns")
    p.write_text(f"Time [s],Beam 1 [m/s],Beam 2 [m/s],Beam 3 [m/s],Beam 4 [m/s]\n{float(tr.t[1])!r},0.1,0.2,30,nan\n")
    with pytest.raises(NespmError, match=r"data row 1, column 'Beam 3 \[m/s\]'.*metres per second"):
        load_track(5, folder)


@pytest.mark.parametrize("key,value,needle", [
    ("beam_angle", "95", "dvl-beams.beam_angle"), ("beam_angle", "0", "dvl-beams.beam_angle"),
    ("beam_angle", "90", "(0, 90)"), ("beam_angle", "-10", "(0, 90)"), ("beam_angle", "nan", "(0, 90)"),
    ("beam_dropout", "1", "dvl-beams.beam_dropout"), ("beam_outage", "5@1:2", "numbered 1..4"),
    ("beam_outage", "1,2", "BEAMS@START:END"), ("beam_outage", "1@20:10", "START < END"), ("std", "0", "positive std"),
])
def test_bad_beam_options_raise_naming_the_option(key, value, needle):
    with pytest.raises(NespmError, match=None) as ei:
        sensor_suite(Spec(tracks=(5,), sensors=("dvl-beams",), sensor_options=(("dvl-beams", key, value),)))
    assert needle in str(ei.value) and "\n" not in str(ei.value), str(ei.value)


def test_bad_beam_angle_on_the_command_line_is_one_line(tmp_path):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--sensors", "dvl-beams", "--sensor-option",
                         "dvl-beams.beam_angle=95", "--out", tmp_path / "x", "--no-progress")
    assert_one_error_line(rc, out, err, "dvl-beams.beam_angle", "(0, 90)")
    assert not (tmp_path / "x").exists()


def test_parse_beam_outage():
    assert parse_beam_outage("2,1@180:240; 3@300:310,400:410", "w") == [((1, 2), [(180.0, 240.0)]),
                                                                         ((3,), [(300.0, 310.0), (400.0, 410.0)])]
    assert parse_beam_outage("", "w") == []
