"""A sensor schedule that cannot be a sensor's is refused before anything runs, in one line naming the
option or the track's file: a recorded file with no measurement (a header only), a jitter that moves
every stamp out of the span, an interval below the IMU step or longer than the track, a 2-D fix file
with ``fix.vertical``, a std whose square underflows (R singular)."""
from __future__ import annotations

import pytest

from conftest import assert_one_error_line, nespm, short_track
from nespm_cli.data.tracks import write_akit

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

EMBEDDED = ["--dvl", "synthetic", "--tracks", "5", "--runs", "2", "--window", "0:30", "--no-progress",
            "--state", "15", "--filters", "ekf"]


def mc(tmp_path, *args):
    return nespm("mc", *args, "--out", tmp_path / "out")


@pytest.mark.parametrize("option, needles", [
    ("fix.jitter=1e6", ["--sensor-option fix.jitter=1e+06", "every stamp of track 5 out of its span"]),
    ("fix.interval=1e-9", ["--sensor-option fix.interval=1e-09", "shorter than track 5's IMU step"]),
    ("fix.interval=100", ["--sensor-option fix.interval=100", "longer than track 5", "no measurement"]),
    ("fix.r_std=1e-300", ["--sensor-option fix.r_std=1e-300", "underflows", "singular"]),
    ("fix.std=1e-200", ["--sensor-option fix.std=1e-200", "underflows"]),
    ("fix.vertical_std=1e-300", ["--sensor-option fix.vertical_std=1e-300"]),
])
def test_a_schedule_or_std_that_cannot_be_is_named(tmp_path, option, needles):
    rc, out, err = mc(tmp_path, "--sensors", "dvl,fix", "--sensor-option", option, *EMBEDDED)
    assert_one_error_line(rc, out, err, *needles)
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_the_default_interval_longer_than_a_short_window_is_not_refused(tmp_path):
    """Only a given interval is refused: a fix every 60 s (its default) on a 29 s window runs, with an
    empty fix record."""
    rc, _, err = mc(tmp_path, "--sensors", "dvl,fix", *EMBEDDED)
    assert rc == 0, err


def test_a_jitter_inside_the_span_still_runs(tmp_path):
    rc, _, err = mc(tmp_path, "--sensors", "dvl,fix", "--sensor-option", "fix.interval=5",
                    "--sensor-option", "fix.jitter=0.5", *EMBEDDED)
    assert rc == 0, err


@pytest.fixture
def folder(tmp_path):
    """Track 1 (31 epochs) in an A-KIT folder; write channel files into ``folder / "Trajectory1"``."""
    d = tmp_path / "data"
    write_akit(short_track(1, 31), d)
    return d


def recorded(tmp_path, d, sensors, *options):
    args = ["--data-dir", d, "--tracks", "1", "--runs", "2", "--state", "15", "--filters", "ekf", "--no-progress",
            "--sensors", sensors, "--dvl", "synthetic"]
    for o in options:
        args += ["--sensor-option", o]
    return mc(tmp_path, *args)


def test_a_header_only_depth_file_is_refused(tmp_path, folder):
    (folder / "Trajectory1" / "DEPTH_trajectory1.csv").write_text("Time [s],Depth [m]\n")
    rc, out, err = recorded(tmp_path, folder, "dvl,depth", "depth.source=recorded")
    assert_one_error_line(rc, out, err, "--sensors depth", "track 1", "no measurement inside the track's span",
                          "0 rows")


def test_a_two_column_fix_file_with_vertical_names_the_option(tmp_path, folder):
    t = short_track(1, 31)
    rows = "".join(f"{float(t.t[k])!r},{float(t.pos[k, 0])!r},{float(t.pos[k, 1])!r}\n" for k in (5, 10, 20))
    (folder / "Trajectory1" / "FIX_trajectory1.csv").write_text("Time [s],Latitude [rad],Longitude [rad]\n" + rows)
    rc, out, err = recorded(tmp_path, folder, "dvl,fix", "fix.source=recorded", "fix.vertical=true")
    assert_one_error_line(rc, out, err, "--sensor-option fix.vertical=true", "track 1", "no altitude column")
    rc, _, err = recorded(tmp_path / "ok", folder, "dvl,fix", "fix.source=recorded")  # without vertical: runs
    assert rc == 0, err
