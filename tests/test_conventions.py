"""Attitude and frame conventions checked against the data at load (issue 39 item 1, nespm_cli/data/conventions.py).

Each corrupted file is built from embedded track 5 (200 epochs): the yaw in the ENU convention, the pitch or
the roll sign flipped, the attitude in radians declared degrees (with and without an IMU file), a DVL in the
earth frame declared body, DVL axes FLU declared FRD. Each is refused in one line naming the likely cause and
the key, exit 2, nothing written; the correct files load with no refusal, the fixes named load and give the
correct track back; the escape (``accept_residual``, ``gt.accept_residual``) turns the refusal into a warning.
"""
from __future__ import annotations

import dataclasses
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_one_error_line, exact_imu_table, nespm
from nespm_cli.data import conventions
from nespm_cli.data.embedded import EMBEDDED_TRACKS, embedded_track
from nespm_cli.data.plausibility import DataWarning
from nespm_cli.data.track import Track
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import wrap_angle

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
N, EPOCHS = 5, 200
REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "snapir-akit"


def base(imu: bool = False) -> Track:
    """Embedded track 5, first 200 epochs (its exact IMU with ``imu``)."""
    tr = embedded_track(N)
    s = slice(0, EPOCHS)
    tr = Track(number=N, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=tr.euler[s], dvl=tr.dvl[s], imu=None,
               source="short")
    return dataclasses.replace(tr, imu=exact_imu_table(tr)) if imu else tr


def with_euler(tr: Track, fn) -> Track:
    e = np.array(tr.euler)
    fn(e)
    return dataclasses.replace(tr, euler=e)


def yaw_enu(e):
    e[:, 2] = wrap_angle(np.pi / 2 - e[:, 2])


def pitch_flip(e):
    e[:, 1] *= -1


def roll_flip(e):
    e[:, 0] *= -1


def refused(folder: Path, tmp_path: Path, *words: str) -> str:
    """``nespm mc`` on ``folder``: one line holding ``words``, exit 2, no --out folder."""
    out = tmp_path / "out"
    line = assert_one_error_line(*nespm("mc", "--data-dir", folder, "--tracks", N, "--runs", 1, "--filters", "ekf",
                                        "--no-progress", "--out", out), *words)
    assert not out.exists()
    return line


def akit(tr: Track, folder: Path) -> Path:
    write_akit(tr, folder)
    return folder


@pytest.mark.parametrize("fn, words", [
    (yaw_enu, ("GT_trajectory5.csv", "ENU convention", "gt.yaw_convention = \"enu\"")),
    (pitch_flip, ("GT_trajectory5.csv", "pitch sign looks flipped", "gt.pitch_sign = \"flipped\"")),
])
def test_attitude_mistakes_are_refused_by_the_dvl(tmp_path, fn, words):
    line = refused(akit(with_euler(base(), fn), tmp_path / "d"), tmp_path, *words, "--accept-residual")
    decl = float(re.search(r"vs body velocity ([0-9.]+) m/s RMS", line).group(1))
    fixed = float(re.search(r": ([0-9.]+) m/s if so", line).group(1))
    assert decl > 2.5 * fixed and fixed < 0.03  # the correct file's residual is the DVL's noise, 0.020


def test_roll_flip_is_refused_by_the_imu(tmp_path):
    """A roll sign is invisible to the DVL of a vehicle that barely moves sideways (residual 0.0200 -> 0.0205
    m/s on track 5); the IMU's gravity and roll rate see it."""
    line = refused(akit(with_euler(base(imu=True), roll_flip), tmp_path / "d"), tmp_path,
                   "GT_trajectory5.csv", "roll sign looks flipped", "gt.roll_sign = \"flipped\"")
    assert "IMU" in line


@pytest.mark.parametrize("fn, key", [(yaw_enu, "gt.yaw_convention"), (pitch_flip, "gt.pitch_sign")])
def test_attitude_mistakes_are_refused_by_the_imu_too(fn, key):
    tr = with_euler(base(imu=True), fn)
    found = conventions.judge(tr.t, tr.euler, tr.v_n, np.full_like(tr.dvl, np.nan), tr.imu, conventions.Declared())
    assert found is not None and key in found[1]


def test_roll_beyond_90_degrees_is_named(tmp_path):
    tr = with_euler(base(), lambda e: e.__setitem__((slice(None), 0), wrap_angle(e[:, 0] + np.pi)))
    refused(akit(tr, tmp_path / "d"), tmp_path, "Roll [rad]", "beyond 90 deg", "upside down", "FLU read as FRD")


def test_earth_frame_dvl_and_flu_axes_are_refused(tmp_path):
    tr = base()
    refused(akit(dataclasses.replace(tr, dvl=tr.v_n), tmp_path / "ned"), tmp_path, "DVL_trajectory5.csv",
            "earth-frame NED", "dvl.frame = \"ned\"")
    refused(akit(dataclasses.replace(tr, dvl=np.array(tr.dvl) * [1, -1, -1]), tmp_path / "flu"), tmp_path,
            "DVL_trajectory5.csv", "axes look permuted", "dvl.axes = \"x,-y,-z\"")


def test_course_judges_a_track_without_dvl():
    tr = with_euler(base(), yaw_enu)
    found = conventions.judge(tr.t, tr.euler, tr.v_n, np.full_like(tr.dvl, np.nan), None, conventions.Declared())
    assert found is not None and "direction of travel" in found[1] and "gt.yaw_convention" in found[1]
    ok = base()
    assert conventions.judge(ok.t, ok.euler, ok.v_n, np.full_like(ok.dvl, np.nan), None, conventions.Declared()) is None


# ----------------------------------------------------------------------------- through a track spec

SPEC = """
[gt]
file = "run{{N}}/truth.csv"
time = "t"
lat = "lat"
lon = "lon"
alt = "alt"
v_north = "vn"
v_east = "ve"
v_down = "vd"
roll = "roll"
pitch = "pitch"
yaw = "yaw"
angle_unit = "{unit}"
{gt_extra}
[dvl]
file = "run{{N}}/dvl.csv"
time = "t"
x = "u"
y = "v"
z = "w"
{dvl_extra}
{imu}"""
IMU = """[imu]
file = "run{N}/imu.csv"
time = "t"
acc_x = "ax"
acc_y = "ay"
acc_z = "az"
gyro_x = "gx"
gyro_y = "gy"
gyro_z = "gz"
"""


def user_folder(folder: Path, tr: Track, *, unit="deg", att_factor=None, dvl=None, gt_extra="", dvl_extra="",
                imu=False) -> Path:
    """A track spec folder of ``tr``: lat/lon and attitude in ``unit`` (attitude times ``att_factor`` instead
    when given: radians declared degrees is ``att_factor=1``)."""
    import pandas as pd

    d = folder / f"run{N}"
    d.mkdir(parents=True)
    f = 1.0 if unit == "rad" else 180.0 / np.pi
    a = f if att_factor is None else att_factor
    pd.DataFrame({"t": tr.t, "lat": tr.pos[:, 0] * f, "lon": tr.pos[:, 1] * f, "alt": tr.pos[:, 2],
                  "vn": tr.v_n[:, 0], "ve": tr.v_n[:, 1], "vd": tr.v_n[:, 2], "roll": tr.euler[:, 0] * a,
                  "pitch": tr.euler[:, 1] * a, "yaw": tr.euler[:, 2] * a}).to_csv(d / "truth.csv", index=False,
                                                                                    float_format="%.17g")
    v = np.asarray(tr.dvl if dvl is None else dvl)
    pd.DataFrame({"t": tr.t, "u": v[:, 0], "v": v[:, 1], "w": v[:, 2]}).to_csv(d / "dvl.csv", index=False,
                                                                              float_format="%.17g")
    if imu:
        pd.DataFrame(tr.imu, columns=["t", "ax", "ay", "az", "gx", "gy", "gz"]).to_csv(d / "imu.csv", index=False,
                                                                                        float_format="%.17g")
    (folder / "nespm-data.toml").write_text(SPEC.format(unit=unit, gt_extra=gt_extra, dvl_extra=dvl_extra,
                                                        imu=IMU if imu else ""))
    return folder


@pytest.mark.parametrize("imu", [False, True])
def test_radians_declared_degrees_is_refused_naming_the_unit(tmp_path, imu):
    """With an IMU file the DVL test runs before the IMU's units (which would blame the gyro's unit)."""
    folder = user_folder(tmp_path / "d", base(imu=imu), att_factor=1.0, imu=imu)
    refused(folder, tmp_path, "truth.csv", "radians declared degrees", "gt.angle_unit = \"rad\"",
            "nespm-data.toml")


@pytest.mark.parametrize("gt_extra, fn", [('yaw_convention = "enu"', yaw_enu), ('pitch_sign = "flipped"', pitch_flip),
                                          ('roll_sign = "flipped"', roll_flip)])
def test_the_named_keys_read_the_files_back(tmp_path, gt_extra, fn):
    """A file in the other convention, declared by the key the refusal names, loads as the correct track."""
    tr = base()
    folder = user_folder(tmp_path / "d", with_euler(tr, fn), unit="rad", gt_extra=gt_extra)
    got = load_track(N, folder)
    np.testing.assert_allclose(got.euler, tr.euler, atol=1e-12)


@pytest.mark.parametrize("frame", ["ned", "enu"])
def test_dvl_frame_key_turns_an_earth_frame_dvl_into_body(tmp_path, frame):
    tr = base()
    earth = np.array(tr.C_bn @ np.asarray(tr.dvl)[..., None])[..., 0]
    if frame == "enu":
        earth = earth @ conventions.ENU_OF_NED.T
    got = load_track(N, user_folder(tmp_path / "d", tr, unit="rad", dvl=earth, dvl_extra=f'frame = "{frame}"'))
    np.testing.assert_allclose(got.dvl, tr.dvl, atol=1e-12)
    refused(user_folder(tmp_path / "bad", tr, unit="rad", dvl=earth), tmp_path, "dvl.csv",
            f"earth-frame {frame.upper()}", f"dvl.frame = \"{frame}\" in nespm-data.toml")


def test_dvl_frame_on_a_truth_free_spec_is_one_line(tmp_path):
    folder = user_folder(tmp_path / "d", base(imu=True), unit="rad", imu=True, dvl_extra='frame = "ned"')
    text = (folder / "nespm-data.toml").read_text()
    gt = text[text.index("[gt]"):text.index("[dvl]")]
    (folder / "nespm-data.toml").write_text(text.replace(gt, "") + "\n[init]\nlat = 32.0\nlon = 34.0\ndepth = 10.0\n"
                                            "v_north = 1.0\nv_east = 0.0\nv_down = 0.0\nroll = 0.0\npitch = 0.0\n"
                                            "yaw = 0.0\n")
    with pytest.raises(NespmError, match=r"key 'dvl.frame': 'ned' needs the truth's attitude.*no \[gt\]"):
        load_track(N, folder)


# ----------------------------------------------------------------------------- the escape and the correct files


def test_accept_residual_turns_the_refusal_into_a_recorded_warning(tmp_path):
    folder = akit(with_euler(base(), yaw_enu), tmp_path / "d")
    with pytest.raises(NespmError):
        load_track(N, folder)
    with pytest.warns(DataWarning, match="ENU convention.*accepted"):
        tr = load_track(N, folder, accept_residual=True)
    assert tr.number == N and (str(folder / f"Trajectory{N}"), N) in conventions.ACCEPTED
    spec = user_folder(tmp_path / "s", with_euler(base(), yaw_enu), unit="rad", gt_extra="accept_residual = true")
    with pytest.warns(DataWarning, match="gt.yaw_convention"):
        load_track(N, spec)
    with pytest.raises(NespmError, match="gt.yaw_convention"):  # the parameter overrides the key
        load_track(N, spec, accept_residual=False)


def test_a_long_path_is_never_cut(tmp_path):
    deep = tmp_path.joinpath(*(["a_rather_long_folder_name_of_forty_chars"] * 8))
    line = refused(akit(with_euler(base(), yaw_enu), deep), tmp_path, f"_chars/Trajectory{N}/GT_trajectory{N}.csv: DVL residual", "error: .../", "ENU convention", "gt.yaw_convention",
                   "--accept-residual (or gt.accept_residual = true)")
    assert " ... " not in line and len(line) <= 400 + len("nespm: error: ")  # the path shortened at its start


@pytest.mark.parametrize("number", EMBEDDED_TRACKS)
def test_every_embedded_track_loads_without_refusal(tmp_path, number):
    tr = embedded_track(number)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        got = load_track(number, akit(tr, tmp_path))
    np.testing.assert_array_equal(got.euler, tr.euler)
    assert conventions.judge(tr.t, tr.euler, tr.v_n, tr.dvl, exact_imu_table(tr), conventions.Declared()) is None


@pytest.mark.skipif(not REAL.is_dir(), reason="the 13 Snapir tracks are not in ../shared/data/snapir-akit")
def test_the_real_tracks_load_without_refusal():
    for n in range(1, 14):
        tr = load_track(n, REAL)
        c = conventions.dvl_candidates(tr.t, tr.euler, tr.v_n, tr.dvl)
        ratio = min(v["rms"] for k, v in c.items() if k != "declared") / c["declared"]["rms"]
        assert ratio > 0.9 > conventions.FIX_RATIO  # measured 0.95 at least (track 9's roll)
