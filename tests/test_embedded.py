"""Tests of nespm_cli.data.embedded: the deterministic Snapir-like tracks used without a data folder."""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.data import embedded
from nespm_cli.nav.earth import radii
from nespm_cli.data.embedded import EMBEDDED_TRACKS, L_DVL, embedded_track
from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import body_rate_from_attitude
from nespm_cli.data.tracks import ENV_DATA_DIR, dvl_lever_arm_fit, load_track, track_summary

ALL = pytest.mark.parametrize("number", EMBEDDED_TRACKS)
FIELDS = ("t", "pos", "v_n", "euler", "dvl")


def _yaw_rate_dps(tr) -> np.ndarray:
    return np.degrees(np.diff(np.unwrap(tr.euler[:, 2])) / np.diff(tr.t))


def test_numbers() -> None:
    assert EMBEDDED_TRACKS == (1, 2, 3, 4, 5, 6)
    with pytest.raises(NespmError) as e:
        embedded_track(7)
    msg = str(e.value)
    assert "\n" not in msg and "embedded" in msg and "no track 7" in msg


@ALL
def test_deterministic_and_read_only(number: int) -> None:
    a = embedded_track(number)
    copies = {f: np.array(getattr(a, f)) for f in FIELDS}
    assert embedded_track(number) is a  # cached
    embedded_track.cache_clear()
    b = embedded_track(number)
    assert b is not a
    for f in FIELDS:
        assert getattr(b, f).tobytes() == copies[f].tobytes(), f  # bit for bit
        assert not getattr(b, f).flags.writeable
    assert b.source == "embedded" and b.number == number and b.imu is None


def test_default_load_is_embedded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ENV_DATA_DIR, raising=False)
    assert load_track(4) is embedded_track(4)


@ALL
def test_time_grid(number: int) -> None:
    tr = embedded_track(number)
    np.testing.assert_array_equal(tr.t, np.arange(400) * (400 / 399))
    assert tr.duration == pytest.approx(400.0, abs=1e-9)


@ALL
def test_ranges(number: int) -> None:
    tr = embedded_track(number)
    speed = np.linalg.norm(tr.v_n, axis=1)
    assert 1.4 <= speed.min() and speed.max() <= 2.4
    depth = -tr.pos[:, 2]
    assert 4.0 <= depth.min() and depth.max() <= 36.0
    assert np.all((tr.euler[:, 2] > -np.pi) & (tr.euler[:, 2] <= np.pi))
    assert np.abs(np.degrees(tr.euler[:, :2])).max() < 12.0  # small roll and pitch
    assert 8.0 <= np.abs(_yaw_rate_dps(tr)).max() <= 18.0
    lat, lon = np.degrees(tr.pos[0, :2])
    assert abs(lat - 32.84) < 0.05 and abs(lon - 34.93) < 0.05


def test_track_character() -> None:
    """Tracks 1, 2 turn most, 3, 4 least (long straight legs), 5, 6 in between."""
    turning = {n: int(np.sum(np.abs(_yaw_rate_dps(embedded_track(n))) > 5.0)) for n in EMBEDDED_TRACKS}
    assert min(turning[1], turning[2]) > max(turning[5], turning[6]) > 0
    assert min(turning[5], turning[6]) > max(turning[3], turning[4]) > 0
    for n in (3, 4):  # a straight leg of at least 100 s
        quiet = np.abs(_yaw_rate_dps(embedded_track(n))) < 0.5
        longest = max(len(run) for run in "".join("1" if q else "0" for q in quiet).split("0"))
        assert longest >= 100


def test_scale_like_real_tracks(real_data_dir) -> None:
    """Like-for-like with the real track 5 (conftest.real_data_dir: skipped without the real data)."""
    real = track_summary(load_track(5, real_data_dir))
    for n in EMBEDDED_TRACKS:
        s = track_summary(embedded_track(n))
        assert 0.75 * real["distance_m"] < s["distance_m"] < 1.25 * real["distance_m"]


@ALL
def test_velocity_consistent_with_position(number: int) -> None:
    tr = embedded_track(number)
    lat, lon, h = tr.pos.T
    lat_m, h_m = 0.5 * (lat[1:] + lat[:-1]), 0.5 * (h[1:] + h[:-1])
    R_N, R_E = radii(lat_m)
    dt = np.diff(tr.t)
    v_fd = np.stack(
        [np.diff(lat) * (R_N + h_m) / dt, np.diff(lon) * (R_E + h_m) * np.cos(lat_m) / dt, -np.diff(h) / dt],
        axis=-1,
    )
    v_mid = 0.5 * (tr.v_n[1:] + tr.v_n[:-1])
    assert np.abs(v_fd - v_mid).max() < 0.02


@ALL
def test_depth_is_integral_of_v_down(number: int) -> None:
    tr = embedded_track(number)
    depth = -tr.pos[:, 2]
    vd = tr.v_n[:, 2]
    integral = depth[0] + np.concatenate([[0.0], np.cumsum(0.5 * (vd[1:] + vd[:-1]) * np.diff(tr.t))])
    assert np.abs(integral - depth).max() < 0.03


@ALL
def test_attitude_consistent_with_velocity(number: int) -> None:
    """Body velocity: forward, with a few degrees of sideslip and angle of attack at most."""
    tr = embedded_track(number)
    v_b = np.einsum("nji,nj->ni", tr.C_bn, tr.v_n)
    assert np.all(v_b[:, 0] > 1.4)
    assert np.degrees(np.abs(np.arctan2(v_b[:, 1], v_b[:, 0]))).max() < 5.0
    assert np.degrees(np.abs(np.arctan2(v_b[:, 2], v_b[:, 0]))).max() < 3.0
    # pitch follows the climb: nose up while the depth decreases
    climbing = tr.v_n[:, 2] < -0.15
    if climbing.any():
        assert np.all(tr.euler[climbing, 1] > 0)


@ALL
def test_dvl_noise_level(number: int) -> None:
    tr = embedded_track(number)
    C = tr.C_bn
    w = body_rate_from_attitude(tr.t, C)
    resid = tr.dvl - np.einsum("nji,nj->ni", C, tr.v_n) - np.cross(w, L_DVL)
    std = resid.std(axis=0)
    assert np.all((std >= 0.015) & (std <= 0.03)), std
    assert np.abs(resid.mean(axis=0)).max() < 0.006


@ALL
def test_lever_arm_recovered(number: int) -> None:
    lever, _ = dvl_lever_arm_fit(embedded_track(number))
    np.testing.assert_allclose(lever, [-1.6, 0.0, 0.0], atol=0.3)


def test_body_rate_matches_attitude() -> None:
    """The analytic body rate used for the DVL agrees with the finite-difference one."""
    tr = embedded_track(1)
    k = embedded._kinematics(embedded._SPECS[1], np.asarray(tr.t))
    w_fd = body_rate_from_attitude(tr.t, tr.C_bn)
    assert np.abs(k["w_b"][1:-1] - w_fd[1:-1]).max() < 3e-3


def test_embedded_tracks_read_back_from_the_user_cache_are_the_same_bits(tmp_path, monkeypatch):
    """The first process builds a track and keeps its arrays in the per-user cache; the next reads
    them: the same bits as a build. A truncated cache file and an unwritable folder only mean a build."""
    from nespm_cli.data import embedded, embedded_cache

    monkeypatch.setenv("NESPM_CACHE_DIR", str(tmp_path / "cache"))
    built = embedded.build_arrays(5)
    path = embedded_cache.cache_file(5)
    assert not path.exists() and embedded_cache.load(5) is None
    embedded.embedded_track.cache_clear()
    try:
        tr = embedded.embedded_track(5)
        assert path.exists()
        for k in embedded_cache.ARRAYS:
            assert getattr(tr, k).tobytes() == built[k].tobytes(), k
        back = embedded_cache.load(5)
        assert all(back[k].tobytes() == built[k].tobytes() and back[k].dtype == built[k].dtype for k in built)
        path.write_bytes(path.read_bytes()[:100])  # truncated: a miss, rebuilt and rewritten
        assert embedded_cache.load(5) is None
        embedded.embedded_track.cache_clear()
        assert embedded.embedded_track(5).pos.tobytes() == built["pos"].tobytes()
        assert embedded_cache.load(5) is not None
        blocker = tmp_path / "file"
        blocker.write_text("not a folder")
        monkeypatch.setenv("NESPM_CACHE_DIR", str(blocker / "cache"))
        embedded.embedded_track.cache_clear()
        assert embedded.embedded_track(5).dvl.tobytes() == built["dvl"].tobytes()
    finally:
        embedded.embedded_track.cache_clear()
