"""``--accept-residual`` (issue 39 item 1): a track whose data contradict its declared conventions runs when the
user accepts it, from the command line (an A-KIT folder has no track spec) or the spec key ``gt.accept_residual``,
and the study says so: the manifest's ``accepted_residuals`` and one caveat line per track in the report.

The wrong track is embedded track 5's first 200 epochs with its yaw in the ENU convention (0 = east,
counter-clockwise): DVL residual ~1.3 m/s against ~0.03 as declared correctly (docs/data-format.md)."""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.data import conventions
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.track import Track
from nespm_cli.data.tracks import write_akit
from nespm_cli.experiments.accepted import accepted_residuals
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.reports.caveats import residual_caveats

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
N, EPOCHS = 5, 200
MC = ("--tracks", N, "--runs", 1, "--filters", "ekf", "--window", "0:60", "--jobs", 1, "--no-progress")
RESIDUAL = re.compile(r"DVL residual vs body velocity ([0-9.]+) m/s RMS")
SPEC = """[gt]
file = "run{N}/truth.csv"
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
angle_unit = "rad"
accept_residual = true
[dvl]
file = "run{N}/dvl.csv"
time = "t"
x = "u"
y = "v"
z = "w"
"""


def enu_track() -> Track:
    """Embedded track 5, first 200 epochs, its yaw in the ENU convention (the truth file's mistake)."""
    tr = embedded_track(N)
    s = slice(0, EPOCHS)
    e = np.array(tr.euler[s])
    e[:, 2] = wrap_angle(np.pi / 2 - e[:, 2])
    return Track(number=N, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=e, dvl=tr.dvl[s], imu=None, source="enu")


def spec_folder(folder: Path, tr: Track) -> Path:
    """A track spec folder of ``tr`` (radians) whose spec sets ``gt.accept_residual = true``."""
    import pandas as pd

    d = folder / f"run{N}"
    d.mkdir(parents=True)
    pd.DataFrame({"t": tr.t, "lat": tr.pos[:, 0], "lon": tr.pos[:, 1], "alt": tr.pos[:, 2], "vn": tr.v_n[:, 0],
                  "ve": tr.v_n[:, 1], "vd": tr.v_n[:, 2], "roll": tr.euler[:, 0], "pitch": tr.euler[:, 1],
                  "yaw": tr.euler[:, 2]}).to_csv(d / "truth.csv", index=False, float_format="%.17g")
    pd.DataFrame({"t": tr.t, "u": tr.dvl[:, 0], "v": tr.dvl[:, 1], "w": tr.dvl[:, 2]}).to_csv(
        d / "dvl.csv", index=False, float_format="%.17g")
    (folder / "nespm-data.toml").write_text(SPEC)
    return folder


@pytest.fixture(scope="module")
def akit(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("enu") / "d"
    write_akit(enu_track(), folder)
    return folder


def manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text(encoding="utf-8"))


def test_an_akit_folder_is_refused_without_the_flag(akit, tmp_path):
    out = tmp_path / "out"
    line = assert_one_error_line(*nespm("mc", "--data-dir", akit, *MC, "--out", out), "GT_trajectory5.csv",
                                 "ENU convention", "gt.yaw_convention", "--accept-residual")
    assert float(RESIDUAL.search(line).group(1)) > 1.0  # the measured residual, far above the DVL's noise
    assert not out.exists()
    assert_one_error_line(*nespm("tracks", "--data-dir", akit, "--no-progress"), "gt.yaw_convention")
    assert_one_error_line(*nespm("corrupt", "--data-dir", akit, "--tracks", N, "--runs", 1, "--out", tmp_path / "c"),
                          "gt.yaw_convention")
    assert not (tmp_path / "c").exists()


def test_the_flag_runs_it_and_the_manifest_and_report_say_so(akit, tmp_path):
    out = tmp_path / "out"
    rc, _, err = nespm("mc", "--data-dir", akit, *MC, "--accept-residual", "--out", out)
    assert rc == 0, err
    assert len([x for x in err.splitlines() if "ENU convention" in x and "accepted" in x]) == 1  # one warning
    m = manifest(out)
    assert m["options"]["accept_residual"] is True
    key = f"{akit.resolve() / f'Trajectory{N}'}#{N}"
    assert list(m["accepted_residuals"]) == [key]
    sentence = m["accepted_residuals"][key]
    assert "ENU convention" in sentence and "gt.yaw_convention" in sentence and "accepted" in sentence
    assert float(RESIDUAL.search(sentence).group(1)) > 1.0
    assert residual_caveats(m) == [f"track {N}: convention residual accepted: {sentence}"]
    rc, _, err = nespm("report", out)
    assert rc == 0, err
    report = (out / "report.md").read_text(encoding="utf-8")
    caveats = report.split("## Caveats", 1)[1].split("\n## ", 1)[0]
    assert f"- track {N}: convention residual accepted: {sentence}" in caveats.splitlines()


def test_the_flag_reaches_tracks_and_corrupt(tmp_path):
    akit = tmp_path / "d"  # its own folder: a track's accepted sentence is said once per process
    write_akit(enu_track(), akit)
    rc, out, err = nespm("tracks", "--data-dir", akit, "--no-progress", "--accept-residual")
    assert rc == 0, err
    assert "ENU convention" in err and re.search(rf"^\W*{N}\W+199\.\d", out, re.M)  # its row: 199.x s
    rc, _, err = nespm("corrupt", "--data-dir", akit, "--tracks", N, "--runs", 1, "--accept-residual",
                       "--out", tmp_path / "c")
    assert rc == 0, err
    assert (tmp_path / "c" / "realizations.parquet").is_file()


def test_the_spec_key_runs_without_the_flag(tmp_path):
    folder = spec_folder(tmp_path / "s", enu_track())
    out = tmp_path / "out"
    rc, _, err = nespm("mc", "--data-dir", folder, *MC, "--out", out)
    assert rc == 0, err
    m = manifest(out)
    assert "accept_residual" not in m["options"]  # the flag's default is not recorded (older folders keep theirs)
    (key, sentence), = m["accepted_residuals"].items()
    assert key == f"{(folder / f'run{N}').resolve()}#{N}"
    assert "truth.csv" in sentence and "gt.yaw_convention" in sentence and "nespm-data.toml" in sentence


def test_a_correct_folder_records_none(tmp_path):
    tr = embedded_track(N)
    folder = tmp_path / "ok"
    write_akit(dataclasses.replace(enu_track(), euler=tr.euler[:EPOCHS]), folder)
    spec = validate(Spec(tracks=(N,), runs=1, filters=("ekf",), data_dir=str(folder), window="0:60",
                         accept_residual=True))
    assert accepted_residuals([spec]) == {}
    assert spec.as_dict()["accept_residual"] is True and "accept_residual" not in Spec().as_dict()
    assert not any(k[0] == str(folder.resolve() / f"Trajectory{N}") for k in conventions.ACCEPTED)
