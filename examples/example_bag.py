"""Write a small ROS 1 bag from embedded track 1, to try ``nespm import`` without a bag of one's own.

    python examples/example_bag.py example.bag                  # the first 90 s (--seconds), 3.5 MB
    nespm import example.bag --spec examples/example-bag.toml --out bag-tracks
    nespm mc --data-dir bag-tracks --tracks 1 --runs 2 --filters ekf --state 15 --sensors dvl,depth,fix \\
        --sensor-option depth.source=recorded --sensor-option fix.source=recorded --out results/bag

The bag holds what an AUV's ROS drivers would publish, in REP-103 frames (world ENU, body FLU),
with header stamps in Unix nanoseconds:

    /ground_truth/odom  nav_msgs/Odometry            GT: pose (ENU metres about ORIGIN_DEG), body twist; 1 Hz
    /imu/data           sensor_msgs/Imu              specific force, angular rate; 100 Hz
    /dvl/twist          geometry_msgs/TwistWithCovarianceStamped   body velocity; on the GT stamps
    /pressure           sensor_msgs/FluidPressure    absolute pressure [Pa]; on the GT stamps
    /gps/fix            sensor_msgs/NavSatFix        latitude, longitude [deg]; every 10th GT stamp

The values are exact: the track's own GT, its DVL, its depth, and the bench's synthesized (exact)
IMU of the cut track, so the imported track equals embedded track 1 over the written span
(tests/test_example_bag.py). examples/example-bag.toml is the import spec of this bag: the same
topics, frames, origin and hydrostatic constants as below. To import your own bag, copy that spec
and change the topics (and frames, origin, ...; docs/rosbags.md lists every key).

Reading needs only ``rosbags`` (pure Python, a dependency of nespm), not a ROS install.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.track import Track
from nespm_cli.nav.earth import ned_offset
from nespm_cli.nav.synthesis import synthesize

ORIGIN_DEG = (32.84, 34.93, 0.0)  # lat, lon [deg], alt [m] of the local ENU frame ([origin] of the spec)
START_NS = 1_700_000_000 * 10**9  # the first GT stamp (the spec's time zero: time.zero = "gt")
RHO, P_ATM, G = 1025.0, 101325.0, 9.80665  # pressure = P_ATM + RHO * G * depth ([depth] of the spec)
FIX_EVERY = 10  # one GNSS fix every 10th GT epoch
ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED -> ENU (its own inverse)
FLU_FRD = np.diag([1.0, -1.0, -1.0])  # FRD -> FLU (its own inverse)


def cut_track(seconds: float) -> Track:
    """The first ``seconds`` of embedded track 1 (the bench's frames: NED, body FRD)."""
    tr = embedded_track(1)
    k = tr.t - tr.t[0] <= seconds
    return Track(number=1, t=tr.t[k], pos=tr.pos[k], v_n=tr.v_n[k], euler=tr.euler[k], dvl=tr.dvl[k],
                 imu=None, source="embedded")


class Messages:
    """ROS 1 messages built with rosbags' type store, collected and then written in stamp order."""

    def __init__(self):
        self.store = get_typestore(Stores.ROS1_NOETIC)
        self.items: list[tuple[int, str, str, object]] = []

    def msg(self, name: str, **fields):
        return self.store.types[name](**fields)

    def header(self, ns: int, frame: str):
        stamp = self.msg("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)
        return self.msg("std_msgs/msg/Header", seq=0, stamp=stamp, frame_id=frame)

    def vec(self, v, name: str = "geometry_msgs/msg/Vector3"):
        return self.msg(name, x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def add(self, topic: str, ns: int, msg) -> None:
        self.items.append((int(ns), topic, msg.__msgtype__, msg))

    def write(self, path: Path) -> None:
        with Writer(path) as writer:
            conns = {}
            for ns, topic, msgtype, msg in sorted(self.items, key=lambda item: item[0]):
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=self.store)
                writer.write(conns[topic], ns, self.store.serialize_ros1(msg, msgtype))


def build(tr: Track) -> Messages:
    """Every message of the bag from the cut track ``tr``."""
    m = Messages()
    stamps = START_NS + np.round((tr.t - tr.t[0]) * 1e9).astype(np.int64)
    cov9, cov36 = np.zeros(9), np.zeros(36)

    # GT: pose of base_link (FLU) in the ENU frame "odom", twist in base_link (the Odometry definition)
    origin = np.array([np.radians(ORIGIN_DEG[0]), np.radians(ORIGIN_DEG[1]), ORIGIN_DEG[2]])
    p_enu = ned_offset(tr.pos, origin) @ ENU_NED.T
    C_flu_enu = ENU_NED @ tr.C_bn @ FLU_FRD  # body FLU -> world ENU
    q = Rotation.from_matrix(C_flu_enu).as_quat()  # [x, y, z, w], as ROS
    v_flu = (FLU_FRD @ np.swapaxes(tr.C_bn, 1, 2) @ tr.v_n[:, :, None])[:, :, 0]
    for k, ns in enumerate(stamps):
        pose = m.msg("geometry_msgs/msg/Pose", position=m.vec(p_enu[k], "geometry_msgs/msg/Point"),
                     orientation=m.msg("geometry_msgs/msg/Quaternion", x=q[k, 0], y=q[k, 1], z=q[k, 2], w=q[k, 3]))
        twist = m.msg("geometry_msgs/msg/Twist", linear=m.vec(v_flu[k]), angular=m.vec((0, 0, 0)))
        m.add("/ground_truth/odom", ns, m.msg(
            "nav_msgs/msg/Odometry", header=m.header(ns, "odom"), child_frame_id="base_link",
            pose=m.msg("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=cov36),
            twist=m.msg("geometry_msgs/msg/TwistWithCovariance", twist=twist, covariance=cov36)))

        # DVL: body velocity in FLU; depth as an absolute pressure; a 2-D fix every FIX_EVERY epochs
        dvl = m.msg("geometry_msgs/msg/Twist", linear=m.vec(FLU_FRD @ tr.dvl[k]), angular=m.vec((0, 0, 0)))
        m.add("/dvl/twist", ns, m.msg(
            "geometry_msgs/msg/TwistWithCovarianceStamped", header=m.header(ns, "base_link"),
            twist=m.msg("geometry_msgs/msg/TwistWithCovariance", twist=dvl, covariance=cov36)))
        m.add("/pressure", ns, m.msg("sensor_msgs/msg/FluidPressure", header=m.header(ns, "base_link"),
                                     fluid_pressure=P_ATM + RHO * G * -tr.pos[k, 2], variance=0.0))
        if k % FIX_EVERY == FIX_EVERY // 2:
            status = m.msg("sensor_msgs/msg/NavSatStatus", status=0, service=1)  # STATUS_FIX, SERVICE_GPS
            m.add("/gps/fix", ns, m.msg(
                "sensor_msgs/msg/NavSatFix", header=m.header(ns, "gps"), status=status,
                latitude=float(np.degrees(tr.pos[k, 0])), longitude=float(np.degrees(tr.pos[k, 1])),
                altitude=float(tr.pos[k, 2]), position_covariance=cov9, position_covariance_type=0))

    # IMU: the bench's exact IMU (sample i is the mean over the step ending at its stamp; the first
    # sample repeats the first step), specific force (REP-145: +9.81 up at rest) and rate in FLU
    ref = synthesize(tr)
    f_b = np.vstack([ref.f_b[:1], ref.f_b]) @ FLU_FRD.T
    w_b = np.vstack([ref.w_ib_b[:1], ref.w_ib_b]) @ FLU_FRD.T
    for ns, f, w in zip(START_NS + np.round((ref.t - tr.t[0]) * 1e9).astype(np.int64), f_b, w_b):
        m.add("/imu/data", ns, m.msg(
            "sensor_msgs/msg/Imu", header=m.header(ns, "base_link"),
            orientation=m.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.array([-1.0] + [0.0] * 8),  # -1: no orientation estimate
            angular_velocity=m.vec(w), angular_velocity_covariance=cov9,
            linear_acceleration=m.vec(f), linear_acceleration_covariance=cov9))
    return m


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the ROS 1 bag to write (.bag; replaced if it exists)")
    ap.add_argument("--seconds", type=float, default=90.0, help="span of track 1 to write [s] (default 90)")
    args = ap.parse_args(argv)
    tr = cut_track(args.seconds)
    messages = build(tr)
    args.out.unlink(missing_ok=True)  # rosbags' writer refuses an existing file
    messages.write(args.out)
    print(f"wrote {args.out}: {len(messages.items)} messages, {tr.t[-1] - tr.t[0]:.1f} s of embedded track 1")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
