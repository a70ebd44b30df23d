"""Bad recorded-IMU files (``IMU_trajectoryN.csv``) are rejected by ``load_track`` with one line
naming the file and, where there is one, the data row; the CLI exits with code 2. The real
100 Hz Snapir IMU files (CRLF, 40,000 rows; track 13: 39,999) load.

The bad files are damaged copies of a valid one: embedded track 5 cut to its first
``EPOCHS`` epochs, with the 100 Hz IMU of :func:`nespm_cli.nav.synthesis.synthesize`.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import exact_imu_table, assert_one_error_line, nespm, short_track
from nespm_cli.data.tracks import IMU_COLUMNS, IMU_MAX_GYRO, load_track, load_tracks, write_akit
from nespm_cli.errors import NespmError

#: The real Snapir tracks with their recorded 100 Hz IMU (same place as conftest's snapir-akit).
REAL_IMU_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "snapir-akit-imu"
needs_real_imu_data = pytest.mark.skipif(
    not REAL_IMU_DATA.is_dir(), reason=f"real Snapir IMU data not found: {REAL_IMU_DATA} does not exist"
)

NUMBER = 5
EPOCHS = 60  # ~59 s of GT at the 400/399 s spacing; ~5,900 IMU rows


_valid_imu = exact_imu_table  # the synthesized IMU as a recorded file holds it


@pytest.fixture(scope="module")
def base():
    """``(track, imu)``: the short track and its valid IMU table."""
    track = short_track(NUMBER, EPOCHS)
    return track, _valid_imu(track)


def _write(folder: Path, track, imu: np.ndarray) -> Path:
    """Write the track with ``imu`` as an A-KIT folder; return the IMU file's path."""
    tdir = write_akit(dataclasses.replace(track, imu=imu), folder)
    return tdir / f"IMU_trajectory{track.number}.csv"


def _write_imu(path: Path, imu: np.ndarray) -> None:
    pd.DataFrame(imu, columns=list(IMU_COLUMNS)).to_csv(path, index=False, float_format="%.17g")


def _set_cell(path: Path, data_row: int, col: int, text: str) -> None:
    """Replace the text of (1-based) ``data_row``, column index ``col`` of the CSV ``path``."""
    lines = path.read_text().splitlines()
    cells = lines[data_row].split(",")
    cells[col] = text
    lines[data_row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def _expect_error(folder: Path, imu_path: Path, *must_contain: str) -> str:
    """load_track raises a one-line NespmError naming the file (and ``must_contain``); ``nespm
    tracks --data-dir`` prints that line once and exits 2. Returns the message."""
    with pytest.raises(NespmError) as info:
        load_track(NUMBER, folder)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{imu_path}: "), msg
    for s in must_contain:
        assert s in msg, f"{s!r} not in {msg!r}"
    line = assert_one_error_line(*nespm("tracks", "--data-dir", folder, "--no-progress"), str(imu_path), *must_contain)
    assert msg in line
    return msg


# --------------------------------------------------------------------------- valid files


def test_valid_synthetic_imu_loads(tmp_path, base):
    track, imu = base
    _write(tmp_path, track, imu)
    tr = load_track(NUMBER, tmp_path)
    assert tr.imu is not None and tr.imu.shape == imu.shape
    np.testing.assert_array_equal(tr.imu, imu)
    rc, out, err = nespm("tracks", "--data-dir", tmp_path, "--no-progress")
    assert rc == 0, err


def test_crlf_and_tiny_rate_jitter_load(tmp_path, base):
    """CRLF line endings (as in the real files) and a 1e-6 relative step jitter are fine."""
    track, imu = base
    imu = imu.copy()
    rng = np.random.default_rng(0)
    imu[1:-1, 0] += rng.uniform(-1e-8, 1e-8, len(imu) - 2)  # 1e-6 of the 0.01 s step
    path = _write(tmp_path, track, imu)
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    assert b"\r\n" in path.read_bytes()
    assert load_track(NUMBER, tmp_path).imu.shape == imu.shape


def test_one_step_short_of_the_gt_span_is_accepted(tmp_path, base):
    """Missing the last sample (less than one step short of the last GT epoch) is not an error."""
    track, imu = base
    _write(tmp_path, track, imu[1:-1])
    assert load_track(NUMBER, tmp_path).imu.shape[0] == len(imu) - 2


# --------------------------------------------------------------------------- bad files


def test_gap_of_50_rows(tmp_path, base):
    track, imu = base
    path = _write(tmp_path, track, np.delete(imu, np.s_[1000:1050], axis=0))
    step = imu[1, 0] - imu[0, 0]
    # the gap ends at old row index 1050, now index 1000 = data row 1001
    msg = _expect_error(tmp_path, path, "data row 1001, column 'Time [s]'", f"step {51 * step:.6g} s",
                        f"the file's step is {step:.6g} s", "gap or non-constant rate")
    assert "constant rate" in msg


def test_irregular_step(tmp_path, base):
    """One sample 5 % of a step late: two irregular steps, the first one ending at that row."""
    track, imu = base
    imu = imu.copy()
    step = imu[1, 0] - imu[0, 0]
    imu[300, 0] += 0.05 * step
    path = _write(tmp_path, track, imu)
    _expect_error(tmp_path, path, "data row 301, column 'Time [s]'", "non-constant rate")


def test_nan_value(tmp_path, base):
    track, imu = base
    path = _write(tmp_path, track, imu)
    _set_cell(path, 777, 5, "nan")
    _expect_error(tmp_path, path, "data row 777, column 'GYRO Y [rad/s]'", "non-finite")


def test_text_value(tmp_path, base):
    track, imu = base
    path = _write(tmp_path, track, imu)
    _set_cell(path, 1234, 2, "n/a?")
    _expect_error(tmp_path, path, "data row 1234, column 'ACC Y [m/s^2]'", "not a number")


def test_starts_2_s_late(tmp_path, base):
    track, imu = base
    cut = imu[200:]  # 200 steps of 0.010025 s: starts 2.005 s after the first GT epoch
    path = _write(tmp_path, track, cut)
    msg = _expect_error(tmp_path, path, "data row 1, column 'Time [s]'", f"covers {cut[0, 0]:.6g}-",
                        f"GT_trajectory{NUMBER}.csv",
                        f"spans {track.t[0]:.6g}-{track.t[-1]:.6g} s", "must cover the GT span")
    assert "starts 2.00501 s after the first GT epoch" in msg


def test_ends_2_s_early(tmp_path, base):
    track, imu = base
    cut = imu[:-200]
    path = _write(tmp_path, track, cut)
    msg = _expect_error(tmp_path, path, f"data row {len(cut)}, column 'Time [s]'",
                        f"covers {cut[0, 0]:.6g}-{cut[-1, 0]:.6g} s", "must cover the GT span")
    assert "ends 2.00501 s before the last GT epoch" in msg


def test_time_in_milliseconds(tmp_path, base):
    track, imu = base
    ms = imu.copy()
    ms[:, 0] *= 1000.0
    path = _write(tmp_path, track, ms)
    _expect_error(tmp_path, path, "column 'Time [s]'", "median step 10.0251 s", "milliseconds")


def test_rate_1_hz(tmp_path, base):
    track, imu = base
    path = _write(tmp_path, track, imu[::100])  # on the GT epochs: covers the span, constant step
    _expect_error(tmp_path, path, "column 'Time [s]'", "median step 1.00251 s", "0.0005-0.1 s",
                  "navigation IMU")


def test_gyro_in_degrees_per_second(tmp_path, base):
    """The short track turns slowly (synthetic gyro < 1e-4 rad/s), so give it a 0.5 rad/s roll
    oscillation first (real tracks 8, 9, 11 reach 0.4-0.64 rad/s): in deg/s that is 28.6 > 20."""
    track, imu = base
    imu = imu.copy()
    imu[:, 4] += 0.5 * np.sin(2 * np.pi * 0.5 * (imu[:, 0] - imu[0, 0]))
    _write(tmp_path / "ok", track, imu)
    with pytest.raises(NespmError, match="x the GT attitude's rate"):  # in rad/s, but a roll the GT does not have
        load_track(NUMBER, tmp_path / "ok")
    deg = imu.copy()
    deg[:, 4:7] = np.degrees(deg[:, 4:7])
    path = _write(tmp_path, track, deg)
    row = int(np.flatnonzero(np.abs(deg[:, 4:7]).max(axis=1) > IMU_MAX_GYRO)[0]) + 1
    assert row > 1
    _expect_error(tmp_path, path, f"data row {row}, column 'GYRO X [rad/s]'", "> 20 rad/s",
                  "degrees per second?")


def test_acc_in_mm_per_s2(tmp_path, base):
    track, imu = base
    mm = imu.copy()
    mm[:, 1:4] *= 1000.0
    path = _write(tmp_path, track, mm)
    row = int(np.flatnonzero(np.abs(mm[:, 1:4]).max(axis=1) > 200)[0]) + 1
    _expect_error(tmp_path, path, f"data row {row}, column 'ACC", "> 200 m/s^2", "m/s^2 expected")


def test_run_with_recorded_imu_reports_the_gap(tmp_path, base):
    """The same one line through ``nespm run --imu recorded``."""
    track, imu = base
    path = _write(tmp_path, track, np.delete(imu, np.s_[1000:1050], axis=0))
    assert_one_error_line(*nespm("run", "--data-dir", tmp_path, "--track", NUMBER, "--filter", "ins", "--clean",
                                 "--imu", "recorded", "--json"),
                          str(path), "data row 1001", "gap or non-constant rate")


# --------------------------------------------------------------------------- real data


@needs_real_imu_data
def test_real_imu_files_load():
    tracks = load_tracks(None, REAL_IMU_DATA)
    assert [t.number for t in tracks] == list(range(1, 14))
    for tr in tracks:
        assert tr.imu is not None, tr.number
        assert tr.imu.shape == ((39_999 if tr.number == 13 else 40_000), 7), (tr.number, tr.imu.shape)
        assert tr.imu[0, 0] == 0.0 and tr.imu[-1, 0] == 400.0
