"""Inputs that used to be silently misread: ``simulate --out`` onto existing tracks, track folders
with leading zeros, corrections files with booleans / duplicate or foreign keys / missing tracks,
and ProcessNet weights that are NaN, pinned at the clip or of the wrong shape. Each ends in one
line (exit 2) naming the file, and nothing is written.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from nespm_cli.data.corrections import read_corrections, resolve
from nespm_cli.data.tracks import available_tracks, load_track, track_files, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.learn.noise_model import check_weights, default_weights, load_weights, reference_windows
from nespm_cli.learn.processnet import VALIDITY_CLIP, load_nets, save_nets
from nespm_cli.vehicles.simulate import MARKER

from conftest import assert_one_error_line, nespm, short_track, write_short_tracks

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


# ----------------------------------------------------------------------------- 1. simulate --out


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_simulate_refuses_a_folder_with_real_tracks(tmp_path):
    d = write_short_tracks(tmp_path / "data", numbers=(5,), epochs=31)
    before = _files(d)
    assert sorted(before) == ["Trajectory5/DVL_trajectory5.csv", "Trajectory5/GT_trajectory5.csv"]
    for first in ("5", "7"):  # the same track number, or another one: the folder is not simulate's
        rc, out, err = nespm("simulate", "--runs", "1", "--duration", "20", "--first-number", first, "--out", d)
        assert_one_error_line(rc, out, err, str(d), "Trajectory5", "nothing was written", MARKER)
    assert _files(d) == before  # GT bytes unchanged, no marker, no Trajectory7
    assert sorted(p.name for p in d.iterdir()) == ["Trajectory5"]


def test_simulate_twice_into_one_folder_rewrites_the_same_tracks(tmp_path):
    d = tmp_path / "sim"
    argv = ("simulate", "--runs", "1", "--duration", "20", "--first-number", "5", "--seed", "3", "--out", d)
    rc, out, err = nespm(*argv)
    assert rc == 0, err
    first = _files(d)
    assert sorted(first) == [MARKER, "Trajectory5/DVL_trajectory5.csv", "Trajectory5/GT_trajectory5.csv",
                             "Trajectory5/IMU_trajectory5.csv"]
    marker = json.loads(first[MARKER])
    assert marker["tracks"] == [5] and marker["folders"] == ["Trajectory5"]
    o = marker["options"]
    assert (o["runs"], o["duration_s"], o["seed"], o["first_number"], o["dvl"]) == (1, 20.0, 3, 5, "measured")
    assert load_track(5, d).t[-1] == 20.0
    rc, out, err = nespm(*argv)
    assert rc == 0, err
    assert _files(d) == first  # same options, same bytes
    # other options into the same folder: refused, naming the option that differs
    rc, out, err = nespm("simulate", "--runs", "1", "--duration", "20", "--first-number", "5", "--out", d)
    assert_one_error_line(rc, out, err, str(d), "Trajectory5", "seed 3, not 0", "nothing was written")
    assert _files(d) == first


def test_simulate_refuses_a_track_folder_added_to_its_own_folder(tmp_path):
    d = tmp_path / "sim"
    argv = ("simulate", "--runs", "1", "--duration", "20", "--out", d)
    assert nespm(*argv)[0] == 0
    write_akit(dataclasses.replace(short_track(5), number=5), d)
    (d / "Trajectory5").rename(d / "Trajectory05")
    before = _files(d)
    rc, out, err = nespm(*argv)
    assert_one_error_line(rc, out, err, "Trajectory05", "does not list it")
    assert _files(d) == before
    shutil.rmtree(d / "Trajectory05")
    (d / MARKER).write_text("{not json")  # a damaged marker vouches for nothing: refused too
    rc, out, err = nespm(*argv)
    assert_one_error_line(rc, out, err, "Trajectory1", "unreadable")


# ----------------------------------------------------------------------------- 2. leading zeros


def _zero_padded(folder: Path, number: int = 7, dir_digits: str = "07", file_digits: str = "07") -> Path:
    """Embedded track 5 cut to 31 epochs, written as track ``number`` under zero-padded names."""
    tdir = write_akit(dataclasses.replace(short_track(5), number=number), folder)
    new = folder / f"Trajectory{dir_digits}"
    tdir.rename(new)
    for kind in ("GT", "DVL"):
        (new / f"{kind}_trajectory{number}.csv").rename(new / f"{kind}_trajectory{file_digits}.csv")
    return new


@pytest.mark.parametrize("file_digits", ["07", "7"])
def test_track_folder_with_leading_zeros_loads(tmp_path, file_digits):
    d = tmp_path / "data"
    tdir = _zero_padded(d, file_digits=file_digits)
    assert available_tracks(d) == [7]
    tr = load_track(7, d)
    ref = short_track(5)
    assert tr.number == 7 and len(tr.t) == 31 and tr.source == str(tdir)
    np.testing.assert_array_equal(tr.pos, ref.pos)
    np.testing.assert_array_equal(tr.dvl, ref.dvl)
    assert track_files(7, d) == [tdir / f"GT_trajectory{file_digits}.csv", tdir / f"DVL_trajectory{file_digits}.csv"]
    assert track_files(7, str(d), True)[2] == tdir / "IMU_trajectory07.csv"  # not there: the folder's spelling
    assert track_files(7, None) == []
    rc, out, err = nespm("tracks", "--data-dir", d, "--no-progress")
    assert rc == 0, err
    row = next(line for line in out.splitlines() if line.strip().strip("│┃|").strip().startswith("7 "))
    assert f" {tr.duration:.1f} " in row and " 31 " in row and "30.1" in row  # duration [s], epochs


def test_two_folders_of_one_track_are_refused(tmp_path):
    d = tmp_path / "data"
    _zero_padded(d)
    write_akit(dataclasses.replace(short_track(6), number=7), d)  # Trajectory7 beside Trajectory07
    rc, out, err = nespm("tracks", "--data-dir", d, "--no-progress")
    assert_one_error_line(rc, out, err, str(d), "Trajectory07 and Trajectory7 are both track 7")
    with pytest.raises(NespmError, match="both track 7"):
        load_track(7, d)
    with pytest.raises(NespmError, match="both track 7"):
        track_files(7, d)


def test_two_gt_files_of_one_track_are_refused(tmp_path):
    d = tmp_path / "data"
    tdir = _zero_padded(d)
    (tdir / "GT_trajectory7.csv").write_bytes((tdir / "GT_trajectory07.csv").read_bytes())
    rc, out, err = nespm("tracks", "--data-dir", d, "--no-progress")
    assert_one_error_line(rc, out, err, str(tdir), "GT_trajectory07.csv and GT_trajectory7.csv")


def test_missing_file_keeps_its_message(tmp_path):
    d = write_short_tracks(tmp_path / "data", numbers=(5,), epochs=31)
    (d / "Trajectory5" / "DVL_trajectory5.csv").unlink()
    with pytest.raises(NespmError, match=r"Trajectory5/DVL_trajectory5\.csv: file not found"):
        load_track(5, d)
    with pytest.raises(NespmError, match=r"no track 6 \(available: 5\)"):
        load_track(6, d)


# ----------------------------------------------------------------------------- 3. corrections files


@pytest.mark.parametrize("text,must", [
    ('{"tracks": {"5": {"dvl_time_offset": true}}}', ["track 5", "'dvl_time_offset'", "boolean true"]),
    ('{"tracks": {"5": {"imu_time_offset": "0.5"}}}', ["track 5", "'imu_time_offset'", "string '0.5'"]),
    ('{"tracks": {"5": {"imu_time_drift": null}}}', ["track 5", "'imu_time_drift'", "null"]),
    ('{"tracks": {"5": {"window": [true, 300]}}}', ["track 5", "'window'", "boolean true"]),
    ('{"tracks": {"5": {"window": "20:300"}}}', ["track 5", "'window'", "string"]),
    ('{"tracks": {"5": {"imu_axes": ["x", "y", "z"]}}}', ["track 5", "'imu_axes'", "a list of 3"]),
    ('{"tracks": {"5": {"dvl_time_offset": 1' + "0" * 400 + '}}}', ["track 5", "out of range"]),
    ('{"tracks": {"5": {}, "05": {"dvl_time_offset": 0.5}}}', ["'5' and '05' are both track 5"]),
    ('{"tracks": {"5": {}, "5": {}}}', ["key '5' appears twice"]),
    ('{"tracks": {"5": {"dvl_time_offset": 0.1, "dvl_time_offset": 0.2}}}', ["'dvl_time_offset' appears twice"]),
    ('{"tracks": {"\u00b2": {}}}', ["'\u00b2'", "not a track number"]),
    ('{"tracks": {"five": {}}}', ["'five'", "not a track number"]),
    ('{"tracks": {"5": 1}}', ["track 5", "expected an object"]),
    ("[" * 100_000 + "]" * 100_000, ["nested too deeply"]),
    ('{"tracks": {"6": {"dvl_time_offset": 0.5}, "7": {}}}', ["no entry for track 5", "tracks: 6, 7"]),
])
def test_bad_corrections_file_is_one_line(tmp_path, text, must):
    p = tmp_path / "corrections.json"
    p.write_text(text, encoding="utf-8")
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--filters", "ekf", "--corrections", p,
                         "--out", tmp_path / "r")
    assert_one_error_line(rc, out, err, f"--corrections {p}", *must)
    assert not (tmp_path / "r" / "metrics.parquet").exists()


def test_corrections_file_not_utf8_is_one_line(tmp_path):
    p = tmp_path / "corrections.json"
    p.write_bytes(b'{"tracks": {"5": {"imu_axes": "x,\xff,z"}}}')
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--corrections", p, "--out", tmp_path / "r")
    assert_one_error_line(rc, out, err, str(p), "not UTF-8", "byte 33")


def test_missing_track_is_refused_for_every_caller(tmp_path):
    p = tmp_path / "corrections.json"
    p.write_text('{"tracks": {"5": {"dvl_time_offset": 0.5}}}')
    rc, out, err = nespm("train", "--tracks", "1", "--test-tracks", "5", "--runs", "1", "--epochs", "1",
                         "--corrections", p, "--out", tmp_path / "w.npz", "--no-progress")
    assert_one_error_line(rc, out, err, str(p), "no entry for track 1", "tracks: 5")
    assert not (tmp_path / "w.npz").exists()
    rc, out, err = nespm("run", "--track", "6", "--filter", "ekf", "--corrections", p, "--json")
    assert_one_error_line(rc, out, err, str(p), "no entry for track 6")
    with pytest.raises(NespmError, match="no entry for track 6"):
        resolve([5, 6], "synthetic", str(p))
    # the track it has: read as numbers, not silently replaced
    got = resolve([5], "synthetic", str(p))
    assert got[5].dvl_time_offset == 0.5 and got[5].window is None
    assert resolve([5, 6], "synthetic")[6].dvl_time_offset == 0.0  # no file: no corrections, no error


def test_good_corrections_file_reads_exact_values(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"tracks": {"05": {"imu_axes": "x,-y,z", "imu_time_offset": -0.25, "imu_time_drift": 0,
                                               "window": [20, 300.5]}, "6": {}}}))
    c = read_corrections(p)
    assert sorted(c) == [5, 6]
    assert (c[5].imu_axes, c[5].imu_time_offset, c[5].imu_time_drift, c[5].window) == ("x,-y,z", -0.25, 0.0,
                                                                                       (20.0, 300.5))
    assert c[6].is_identity


# ----------------------------------------------------------------------------- 4. ProcessNet weights


def _weights(tmp_path: Path, name: str, edit) -> Path:
    """The packaged weights with ``edit(nets)`` applied, saved as ``tmp_path/name``."""
    nets, meta = load_nets(default_weights())
    edit(nets)
    return save_nets(tmp_path / name, nets, meta)


def test_nan_weights_are_refused_before_anything_is_written(tmp_path, short_data_dir):
    def nan(nets):
        nets["acc"].params["W3"][0, 0, 0] = np.nan

    f = _weights(tmp_path, "nan.npz", nan)
    out = tmp_path / "mc"
    rc, so, err = nespm("mc", "--filters", "anekf", "--tracks", "5", "--runs", "1", "--weights", f,
                        "--data-dir", short_data_dir, "--out", out, "--no-progress")
    assert_one_error_line(rc, so, err, f"--weights {f}", "acc network", "W3", "1 non-finite value")
    assert not out.exists() or not any(out.rglob("*.parquet"))


@pytest.mark.parametrize("sensor,scale,shift,must", [
    ("gyro", 1000.0, 0.0, "at or beyond the validity clip"),  # every output far above 24 x nominal
    ("acc", 0.0, -5.0, "120 of 120 outputs are <= 0"),  # every output negative: one rule with q_scale <= 0
    ("acc", 0.0, 3.0, "does not read the noise level"),  # a constant 3 x nominal
])
def test_weights_that_cannot_adapt_are_refused(tmp_path, sensor, scale, shift, must):
    def edit(nets):
        p = nets[sensor].params
        p["W5"] *= scale
        p["b5"] = p["b5"] * scale + shift

    f = _weights(tmp_path, f"{sensor}-{scale}-{shift}.npz", edit)
    with pytest.raises(NespmError, match=f"{sensor} network") as e:
        load_weights(str(f))
    assert str(f) in str(e.value) and must in str(e.value)
    rc, so, err = nespm("run", "--track", "5", "--filter", "anukf", "--weights", f, "--json")
    assert_one_error_line(rc, so, err, str(f), must)


def test_wrong_shape_names_the_file(tmp_path, short_data_dir):
    with np.load(default_weights(), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["gyro/W2"] = arrays["gyro/W2"][:, :, :29]
    f = tmp_path / "shape.npz"
    np.savez(f, **arrays)
    rc, so, err = nespm("mc", "--filters", "anukf", "--tracks", "5", "--runs", "1", "--weights", f,
                        "--data-dir", short_data_dir, "--out", tmp_path / "mc", "--no-progress")
    assert_one_error_line(rc, so, err, f"--weights {f}", "gyro/W2", "(3, 30, 29)", "(3, 30, 30)")


def test_packaged_and_freshly_trained_weights_pass(tmp_path):
    acc, gyro, meta = load_weights(None)
    assert load_weights(None)[0] is acc  # cached: checked once per process
    f, w = reference_windows()
    assert f.shape == w.shape == (2, 20, 100, 3)
    from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

    for net, x, nominal in ((acc, f, NOMINAL_ACC_NOISE), (gyro, w, NOMINAL_GYRO_NOISE)):
        p = net.predict_std(x.reshape(-1, 100, 3)).reshape(2, 20, 3) / nominal
        assert p[0].mean() == pytest.approx(1.0, abs=0.1) and p[1].mean() == pytest.approx(4.0, abs=0.3)
        assert VALIDITY_CLIP[0] < p.min() and p.max() < VALIDITY_CLIP[1]
    out = tmp_path / "w.npz"
    rc, so, err = nespm("train", "--tracks", "1", "--test-tracks", "5", "--runs", "2", "--epochs", "1",
                        "--out", out, "--no-progress")
    assert rc == 0, err
    a2, g2, _ = load_weights(str(out))
    check_weights(a2, g2, "again")  # no exception: the weak network still reads the level
