"""``nespm import``: a bag's frames cannot come in wrong silently, its topics can be listed, and the origin
can come from the first fix (issue 30, item 3), plus the import's folder defects.

* ``[frames]`` has no default: a spec without ``frames.world``/``frames.body`` is one line.
* A NED/FRD bag (``frame_id`` ``odom_ned``, ``base_link_frd``) imported as ENU/FLU is refused in one line
  naming ``frames.world`` (or ``frames.body``), the topic and the frame_id; declared NED/FRD it imports equal
  to the source (depth 10.0-11.4 m as the source, not mirrored).
* ``nespm import BAG --list``: topics, types, counts, rates and frame_ids; writes nothing.
* ``origin = "first-fix"``: the same track as the origin typed by hand.
* ``--out`` holding a track spec is refused (the spec would hide the imported TrajectoryN); an ``--overwrite``
  leaves no ``.nespm-replaced-*`` behind (a symlinked or read-only old track), and never deletes what a
  symlinked old track points to.

The bags are written with the writers of tests/test_rosbag_import.py from the same known trajectory.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm

pytest.importorskip("rosbags")
from test_rosbag_import import (ORIGIN_DEG, ORIGIN_TOML, SPEC_ROS1, SRC, Bag, Stores, _add_fix,  # noqa: E402
                                _add_imu, _gt_ros, ros1_bag)

from nespm_cli.data.tracks import load_track  # noqa: E402


class FramedBag(Bag):
    """A bag whose headers carry ``frame`` (set per message)."""

    frame = "base_link"

    def header(self, ns: int):
        h = super().header(ns)
        h.frame_id = self.frame
        return h


def ned_bag(path: Path) -> Path:
    """Odometry in NED/FRD (frame_id ``odom_ned``, child ``base_link_frd``), Imu in FRD, NavSatFix."""
    bag = FramedBag(Stores.ROS1_NOETIC)
    pos, q, v_body, _ = _gt_ros("ned", "frd")
    for k, ns in enumerate(SRC.gt_ns):
        bag.frame = "odom_ned"
        msg = bag.T["nav_msgs/msg/Odometry"](
            header=bag.header(ns), child_frame_id="base_link_frd",
            pose=bag.T["geometry_msgs/msg/PoseWithCovariance"](pose=bag.pose(pos[k], q[k]), covariance=np.zeros(36)),
            twist=bag.twist_cov(v_body[k]))
        bag.add("/odom", "nav_msgs/msg/Odometry", ns, msg)
    bag.frame = "base_link_frd"
    _add_imu(bag, "frd")
    bag.frame = "gps"
    _add_fix(bag)
    return bag.write(path)


def spec_text(world: str | None, body: str | None, origin: str = ORIGIN_TOML) -> str:
    frames = "".join(f"{k} = \"{v}\"\n" for k, v in (("world", world), ("body", body)) if v)
    return (f"track = 2\n{origin}\n" + ("[frames]\n" + frames + "\n" if frames else "")
            + '[gt]\ntopic = "/odom"\n\n[imu]\ntopic = "/imu/data"\n\n[fix]\ntopic = "/gps/fix"\n')


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("frames")
    return ned_bag(root / "ned.bag"), ros1_bag(root / "enu.bag"), root


def _spec(tmp_path: Path, text: str) -> Path:
    p = tmp_path / f"spec{abs(hash(text))}.toml"
    p.write_text(text)
    return p


def test_frames_have_no_default(bags, tmp_path):
    ned, _, _ = bags
    for world, body, key in ((None, None, "frames.world"), ("ned", None, "frames.body")):
        line = assert_one_error_line(*nespm("import", ned, "--spec", _spec(tmp_path, spec_text(world, body)), "--out",
                                            tmp_path / "out"), f"key '{key}' is missing", "no default")
        assert "spec" in line
    assert not (tmp_path / "out").exists()


def test_a_ned_bag_read_as_enu_is_refused_and_declared_ned_imports_unmirrored(bags, tmp_path):
    ned, _, _ = bags
    for world, body, key, word in (("enu", "frd", "frames.world", "'odom_ned'"),
                                   ("ned", "flu", "frames.body", "'base_link_frd'")):
        assert_one_error_line(*nespm("import", ned, "--spec", _spec(tmp_path, spec_text(world, body)), "--out",
                                     tmp_path / "out"), f"key '{key}'", "'/odom'", word, "mirrored")
    assert not (tmp_path / "out").exists()
    rc, so, se = nespm("import", ned, "--spec", _spec(tmp_path, spec_text("ned", "frd")), "--out", tmp_path / "out")
    assert rc == 0, se
    got = load_track(2, tmp_path / "out")
    np.testing.assert_allclose(got.pos[:, 2], SRC.track.pos[:, 2], atol=1e-6)  # depth as the source: not mirrored
    np.testing.assert_allclose(got.euler, SRC.track.euler, atol=1e-9)
    np.testing.assert_allclose(got.imu[:, 1:], SRC.imu[: len(got.imu)], atol=1e-9)


def test_list_shows_topics_types_counts_rates_and_frame_ids(bags, tmp_path):
    ned, _, _ = bags
    rc, so, se = nespm("import", ned, "--list")
    assert rc == 0, se
    rows = {line.split()[0]: line.split() for line in so.splitlines()[3:]}
    assert set(rows) == {"/odom", "/imu/data", "/gps/fix"} and "3 topics" in so.splitlines()[0]
    odom = rows["/odom"]
    assert odom[1] == "nav_msgs/msg/Odometry" and int(odom[2]) == len(SRC.gt_ns)
    assert abs(float(odom[3]) - (len(SRC.gt_ns) - 1) / ((SRC.gt_ns[-1] - SRC.gt_ns[0]) / 1e9)) < 1e-3
    assert odom[4:] == ["'odom_ned'", "'base_link_frd'"]
    assert rows["/imu/data"][4] == "'base_link_frd'" and abs(float(rows["/imu/data"][3]) - 100.0) < 1.0
    assert_one_error_line(*nespm("import", ned, "--list", "--out", tmp_path / "x"), "--list writes nothing")
    assert_one_error_line(*nespm("import", ned, "--out", tmp_path / "x"), "--spec is required")
    assert not (tmp_path / "x").exists()


def test_origin_from_the_first_fix(bags, tmp_path):
    _, enu, _ = bags
    typed = SPEC_ROS1
    first = SPEC_ROS1.replace(ORIGIN_TOML, 'origin = "first-fix"\n')
    assert first != typed
    for name, text in (("typed", typed), ("first", first)):
        rc, so, se = nespm("import", enu, "--spec", _spec(tmp_path, text), "--out", tmp_path / name)
        assert rc == 0, se
    a, b = load_track(3, tmp_path / "typed"), load_track(3, tmp_path / "first")
    # the horizontal from the fix (its interpolated GT position to ~1e-9 rad: 6 mm); the altitude: sea surface
    np.testing.assert_allclose(b.pos[:, :2], a.pos[:, :2], atol=2e-9)
    np.testing.assert_allclose(b.pos[:, 2] + ORIGIN_DEG[2], a.pos[:, 2], atol=1e-9)
    note = (tmp_path / "first" / "Trajectory3" / "IMPORT.md").read_text()
    assert "first fix of '/gps/fix'" in note
    no_fix = first.split("[fix]")[0]
    assert_one_error_line(*nespm("import", enu, "--spec", _spec(tmp_path, no_fix), "--out", tmp_path / "nf"),
                          "key 'origin'", "needs a [fix] table")


def test_out_holding_a_track_spec_is_refused(bags, tmp_path):
    _, enu, _ = bags
    out = tmp_path / "data"
    out.mkdir()
    (out / "nespm-data.toml").write_text("[gt]\n")
    assert_one_error_line(*nespm("import", enu, "--spec", _spec(tmp_path, SPEC_ROS1), "--out", out),
                          f"--out {out}", "holds a track spec", "hidden")
    assert sorted(p.name for p in out.iterdir()) == ["nespm-data.toml"]


def test_overwrite_leaves_no_replaced_folder(bags, tmp_path):
    _, enu, _ = bags
    spec = _spec(tmp_path, SPEC_ROS1)
    out = tmp_path / "out"
    assert nespm("import", enu, "--spec", spec, "--out", out)[0] == 0
    # the old track read-only (files and folder)
    tdir = out / "Trajectory3"
    for p in tdir.iterdir():
        p.chmod(stat.S_IRUSR)
    tdir.chmod(stat.S_IRUSR | stat.S_IXUSR)
    rc, so, se = nespm("import", enu, "--spec", spec, "--out", out, "--overwrite")
    assert rc == 0, se
    assert sorted(p.name for p in out.iterdir()) == ["Trajectory3"]
    # the old track a symlink to a folder elsewhere: the link is replaced, its target kept as it was
    elsewhere = tmp_path / "elsewhere"
    (tdir).rename(elsewhere)
    os.symlink(elsewhere, out / "Trajectory3")
    before = sorted(p.name for p in elsewhere.iterdir())
    rc, so, se = nespm("import", enu, "--spec", spec, "--out", out, "--overwrite")
    assert rc == 0, se
    assert sorted(p.name for p in out.iterdir()) == ["Trajectory3"] and not (out / "Trajectory3").is_symlink()
    assert sorted(p.name for p in elsewhere.iterdir()) == before


def test_a_bag_imu_in_deg_per_s_is_refused_naming_the_topic(tmp_path, monkeypatch):
    import test_rosbag_import as src

    imu = src.SRC.imu.copy()
    imu[:, 3:] = np.degrees(imu[:, 3:])  # a driver publishing deg/s in sensor_msgs/Imu
    monkeypatch.setattr(src.SRC, "imu", imu)
    bag = ned_bag(tmp_path / "deg.bag")
    line = assert_one_error_line(*nespm("import", bag, "--spec", _spec(tmp_path, spec_text("ned", "frd")), "--out",
                                        tmp_path / "out"), "IMU_trajectory2.csv", "a gyro in deg/s read as rad/s",
                                 "spec key imu.topic", "nothing written")
    assert str(tmp_path / "out" / "Trajectory2") in line and not (tmp_path / "out").exists()


def neutral_frd_bag(path: Path) -> Path:
    """The NED/FRD bag of :func:`ned_bag` with frame_ids that name no frame (``odom``, ``base_link``)."""
    bag = FramedBag(Stores.ROS1_NOETIC)
    pos, q, v_body, _ = _gt_ros("ned", "frd")
    for k, ns in enumerate(SRC.gt_ns):
        bag.frame = "odom"
        msg = bag.T["nav_msgs/msg/Odometry"](
            header=bag.header(ns), child_frame_id="base_link",
            pose=bag.T["geometry_msgs/msg/PoseWithCovariance"](pose=bag.pose(pos[k], q[k]), covariance=np.zeros(36)),
            twist=bag.twist_cov(v_body[k]))
        bag.add("/odom", "nav_msgs/msg/Odometry", ns, msg)
    bag.frame = "base_link"
    _add_imu(bag, "frd")
    bag.frame = "gps"
    _add_fix(bag)
    return bag.write(path)


@pytest.mark.parametrize("which, world, body", [("flu", "enu", "frd"), ("frd", "ned", "flu")])
def test_a_body_frame_declared_wrong_is_refused_upside_down(bags, tmp_path, which, world, body):
    """Issue 39: a FLU body declared FRD (and the reverse) with frame_ids that do not say imported the vehicle
    upside down (roll +-178 deg) without a word; now one line naming frames.body, nothing written."""
    bag = bags[1] if which == "flu" else neutral_frd_bag(tmp_path / "frd.bag")
    line = assert_one_error_line(*nespm("import", bag, "--spec", _spec(tmp_path, spec_text(world, body)), "--out",
                                        tmp_path / "out"), "beyond 90 deg", "upside down", "key 'frames.body'")
    assert "nothing written" in line
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    rc, so, se = nespm("import", bag, "--spec", _spec(tmp_path, spec_text(world, which)), "--out", tmp_path / "ok")
    assert rc == 0, se
    np.testing.assert_allclose(load_track(2, tmp_path / "ok").euler, SRC.track.euler, atol=1e-9)
