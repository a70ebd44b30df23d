"""`nespm check`'s verdict counts the DVL (issue 39 item 2): a DVL in the earth frame, in permuted
axes, with a scale error or a time offset beyond the search makes the track inconsistent, and the
verdict's line names the DVL, the numbers and the key to set; a correct DVL keeps its verdict.

Tracks: embedded track 5 (400 s, DVL noise 0.02 m/s per axis, DVL_NOISE) with its DVL replaced.
Measured on the six embedded tracks: the DVL's own noise from its second difference 0.0196-0.0206
m/s (so the bound is 6 x that = 0.12 m/s), the correct DVL's residual 0.019-0.020 m/s, the earth-
frame DVL's 0.92-1.18 m/s as body and 0.020-0.021 as NED; on the 13 Snapir tracks the correct DVL's
residual is 0.5-3.2 noise stds, the earth-frame one's 53-258.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from conftest import cli
from nespm_cli.checks import dvl_verdict
from nespm_cli.checks.dvl_frame import ENU_OF_NED, own_noise
from nespm_cli.checks.verdict import check_track
from nespm_cli.data.corrections import axes_matrix
from nespm_cli.data.embedded import DVL_NOISE, embedded_track
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.nav.rotations import euler_to_dcm


@pytest.fixture(scope="module")
def track():
    return embedded_track(5)


@pytest.fixture(scope="module")
def earth(track):
    """Track 5 with the DVL holding the NED velocity plus the DVL's noise, declared body."""
    noise = np.random.default_rng(7).normal(0.0, DVL_NOISE, track.v_n.shape)
    return dataclasses.replace(track, dvl=np.asarray(track.v_n) + noise)


@pytest.fixture(scope="module")
def earth_result(earth):
    return check_track(earth)


@pytest.mark.parametrize("number", [1, 3, 5])
def test_correct_dvl_keeps_its_verdict(number):
    r = check_track(embedded_track(number))
    assert r["verdict"] == "consistent" and r["verdict_reasons"] == []
    j = r["dvl"]["judged"]
    assert abs(j["noise"] - DVL_NOISE) < 0.002  # 0.0196-0.0206 measured
    assert j["bound"] == pytest.approx(dvl_verdict.RESID_SIGMAS * j["noise"])
    assert r["dvl"]["resid_rms_after"] < 0.25 * j["bound"]  # 0.020 against 0.12
    assert j["frame"]["body"]["rms"] < 0.025 and min(j["frame"][k]["rms"] for k in ("ned", "enu", "axes")) > 0.025
    assert not any(f.startswith("DVL ") and "time offset" not in f for f in r["findings"])


def test_own_noise_reads_the_white_noise_alone(track):
    """The second-difference estimate needs no GT: the same on the body and the earth-frame DVL,
    and it skips NaN rows (no measurement)."""
    rng = np.random.default_rng(3)
    body = np.asarray(track.dvl)
    assert np.all(np.abs(own_noise(body) - DVL_NOISE) < 0.003)
    dvl = body.copy()
    dvl[rng.choice(len(dvl), 40, replace=False)] = np.nan
    assert np.all(np.abs(own_noise(dvl) - DVL_NOISE) < 0.003)
    assert np.isnan(own_noise(body[:3])).all()


def test_earth_frame_dvl_is_inconsistent_and_named(earth_result):
    r = earth_result
    assert r["verdict"] == "inconsistent"
    assert r["verdict_reasons"][0] == "DVL looks like NED velocity"
    assert any(x.startswith("DVL residual 1.") for x in r["verdict_reasons"])
    assert any(x.startswith("DVL scale -") for x in r["verdict_reasons"])
    first = r["findings"][0]
    assert first.startswith("DVL looks like earth-frame NED velocity (residual 0.0")
    assert f'{dvl_verdict.DVL_FRAME_KEY} = "ned"' in first
    f = r["dvl"]["judged"]["frame"]
    assert abs(f["ned"]["rms"] - DVL_NOISE) < 0.003 and f["ned"]["offset_s"] == 0.0
    assert r["dvl"]["resid_rms_after"] > 0.9 and f["body"]["rms"] > 1.0
    assert (f" vs {f['body']['rms']:.2f} as body, {r['dvl']['resid_rms_after']:.2f} with scale and misalignment "
            "fitted too" in first)
    # the residual's sentence says how far above the noise it is
    resid = next(x for x in r["findings"] if x.startswith("DVL residual"))
    assert f"{r['dvl']['resid_rms_after'] / r['dvl']['judged']['noise']:.0f}x the DVL's own noise" in resid


def test_enu_dvl_is_named_enu(track):
    noise = np.random.default_rng(8).normal(0.0, DVL_NOISE, track.v_n.shape)
    r = check_track(dataclasses.replace(track, dvl=np.asarray(track.v_n) @ ENU_OF_NED.T + noise))
    assert r["verdict"] == "inconsistent" and r["verdict_reasons"][0] == "DVL looks like ENU velocity"
    assert f'{dvl_verdict.DVL_FRAME_KEY} = "enu"' in r["findings"][0]


def test_rotated_mounting_is_named_and_the_named_axes_undo_it(track):
    """A DVL mounted 90 deg off in yaw (its x the hull's starboard, y,-x,z): the check names y,-x,z, and
    those axes applied give the correct verdict back. (A FLU DVL, x,-y,-z, is not told apart on this
    track: it moves the DVL by twice the small lateral and vertical velocity, 0.039 against 0.020 m/s
    as FRD, under the 0.12 m/s bound.)"""
    A = axes_matrix("y,-x,z")  # body = A dvl
    rotated = np.asarray(track.dvl) @ A  # rows: A^T body
    r = check_track(dataclasses.replace(track, dvl=rotated))
    assert r["verdict"] == "inconsistent" and r["verdict_reasons"][0] == "DVL axes look like y,-x,z"
    assert f'{dvl_verdict.DVL_AXES_KEY} = "y,-x,z"' in r["findings"][0]
    assert any(x.startswith("DVL misalignment") for x in r["verdict_reasons"])  # the fit's rotation, ~77 deg
    fixed = check_track(dataclasses.replace(track, dvl=rotated @ A.T))
    assert fixed["verdict"] == "consistent"


@pytest.mark.parametrize("scale", [0.01, 0.10])
def test_scale_counts_when_its_effect_is_above_the_bound(track, scale):
    """1 %: 0.02 m/s at the track's ~2 m/s, below the 0.12 m/s bound; 10 %: 0.2 m/s, above it."""
    r = check_track(dataclasses.replace(track, dvl=(1 + scale) * np.asarray(track.dvl)))
    j = r["dvl"]["judged"]
    s = r["dvl"]["scale_factor"]
    assert s == pytest.approx(scale, abs=0.003)
    effect = abs(s) * j["speed_rms"]
    assert (effect > j["bound"]) == (scale > 0.05)
    flagged = [x for x in r["verdict_reasons"] if x.startswith("DVL scale")]
    assert flagged == ([f"DVL scale {100 * s:+.1f} %"] if scale > 0.05 else [])
    assert r["verdict"] == ("inconsistent" if scale > 0.05 else "consistent")
    assert not any("looks like" in x for x in r["verdict_reasons"])


def test_offset_beyond_the_search_is_inconsistent(track):
    """A DVL stamped 3 s late (the search reaches 2 s): the offset sits on the +2 s edge and counts."""
    t = np.asarray(track.t)
    dvl = CubicSpline(t, track.dvl, axis=0)(t - 3.0)
    dvl[t - 3.0 < t[0]] = np.nan
    r = check_track(dataclasses.replace(track, dvl=dvl))
    assert r["dvl"]["time_offset_at_edge"] and r["dvl"]["time_offset_s"] == 2.0
    assert r["verdict"] == "inconsistent"
    assert "DVL offset at the +2 s edge" in r["verdict_reasons"]
    assert any(f.startswith("DVL time offset +2.00 s at the edge of the +-2 s search") for f in r["findings"])


def test_straight_track_with_an_undetermined_offset_stays_consistent(track):
    """Constant velocity and attitude: nothing times the DVL (a flat offset curve), the residual is
    at the noise: the offset is undetermined, not a reason, wherever its grid minimum lands."""
    n = len(track.t)
    v = np.tile([1.5, 0.3, 0.05], (n, 1))
    euler = np.tile(np.radians([1.0, 2.0, 30.0]), (n, 1))
    body = np.einsum("kji,kj->ki", euler_to_dcm(euler), v)
    straight = dataclasses.replace(track, v_n=v, euler=euler,
                                   dvl=body + np.random.default_rng(4).normal(0.0, DVL_NOISE, (n, 3)))
    r = check_track(straight)
    c = np.asarray(r["dvl"]["offset_curve"]["rms"])
    assert c.max() - c.min() < r["dvl"]["judged"]["noise"]  # flat within the noise
    assert "time_offset" in r["dvl"]["undetermined"]
    assert r["verdict_reasons"] == [] and r["verdict"] == "consistent"


def test_check_command_names_the_earth_frame_dvl(tmp_path, capsys, earth):
    """The must-hold: `nespm check` on a DVL in the earth frame declared body: verdict not consistent,
    the DVL named, in the printed table, the printed findings, check.md and check.json."""
    write_akit(earth, tmp_path / "data")
    rc, out, err = cli(capsys, "check", "--data-dir", tmp_path / "data", "--tracks", "5", "--no-figures",
                       "--no-progress", "--out", tmp_path / "check")
    assert rc == 0, err
    row = next(line for line in out.splitlines() if line.startswith("| 5 |"))
    assert "| inconsistent (DVL looks like NED velocity; DVL residual 1." in row
    assert "consistent after corrections" not in row
    assert "track 5: DVL looks like earth-frame NED velocity (residual 0.0" in out
    md = (tmp_path / "check" / "check.md").read_text()
    assert "**Inconsistent:** DVL looks like NED velocity" in md
    assert "frame test, RMS residual at each reading's best offset: as body 1." in md
    js = json.loads((tmp_path / "check" / "check.json").read_text())
    t5 = js["tracks"][0]
    assert t5["verdict"] == "inconsistent" and t5["verdict_reasons"][0] == "DVL looks like NED velocity"
    assert js["summary"] == {"inconsistent": 1}


def test_real_earth_frame_dvl(real_data_dir):
    """The issue's case: Snapir track 5 with the DVL replaced by its GT's NED velocity (residual 1.19
    m/s, scale -95.7 %, offset +2.00 s at the edge were reported 'consistent after corrections');
    the same track as recorded keeps its verdict."""
    tr = load_track(5, real_data_dir)
    good = check_track(tr)
    assert good["verdict"] == "consistent after corrections" and good["verdict_reasons"] == []
    r = check_track(dataclasses.replace(tr, dvl=np.asarray(tr.v_n)))
    assert r["verdict_reasons"] == ["DVL looks like NED velocity", "DVL residual 1.19 m/s", "DVL scale -95.7 %",
                                    "DVL offset at the +2 s edge"]
    assert r["findings"][0].startswith("DVL looks like earth-frame NED velocity (residual 0.000 m/s as NED vs 1.73 as body, 1.19 with")
