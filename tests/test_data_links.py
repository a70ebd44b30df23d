"""Symbolic links in a data folder (issue 30 defects): a track spec ``nespm-data.toml`` that is a link loop
(or a broken link) is refused, not skipped (the folder was read as an A-KIT folder, exit 0); a data file
that is a link loop is named as one (was "file not found"), in the A-KIT layout and through a spec."""
from __future__ import annotations

import os
import sys

import pytest

from conftest import assert_one_error_line, nespm, short_track
from nespm_cli.data.tracks import write_akit

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="symbolic links")


@pytest.fixture
def folder(tmp_path):
    write_akit(short_track(5, 41), tmp_path / "d")
    return tmp_path / "d"


def test_a_looped_or_broken_track_spec_is_refused(folder):
    assert nespm("tracks", "--data-dir", folder, "--no-progress")[0] == 0
    os.symlink("nespm-data.toml", folder / "nespm-data.toml")
    for cmd in (("tracks",), ("check", "--no-figures", "--out", str(folder.parent / "c"))):
        assert_one_error_line(*nespm(*cmd, "--data-dir", folder, "--no-progress"), "nespm-data.toml",
                              "symbolic link loop")
    (folder / "nespm-data.toml").unlink()
    os.symlink("gone.toml", folder / "nespm-data.toml")
    assert_one_error_line(*nespm("tracks", "--data-dir", folder, "--no-progress"), "nespm-data.toml",
                          "broken symbolic link (to gone.toml")


def test_a_looped_data_file_is_named(folder):
    dvl = folder / "Trajectory5" / "DVL_trajectory5.csv"
    dvl.unlink()
    os.symlink(dvl.name, dvl)
    assert_one_error_line(*nespm("tracks", "--data-dir", folder, "--no-progress"), str(dvl), "symbolic link loop")
    # through a track spec naming the A-KIT files
    spec = ('[gt]\nfile = "Trajectory{N}/GT_trajectory{N}.csv"\ntime = "Time [s]"\nlat = "Latitude [rad]"\n'
            'lon = "Longitude [rad]"\nalt = "Altitude [m]"\nv_north = "V North [m/s]"\nv_east = "V East [m/s]"\n'
            'v_down = "V Down [m/s]"\nroll = "Roll [rad]"\npitch = "Pitch [rad]"\nyaw = "Yaw [rad]"\n\n[dvl]\n'
            'file = "Trajectory{N}/DVL_trajectory{N}.csv"\ntime = "Time [s]"\nx = "DVL X [m/s]"\ny = "DVL Y [m/s]"\n'
            'z = "DVL Z [m/s]"\n')
    (folder / "nespm-data.toml").write_text(spec)
    assert_one_error_line(*nespm("tracks", "--data-dir", folder, "--no-progress"), "DVL_trajectory5.csv",
                          "symbolic link loop")
