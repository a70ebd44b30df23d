"""Optional per-sensor recorded files of a track folder (``Track.channels``): ``DEPTH_trajectoryN.csv``
and ``FIX_trajectoryN.csv`` read, validated, listed and written bit-exactly; NaN rows as "no
measurement"; a DVL row of three NaN as a missing epoch (and one or two NaN refused)."""
from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from nespm_cli.data import plausibility
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.sensor_files import DEPTH_COLUMNS, FIX_ALT_COLUMN, FIX_COLUMNS, read_channel
from nespm_cli.data.track import Track
from nespm_cli.data.tracks import DVL_COLUMNS, load_track, track_files, track_summary, write_akit
from nespm_cli.errors import NespmError

from conftest import short_track

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

EPOCHS = 31


def _track(**changes) -> Track:
    return dataclasses.replace(short_track(1, EPOCHS), **changes)


def _same(a, b) -> bool:
    """Bit-exact equality of float arrays, NaN where NaN."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True) and \
        np.array_equal(np.signbit(a), np.signbit(b))


def _stamps(t: np.ndarray) -> np.ndarray:
    """Off-grid stamps inside the GT span, with awkward binary fractions, ending on the last epoch."""
    return np.array([t[0], t[0] + 0.1, (t[1] + t[2]) / 3.0 + 1.0 / 7.0, t[10] + np.pi / 100, t[-1]])


def _folder(tmp_path: Path, **files: str) -> Path:
    """An A-KIT folder with track 1 (31 epochs) plus the files ``{KIND: text}`` (``DEPTH``, ``FIX``)."""
    d = tmp_path / "data"
    tdir = write_akit(_track(), d)
    for kind, text in files.items():
        (tdir / f"{kind}_trajectory1.csv").write_text(text)
    return d


def _refused(d: Path, kind: str, *must: str) -> str:
    with pytest.raises(NespmError) as ei:
        load_track(1, d, warnings="error")
    msg = str(ei.value)
    assert "\n" not in msg and msg.isprintable(), msg
    assert f"{kind}_trajectory1.csv" in msg, msg
    for s in must:
        assert s in msg, (s, msg)
    return msg


# ----------------------------------------------------------------------------- Track.channels


def test_channels_default_empty_and_positional_construction_works():
    tr = short_track(1, EPOCHS)
    pos = Track(tr.number, tr.t, tr.pos, tr.v_n, tr.euler, tr.dvl, None, "x")
    assert pos.channels == {} and tr.channels == {}
    assert Track(tr.number, tr.t, tr.pos, tr.v_n, tr.euler, tr.dvl, None, "x").channels is not pos.channels
    assert embedded_track(5).channels == {}


def test_channels_are_private_read_only_copies_and_shapes_checked():
    t = np.array([1.0, 2.0])
    z = np.array([3.0, 4.0])  # 1-D: one value column
    tr = _track(channels={"depth": (t, z)})
    tc, zc = tr.channels["depth"]
    assert zc.shape == (2, 1) and tc.shape == (2,)
    assert not tc.flags.writeable and not zc.flags.writeable
    t[0] = 99.0
    assert tc[0] == 1.0
    with pytest.raises(ValueError, match=r"channels\['fix'\]"):
        _track(channels={"fix": (t, np.zeros((3, 2)))})
    with pytest.raises(ValueError, match="pair"):
        _track(channels={"fix": np.zeros(3)})


# ----------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("m", [2, 3])
def test_write_then_load_round_trips_depth_and_fix_bit_exactly(tmp_path, m):
    base = _track()
    ts = _stamps(base.t)
    depth = np.array([[3.25], [np.nan], [1.0 / 3.0], [11999.999999999998], [-0.0]])
    fix = np.column_stack([0.5633 + np.arange(5) / 3e7, 0.6111 - np.arange(5) / 7e7, -np.arange(5) / 9.0])[:, :m]
    fix[1] = np.nan
    tr = dataclasses.replace(base, channels={"depth": (ts, depth), "fix": (ts, fix)})
    tdir = write_akit(tr, tmp_path)
    assert (tdir / "DEPTH_trajectory1.csv").read_text().splitlines()[0] == "Time [s],Depth [m]"
    header = (tdir / "FIX_trajectory1.csv").read_text().splitlines()[0]
    assert header == ",".join(FIX_COLUMNS + ((FIX_ALT_COLUMN,) if m == 3 else ()))
    assert "nan" in (tdir / "DEPTH_trajectory1.csv").read_text().splitlines()[2]
    back = load_track(1, tmp_path, warnings="error")
    assert sorted(back.channels) == ["depth", "fix"]
    for name in ("depth", "fix"):
        for got, want in zip(back.channels[name], tr.channels[name]):
            assert _same(got, want), name
    assert back.channels["fix"][1].shape == (5, m)
    assert np.isnan(back.channels["fix"][1][1]).all() and np.isnan(back.channels["depth"][1][1, 0])
    assert back.channels["depth"][0][0] == base.t[0]  # file time, not shifted
    assert not back.channels["fix"][1].flags.writeable
    # and again: the written files are a fixed point
    again = tmp_path / "again"
    write_akit(back, again)
    for kind in ("DEPTH", "FIX"):
        assert (again / "Trajectory1" / f"{kind}_trajectory1.csv").read_bytes() == \
            (tdir / f"{kind}_trajectory1.csv").read_bytes()


def test_header_only_files_give_empty_channels(tmp_path):
    d = _folder(tmp_path, DEPTH="Time [s],Depth [m]\n", FIX="Time [s], Latitude [rad] ,Longitude [rad]\n")
    tr = load_track(1, d, warnings="error")
    assert tr.channels["depth"][0].shape == (0,) and tr.channels["depth"][1].shape == (0, 1)
    assert tr.channels["fix"][1].shape == (0, 2)


def test_columns_in_any_order_and_stamp_tolerance(tmp_path):
    t = short_track(1, EPOCHS).t
    lo, hi = float(t[0]) - 5e-7, float(t[-1]) + 5e-7
    d = _folder(tmp_path, FIX=f"Longitude [rad],Altitude [m],Time [s],Latitude [rad]\n0.6,-2.5,{lo!r},0.5\n"
                              f"nan,nan,{hi!r},nan\n")
    ts, z = load_track(1, d).channels["fix"]
    assert ts.tolist() == [lo, hi]
    assert z[0].tolist() == [0.5, 0.6, -2.5] and np.isnan(z[1]).all()


def test_no_channel_files_no_channels(tmp_path):
    assert load_track(1, _folder(tmp_path)).channels == {}


# ----------------------------------------------------------------------------- refusals


def _depth_text(rows: list[tuple[str, str]]) -> str:
    return "Time [s],Depth [m]\n" + "".join(f"{a},{b}\n" for a, b in rows)


def test_unsorted_stamp_is_refused_naming_the_row(tmp_path):
    d = _folder(tmp_path, DEPTH=_depth_text([("1", "2"), ("3", "2"), ("2", "2")]))
    msg = _refused(d, "DEPTH", "data row 3", "unsorted", "'Time [s]'", "2.0", "3.0")
    assert "strictly increasing" in msg


def test_duplicate_stamp_is_refused_naming_the_row(tmp_path):
    d = _folder(tmp_path, FIX="Time [s],Latitude [rad],Longitude [rad]\n1,0.5,0.6\n2,0.5,0.6\n4,0.5,0.6\n"
                              "4,0.5,0.6\n")
    _refused(d, "FIX", "data row 4", "duplicate stamp 4.0", "data row 3")


@pytest.mark.parametrize("stamp, row", [("-0.001", 1), ("30.1", 2)])
def test_stamp_outside_the_gt_span_is_refused(tmp_path, stamp, row):
    t_end = short_track(1, EPOCHS).t[-1]  # 30.075... s
    rows = [(stamp, "1")] if row == 1 else [("1", "1"), (stamp, "1")]
    d = _folder(tmp_path, DEPTH=_depth_text(rows))
    _refused(d, "DEPTH", f"data row {row}", "outside the GT span", "GT_trajectory1.csv", repr(float(t_end)))


@pytest.mark.parametrize("header, what", [
    ("Time [s],Depth [m],Pressure [dbar]", "unknown column 'Pressure [dbar]'"),
    ("Time [s],Depth [ft]", "unknown column 'Depth [ft]'"),
    ("Time [s]", "missing column 'Depth [m]'"),
])
def test_bad_depth_columns_are_refused(tmp_path, header, what):
    n = header.count(",") + 1
    d = _folder(tmp_path, DEPTH=header + "\n" + ",".join(["1"] * n) + "\n")
    _refused(d, "DEPTH", what)


def test_bad_fix_columns_are_refused(tmp_path):
    d = _folder(tmp_path, FIX="Time [s],Latitude [deg],Longitude [rad]\n1,30,0.6\n")
    _refused(d, "FIX", "unknown column 'Latitude [deg]'", "optionally 'Altitude [m]'")
    d2 = _folder(tmp_path / "b", FIX="Time [s],Latitude [rad]\n1,0.5\n")
    _refused(d2, "FIX", "missing column 'Longitude [rad]'")


def test_non_numeric_text_is_refused_naming_row_and_column(tmp_path):
    d = _folder(tmp_path, DEPTH=_depth_text([("1", "2"), ("2", "two"), ("3", "2")]))
    _refused(d, "DEPTH", "data row 2", "column 'Depth [m]'", "not a number ('two')")


@pytest.mark.parametrize("rows, must", [
    ([("1", "2"), ("nan", "2")], ("data row 2", "column 'Time [s]'", "non-finite")),
    ([("1", "2"), ("", "2")], ("data row 2", "column 'Time [s]'", "non-finite")),
    ([("1", "2"), ("2", "inf")], ("data row 2", "column 'Depth [m]'", "infinite value")),
    ([("1", "-10.5")], ("data row 1", "column 'Depth [m]'", "-10.5 is outside -10 .. 12000")),
    ([("1", "5"), ("2", "12000.5")], ("data row 2", "12000.5 is outside")),
])
def test_bad_depth_values_are_refused(tmp_path, rows, must):
    _refused(_folder(tmp_path, DEPTH=_depth_text(rows)), "DEPTH", *must)


@pytest.mark.parametrize("row, must", [
    ("2,1.6,0.6", ("data row 2", "column 'Latitude [rad]'", "|1.6| > pi/2", "radians")),
    ("2,0.5,-3.2", ("data row 2", "column 'Longitude [rad]'", "|-3.2| > pi (radians")),
    ("2,0.5,nan", ("data row 2", "NaN in 'Longitude [rad]' only")),
    ("2,0.5,-inf", ("data row 2", "column 'Longitude [rad]'", "infinite value")),
])
def test_bad_fix_values_are_refused(tmp_path, row, must):
    d = _folder(tmp_path, FIX=f"Time [s],Latitude [rad],Longitude [rad]\n1,0.5,0.6\n{row}\n")
    _refused(d, "FIX", *must)


def test_fix_altitude_in_other_units_is_refused(tmp_path):
    d = _folder(tmp_path, FIX="Time [s],Latitude [rad],Longitude [rad],Altitude [m]\n1,0.5,0.6,-3\n2,0.5,0.6,-30000\n")
    _refused(d, "FIX", "data row 2", "column 'Altitude [m]'", "|-30000.0| > 12000 m")


def test_empty_file_without_header_is_refused(tmp_path):
    _refused(_folder(tmp_path, DEPTH=""), "DEPTH", "empty file")


def test_read_channel_directly(tmp_path):
    p = tmp_path / "DEPTH_trajectory1.csv"
    p.write_text(_depth_text([("0", "1.5"), ("0.5", "nan")]))
    t, z = read_channel("depth", p, np.array([0.0, 1.0]), "GT.csv")
    assert t.tolist() == [0.0, 0.5] and z[0, 0] == 1.5 and np.isnan(z[1, 0])
    p.write_text(_depth_text([("0", "1.5"), ("1.5", "1")]))
    with pytest.raises(NespmError, match=r"data row 2.*outside the GT span 0.0 .. 1.0 s of GT.csv"):
        read_channel("depth", p, np.array([0.0, 1.0]), "GT.csv")
    assert DEPTH_COLUMNS == ("Time [s]", "Depth [m]")


# ----------------------------------------------------------------------------- file names and listing


def test_track_files_lists_the_channel_files_that_exist(tmp_path):
    d = _folder(tmp_path)
    tdir = d / "Trajectory1"
    assert [p.name for p in track_files(1, d)] == ["GT_trajectory1.csv", "DVL_trajectory1.csv"]
    (tdir / "FIX_trajectory1.csv").write_text("Time [s],Latitude [rad],Longitude [rad]\n")
    assert [p.name for p in track_files(1, d, imu=True)] == \
        ["GT_trajectory1.csv", "DVL_trajectory1.csv", "IMU_trajectory1.csv", "FIX_trajectory1.csv"]
    (tdir / "DEPTH_trajectory1.csv").write_text("Time [s],Depth [m]\n")
    assert [p.name for p in track_files(1, d)] == \
        ["GT_trajectory1.csv", "DVL_trajectory1.csv", "DEPTH_trajectory1.csv", "FIX_trajectory1.csv"]
    assert track_files(1, None) == []


def test_leading_zeros_in_channel_file_names(tmp_path):
    d = _folder(tmp_path)
    (d / "Trajectory1").rename(d / "Trajectory01")
    tdir = d / "Trajectory01"
    (tdir / "DEPTH_trajectory001.csv").write_text(_depth_text([("1", "4.5")]))
    (tdir / "FIX_trajectory1.csv").write_text("Time [s],Latitude [rad],Longitude [rad]\n2,0.5,0.6\n")
    tr = load_track(1, d, warnings="error")
    assert tr.channels["depth"][1].tolist() == [[4.5]] and tr.channels["fix"][1].tolist() == [[0.5, 0.6]]
    assert [p.name for p in track_files(1, d)][2:] == ["DEPTH_trajectory001.csv", "FIX_trajectory1.csv"]
    (tdir / "DEPTH_trajectory01.csv").write_text(_depth_text([("1", "4.5")]))
    with pytest.raises(NespmError, match="both the DEPTH file of track 1"):
        load_track(1, d)


# ----------------------------------------------------------------------------- NaN DVL rows


def _dvl_lines(tmp_path: Path, rows: dict[int, str]) -> Path:
    """Track 1 written, then DVL data rows ``{row (1-based): 'x,y,z'}`` replaced."""
    d = _folder(tmp_path)
    p = d / "Trajectory1" / "DVL_trajectory1.csv"
    lines = p.read_text().splitlines()
    for r, xyz in rows.items():
        lines[r] = lines[r].split(",")[0] + "," + xyz
    p.write_text("\n".join(lines) + "\n")
    return d


def test_dvl_row_of_nan_is_a_missing_epoch(tmp_path):
    d = _dvl_lines(tmp_path, {4: "nan,nan,nan", 9: ",,"})
    ref = short_track(1, EPOCHS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tr = load_track(1, d, warnings="error")  # no finding: the NaN rows are skipped by every check
    assert np.isnan(tr.dvl[[3, 8]]).all()
    ok = np.ones(EPOCHS, dtype=bool)
    ok[[3, 8]] = False
    assert np.array_equal(tr.dvl[ok], ref.dvl[ok])
    # written back with 'nan' and read again identically
    write_akit(tr, tmp_path / "again")
    assert "nan,nan,nan" in (tmp_path / "again" / "Trajectory1" / "DVL_trajectory1.csv").read_text()
    assert _same(load_track(1, tmp_path / "again").dvl, tr.dvl)
    s = track_summary(tr)  # the lever-arm fit leaves the missing epochs out
    assert np.isfinite(s["lever_arm"]).all() and np.isfinite(s["dvl_resid_std"])
    assert np.isfinite(s["lever_arm_std"]).all()


def test_dvl_row_with_some_nan_is_refused(tmp_path):
    d = _dvl_lines(tmp_path, {6: "1.5,nan,0.1"})
    msg = _refused(d, "DVL", "data row 6", "NaN in 'DVL Y [m/s]' only", "missing epoch")
    assert all(f"'{c}'" in msg for c in DVL_COLUMNS[1:])
    d = _dvl_lines(tmp_path / "b", {2: "1.5,0.1,inf"})
    _refused(d, "DVL", "data row 2", "column 'DVL Z [m/s]'", "infinite")


def test_dvl_speed_check_skips_nan_rows():
    tr = short_track(1, EPOCHS)
    dvl = np.array(tr.dvl)
    dvl[::2] = np.nan
    assert plausibility.check_dvl_speed("DVL.csv", dvl, tr.v_n) == []
    assert plausibility.check_dvl_speed("DVL.csv", np.full_like(dvl, np.nan), tr.v_n) == []
    dvl[1::2] *= 3.0  # still caught on the rows that are there
    (f,) = plausibility.check_dvl_speed("DVL.csv", dvl, tr.v_n)
    assert f.level == "warning" and "3x the median GT speed" in f.text
