"""Physical plausibility checks of the track loader (nespm_cli.data.plausibility): each implausible
damage of a valid track folder is an error naming the file, the row and the column; a gentle one is a
warning that ``warnings="ignore"`` silences and ``warnings="error"`` raises."""
from __future__ import annotations

import warnings as pywarnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.data import plausibility as P
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError

N = 5  # embedded track used throughout


def _folder(tmp_path: Path) -> tuple[Path, Path, Path]:
    write_akit(embedded_track(N), tmp_path)
    tdir = tmp_path / f"Trajectory{N}"
    return tmp_path, tdir / f"GT_trajectory{N}.csv", tdir / f"DVL_trajectory{N}.csv"


def _rewrite(path: Path, df: pd.DataFrame) -> None:
    df.to_csv(path, index=False, float_format="%.17g")


def _error(folder: Path, **kw) -> str:
    with pytest.raises(NespmError) as exc:
        load_track(N, folder, **kw)
    msg = str(exc.value)
    assert "\n" not in msg and msg.isprintable(), msg
    return msg


def _shift_time(gt: Path, dvl: Path, k: int, dt: float) -> None:
    """Add ``dt`` to the time of 0-based rows k.. in both files."""
    for p in (gt, dvl):
        df = pd.read_csv(p)
        df.loc[k:, "Time [s]"] += dt
        _rewrite(p, df)


def test_clean_embedded_remus_tracks_load_without_findings(tmp_path):
    """The six embedded tracks and a simulated REMUS 100 track pass the plausibility checks without any warning."""
    from nespm_cli.vehicles import simulate_runs
    from nespm_cli.vehicles.simulate import to_track

    for n in range(1, 7):
        write_akit(embedded_track(n), tmp_path / "emb")
    write_akit(to_track(simulate_runs(1, 100.0, seed=1), 0, 1), tmp_path / "remus")
    with pywarnings.catch_warnings():
        pywarnings.simplefilter("error")  # any warning fails
        for n in range(1, 7):
            load_track(n, tmp_path / "emb", warnings="error")
        load_track(1, tmp_path / "remus", warnings="error")


def test_yaw_in_degrees_is_an_error(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    deg = np.degrees(df["Yaw [rad]"].to_numpy())
    df["Yaw [rad]"] = deg
    _rewrite(gt, df)
    row = int(np.flatnonzero(np.abs(deg) > np.pi + 1e-6)[0]) + 1
    msg = _error(folder)
    assert msg.startswith(str(gt)) and f"data row {row}," in msg and "'Yaw [rad]'" in msg, msg
    assert "degrees" in msg


@pytest.mark.parametrize("col,limit", [("Roll [rad]", np.pi), ("Pitch [rad]", np.pi / 2)])
def test_roll_or_pitch_in_degrees_is_an_error(tmp_path, col, limit):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    deg = np.degrees(df[col].to_numpy())
    df[col] = deg
    _rewrite(gt, df)
    over_pi = np.flatnonzero(np.abs(deg) > np.pi + 1e-6)
    row = int((over_pi if over_pi.size else np.flatnonzero(np.abs(deg) > limit + 1e-6))[0]) + 1
    msg = _error(folder)
    assert msg.startswith(str(gt)) and f"data row {row}," in msg and f"'{col}'" in msg, msg
    assert "degrees instead of radians" in msg


def test_attitude_jump_is_an_error_and_a_fast_step_a_warning(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    orig = df["Yaw [rad]"].to_numpy().copy()
    yaw = orig.copy()
    yaw[150] = np.angle(np.exp(1j * (yaw[150] + np.radians(60))))  # a 60 deg spike (wrapped to +-pi)
    df["Yaw [rad]"] = yaw
    _rewrite(gt, df)
    msg = _error(folder)
    assert "data row 151," in msg and "'Yaw [rad]'" in msg and "deg/s" in msg, msg
    yaw = orig.copy()
    yaw[150] += np.radians(40)  # 40 deg/s: above the 35 deg/s warning, below the 45 deg/s error
    df["Yaw [rad]"] = np.angle(np.exp(1j * yaw))
    _rewrite(gt, df)
    with pytest.warns(P.DataWarning, match=r"data row 151, column 'Yaw \[rad\]'"):
        load_track(N, folder)


def test_yaw_wrap_is_not_a_step(tmp_path):
    """A yaw crossing +-pi (wrapped) is fine; the same yaw unwrapped beyond pi is an error."""
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    df["Yaw [rad]"] = np.angle(np.exp(1j * (df["Yaw [rad]"].to_numpy() + 2.5)))
    _rewrite(gt, df)
    with pytest.warns(P.DataWarning, match="accepted"):  # a heading 2.5 rad off contradicts the DVL (issue 39)
        load_track(N, folder, warnings="error", accept_residual=True)


def test_altitude_times_1e7_is_an_error(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    df["Altitude [m]"] *= 1e7
    _rewrite(gt, df)
    msg = _error(folder)
    assert msg.startswith(str(gt)) and "data row 1," in msg and "'Altitude [m]'" in msg and "11000 m" in msg, msg


def test_altitude_far_above_sea_is_a_warning(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    df["Altitude [m]"] += 300.0
    _rewrite(gt, df)
    row = int(np.argmax(df["Altitude [m]"].to_numpy())) + 1
    msg = _error(folder, warnings="error")
    assert f"data row {row}," in msg and "'Altitude [m]'" in msg and "above the sea" in msg, msg
    load_track(N, folder, warnings="ignore")


def test_time_in_milliseconds_is_an_error(tmp_path):
    folder, gt, dvl = _folder(tmp_path)
    for p in (gt, dvl):
        df = pd.read_csv(p)
        df["Time [s]"] *= 1000.0
        _rewrite(p, df)
    msg = _error(folder)
    assert msg.startswith(str(gt)) and "'Time [s]'" in msg and "milliseconds" in msg, msg


def test_gap_of_an_hour_is_an_error(tmp_path):
    folder, gt, dvl = _folder(tmp_path)
    _shift_time(gt, dvl, 200, 3600.0)
    msg = _error(folder)
    assert msg.startswith(str(gt)) and "data row 201," in msg and "'Time [s]'" in msg and "gap" in msg, msg


def test_swapped_velocity_columns_are_an_error(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    df[["V North [m/s]", "V East [m/s]"]] = df[["V East [m/s]", "V North [m/s]"]].to_numpy()
    _rewrite(gt, df)
    a = df.to_numpy()
    mis = P.velocity_position_mismatch(a[:, 0], a[:, [2, 1, 3]], a[:, 4:7])
    row = int(np.argmax(mis)) + 2
    msg = _error(folder)
    assert msg.startswith(str(gt)) and f"data row {row}," in msg and "'V North [m/s]'" in msg, msg
    assert "swapped" in msg


@pytest.mark.parametrize("factor", [5.0, 10.0])
def test_scaled_velocity_is_an_error(tmp_path, factor):
    folder, gt, dvl = _folder(tmp_path)
    df = pd.read_csv(gt)
    df[["V North [m/s]", "V East [m/s]", "V Down [m/s]"]] *= factor
    _rewrite(gt, df)
    msg = _error(folder)
    assert msg.startswith(str(gt)) and "data row " in msg and "V North [m/s]" in msg, msg


def test_dvl_in_other_units_is_a_warning(tmp_path):
    folder, gt, dvl = _folder(tmp_path)
    df = pd.read_csv(dvl)
    df[["DVL X [m/s]", "DVL Y [m/s]", "DVL Z [m/s]"]] *= 3.0
    _rewrite(dvl, df)
    msg = _error(folder, warnings="error")
    assert msg.startswith(str(dvl)) and "DVL" in msg and "units" in msg, msg


def test_irregular_step_is_a_warning_ignore_silences_error_raises(tmp_path):
    folder, gt, dvl = _folder(tmp_path)
    step = float(np.diff(embedded_track(N).t).mean())
    _shift_time(gt, dvl, 100, 0.015 * step)  # one step 1.5 % long: irregular, not a gap
    with pytest.warns(P.DataWarning) as rec:
        tr = load_track(N, folder)
    texts = [str(w.message) for w in rec if issubclass(w.category, P.DataWarning)]
    assert len(texts) == 1 and "\n" not in texts[0], texts
    assert texts[0].startswith(str(gt)) and "data row 101, column 'Time [s]'" in texts[0], texts
    assert len(tr.t) == 400
    with pywarnings.catch_warnings():
        pywarnings.simplefilter("error")
        load_track(N, folder, warnings="ignore")
        load_track(N, folder)  # "warn" again: once per (file, message) in a process, so silent now
    msg = _error(folder, warnings="error")
    assert msg.startswith(str(gt)) and "data row 101, column 'Time [s]'" in msg, msg


def test_set_warning_mode_is_used_when_not_given(tmp_path):
    folder, gt, dvl = _folder(tmp_path)
    _shift_time(gt, dvl, 50, 0.02)
    assert P.get_warning_mode() == "warn"
    try:
        P.set_warning_mode("error")
        assert "data row 51," in _error(folder)
        P.set_warning_mode("ignore")
        with pywarnings.catch_warnings():
            pywarnings.simplefilter("error")
            load_track(N, folder)
        with pytest.raises(ValueError):
            P.set_warning_mode("loud")
    finally:
        P.set_warning_mode("warn")


def test_cli_exits_2_with_one_line_on_implausible_data(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    df = pd.read_csv(gt)
    df["Yaw [rad]"] = np.degrees(df["Yaw [rad]"])
    _rewrite(gt, df)
    rc, out, err = nespm("tracks", "--data-dir", str(folder), "--no-progress")
    assert_one_error_line(rc, out, err, str(gt), "'Yaw [rad]'", "degrees")


def test_all_nul_file_gives_a_short_printable_line(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    gt.write_bytes(b"\x00" * 2000)
    rc, out, err = nespm("tracks", "--data-dir", str(folder), "--no-progress")
    line = assert_one_error_line(rc, out, err, str(gt), "NUL")
    assert line.isprintable() and len(line) < 300, line


def test_binary_and_long_text_are_quoted_short_and_printable(tmp_path):
    folder, gt, _ = _folder(tmp_path)
    text = gt.read_text().splitlines()
    parts = text[5].split(",")
    parts[3] = "x\x07\x1b[31m" + "y" * 500
    text[5] = ",".join(parts)
    gt.write_text("\n".join(text) + "\n")
    msg = _error(folder)
    assert "data row 5, column 'Altitude [m]'" in msg and len(msg) < len(str(gt)) + 150, msg
    gt.write_bytes(b"Time [s],\xff\xfe\xfa\n1,2\n")
    msg = _error(folder)
    assert len(msg) < len(str(gt)) + 150, msg


def test_printable_helper():
    assert P.printable("a\x00\x00b\n c") == "a?x2b c"
    assert P.printable("x" * 100, limit=10) == "xxxxxxx..."
    assert P.printable("\ufeffok\u200b") == "?ok?"
    s = P.printable("".join(chr(i) for i in range(0, 300)), limit=1000)
    assert s.isprintable() and "\n" not in s


def test_findings_on_a_long_track():
    """A clean 100,000-epoch track gives no error finding (how fast: benchmarks/bench_claims.py)."""
    n = 100_000
    t = np.arange(n) * 0.1
    v = np.column_stack([np.full(n, 1.5), np.zeros(n), np.zeros(n)])
    lat = 0.5 + np.cumsum(np.r_[0.0, np.full(n - 1, 0.15 / 6.36e6)])
    gt = np.column_stack([t, np.full(n, 0.6), lat, np.full(n, -10.0), v, np.zeros((n, 3))])
    dvl = np.column_stack([t, v])
    f = P.check_track_arrays("gt.csv", gt, "dvl.csv", dvl)
    assert [x for x in f if x.level == "error"] == [], [x.text for x in f]
