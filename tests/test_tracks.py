"""Tests of nespm_cli.data.tracks: loading the real Snapir tracks, validation errors, summaries.

The real-data tests take conftest's ``real_data_dir`` (skipped, with the reason, without the
real data); everything else runs on embedded tracks written to temporary A-KIT folders.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from nespm_cli.data.embedded import embedded_track
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import euler_to_dcm
from nespm_cli.nav.dvl import body_rate_from_attitude
from nespm_cli.data.tracks import (
    DVL_COLUMNS,
    ENV_DATA_DIR,
    GT_COLUMNS,
    IMU_COLUMNS,
    Track,
    available_tracks,
    dvl_lever_arm_fit,
    load_track,
    load_tracks,
    resolve_data_dir,
    track_summary,
    write_akit,
)

@pytest.fixture(autouse=True)
def _no_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ENV_DATA_DIR, raising=False)


# ----------------------------------------------------------------------------- real data


def test_all_13_real_tracks_load(real_data_dir: Path) -> None:
    assert available_tracks(real_data_dir) == list(range(1, 14))
    tracks = load_tracks(None, real_data_dir)
    assert [tr.number for tr in tracks] == list(range(1, 14))
    for tr in tracks:
        assert tr.t.shape == (400,)
        for a in (tr.pos, tr.v_n, tr.euler, tr.dvl):
            assert a.shape == (400, 3)
        assert tr.imu is None
        assert tr.source == str(real_data_dir / f"Trajectory{tr.number}")
        assert np.all(np.diff(tr.t) > 0)
        assert np.allclose(np.diff(tr.t), 400 / 399, atol=1e-9)
        assert np.all(tr.pos[:, 2] < 0.5)  # altitude negative below the surface
        assert np.degrees(tr.pos[:, 0]).min() > 32 and np.degrees(tr.pos[:, 1]).min() > 34  # off Haifa
        s = track_summary(tr)
        assert 1.0 < s["mean_speed"] < 3.0
        assert 0.0 <= s["depth_min"] <= s["depth_max"] <= 36.0


def test_track5_first_epoch_matches_file(real_data_dir: Path) -> None:
    tr = load_track(5, real_data_dir)
    with open(real_data_dir / "Trajectory5/GT_trajectory5.csv", newline="") as f:
        rows = list(csv.reader(f))
    head, first = rows[0], [float(x) for x in rows[1]]
    col = {name.strip(): j for j, name in enumerate(head)}
    assert len(rows) - 1 == 400 and len(tr.t) == 400
    assert tr.pos[0, 0] == first[col["Latitude [rad]"]]
    assert tr.pos[0, 1] == first[col["Longitude [rad]"]]
    assert tr.pos[0, 2] == first[col["Altitude [m]"]]
    assert tr.v_n[0, 0] == first[col["V North [m/s]"]]
    assert tr.euler[0, 2] == first[col["Yaw [rad]"]]
    assert tr.t[0] == 0.0
    assert tr.duration == pytest.approx(400.0, abs=1e-9)
    with open(real_data_dir / "Trajectory5/DVL_trajectory5.csv", newline="") as f:
        dvl_first = [float(x) for x in list(csv.reader(f))[1]]
    assert tr.dvl[0].tolist() == dvl_first[1:]


def test_real_track5_lever_arm(real_data_dir: Path) -> None:
    tr = load_track(5, real_data_dir)
    lever, resid = dvl_lever_arm_fit(tr)
    assert -2.5 < lever[0] < -0.8
    assert resid.shape == (400, 3)
    raw = tr.dvl - np.einsum("nji,nj->ni", tr.C_bn, tr.v_n)
    # the fit explains a good part of the across-track (Y) residual
    assert resid[:, 1].std() < 0.6 * raw[:, 1].std()
    s = track_summary(tr)
    assert s["lever_arm"] == tuple(lever)
    assert s["dvl_resid_std"] == pytest.approx(np.sqrt(np.mean(resid.std(axis=0) ** 2)))


# ----------------------------------------------------------------------------- data folder choice


def test_resolve_data_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    data = tmp_path / "data"
    write_akit(embedded_track(5), data)
    other = tmp_path / "other"
    other.mkdir()
    assert resolve_data_dir(None) is None
    assert resolve_data_dir("") is None
    monkeypatch.setenv(ENV_DATA_DIR, str(data))
    assert resolve_data_dir(None) == data
    assert resolve_data_dir(other) == other  # --data-dir wins over the environment
    assert load_track(5).source == str(data / "Trajectory5")
    monkeypatch.setenv(ENV_DATA_DIR, str(tmp_path / "nope"))
    with pytest.raises(NespmError) as e:
        resolve_data_dir(None)
    _check_msg(e, str(tmp_path / "nope"), "not found", ENV_DATA_DIR)


def test_default_is_embedded() -> None:
    tr = load_track(3)
    assert tr.source == "embedded"
    assert tr is embedded_track(3)
    assert available_tracks(None) == [1, 2, 3, 4, 5, 6]
    assert [t.number for t in load_tracks([2, 6])] == [2, 6]


# ----------------------------------------------------------------------------- round trip


def test_write_akit_round_trip(tmp_path: Path) -> None:
    src = embedded_track(2)
    folder = write_akit(src, tmp_path)
    assert folder == tmp_path / "Trajectory2"
    header = (folder / "GT_trajectory2.csv").read_text().splitlines()[0]
    assert header == ",".join(GT_COLUMNS)
    assert (folder / "DVL_trajectory2.csv").read_text().splitlines()[0] == ",".join(DVL_COLUMNS)
    back = load_track(2, tmp_path)
    assert back.source == str(folder) and back.number == 2 and back.imu is None
    for name in ("t", "pos", "v_n", "euler", "dvl"):
        assert np.max(np.abs(getattr(back, name) - getattr(src, name))) <= 1e-15, name


def test_write_akit_round_trip_with_imu(tmp_path: Path) -> None:
    src = embedded_track(1)
    t_imu = np.arange(0.0, 400.0, 0.01)
    imu = np.column_stack([t_imu, np.sin(t_imu)[:, None] * np.arange(1, 7) / 7.0])
    imu[:, 3] -= 9.8  # gravity, and rates the GT's turns allow: the load compares both (imu_file.check_imu_units)
    imu[:, 4:7] *= 0.05
    tr = Track(src.number, src.t, src.pos, src.v_n, src.euler, src.dvl, imu, "test")
    write_akit(tr, tmp_path)
    assert (tmp_path / "Trajectory1/IMU_trajectory1.csv").read_text().splitlines()[0] == ",".join(IMU_COLUMNS)
    back = load_track(1, tmp_path)
    assert back.imu is not None and back.imu.shape == imu.shape
    assert np.max(np.abs(back.imu - imu)) <= 1e-15


def test_write_akit_is_atomic_and_leaves_no_temporaries(tmp_path: Path) -> None:
    from nespm_cli.data.atomic import write_atomic

    folder = write_akit(embedded_track(3), tmp_path)
    assert sorted(p.name for p in folder.iterdir()) == ["DVL_trajectory3.csv", "GT_trajectory3.csv"]
    # a failing writer leaves the old file untouched and no temporary behind
    target = folder / "GT_trajectory3.csv"
    before = target.read_text()

    def boom(tmp: Path) -> None:
        tmp.write_text("partial")
        raise OSError("disk full")

    with pytest.raises(NespmError, match="GT_trajectory3.csv: cannot write \\(disk full\\)"):
        write_atomic(target, boom)
    assert target.read_text() == before
    assert sorted(p.name for p in folder.iterdir()) == ["DVL_trajectory3.csv", "GT_trajectory3.csv"]


def test_track_arrays_read_only(tmp_path: Path) -> None:
    write_akit(embedded_track(5), tmp_path)
    tr = load_track(5, tmp_path)  # as read from files
    with pytest.raises(ValueError):
        tr.pos[0, 0] = 0.0
    assert tr.C_bn.shape == (400, 3, 3)
    np.testing.assert_allclose(tr.C_bn[7], euler_to_dcm(tr.euler[7]))


def test_whitespace_in_header_and_extra_columns_accepted(tmp_path: Path) -> None:
    folder = write_akit(embedded_track(4), tmp_path)
    gt = folder / "GT_trajectory4.csv"
    lines = gt.read_text().splitlines()
    lines[0] = ", ".join(f" {c} " for c in GT_COLUMNS) + ",Extra"
    lines[1:] = [ln + ",7" for ln in lines[1:]]
    gt.write_text("\n".join(lines) + "\n")
    np.testing.assert_array_equal(load_track(4, tmp_path).pos, embedded_track(4).pos)


# ----------------------------------------------------------------------------- malformed input


def _copy(tmp_path: Path, number: int = 1) -> Path:
    """Write embedded track ``number`` into tmp_path; return its TrajectoryN folder."""
    return write_akit(embedded_track(number), tmp_path)


def _edit(path: Path, row: int, column: str, value: str) -> None:
    """Set data row ``row`` (1-based, after the header) of ``column`` to the text ``value``."""
    lines = path.read_text().splitlines()
    j = [c.strip() for c in lines[0].split(",")].index(column)
    fields = lines[row].split(",")
    fields[j] = value
    lines[row] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


def _cell(path: Path, row: int, column: str) -> float:
    lines = path.read_text().splitlines()
    j = lines[0].split(",").index(column)
    return float(lines[row].split(",")[j])


def _check_msg(excinfo: pytest.ExceptionInfo, *fragments: str) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg and "\r" not in msg, msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


def test_missing_column(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    text = gt.read_text()
    gt.write_text(text.replace("V East [m/s]", "V_East", 1))
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "missing column 'V East [m/s]'")


@pytest.mark.parametrize("value", ["nan", "", "inf", "-inf"])
def test_nan_or_inf(tmp_path: Path, value: str) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 17, "Roll [rad]", value)
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 17", "'Roll [rad]'", "non-finite")


def test_text_in_number_field(tmp_path: Path) -> None:
    dvl = _copy(tmp_path) / "DVL_trajectory1.csv"
    _edit(dvl, 23, "DVL Y [m/s]", "abc")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(dvl), "data row 23", "'DVL Y [m/s]'", "'abc'")


def test_decreasing_time(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 30, "Time [s]", repr(_cell(gt, 29, "Time [s]") - 0.5))
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 30", "'Time [s]'", "strictly increasing")


def test_repeated_time(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 2, "Time [s]", "0")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 2", "strictly increasing")


def test_unknown_track_number(tmp_path: Path) -> None:
    _copy(tmp_path, 1)
    _copy(tmp_path, 3)
    with pytest.raises(NespmError) as e:
        load_track(7, tmp_path)
    _check_msg(e, str(tmp_path), "no track 7", "available: 1, 3")


def test_unknown_real_track_number(real_data_dir: Path) -> None:
    with pytest.raises(NespmError) as e:
        load_track(14, real_data_dir)
    _check_msg(e, str(real_data_dir), "no track 14", "available: 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13")


def test_unknown_embedded_track_number() -> None:
    with pytest.raises(NespmError) as e:
        load_track(7)
    _check_msg(e, "embedded", "no track 7", "1, 2, 3, 4, 5, 6")


def test_folder_without_tracks(tmp_path: Path) -> None:
    (tmp_path / "notes").mkdir()
    (tmp_path / "Trajectory.csv").write_text("x\n")
    with pytest.raises(NespmError) as e:
        available_tracks(tmp_path)
    _check_msg(e, str(tmp_path), "no TrajectoryN folders found")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(tmp_path), "no TrajectoryN folders found")


def test_data_dir_not_existing(tmp_path: Path) -> None:
    missing = tmp_path / "missing"
    with pytest.raises(NespmError) as e:
        load_track(1, missing)
    _check_msg(e, str(missing), "data directory not found")
    with pytest.raises(NespmError) as e:
        available_tracks(missing)
    _check_msg(e, str(missing), "not found")


def test_dvl_at_its_own_stamps(tmp_path: Path) -> None:
    """A DVL stamp off the GT epoch is a DVL at its own stamps: the filters get the samples as
    recorded (``channels['dvl']``), the checks the samples interpolated at the epochs."""
    dvl = _copy(tmp_path) / "DVL_trajectory1.csv"
    t10 = _cell(dvl, 10, "Time [s]")
    _edit(dvl, 10, "Time [s]", repr(t10 + 0.25))
    tr = load_track(1, tmp_path)
    t, v = tr.channels["dvl"]
    assert len(t) == 400 and t[9] == t10 + 0.25 and np.isfinite(tr.dvl).all()
    # the epoch at t10 now lies between the samples at t[8] and t10 + 0.25: linear between them
    w = (tr.t[9] - t[8]) / (t[9] - t[8])
    assert np.allclose(tr.dvl[9], v[8] * (1 - w) + v[9] * w, rtol=0, atol=1e-12)


def test_gt_dvl_epoch_tolerance(tmp_path: Path) -> None:
    dvl = _copy(tmp_path) / "DVL_trajectory1.csv"
    _edit(dvl, 10, "Time [s]", repr(_cell(dvl, 10, "Time [s]") + 5e-7))
    tr = load_track(1, tmp_path)
    assert len(tr.t) == 400 and "dvl" not in tr.channels  # within 1e-6 s: on the epochs


def test_dvl_with_fewer_rows_and_stamps_outside(tmp_path: Path) -> None:
    dvl = _copy(tmp_path) / "DVL_trajectory1.csv"
    lines = dvl.read_text().splitlines()
    dvl.write_text("\n".join(lines[:-1]) + "\n")  # the last epoch without a DVL sample: own stamps
    tr = load_track(1, tmp_path)
    assert len(tr.channels["dvl"][0]) == 399 and np.isnan(tr.dvl[-1]).all() and np.isfinite(tr.dvl[:-1]).all()
    _edit(dvl, 399, "Time [s]", repr(_cell(dvl, 399, "Time [s]") + 5.0))  # past the GT's end
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(dvl), "data row 399", "outside the GT span")


def test_latitude_out_of_range(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 5, "Latitude [rad]", "32.84")  # degrees instead of radians
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 5", "'Latitude [rad]'", "pi/2")


def test_longitude_out_of_range(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 6, "Longitude [rad]", "-3.5")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 6", "'Longitude [rad]'", "> pi")


def test_speed_too_high(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    _edit(gt, 8, "V North [m/s]", "20.0")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "data row 8", "speed", ">= 20 m/s")


def test_missing_dvl_file(tmp_path: Path) -> None:
    dvl = _copy(tmp_path) / "DVL_trajectory1.csv"
    dvl.unlink()
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(dvl), "file not found")


def test_missing_gt_file(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    gt.unlink()
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), "file not found")


@pytest.mark.parametrize(
    ("text", "fragment"), [("", "empty file"), (",".join(GT_COLUMNS) + "\n", "no data rows")]
)
def test_empty_file(tmp_path: Path, text: str, fragment: str) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    gt.write_text(text)
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt), fragment)


def test_ragged_csv_is_one_line_error(tmp_path: Path) -> None:
    gt = _copy(tmp_path) / "GT_trajectory1.csv"
    lines = gt.read_text().splitlines()
    lines[3] += ",1,2,3"
    gt.write_text("\n".join(lines) + "\n")
    with pytest.raises(NespmError) as e:
        load_track(1, tmp_path)
    _check_msg(e, str(gt))


# ----------------------------------------------------------------------------- analysis


def test_body_rate_from_attitude_constant_rate() -> None:
    t = np.arange(50) * 0.7
    w_true = np.array([0.01, -0.02, 0.15])
    from nespm_cli.nav.rotations import exp_so3

    C = exp_so3(t[:, None] * w_true)  # constant body rate: C(t) = exp(t [w x])
    np.testing.assert_allclose(body_rate_from_attitude(t, C), np.broadcast_to(w_true, (50, 3)), atol=1e-12)


def test_lever_arm_fit_recovers_embedded() -> None:
    lever, resid = dvl_lever_arm_fit(embedded_track(1))
    np.testing.assert_allclose(lever, [-1.6, 0.0, 0.0], atol=0.3)
    assert np.all((resid.std(axis=0) > 0.015) & (resid.std(axis=0) < 0.03))


def test_track_summary_embedded() -> None:
    tr = embedded_track(3)
    s = track_summary(tr)
    assert set(s) == {
        "track", "duration_s", "epochs", "distance_m", "mean_speed", "max_yaw_rate_dps",
        "depth_min", "depth_max", "imu", "dvl_resid_std", "dvl_resid_std_xyz", "lever_arm",
        "lever_arm_std", "yaw_rate_rms_dps", "lever_arm_warning",  # the lever-arm uncertainty (tracks.lever_arm_std)
    }
    assert s["track"] == 3 and s["epochs"] == 400 and s["imu"] is False
    assert s["duration_s"] == pytest.approx(400.0, abs=1e-9)
    # horizontal path length from the position differences agrees with the integrated speed
    from nespm_cli.nav.earth import radii

    R_N, R_E = radii(tr.pos[:, 0])
    dN = np.diff(tr.pos[:, 0]) * (R_N[1:] + tr.pos[1:, 2])
    dE = np.diff(tr.pos[:, 1]) * (R_E[1:] + tr.pos[1:, 2]) * np.cos(tr.pos[1:, 0])
    assert s["distance_m"] == pytest.approx(np.hypot(dN, dE).sum(), rel=2e-3)
    assert s["mean_speed"] == pytest.approx(np.linalg.norm(tr.v_n, axis=1).mean())
    assert s["depth_min"] == pytest.approx(-tr.pos[:, 2].max())
    assert s["depth_max"] == pytest.approx(-tr.pos[:, 2].min())
    assert 8.0 < s["max_yaw_rate_dps"] < 18.0
    assert len(s["lever_arm"]) == 3 and len(s["dvl_resid_std_xyz"]) == 3 and len(s["lever_arm_std"]) == 3
