"""The track spec (``nespm-data.toml``, docs/data.md): a user's own files read through it give the same
Track, the same ``nespm mc`` metrics and the same checks as the A-KIT folder they were converted from.

The user layout is written here by a converter of our own from an A-KIT track (embedded track 5 cut to
80 epochs, with its exact IMU, a DVL at its own 2 Hz stamps, a 5 Hz depth and a 0.1 Hz fix): time in
milliseconds with a zero and per-file offsets (the DVL stamped 0.07 s after the truth), degrees, local NED
metres about an origin, cm/s, g and deg/s, feet for the depth, renamed columns in another order, and the
IMU and DVL in other axes.
"""
from __future__ import annotations

import ast
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import nespm_cli.data.track_spec as track_spec
from nespm_cli.data.corrections import axes_matrix
from nespm_cli.data.track_spec.convert import read_spec_track
from nespm_cli.data.track_spec.files import spec_tracks
from nespm_cli.data.track_spec.schema import SPEC_NAME, read_spec
from nespm_cli.data.track_spec.units import to_seconds
from nespm_cli.data.tracks import available_tracks, load_track, track_files, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.nav.earth import ned_offset

from conftest import assert_one_error_line, exact_imu_table, nespm, short_track

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

N = 5
ORIGIN_DEG = (32.85, 34.9, 1.5)  # origin of the local NED metres: lat, lon [deg], alt [m up]
ZERO_MS = 5000.0  # the files' time zero [ms]
DVL_OFFSET, IMU_OFFSET = 0.07, -0.02  # stamp minus GT time [s]
FT, G = 0.3048, 9.80665
DVL_AXES, IMU_AXES = "x,-y,-z", "y,x,-z"  # body axis i = the file's signed axis at position i

SPEC = f"""
# the track spec of the test's user layout (docs/data.md)
[defaults]
time_unit = "ms"
time_zero = {ZERO_MS}
angle_unit = "deg"

[origin]
lat_deg = {ORIGIN_DEG[0]}
lon_deg = {ORIGIN_DEG[1]}
alt_m = {ORIGIN_DEG[2]}

[gt]
file = "run{{N}}/truth.csv"
time = "t_ms"
position = "ned"
north = "N_m"
east = "E_m"
down = "D_m"
v_north = "vn"
v_east = "ve"
v_down = "vd"
roll = "roll_deg"
pitch = "pitch_deg"
yaw = "yaw_deg"

[dvl]
file = "run{{N}}/dvl.csv"
time = "stamp_ms"
time_offset = {DVL_OFFSET}
x = "u"
y = "v"
z = "w"
speed_unit = "cm/s"
axes = "{DVL_AXES}"

[imu]
file = "run{{N}}/imu.csv"
time = "time_us"
time_unit = "us"
time_zero = {ZERO_MS * 1000}
time_offset = {IMU_OFFSET}
acc_x = "ax_g"
acc_y = "ay_g"
acc_z = "az_g"
gyro_x = "gx_dps"
gyro_y = "gy_dps"
gyro_z = "gz_dps"
acceleration_unit = "g"
rate_unit = "deg/s"
axes = "{IMU_AXES}"

[depth]
file = "run{{N}}/depth.csv"
time = "time_ms"
depth = "depth_ft"
length_unit = "ft"

[fix]
file = "run{{N}}/fix.csv"
time = "t_ms"
lat = "lat_deg"
lon = "lon_deg"
"""


def base_track(number: int = N):
    """Embedded track ``number`` (5), 80 epochs, numbered 5, with its exact IMU, a DVL at its own stamps
    (2 Hz, one NaN row, the last stamp on the last epoch), a depth (5 Hz, one NaN row) and a horizontal
    fix (0.1 Hz)."""
    tr = dataclasses.replace(short_track(number, 80), number=N)
    t = tr.t
    t_dvl = np.append(np.arange(t[0] + 0.21, t[-1], 0.5), t[-1])
    v_dvl = np.column_stack([np.interp(t_dvl, t, tr.dvl[:, i]) for i in range(3)]) + 0.01 * np.sin(t_dvl)[:, None]
    v_dvl[7] = np.nan
    t_dep = np.arange(t[0] + 0.05, t[-1], 0.2)
    dep = -np.interp(t_dep, t, tr.pos[:, 2]) + 0.02 * np.cos(t_dep)
    dep[11] = np.nan
    t_fix = np.arange(t[0] + 3.3, t[-1], 10.0)
    fix = np.column_stack([np.interp(t_fix, t, tr.pos[:, 0]), np.interp(t_fix, t, tr.pos[:, 1])]) + 1e-7
    return dataclasses.replace(tr, imu=exact_imu_table(tr),
                               channels={"dvl": (t_dvl, v_dvl), "depth": (t_dep, dep), "fix": (t_fix, fix)})


def _csv(path: Path, columns: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(columns).to_csv(path, index=False, float_format="%.17g", na_rep="nan")


def to_file_axes(body: np.ndarray, axes: str) -> np.ndarray:
    """Body-axis rows (K, 3) as the file's axes hold them: body = A file, so file = Aᵀ body."""
    return body @ axes_matrix(axes)


def write_user(track, folder: Path, spec: str = SPEC) -> Path:
    """``track`` in the user layout of :data:`SPEC` (our own converter), with the spec beside it."""
    run = Path(folder) / f"run{N:02d}"  # leading zero: {N} matches it
    origin = np.array([np.radians(ORIGIN_DEG[0]), np.radians(ORIGIN_DEG[1]), ORIGIN_DEG[2]])
    ned = ned_offset(track.pos, origin)
    ms = lambda t, offset=0.0: (t + offset) * 1000.0 + ZERO_MS  # noqa: E731
    e = np.degrees(track.euler)
    _csv(run / "truth.csv", {"yaw_deg": e[:, 2], "t_ms": ms(track.t), "vd": track.v_n[:, 2], "N_m": ned[:, 0],
                             "roll_deg": e[:, 0], "ve": track.v_n[:, 1], "E_m": ned[:, 1], "pitch_deg": e[:, 1],
                             "vn": track.v_n[:, 0], "D_m": ned[:, 2], "note": "x"})
    t_dvl, v_dvl = track.channels["dvl"]
    f = to_file_axes(v_dvl, DVL_AXES) * 100.0
    _csv(run / "dvl.csv", {"w": f[:, 2], "stamp_ms": ms(t_dvl, DVL_OFFSET), "u": f[:, 0], "v": f[:, 1]})
    imu = track.imu
    acc, gyro = to_file_axes(imu[:, 1:4], IMU_AXES) / G, np.degrees(to_file_axes(imu[:, 4:7], IMU_AXES))
    _csv(run / "imu.csv", {"time_us": (imu[:, 0] + IMU_OFFSET) * 1e6 + ZERO_MS * 1000, "gz_dps": gyro[:, 2],
                           "gy_dps": gyro[:, 1], "gx_dps": gyro[:, 0], "az_g": acc[:, 2], "ay_g": acc[:, 1],
                           "ax_g": acc[:, 0]})
    t_dep, dep = track.channels["depth"]
    _csv(run / "depth.csv", {"depth_ft": dep[:, 0] / FT, "time_ms": ms(t_dep)})
    t_fix, fix = track.channels["fix"]
    _csv(run / "fix.csv", {"lon_deg": np.degrees(fix[:, 1]), "lat_deg": np.degrees(fix[:, 0]), "t_ms": ms(t_fix)})
    (Path(folder) / SPEC_NAME).write_text(spec)
    return Path(folder)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """``(akit, user)``: the A-KIT folder and the user layout of the same track."""
    root = tmp_path_factory.mktemp("spec")
    tr = base_track()
    write_akit(tr, root / "akit")
    return root / "akit", write_user(tr, root / "user")


def _user(tmp_path: Path, spec: str = SPEC, edit=None, number: int = N) -> Path:
    """A fresh user folder of embedded track ``number`` as track 5 (``spec`` beside it; ``edit(run folder)``
    changes its files)."""
    d = write_user(base_track(number), tmp_path / "user", spec)
    if edit:
        edit(d / f"run{N:02d}")
    return d


def _refused(d: Path, *must: str) -> str:
    with pytest.raises(NespmError) as ei:
        load_track(N, d, warnings="error")
    msg = str(ei.value)
    assert "\n" not in msg and msg.isprintable(), msg
    for s in must:
        assert s in msg, (s, msg)
    return msg


def _close(a, b, tol=1e-9) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol, equal_nan=True)


# ----------------------------------------------------------------------------- the same Track


def test_spec_gives_the_akit_track(folders):
    akit, user = folders
    ref, got = load_track(N, akit), load_track(N, user)
    assert available_tracks(user) == [N]
    assert got.source == str(user / f"run{N:02d}")
    _close(got.t, ref.t, 1e-12)  # [s]: one division of ms and one offset: ~1e-14 s
    np.testing.assert_allclose(got.pos[:, :2], ref.pos[:, :2], rtol=0, atol=1e-13)  # [rad]: 0.6 mm
    _close(got.pos[:, 2], ref.pos[:, 2], 1e-9)
    for name in ("v_n", "euler", "dvl", "imu"):
        _close(getattr(got, name), getattr(ref, name))
    assert sorted(got.channels) == sorted(ref.channels) == ["depth", "dvl", "fix"]
    for name in ref.channels:
        for a, b in zip(got.channels[name], ref.channels[name]):
            _close(a, b)
    # the DVL was stamped 0.07 s late in its file and shifted before anything else: its own stamps are kept
    t_dvl = got.channels["dvl"][0]
    assert np.isclose(t_dvl[-1], got.t[-1], rtol=0, atol=1e-9) and np.isnan(got.channels["dvl"][1][7]).all()
    assert not np.allclose(got.dvl, ref.dvl * 0.0)  # not a vacuous comparison
    assert np.isnan(got.dvl).any(axis=1).sum() == np.isnan(ref.dvl).any(axis=1).sum() >= 1


def test_spec_of_the_akit_files_is_bit_identical(tmp_path, folders):
    """A spec that names the A-KIT files and columns in SI units reads the same floats bit for bit."""
    akit, _ = folders
    d = tmp_path / "same"
    shutil.copytree(akit, d)
    (d / SPEC_NAME).write_text(_akit_spec(("gt", "dvl", "imu", "depth", "fix")))
    ref, got = load_track(N, akit), load_track(N, d)
    for name in ("t", "pos", "v_n", "euler", "dvl", "imu"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name))
    for name in ref.channels:
        for a, b in zip(got.channels[name], ref.channels[name]):
            np.testing.assert_array_equal(a, b)


def _akit_spec(tables=("gt", "dvl", "depth", "fix")) -> str:
    """A spec naming the A-KIT files and columns (SI units)."""
    cols = {"gt": dict(time="Time [s]", lat="Latitude [rad]", lon="Longitude [rad]", alt="Altitude [m]",
                       v_north="V North [m/s]", v_east="V East [m/s]", v_down="V Down [m/s]", roll="Roll [rad]",
                       pitch="Pitch [rad]", yaw="Yaw [rad]"),
            "dvl": dict(time="Time [s]", x="DVL X [m/s]", y="DVL Y [m/s]", z="DVL Z [m/s]"),
            "imu": dict(time="Time [s]", acc_x="ACC X [m/s^2]", acc_y="ACC Y [m/s^2]", acc_z="ACC Z [m/s^2]",
                        gyro_x="GYRO X [rad/s]", gyro_y="GYRO Y [rad/s]", gyro_z="GYRO Z [rad/s]"),
            "depth": dict(time="Time [s]", depth="Depth [m]"),
            "fix": dict(time="Time [s]", lat="Latitude [rad]", lon="Longitude [rad]")}
    return "".join(f'[{t}]\nfile = "Trajectory{{N}}/{t.upper()}_trajectory{{N}}.csv"\n'
                   + "".join(f'{k} = "{v}"\n' for k, v in cols[t].items()) + "\n" for t in tables)


def test_real_tracks_through_a_spec_are_bit_identical(tmp_path, real_data_dir):
    """The 13 real Snapir tracks through a spec naming their files: the same floats, no sign refusal."""
    for tdir in real_data_dir.glob("Trajectory*"):
        (tmp_path / tdir.name).symlink_to(tdir, target_is_directory=True)
    (tmp_path / SPEC_NAME).write_text(_akit_spec(("gt", "dvl")))
    assert available_tracks(tmp_path) == available_tracks(real_data_dir) == list(range(1, 14))
    for n in range(1, 14):
        ref, got = load_track(n, real_data_dir), load_track(n, tmp_path)
        for name in ("t", "pos", "v_n", "euler", "dvl"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name))


def test_track_files_list_the_spec_and_the_users_files(folders):
    _, user = folders
    run = user / f"run{N:02d}"
    assert track_files(N, user) == [user / SPEC_NAME, run / "truth.csv", run / "dvl.csv", run / "depth.csv",
                                    run / "fix.csv"]
    assert track_files(N, user, True)[3] == run / "imu.csv"


def test_time_base_and_units():
    us = np.array([1_718_000_000_123_456.0, 1_718_000_000_223_456.0])  # UNIX microseconds: exact in float64
    t = to_seconds(us, "us", zero=1_718_000_000_000_000.0, offset=0.02)
    np.testing.assert_array_equal(t, np.array([0.123456, 0.223456]) - 0.02)
    raw = np.array([0.1, 0.2, 0.3])
    assert to_seconds(raw, "s") is not raw and np.array_equal(to_seconds(raw, "s"), raw)


def test_local_enu_fix_with_altitude_and_an_altitude_depth_file(tmp_path):
    """A fix in local ENU metres with ``up``, and a depth file given as an altitude (``altitude`` key)."""
    tr = base_track()
    origin = np.array([np.radians(ORIGIN_DEG[0]), np.radians(ORIGIN_DEG[1]), ORIGIN_DEG[2]])
    t_fix = tr.channels["fix"][0]
    pos = np.column_stack([tr.channels["fix"][1], -6.5 - 0.01 * t_fix])
    ned = ned_offset(pos, origin)
    spec = SPEC.replace('lat = "lat_deg"\nlon = "lon_deg"\n',
                        'position = "enu"\nnorth = "y_m"\neast = "x_m"\nup = "z_m"\noptional = true\n')
    spec = spec.replace('depth = "depth_ft"', 'altitude = "alt_ft"')

    def edit(run: Path) -> None:
        _csv(run / "fix.csv", {"t_ms": t_fix * 1000 + ZERO_MS, "x_m": ned[:, 1], "y_m": ned[:, 0], "z_m": -ned[:, 2]})
        dep = pd.read_csv(run / "depth.csv")
        _csv(run / "depth.csv", {"time_ms": dep["time_ms"], "alt_ft": -dep["depth_ft"]})

    got = load_track(N, _user(tmp_path, spec, edit))
    _close(got.channels["fix"][1], pos, 1e-9)
    _close(got.channels["depth"][1], tr.channels["depth"][1], 1e-9)


# ----------------------------------------------------------------------------- nespm mc on both folders


MC = ("--tracks", str(N), "--runs", "2", "--filters", "ekf", "--no-progress", "--jobs", "1")
AIDED = ("--imu", "recorded", "--state", "15", "--sensors", "dvl,depth,fix", "--sensor-option",
         "depth.source=recorded", "--sensor-option", "fix.source=recorded")


@pytest.mark.parametrize("extra", [(), AIDED], ids=["synthetic-imu", "recorded-imu-dvl-depth-fix"])
def test_mc_gives_the_same_metrics(tmp_path, folders, extra):
    akit, user = folders
    out = {}
    for name, d in (("akit", akit), ("user", user)):
        rc, so, err = nespm("mc", "--data-dir", d, *MC, *extra, "--out", tmp_path / name)
        assert rc == 0, err
        out[name] = pd.read_parquet(tmp_path / name / "metrics.parquet")
    a, b = out["akit"], out["user"]
    assert list(a.columns) == list(b.columns) and len(a) == len(b) == 2
    num = [c for c in a.columns if pd.api.types.is_float_dtype(a[c]) and c != "seconds"]  # not wall time
    assert "vrmse" in num and (a["vrmse"] > 1e-4).all()
    np.testing.assert_allclose(b[num].to_numpy(), a[num].to_numpy(), rtol=1e-9, atol=1e-12, equal_nan=True)
    if extra:
        assert np.isfinite(a["nis_depth"]).all() and np.isfinite(a["nis_fix"]).all()


def test_manifest_lists_the_users_files_and_a_changed_one_is_refused(tmp_path):
    d = _user(tmp_path)
    out = tmp_path / "r"
    rc, _, err = nespm("mc", "--data-dir", d, *MC, *AIDED, "--out", out)
    assert rc == 0, err
    inputs = json.loads((out / "manifest.json").read_text())["inputs"]
    run = d / f"run{N:02d}"
    for p in (d / SPEC_NAME, run / "truth.csv", run / "dvl.csv", run / "imu.csv", run / "depth.csv", run / "fix.csv"):
        assert str(p.resolve()) in inputs, p
    with (run / "depth.csv").open("a") as fh:
        fh.write(f"20.0,{79.1 * 1000 + ZERO_MS!r}\n")  # depth_ft, time_ms: one more depth, 0.05 s after the last
    rc, so, err = nespm("mc", "--data-dir", d, *MC, *AIDED, "--runs", "3", "--out", out)
    assert_one_error_line(rc, so, err, "depth.csv", "changed since")


# ----------------------------------------------------------------------------- one-line refusals


def test_several_missing_columns_in_one_message(tmp_path):
    def edit(run: Path) -> None:
        df = pd.read_csv(run / "truth.csv").rename(columns={"N_m": "north", "pitch_deg": "pitch", "vd": "v_d"})
        df.to_csv(run / "truth.csv", index=False, float_format="%.17g")

    msg = _refused(_user(tmp_path, edit=edit), "truth.csv", "missing columns 'N_m', 'vd', 'pitch_deg'",
                   "keys gt.north, gt.v_down, gt.pitch of " + SPEC_NAME)
    assert msg.count("missing column") == 1


def test_unknown_unit(tmp_path):
    d = _user(tmp_path, SPEC.replace('angle_unit = "deg"', 'angle_unit = "degree"'))
    _refused(d, SPEC_NAME, "key 'defaults.angle_unit'", "'degree' is not a unit of angle (rad, deg)")
    rc, so, err = nespm("tracks", "--data-dir", d, "--no-progress")
    assert_one_error_line(rc, so, err, SPEC_NAME, "angle_unit")


@pytest.mark.parametrize("spec, must", [
    (SPEC.replace('time = "t_ms"\nposition', 'position'), "key 'gt.time' is missing"),
    (SPEC.replace('lat_deg = 32.85', ''), "key 'origin.lat_deg' is missing"),
    (SPEC.replace('yaw = "yaw_deg"', 'yaw = "yaw_deg"\nlattitude = "x"'), "unknown key 'gt.lattitude'"),
    (SPEC.replace('x = "u"', 'x = "u"\nsped_unit = "kn"'), "unknown key 'dvl.sped_unit'"),
    (SPEC.replace('speed_unit = "cm/s"', 'speed_unit = "knots"'), "key 'dvl.speed_unit': 'knots' is not a unit"),
    (SPEC.replace('axes = "x,-y,-z"', 'axes = "x,y,y"'), "key 'dvl.axes'"),
    (SPEC.replace('down = "D_m"', 'down = "D_m"\nalt = "D_m"'), "key 'gt.alt' does not apply with position = 'ned'"),
    (SPEC.replace('east = "E_m"', 'east = "N_m"'), "key 'gt.east' names column 'N_m', as 'gt.north' does"),
    (SPEC.replace('file = "run{N}/dvl.csv"', 'file = "../dvl.csv"'), "key 'dvl.file'"),
    (SPEC.replace('time_zero = 5000.0', 'time_zero = "5000"'), "key 'defaults.time_zero' must be a number"),
])
def test_spec_mistakes_are_one_line_naming_the_key(tmp_path, spec, must):
    _refused(_user(tmp_path, spec), SPEC_NAME, must)


def test_missing_file_names_the_key(tmp_path):
    d = _user(tmp_path, edit=lambda run: (run / "depth.csv").unlink())
    _refused(d, SPEC_NAME, "key 'depth.file'", "run5/depth.csv", "track 5")
    with pytest.raises(NespmError, match="key 'depth.file'"):
        track_files(N, d)
    d2 = _user(tmp_path / "b", SPEC.replace('length_unit = "ft"', 'length_unit = "ft"\noptional = true'),
               edit=lambda run: (run / "depth.csv").unlink())
    assert sorted(load_track(N, d2).channels) == ["dvl", "fix"]


def _flip(file: str, column: str):
    def edit(run: Path) -> None:
        df = pd.read_csv(run / file)
        df[column] = -df[column]
        df.to_csv(run / file, index=False, float_format="%.17g")
    return edit


def test_depth_given_as_altitude_is_refused(tmp_path):
    """An altitude (positive up) under the spec's ``depth`` key: the depth file does not fit the GT."""
    _refused(_user(tmp_path, edit=_flip("depth.csv", "depth_ft")), "depth.csv", "column 'depth_ft as Depth [m]'",
             "fit the GT's altitude, not its depth", "key 'depth.depth' says positive down and 'gt.down' says "
             "positive down: one of the two columns has the other sign")


def test_gt_vertical_of_the_wrong_sign_is_refused(tmp_path):
    """An up column under the spec's ``down`` key: refused by the GT's own vertical velocity where the track
    changes depth (track 6: 9-18 m), by the depth file where it does not (track 5: 6.00-6.06 m)."""
    _refused(_user(tmp_path, edit=_flip("truth.csv", "D_m"), number=6), "truth.csv", "'-D_m as Altitude [m]'",
             "moves against the vertical velocity", "key 'gt.down' says positive down")
    _refused(_user(tmp_path / "b", edit=_flip("truth.csv", "D_m")), "depth.csv", "not its depth",
             "'gt.down' says positive down: one of the two columns has the other sign")
    depth = '[depth]\nfile = "run{N}/depth.csv"\ntime = "time_ms"\ndepth = "depth_ft"\nlength_unit = "ft"\n'
    spec = SPEC.replace(depth, "")
    assert "[depth]" not in spec
    load_track(N, _user(tmp_path / "c", spec, edit=_flip("truth.csv", "D_m")))  # nothing to tell the sign by


def test_time_offset_is_applied_before_the_checks(tmp_path):
    """Without ``time_offset`` the DVL's last stamp (0.07 s after the last epoch) is outside the GT span."""
    _refused(_user(tmp_path, SPEC.replace(f"time_offset = {DVL_OFFSET}\n", "")), "dvl.csv",
             "column 'stamp_ms as Time [s]'", "outside the GT span")


def test_converted_values_are_checked_with_the_users_column_names(tmp_path):
    d = _user(tmp_path, SPEC.replace('yaw = "yaw_deg"', 'yaw = "yaw_deg"\nangle_unit = "rad"'))
    _refused(d, "truth.csv", "data row 74, column 'roll_deg as Roll [rad]'", "not an angle in radians")
    d2 = _user(tmp_path / "b", SPEC.replace('speed_unit = "cm/s"', 'speed_unit = "m/s"'))
    _refused(d2, "dvl.csv", "columns 'u as DVL X [m/s]', '-v as DVL Y [m/s]', '-w as DVL Z [m/s]': speed",
             ">= 20 m/s")


def test_spec_tracks_and_file_patterns(tmp_path):
    d = _user(tmp_path)
    shutil.copytree(d / "run05", d / "run5")
    _refused(d, "key 'gt.file'", "run05/truth.csv and run5/truth.csv are both track 5")
    shutil.rmtree(d / "run05")
    assert spec_tracks(read_spec(d / SPEC_NAME)) == [5] and load_track(5, d).t.shape == (80,)
    with pytest.raises(NespmError, match=r"no track 6 \(key 'gt.file' 'run\{N\}/truth.csv' finds tracks: 5\)"):
        load_track(6, d)
    sp = read_spec_track(read_spec(d / SPEC_NAME), 5)
    assert sp.gt_keys[:4] == ("gt.time", "gt.east", "gt.north", "gt.down")
    assert sp.imu_names[1:4] == ("ay_g", "ax_g", "-az_g")  # body x, y, z from the file's y, x, -z


def test_the_example_of_docs_data_md_is_a_valid_spec(tmp_path):
    text = (Path(__file__).resolve().parents[1] / "docs" / "data.md").read_text()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    (tmp_path / SPEC_NAME).write_text(block)
    spec = read_spec(tmp_path / SPEC_NAME)
    assert spec.tables["dvl"]["time_offset"] == 0.07 and spec.tables["dvl"]["time_unit"] == "ms"
    assert spec.tables["imu"]["time_zero"] == 36_000_000_000 and spec.tables["gt"]["time_zero"] == 36_000_000
    assert spec.tables["fix"]["angle_unit"] == "deg" and spec.tables["depth"]["length_unit"] == "ft"
    np.testing.assert_allclose(spec.origin, [np.radians(32.85), np.radians(34.90), 0.0])


#: the modules of nespm_cli.data.track_spec, one concept each, in the order they may import each other
SPEC_MODULES = ("units", "schema", "files", "convert", "data_checks")


def test_the_spec_modules_import_only_the_ones_before_them():
    """Reading a spec no longer alternates between two files: each module of the package imports only the
    modules before it in :data:`SPEC_MODULES` (function-level imports count; the package itself, which
    re-exports them, never), and each stays under 500 lines."""
    root = Path(track_spec.__file__).parent
    assert sorted(p.stem for p in root.glob("*.py")) == sorted(SPEC_MODULES + ("__init__",))
    for i, name in enumerate(SPEC_MODULES):
        src = (root / f"{name}.py").read_text()
        assert len(src.splitlines()) <= 500, name
        used = {n.module.removeprefix("nespm_cli.data.track_spec").lstrip(".") or "the package"
                for n in ast.walk(ast.parse(src))
                if isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("nespm_cli.data.track_spec")}
        assert used <= set(SPEC_MODULES[:i]), f"{name} imports {sorted(used - set(SPEC_MODULES[:i]))}"
    assert track_spec.read_spec_track is read_spec_track and track_spec.to_seconds is to_seconds
