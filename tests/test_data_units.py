"""Own data cannot come in wrong silently (issue 30, item 3): units and angles.

* A track in a foreign CSV layout (time in ms, lat/lon and Euler angles in degrees with the heading in
  0-360°, speeds in knots and cm/s, depth in feet) loads through a track spec, and ``mc``'s EKF metrics on
  it equal those of the same track in the A-KIT layout to 1e-9 relative (round-off of the unit conversion
  only; measured: 5.4e-13).
* An IMU whose units are not what was declared (a gyro in deg/s declared rad/s, an accelerometer in g
  declared m/s²) is refused at load in one line naming the file and the unit key (exit 2 from the CLI).
* Where the angle unit is declared, the "(degrees instead of radians?)" hint is not given.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, exact_imu_table, nespm, short_track
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.imu_file import RATE_RATIO_MAX, imu_unit_figures
from nespm_cli.data.track_spec.schema import SPEC_NAME
from nespm_cli.data.track_spec.units import STANDARD_GRAVITY
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError

KN = 1852.0 / 3600.0  # [m/s] per knot
FT = 0.3048  # [m] per foot
ZERO_MS = 36_000_000  # 10:00:00 in ms

SPEC = """
[defaults]
time_unit = "ms"
time_zero = 36000000
angle_unit = "deg"

[gt]
file = "run{N}/nav.csv"
time = "t_ms"
lat = "lat"
lon = "lon"
depth = "depth_ft"
length_unit = "ft"
v_north = "vn_kn"
v_east = "ve_kn"
v_down = "vd_kn"
speed_unit = "kn"
roll = "roll"
pitch = "pitch"
yaw = "heading"

[dvl]
file = "run{N}/dvl.csv"
time = "t_ms"
x = "vx"
y = "vy"
z = "vz"
speed_unit = "cm/s"
"""

IMU_SPEC = """
[imu]
file = "run{N}/imu.csv"
time = "t_ms"
acc_x = "ax"
acc_y = "ay"
acc_z = "az"
gyro_x = "gx"
gyro_y = "gy"
gyro_z = "gz"
acceleration_unit = "ACC"
rate_unit = "RATE"
"""


def _csv(path: Path, columns: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(columns).to_csv(path, index=False, float_format="%.17g", na_rep="nan")


def write_foreign(track, folder: Path, imu: np.ndarray | None = None, acc_unit: str = "g",
                  rate_unit: str = "deg/s") -> Path:
    """``track`` as a foreign layout (the units of :data:`SPEC`, heading in 0-360°) with the spec beside it; with
    ``imu`` (M, 7) [s, m/s², rad/s] also an IMU file, its values written in ``acc_unit``/``rate_unit`` as they are
    given (a test declares other units to make the mistake)."""
    folder = Path(folder)
    run = folder / f"run{track.number}"
    ms = lambda t: t * 1000.0 + ZERO_MS  # noqa: E731
    e = np.degrees(track.euler)
    _csv(run / "nav.csv", {"t_ms": ms(track.t), "lat": np.degrees(track.pos[:, 0]), "lon": np.degrees(track.pos[:, 1]),
                           "depth_ft": -track.pos[:, 2] / FT, "vn_kn": track.v_n[:, 0] / KN,
                           "ve_kn": track.v_n[:, 1] / KN, "vd_kn": track.v_n[:, 2] / KN, "roll": e[:, 0],
                           "pitch": e[:, 1], "heading": np.mod(e[:, 2], 360.0)})
    _csv(run / "dvl.csv", {"t_ms": ms(track.t), "vx": track.dvl[:, 0] * 100.0, "vy": track.dvl[:, 1] * 100.0,
                           "vz": track.dvl[:, 2] * 100.0})
    spec = SPEC
    if imu is not None:
        _csv(run / "imu.csv", {"t_ms": ms(imu[:, 0]), **dict(zip(("ax", "ay", "az", "gx", "gy", "gz"), imu[:, 1:].T))})
        spec += IMU_SPEC.replace("ACC", acc_unit).replace("RATE", rate_unit)
    (folder / SPEC_NAME).write_text(spec)
    return folder


def _refused(folder: Path, number: int, *must: str) -> str:
    with pytest.raises(NespmError) as ei:
        load_track(number, folder)
    msg = str(ei.value)
    assert "\n" not in msg and msg.isprintable(), msg
    for s in must:
        assert s in msg, (s, msg)
    return msg


# ----------------------------------------------------------------------------- angles


def test_a_0_360_heading_in_degrees_loads_as_the_akit_track(tmp_path):
    tr = short_track(5, 41)
    assert (tr.euler[:, 2] < 0).all()  # heading 329.3 deg in the file: wrapped after the conversion
    got = load_track(5, write_foreign(tr, tmp_path / "foreign"))
    np.testing.assert_allclose(got.euler, tr.euler, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got.v_n, tr.v_n, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(got.pos[:, 2], tr.pos[:, 2], rtol=1e-14, atol=1e-12)


def test_declared_units_give_no_degrees_hint(tmp_path):
    tr = short_track(5, 41)
    d = write_foreign(tr, tmp_path / "a")
    nav = d / "run5" / "nav.csv"
    df = pd.read_csv(nav)
    df.loc[9, "roll"] = 400.0  # beyond one turn even in degrees
    df.to_csv(nav, index=False, float_format="%.17g")
    msg = _refused(d, 5, "nav.csv: data row 10, column 'roll as Roll [rad]'", "not an angle in radians",
                   "declared gt.angle_unit = 'deg'")
    assert "degrees instead of radians" not in msg
    # declared radians for a degree column: the key is named, not guessed at
    df.loc[9, "roll"] = df.loc[8, "roll"]
    df["lat"], df["lon"] = np.radians(df["lat"]), np.radians(df["lon"])
    df.to_csv(nav, index=False, float_format="%.17g")
    (d / SPEC_NAME).write_text((d / SPEC_NAME).read_text().replace('yaw = "heading"', 'yaw = "heading"\nangle_unit = "rad"'))
    msg = _refused(d, 5, "key 'gt.angle_unit' of nespm-data.toml declares 'rad'")
    assert "degrees instead of radians" not in msg


def test_mc_metrics_of_the_foreign_layout_equal_the_akit_folders(tmp_path):
    """The must-hold of issue 30: the same track in both layouts, the same EKF metrics to 1e-9 relative."""
    tr = short_track(5, 41)
    write_akit(tr, tmp_path / "akit")
    write_foreign(tr, tmp_path / "foreign")
    out = {}
    for name in ("akit", "foreign"):
        rc, so, err = nespm("mc", "--data-dir", str(tmp_path / name), "--tracks", "5", "--runs", "2", "--filters",
                            "ekf", "--no-progress", "--out", str(tmp_path / f"mc-{name}"))
        assert rc == 0, err
        out[name] = pd.read_parquet(tmp_path / f"mc-{name}" / "metrics.parquet")
    a, b = out["akit"], out["foreign"]
    num = [c for c in a.columns if pd.api.types.is_float_dtype(a[c]) and c != "seconds"]  # not the wall time
    assert len(num) >= 5 and len(a) == 2
    for c in num:
        np.testing.assert_allclose(b[c].to_numpy(), a[c].to_numpy(), rtol=1e-9, atol=0, err_msg=c)


# ----------------------------------------------------------------------------- the IMU's units against the GT


@pytest.fixture(scope="module")
def turning():
    """Embedded track 1's first 60 epochs (it turns: yaw -177..173 deg) with its exact 100 Hz IMU plus the
    papers' noise and a bias (acc 0.03 m/s² per sample, gyro 7.3e-6 rad/s; bias 0.01 m/s², 10 deg/h)."""
    tr = dataclasses.replace(short_track(1, 60), number=1)
    imu = exact_imu_table(tr)
    rng = np.random.default_rng(1)
    imu[:, 1:4] += 0.03 * rng.standard_normal((len(imu), 3)) + 0.01
    imu[:, 4:7] += 7.3e-6 * rng.standard_normal((len(imu), 3)) + math.radians(10 / 3600)
    return tr, imu


def test_a_right_imu_passes_in_foreign_units(tmp_path, turning):
    tr, imu = turning
    fig = imu_unit_figures(imu, tr.t, tr.euler)
    assert 0.95 < fig["ratio"] < 1.05 and 9.7 < fig["median_f"] < 9.9
    files = imu.copy()
    files[:, 1:4] /= STANDARD_GRAVITY
    files[:, 4:7] = np.degrees(files[:, 4:7])
    got = load_track(1, write_foreign(tr, tmp_path / "ok", files, "g", "deg/s"))
    np.testing.assert_allclose(got.imu, imu, rtol=1e-12, atol=1e-11)  # time through ms: ~4e-12 s


def test_gyro_in_deg_per_s_declared_rad_per_s_is_refused(tmp_path, turning):
    tr, imu = turning
    files = imu.copy()
    files[:, 1:4] /= STANDARD_GRAVITY
    files[:, 4:7] = np.degrees(files[:, 4:7])
    assert np.abs(files[:, 4:7]).max() < 20  # every sample passes the per-sample limit of 20 rad/s
    d = write_foreign(tr, tmp_path / "deg", files, "g", "rad/s")
    msg = _refused(d, 1, "imu.csv: columns 'gx as GYRO X [rad/s]'", "key 'imu.rate_unit'",
                   "a gyro in deg/s read as rad/s")
    ratio = float(msg.split(" is ")[1].split("x the GT")[0])
    assert 50 < ratio < 65 and ratio > RATE_RATIO_MAX
    assert_one_error_line(*nespm("mc", "--data-dir", str(d), "--tracks", "1", "--runs", "1", "--imu", "recorded",
                                 "--no-progress", "--out", str(tmp_path / "mc")), "key 'imu.rate_unit'")
    # the A-KIT layout: the same mistake names the file and its rad/s columns
    write_akit(dataclasses.replace(tr, imu=np.column_stack([imu[:, :4], np.degrees(imu[:, 4:7])])), tmp_path / "ak")
    _refused(tmp_path / "ak", 1, "IMU_trajectory1.csv: columns 'GYRO X [rad/s]'", "the A-KIT columns are rad/s")


def test_accelerometer_in_g_declared_m_per_s2_is_refused(tmp_path, turning):
    tr, imu = turning
    files = imu.copy()
    files[:, 1:4] /= STANDARD_GRAVITY
    files[:, 4:7] = np.degrees(files[:, 4:7])
    d = write_foreign(tr, tmp_path / "g", files, "m/s^2", "deg/s")
    msg = _refused(d, 1, "imu.csv: columns 'ax as ACC X [m/s^2]'", "key 'imu.acceleration_unit'",
                   "an accelerometer in g read as m/s^2")
    assert 0.95 < float(msg.split("median |specific force| ")[1].split(" ")[0]) < 1.05
    files[:, 1:4] = imu[:, 1:4]  # m/s^2 declared g: 96 m/s^2
    d = write_foreign(tr, tmp_path / "ms2", files, "g", "deg/s")
    msg = _refused(d, 1, "key 'imu.acceleration_unit'", "m/s^2 read as g")
    assert 94 < float(msg.split("median |specific force| ")[1].split(" ")[0]) < 98


def test_the_real_imu_files_pass_the_units_check(real_data_dir):
    """The 13 real Snapir IMU files (biases, noise, vibration): ratio and gravity near 1 and 9.8."""
    folder = real_data_dir.parent / "snapir-akit-imu"  # the earlier release with IMU files, beside the data
    if not folder.is_dir():
        pytest.skip(f"real Snapir IMU data not found: {folder} does not exist")
    for n in (6, 11, 12):  # the largest ratios measured (1.021, 1.028) and the slowest turner (0.006 rad/s)
        tr = load_track(n, folder, warnings="ignore")
        fig = imu_unit_figures(tr.imu, tr.t, tr.euler)
        assert 0.95 < fig["ratio"] < 1.1 and 9.7 < fig["median_f"] < 9.9, (n, fig)


def test_real_track_in_a_foreign_layout_gives_the_same_ekf_metrics(tmp_path, real_data_dir):
    """The must-hold on real data (skipped, naming where it looked, without it): real track 5 (its headings
    span 0-360 deg in the file) in the foreign layout; EKF metrics equal to the A-KIT folder's to 1e-9."""
    tr = load_track(5, real_data_dir, warnings="ignore")
    assert (np.mod(np.degrees(tr.euler[:, 2]), 360.0) > 180.0).any()
    write_foreign(tr, tmp_path / "foreign")
    out = {}
    for name, d in (("akit", real_data_dir), ("foreign", tmp_path / "foreign")):
        rc, so, err = nespm("mc", "--data-dir", str(d), "--tracks", "5", "--runs", "1", "--filters", "ekf",
                            "--data-warnings", "ignore", "--no-progress", "--out", str(tmp_path / f"mc-{name}"))
        assert rc == 0, err
        out[name] = pd.read_parquet(tmp_path / f"mc-{name}" / "metrics.parquet")
    a, b = out["akit"], out["foreign"]
    for c in [c for c in a.columns if pd.api.types.is_float_dtype(a[c]) and c != "seconds"]:
        np.testing.assert_allclose(b[c].to_numpy(), a[c].to_numpy(), rtol=1e-9, atol=0, err_msg=c)
