"""``nespm import``: ROS 1 and ROS 2 bags (written here with rosbags' writers from a known trajectory)
imported into an A-KIT track folder whose channels equal the source after the frame conversions.

The source is the first ``EPOCHS`` epochs of embedded track 1 with its exact 100 Hz IMU, written in ROS
conventions (REP-103: ENU world, FLU body; or NED/FRD where a bag says so); the expected values are the
track's own arrays in the bench's frames, so the test checks the importer against the bench, not
against itself. Three bags: ROS 1 (Odometry, Imu, TwistWithCovarianceStamped DVL on the GT epochs,
FluidPressure, 2-D NavSatFix); ROS 2 sqlite3 (Odometry, Imu, a custom DVL message with a valid flag at
its own stamps, a std_msgs/Float64 depth at bag time, 3-D NavSatFix); ROS 2 mcap (PoseStamped +
TwistStamped in NED/FRD, world-frame twist, tangent-plane origin, TwistWithCovarianceStamped DVL).
"""
from __future__ import annotations

import hashlib
import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_one_error_line, exact_imu_table, nespm, short_track

from nespm_cli.data.tracks import load_track
from nespm_cli.nav.earth import A, E2, ned_offset

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

EPOCHS = 60
BASE_NS = 1_700_000_000 * 10**9  # a Unix time: the bag's stamps are absolute
NS = 10**9
ORIGIN_DEG = (32.84, 34.95, 1.5)  # lat, lon [deg], alt [m] of the local frame
W = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # ENU <-> NED
B = np.diag([1.0, -1.0, -1.0])  # FLU <-> FRD
RHO, P_ATM, G = 1027.5, 101000.0, 9.81
DVL_MSG = "std_msgs/Header header\ngeometry_msgs/Vector3 velocity\nbool velocity_valid\n"
MAXDIFF: dict[str, float] = {}


def _origin() -> np.ndarray:
    return np.array([np.radians(ORIGIN_DEG[0]), np.radians(ORIGIN_DEG[1]), ORIGIN_DEG[2]])


def _tangent_ned(pos: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """NED [m] of geodetic ``pos`` in the WGS-84 tangent plane at ``origin`` (the test's own conversion)."""
    def ecef(p):
        lat, lon, h = p[..., 0], p[..., 1], p[..., 2]
        n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
        return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                         (n * (1 - E2) + h) * np.sin(lat)], -1)
    la, lo = origin[0], origin[1]
    north = [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)]
    east = [-np.sin(lo), np.cos(lo), 0.0]
    down = [-np.cos(la) * np.cos(lo), -np.cos(la) * np.sin(lo), -np.sin(la)]
    return (ecef(pos) - ecef(origin)) @ np.array([north, east, down]).T


class Source:
    """The known trajectory and the sensor samples the bags carry, in the bench's frames and units."""

    def __init__(self):
        tr = short_track(1, EPOCHS)
        self.track = tr
        self.gt_ns = BASE_NS + np.round(tr.t * NS).astype(np.int64)  # stamps: the times rounded to ns
        imu = exact_imu_table(tr)
        self.imu_ns = BASE_NS + np.round(imu[:, 0] * NS).astype(np.int64)
        self.imu_t = imu[:, 0]
        self.imu = imu[:, 1:]
        # DVL at its own stamps (every 0.5 s, off the epochs), valid flag false on every 7th
        t_dvl = np.arange(0.25, tr.t[-1], 0.5)
        self.dvl_ns = BASE_NS + np.round(t_dvl * NS).astype(np.int64)
        self.dvl_t = t_dvl
        self.dvl = np.column_stack([np.interp(t_dvl, tr.t, tr.dvl[:, i]) for i in range(3)])
        self.dvl_valid = np.arange(len(t_dvl)) % 7 != 3
        # depth every 0.5 s, one sample before the GT span (left out by the import)
        t_depth = np.arange(-0.5, tr.t[-1], 0.5)
        self.depth_ns = BASE_NS + np.round(t_depth * NS).astype(np.int64)
        self.depth_t = t_depth
        self.depth = np.interp(t_depth, tr.t, -tr.pos[:, 2]) + 0.01 * np.sin(t_depth)
        # fixes every 10 s, the second one without a fix
        t_fix = np.arange(5.0, tr.t[-1], 10.0)
        self.fix_ns = BASE_NS + np.round(t_fix * NS).astype(np.int64)
        self.fix_t = t_fix
        self.fix = np.column_stack([np.interp(t_fix, tr.t, tr.pos[:, i]) for i in range(3)])
        self.fix_ok = np.arange(len(t_fix)) != 1


SRC = Source()


# --------------------------------------------------------------------------- writing bags


class Bag:
    """Messages of one bag: collected, then written in time order by rosbags' writer."""

    def __init__(self, store):
        self.ts = get_typestore(store)
        self.ts.register(get_types_from_msg(DVL_MSG, "nespm_test/msg/Dvl"))
        self.T = self.ts.types
        self.ros1 = store == Stores.ROS1_NOETIC
        self.items: list[tuple[int, str, str, object]] = []

    def header(self, ns: int):
        stamp = self.T["builtin_interfaces/msg/Time"](sec=int(ns) // NS, nanosec=int(ns) % NS)
        extra = {"seq": 0} if self.ros1 else {}
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id="base_link", **extra)

    def vec(self, v):
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def point(self, v):
        return self.T["geometry_msgs/msg/Point"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q):
        return self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def add(self, topic: str, msgtype: str, ns: int, msg) -> None:
        self.items.append((int(ns), topic, msgtype, msg))

    def pose(self, p, q):
        return self.T["geometry_msgs/msg/Pose"](position=self.point(p), orientation=self.quat(q))

    def twist(self, v):
        return self.T["geometry_msgs/msg/Twist"](linear=self.vec(v), angular=self.vec((0, 0, 0)))

    def twist_cov(self, v):
        return self.T["geometry_msgs/msg/TwistWithCovariance"](twist=self.twist(v), covariance=np.zeros(36))

    def write(self, path: Path, plugin=None) -> Path:
        items = sorted(self.items, key=lambda x: x[0])
        if self.ros1:
            writer = Writer1(path)
        else:
            writer = Writer2(path, version=9, storage_plugin=plugin)
        with writer:
            conns = {}
            for ns, topic, msgtype, msg in items:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=self.ts)
                data = (self.ts.serialize_ros1 if self.ros1 else self.ts.serialize_cdr)(msg, msgtype)
                writer.write(conns[topic], ns, data)
        return path


def _gt_ros(world: str, body: str, tangent: bool = False):
    """Local positions [m], quaternions [x, y, z, w] and body velocity of the source GT in ROS frames."""
    tr = SRC.track
    ned = _tangent_ned(tr.pos, _origin()) if tangent else ned_offset(tr.pos, _origin())
    Wm = W if world == "enu" else np.eye(3)
    Bm = B if body == "flu" else np.eye(3)
    R = Wm @ tr.C_bn @ Bm  # body (ROS axes) -> world
    q = Rotation.from_matrix(R).as_quat()  # scalar last, as ROS
    v_body = (Bm @ np.swapaxes(tr.C_bn, -1, -2) @ tr.v_n[..., None])[..., 0]
    return ned @ Wm.T, q, v_body, (tr.v_n @ Wm.T)


def _add_imu(bag: Bag, body: str, duplicate: bool = False) -> None:
    Bm = B if body == "flu" else np.eye(3)
    T = bag.T
    for k, ns in enumerate(SRC.imu_ns):
        f, w = Bm @ SRC.imu[k, :3], Bm @ SRC.imu[k, 3:]
        msg = T["sensor_msgs/msg/Imu"](header=bag.header(ns), orientation=bag.quat((0, 0, 0, 1)),
                                       orientation_covariance=np.zeros(9), angular_velocity=bag.vec(w),
                                       angular_velocity_covariance=np.zeros(9), linear_acceleration=bag.vec(f),
                                       linear_acceleration_covariance=np.zeros(9))
        bag.add("/imu/data", "sensor_msgs/msg/Imu", ns, msg)
        if duplicate and k == 10:  # a second message with the same stamp: the first is kept
            bag.add("/imu/data", "sensor_msgs/msg/Imu", ns, T["sensor_msgs/msg/Imu"](
                header=bag.header(ns), orientation=bag.quat((0, 0, 0, 1)), orientation_covariance=np.zeros(9),
                angular_velocity=bag.vec((9, 9, 9)), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=bag.vec((9, 9, 9)), linear_acceleration_covariance=np.zeros(9)))


def _add_pressure(bag: Bag) -> None:
    for ns, d in zip(SRC.depth_ns, SRC.depth):
        msg = bag.T["sensor_msgs/msg/FluidPressure"](header=bag.header(ns), fluid_pressure=P_ATM + RHO * G * d,
                                                     variance=0.0)
        bag.add("/pressure", "sensor_msgs/msg/FluidPressure", ns, msg)


def _add_fix(bag: Bag) -> None:
    T = bag.T
    for ns, p, ok in zip(SRC.fix_ns, SRC.fix, SRC.fix_ok):
        status = T["sensor_msgs/msg/NavSatStatus"](status=0 if ok else -1, service=1)
        msg = T["sensor_msgs/msg/NavSatFix"](header=bag.header(ns), status=status, latitude=float(np.degrees(p[0])),
                                             longitude=float(np.degrees(p[1])), altitude=float(p[2]),
                                             position_covariance=np.zeros(9), position_covariance_type=0)
        bag.add("/gps/fix", "sensor_msgs/msg/NavSatFix", ns, msg)


def _add_odometry(bag: Bag) -> None:
    pos, q, v_body, _ = _gt_ros("enu", "flu")
    for k, ns in enumerate(SRC.gt_ns):
        msg = bag.T["nav_msgs/msg/Odometry"](
            header=bag.header(ns), child_frame_id="base_link",
            pose=bag.T["geometry_msgs/msg/PoseWithCovariance"](pose=bag.pose(pos[k], q[k]), covariance=np.zeros(36)),
            twist=bag.twist_cov(v_body[k]))
        bag.add("/odom", "nav_msgs/msg/Odometry", ns, msg)


def ros1_bag(path: Path) -> Path:
    """Odometry, Imu (one duplicate stamp), DVL TwistWithCovarianceStamped on the GT epochs, FluidPressure,
    NavSatFix; REP-103 frames."""
    bag = Bag(Stores.ROS1_NOETIC)
    _add_odometry(bag)
    _add_imu(bag, "flu", duplicate=True)
    for ns, v in zip(SRC.gt_ns, SRC.track.dvl):
        msg = bag.T["geometry_msgs/msg/TwistWithCovarianceStamped"](header=bag.header(ns), twist=bag.twist_cov(B @ v))
        bag.add("/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", ns, msg)
    _add_pressure(bag)
    _add_fix(bag)
    return bag.write(path)


def ros2_sqlite_bag(path: Path) -> Path:
    """Odometry, Imu, the custom DVL message at its own stamps, Float64 depth (bag time), NavSatFix."""
    bag = Bag(Stores.ROS2_HUMBLE)
    _add_odometry(bag)
    _add_imu(bag, "flu")
    for ns, v, ok in zip(SRC.dvl_ns, SRC.dvl, SRC.dvl_valid):
        msg = bag.T["nespm_test/msg/Dvl"](header=bag.header(ns), velocity=bag.vec(B @ v), velocity_valid=bool(ok))
        bag.add("/dvl", "nespm_test/msg/Dvl", ns, msg)
    for ns, d in zip(SRC.depth_ns, SRC.depth):
        bag.add("/depth", "std_msgs/msg/Float64", ns, bag.T["std_msgs/msg/Float64"](data=float(d)))
    _add_fix(bag)
    return bag.write(path, StoragePlugin.SQLITE3)


def ros2_mcap_bag(path: Path) -> Path:
    """PoseStamped + TwistStamped (NED world, FRD body, twist in the world frame, tangent-plane positions),
    Imu and DVL in FRD, FluidPressure, NavSatFix."""
    bag = Bag(Stores.ROS2_HUMBLE)
    pos, q, _, v_world = _gt_ros("ned", "frd", tangent=True)
    for k, ns in enumerate(SRC.gt_ns):
        bag.add("/pose", "geometry_msgs/msg/PoseStamped", ns,
                bag.T["geometry_msgs/msg/PoseStamped"](header=bag.header(ns), pose=bag.pose(pos[k], q[k])))
        bag.add("/vel", "geometry_msgs/msg/TwistStamped", ns + 200_000,  # 0.2 ms later: matched within tolerance
                bag.T["geometry_msgs/msg/TwistStamped"](header=bag.header(ns + 200_000), twist=bag.twist(v_world[k])))
    _add_imu(bag, "frd")
    for ns, v in zip(SRC.dvl_ns, SRC.dvl):
        msg = bag.T["geometry_msgs/msg/TwistWithCovarianceStamped"](header=bag.header(ns), twist=bag.twist_cov(v))
        bag.add("/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", ns, msg)
    _add_pressure(bag)
    _add_fix(bag)
    return bag.write(path, StoragePlugin.MCAP)


ORIGIN_TOML = f"[origin]\nlat_deg = {ORIGIN_DEG[0]!r}\nlon_deg = {ORIGIN_DEG[1]!r}\nalt_m = {ORIGIN_DEG[2]!r}\n"
SPEC_ROS1 = f"""track = 3
{ORIGIN_TOML}
[frames]
world = "enu"
body = "flu"

[gt]
topic = "/odom"

[imu]
topic = "/imu/data"

[dvl]
topic = "/dvl/twist"

[depth]
topic = "/pressure"
density = {RHO}
atmospheric = {P_ATM}
gravity = {G}

[fix]
topic = "/gps/fix"
"""
SPEC_SQLITE = f"""track = 4
{ORIGIN_TOML}
[frames]
world = "enu"
body = "flu"

[gt]
topic = "/odom"

[imu]
topic = "/imu/data"

[dvl]
topic = "/dvl"
velocity = "velocity"
valid = "velocity_valid"

[depth]
topic = "/depth"
depth = "data"
stamp = "bag"

[fix]
topic = "/gps/fix"
vertical = true
"""
SPEC_MCAP = f"""track = 5
{ORIGIN_TOML}model = "tangent"

[frames]
world = "ned"
body = "frd"

[gt]
pose_topic = "/pose"
twist_topic = "/vel"
twist_frame = "world"

[imu]
topic = "/imu/data"

[dvl]
topic = "/dvl/twist"

[depth]
topic = "/pressure"
density = {RHO}
atmospheric = {P_ATM}
gravity = {G}

[fix]
topic = "/gps/fix"
"""
KINDS = {"ros1": (ros1_bag, "src.bag", SPEC_ROS1, 3), "sqlite3": (ros2_sqlite_bag, "src_sqlite", SPEC_SQLITE, 4),
         "mcap": (ros2_mcap_bag, "src_mcap", SPEC_MCAP, 5)}


def _digest(path: Path) -> str:
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """``{kind: (bag, spec, data dir, track number, rc, stdout, stderr)}``: each bag written and imported."""
    root = tmp_path_factory.mktemp("rosbags")
    out = {}
    for kind, (make, name, text, number) in KINDS.items():
        bag = make(root / name)
        spec = root / f"{kind}.toml"
        spec.write_text(text)
        before = _digest(bag)
        data = root / "data"
        rc, so, se = nespm("import", bag, "--spec", spec, "--out", data)
        assert _digest(bag) == before, "the bag was modified"
        out[kind] = (bag, spec, data, number, rc, so, se)
    return out


def _diff(name: str, a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (name, a.shape, b.shape)
    assert np.array_equal(np.isnan(a), np.isnan(b)), name
    d = float(np.nanmax(np.abs(a - b))) if a.size else 0.0
    MAXDIFF[name] = max(MAXDIFF.get(name, 0.0), d)
    return d


@pytest.mark.parametrize("kind", list(KINDS))
def test_import_equals_source(imported, kind):
    """A ROS 1 / ROS 2 / MCAP bag imports to the track it was written from (times, positions, attitude, DVL)."""
    bag, spec, data, number, rc, so, se = imported[kind]
    assert rc == 0, (so, se)
    assert f"track {number}" in so
    tr = load_track(number, data, warnings="error")
    src = SRC.track
    assert _diff("t [s]", tr.t, src.t) <= 1e-9  # the source times (the stamps are them rounded to ns)
    assert _diff("lat,lon [rad]", tr.pos[:, :2], src.pos[:, :2]) <= 1e-12
    alt_tol = 1e-7 if kind == "mcap" else 1e-9  # tangent plane: ECEF round-off at 6.4e6 m
    assert _diff(f"alt [m] ({'tangent' if kind == 'mcap' else 'flat'})", tr.pos[:, 2], src.pos[:, 2]) <= alt_tol
    assert _diff("v_n [m/s]", tr.v_n, src.v_n) <= 1e-9
    d_euler = (tr.euler - src.euler + np.pi) % (2 * np.pi) - np.pi
    assert _diff("euler [rad]", d_euler, np.zeros_like(d_euler)) <= 1e-9
    # IMU: every sample, the duplicate stamp of the ROS 1 bag kept once (its first message)
    assert _diff("IMU t [s]", tr.imu[:, 0], SRC.imu_t) <= 1e-9
    assert _diff("IMU f, w", tr.imu[:, 1:], SRC.imu) <= 1e-9
    if kind == "ros1":  # DVL on the GT epochs
        assert "dvl" not in tr.channels
        assert _diff("DVL [m/s]", tr.dvl, src.dvl) <= 1e-9
    else:
        t_dvl, v = tr.channels["dvl"]
        want = SRC.dvl.copy()
        if kind == "sqlite3":
            want[~SRC.dvl_valid] = np.nan
        assert _diff("DVL t [s]", t_dvl, SRC.dvl_t) <= 1e-9
        assert _diff("DVL [m/s]", v, want) <= 1e-9
    t_d, z_d = tr.channels["depth"]
    inside = SRC.depth_ns >= SRC.gt_ns[0]
    assert _diff("depth t [s]", t_d, SRC.depth_t[inside]) <= 1e-9
    assert _diff("depth [m]", z_d[:, 0], SRC.depth[inside]) <= 1e-9
    t_f, z_f = tr.channels["fix"]
    want = SRC.fix[:, : 3 if kind == "sqlite3" else 2].copy()
    want[~SRC.fix_ok] = np.nan
    assert _diff("fix t [s]", t_f, SRC.fix_t) <= 1e-9
    assert _diff("fix lat, lon [rad] (alt [m])", z_f, want) <= 1e-12
    tdir = data / f"Trajectory{number}"
    assert (tdir / "import-spec.toml").read_text() == spec.read_text()
    note = json.loads((tdir / "import.json").read_text())
    by = {c["channel"]: c for c in note["channels"]}
    assert by["gt"]["written"] == EPOCHS and by["gt"]["messages"] == EPOCHS
    assert by["depth"]["outside_gt_span"] == 1
    assert by["imu"]["duplicates"] == (1 if kind == "ros1" else 0)
    assert by["fix"]["no_measurement"] == 1
    assert note["time_zero_ns"] == int(SRC.gt_ns[0])
    md = (tdir / "IMPORT.md").read_text()
    assert "| gt | GT |" in md and "/gps/fix" in md and "degrees -> rad" in md


def test_report_max_differences(imported):
    """Prints the largest differences of every channel (run with -s to see them)."""
    for kind in KINDS:
        test_import_equals_source(imported, kind)
    print("\nmax |imported - source| over the three bags:")
    for name, d in MAXDIFF.items():
        print(f"  {name:<32} {d:.3g}")
    assert MAXDIFF


def test_mc_runs_on_the_imported_track(imported, tmp_path):
    _, _, data, number, *_ = imported["ros1"]
    rc, so, se = nespm("mc", "--data-dir", data, "--tracks", number, "--runs", 2, "--filters", "ekf", "--state", "15",
                       "--sensors", "dvl,depth,fix", "--sensor-option", "depth.source=recorded",
                       "--sensor-option", "fix.source=recorded", "--out", tmp_path / "mc", "--no-progress",
                       "--jobs", 1)
    assert rc == 0, (so, se)
    assert (tmp_path / "mc" / "metrics.parquet").exists()


def test_mc_recorded_imu_on_the_own_stamps_track(imported, tmp_path):
    _, _, data, number, *_ = imported["mcap"]
    rc, so, se = nespm("mc", "--data-dir", data, "--tracks", number, "--runs", 2, "--filters", "ekf", "--state", "15",
                       "--sensors", "dvl,depth,fix", "--sensor-option", "depth.source=recorded",
                       "--sensor-option", "fix.source=recorded", "--imu", "recorded", "--out", tmp_path / "mc",
                       "--no-progress", "--jobs", 1)
    assert rc == 0, (so, se)


# --------------------------------------------------------------------------- refusals


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The ROS 1 bag and its spec, for the refusals."""
    root = tmp_path_factory.mktemp("small")
    bag = ros1_bag(root / "small.bag")
    spec = root / "spec.toml"
    spec.write_text(SPEC_ROS1)
    return bag, spec, root


def _spec(root: Path, text: str) -> Path:
    p = root / f"spec{abs(hash(text))}.toml"
    p.write_text(text)
    return p


def test_refuses_a_topic_missing_from_the_bag(small, tmp_path):
    bag, _, root = small
    spec = _spec(root, SPEC_ROS1.replace('topic = "/dvl/twist"', 'topic = "/dvl/nope"'))
    line = assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path), "dvl.topic", "/dvl/nope",
                                 str(bag))
    assert "/dvl/twist" in line  # the bag's topics are listed
    assert not list(tmp_path.iterdir())


def test_refuses_a_wrong_message_type(small, tmp_path):
    bag, _, root = small
    spec = _spec(root, SPEC_ROS1.replace('topic = "/imu/data"', 'topic = "/odom"'))
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path), "imu.topic", "/odom",
                          "nav_msgs/msg/Odometry", "sensor_msgs/msg/Imu", "imu.angular_velocity")


def test_refuses_a_field_path_the_message_lacks(small, tmp_path):
    bag, _, root = small
    spec = _spec(root, SPEC_ROS1.replace('topic = "/dvl/twist"', 'topic = "/dvl/twist"\nvelocity = "twist.linear"'))
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path), "dvl.velocity", "twist.linear",
                          "fields of twist: twist, covariance")


@pytest.mark.parametrize("text, key", [
    (SPEC_ROS1.replace("[dvl]", "[dvl]\nlever = 1"), "dvl.lever"),
    (SPEC_ROS1.replace("track = 3", "track = 3\nunits = 'si'"), "units"),
    (SPEC_ROS1 + "\n[sonar]\ntopic = '/x'\n", "sonar"),
    (SPEC_ROS1.replace('world = "enu"', 'world = "nwu"'), "frames.world"),
    (SPEC_ROS1.replace(f"density = {RHO}", "density = 'salty'"), "depth.density"),
    (SPEC_ROS1.replace(f"density = {RHO}", "density = 0"), "depth.density"),
    (SPEC_ROS1.replace('[gt]\ntopic = "/odom"', '[gt]\npose_topic = "/odom"\ntwist_topic = "/odom"'), "gt.twist_frame"),
    (SPEC_ROS1.replace(f"lat_deg = {ORIGIN_DEG[0]!r}\n", ""), "origin.lat_deg"),
    (SPEC_ROS1.replace("track = 3", "track = 0"), "track"),
    ("track = [", "not a valid TOML"),
])
def test_refuses_a_bad_spec(small, tmp_path, text, key):
    bag, _, root = small
    spec = _spec(root, text)
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path), str(spec), key)


def test_refuses_an_unreadable_bag(tmp_path, small):
    _, spec, _ = small
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    assert_one_error_line(*nespm("import", junk, "--spec", spec, "--out", tmp_path / "o"), str(junk), "cannot read")
    folder = tmp_path / "notabag"
    folder.mkdir()
    assert_one_error_line(*nespm("import", folder, "--spec", spec, "--out", tmp_path / "o"), str(folder),
                          "not a ROS bag")
    assert_one_error_line(*nespm("import", tmp_path / "none.bag", "--spec", spec, "--out", tmp_path / "o"),
                          "none.bag", "not found")
    assert_one_error_line(*nespm("import", junk, "--spec", tmp_path / "none.toml", "--out", tmp_path / "o"),
                          "none.toml", "not found")


def test_existing_track_needs_overwrite(small, tmp_path):
    bag, spec, _ = small
    assert nespm("import", bag, "--spec", spec, "--out", tmp_path)[0] == 0
    stale = tmp_path / "Trajectory3" / "stale.txt"
    stale.write_text("old")
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path), "Trajectory3", "--overwrite")
    assert stale.exists()
    rc, so, se = nespm("import", bag, "--spec", spec, "--out", tmp_path, "--overwrite")
    assert rc == 0, se
    assert not stale.exists() and (tmp_path / "Trajectory3" / "GT_trajectory3.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Trajectory3"]  # no staging or replaced folder left
    rc, so, se = nespm("import", bag, "--spec", spec, "--out", tmp_path, "--track", 8)
    assert rc == 0 and (tmp_path / "Trajectory8" / "GT_trajectory8.csv").exists(), se


def test_custom_type_without_definitions_needs_its_msg_file(tmp_path):
    """A ROS 2 sqlite3 bag without stored definitions (as ROS 2 Humble records them): the standard types
    come from the type store, the custom DVL message from [bag.types]."""
    bag = ros2_sqlite_bag(tmp_path / "nodefs")
    with sqlite3.connect(next(bag.glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC_SQLITE)
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", tmp_path / "o"), "nespm_test/msg/Dvl",
                          "bag.types")
    (tmp_path / "Dvl.msg").write_text(DVL_MSG)
    spec.write_text(SPEC_SQLITE.replace("track = 4", 'track = 4\n[bag]\ntypes = { "nespm_test/msg/Dvl" = "Dvl.msg" }'))
    rc, so, se = nespm("import", bag, "--spec", spec, "--out", tmp_path / "o")
    assert rc == 0, se
    t_dvl, v = load_track(4, tmp_path / "o").channels["dvl"]
    assert np.array_equal(np.isnan(v[:, 0]), ~SRC.dvl_valid)


def test_a_refused_track_leaves_nothing(imported, tmp_path):
    """The bench's own checks run on the written track before it is installed: a depth field read with the
    wrong sign (positive up) gives depths of about -10 m, which the DEPTH file check refuses; the message
    names the final path and nothing is written."""
    bag, _, _, _, *_ = imported["sqlite3"]
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC_SQLITE.replace('depth = "data"', 'depth = "data"\npositive = "up"'))
    out = tmp_path / "out"
    assert_one_error_line(*nespm("import", bag, "--spec", spec, "--out", out),
                          str(out / "Trajectory4" / "DEPTH_trajectory4.csv"), "Depth [m]", "nothing written")
    assert not out.exists()


def test_the_documented_spec_imports(small, tmp_path):
    """The complete example of docs/rosbags.md, its GT topic renamed to the test bag's."""
    bag, _, _ = small
    doc = (Path(__file__).resolve().parents[1] / "docs" / "rosbags.md").read_text()
    text = doc.split("```toml\n", 1)[1].split("```", 1)[0]
    spec = tmp_path / "doc.toml"
    spec.write_text(text.replace("/odometry/truth", "/odom"))
    rc, so, se = nespm("import", bag, "--spec", spec, "--out", tmp_path / "o")
    assert rc == 0, se
    tr = load_track(7, tmp_path / "o")
    assert tr.imu is not None and set(tr.channels) == {"depth", "fix"}


def test_every_and_bag_zero(small, tmp_path):
    """``gt.every = 2`` keeps epochs 0, 2, 4, ...; ``time.zero = "bag"`` counts from the bag's first message."""
    bag, _, root = small
    spec = _spec(root, SPEC_ROS1.replace('topic = "/odom"', 'topic = "/odom"\nevery = 2')
                 .replace("track = 3", 'track = 3\n[time]\nzero = "bag"'))
    rc, so, se = nespm("import", bag, "--spec", spec, "--out", tmp_path)
    assert rc == 0, se
    tr = load_track(3, tmp_path)
    first = min(SRC.gt_ns[0], SRC.imu_ns[0], SRC.depth_ns[0])  # the depth sample before the GT span
    assert np.abs(tr.t - (SRC.gt_ns[::2] - first) / NS).max() == 0
    assert np.abs(tr.pos[:, :2] - SRC.track.pos[::2, :2]).max() < 1e-15
    assert json.loads((tmp_path / "Trajectory3" / "import.json").read_text())["channels"][0]["every"] == 2
