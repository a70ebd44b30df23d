"""The import spec of ``nespm import``: a TOML file mapping bag topics to the bench's channels
(docs/rosbags.md lists every key). :func:`read_spec` parses and checks it and fills the defaults;
every refusal is one line naming the spec file and the key (``gt.toppic``).

Units in the spec: degrees for the origin's latitude and longitude (``origin.lat_deg``), metres,
seconds, Pa, kg/m³, m/s² elsewhere, as each key's name or docs/rosbags.md says.
"""
from __future__ import annotations

from pathlib import Path

from nespm_cli.data.plausibility import printable
from nespm_cli.data.toml_keys import BOOL, INT, NUM, STR, TABLE, checked_table, read_toml
from nespm_cli.errors import NespmError

BODY, STAMP = ("flu", "frd"), STR
#: every key of the spec: ``{table: {key: type or tuple of choices}}`` ("" is the top level)
SCHEMA = {
    "": {"track": INT, "bag": TABLE, "time": TABLE, "frames": TABLE, "origin": TABLE, "gt": TABLE, "imu": TABLE,
         "dvl": TABLE, "depth": TABLE, "fix": TABLE},
    "bag": {"typestore": STR, "types": TABLE},
    "time": {"zero": ("gt", "bag", "none"), "stamp": STAMP},
    "frames": {"world": ("enu", "ned"), "body": BODY},
    "origin": {"lat_deg": NUM, "lon_deg": NUM, "alt_m": NUM, "model": ("flat", "tangent")},
    "gt": {"topic": STR, "pose_topic": STR, "twist_topic": STR, "position": STR, "orientation": STR,
           "velocity": STR, "twist_frame": ("body", "world"), "body": BODY, "stamp": STAMP, "every": INT,
           "sync_tolerance": NUM},
    "imu": {"topic": STR, "angular_velocity": STR, "linear_acceleration": STR, "body": BODY, "stamp": STAMP},
    "dvl": {"topic": STR, "velocity": STR, "valid": STR, "body": BODY, "stamp": STAMP},
    "depth": {"topic": STR, "pressure": STR, "depth": STR, "positive": ("down", "up"), "density": NUM,
              "atmospheric": NUM, "gravity": NUM, "stamp": STAMP},
    "fix": {"topic": STR, "latitude": STR, "longitude": STR, "altitude": STR, "status": STR, "vertical": BOOL,
            "stamp": STAMP},
}
DEFAULTS = {
    "": {"track": 1},
    "bag": {"typestore": None, "types": {}},
    "time": {"zero": "gt", "stamp": "header"},
    "origin": {"alt_m": 0.0, "model": "flat"},
    "gt": {"every": 1, "sync_tolerance": 0.001},
    "depth": {"positive": "down", "density": 1025.0, "atmospheric": 101325.0, "gravity": 9.80665},
    "fix": {"vertical": False},
}
CHANNELS = ("gt", "imu", "dvl", "depth", "fix")
FIRST_FIX = "first-fix"  # origin = "first-fix": the origin from the first GNSS fix (inspect_bag.first_fix_origin)

ODOM, IMU, NAVSAT, PRESSURE = "nav_msgs/msg/Odometry", "sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix", \
    "sensor_msgs/msg/FluidPressure"
POSE, POSE_COV = "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped"
TWIST, TWIST_COV, VEC3 = "geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/TwistWithCovarianceStamped", \
    "geometry_msgs/msg/Vector3Stamped"
#: the field paths of the known message types, per topic key: ``{key: {type: {field: path}}}``; a type not
#: listed needs every field path in the spec (a custom message)
FIELD_PATHS = {
    "gt.topic": {ODOM: {"position": "pose.pose.position", "orientation": "pose.pose.orientation",
                        "velocity": "twist.twist.linear"}},
    "gt.pose_topic": {POSE: {"position": "pose.position", "orientation": "pose.orientation"},
                      POSE_COV: {"position": "pose.pose.position", "orientation": "pose.pose.orientation"},
                      ODOM: {"position": "pose.pose.position", "orientation": "pose.pose.orientation"}},
    "gt.twist_topic": {TWIST: {"velocity": "twist.linear"}, TWIST_COV: {"velocity": "twist.twist.linear"},
                       ODOM: {"velocity": "twist.twist.linear"}},
    "imu.topic": {IMU: {"angular_velocity": "angular_velocity", "linear_acceleration": "linear_acceleration"}},
    "dvl.topic": {TWIST_COV: {"velocity": "twist.twist.linear"}, TWIST: {"velocity": "twist.linear"},
                  VEC3: {"velocity": "vector"}},
    "depth.topic": {PRESSURE: {"pressure": "fluid_pressure"}},
    "fix.topic": {NAVSAT: {"latitude": "latitude", "longitude": "longitude", "altitude": "altitude",
                           "status": "status.status"}},
}


def read_spec(path: Path) -> dict:
    """The spec ``path`` as ``{table: {key: value}}`` with the defaults filled in, ``"track"`` at the top
    level and ``bag.types`` as ``{type name: .msg text}`` (files relative to the spec's folder).

    Refused, in one line naming ``path`` and the key: an unreadable or invalid TOML file, an unknown key,
    a value of the wrong type or outside its choices, no ``[gt]``, no ``[origin]`` (or ``origin = "first-fix"``
    without a ``[fix]``), ``frames.world`` or ``frames.body`` missing (no default), a ``[gt]`` without
    ``topic`` or ``pose_topic`` + ``twist_topic`` (or both), ``twist_frame`` missing with a separate twist
    topic, a table without ``topic``, ``depth.pressure`` and ``depth.depth`` both given, a track below 1,
    an origin outside ±90°/±180°, a density, gravity or ``every`` not positive."""
    raw = read_toml(path, "the spec")
    first_fix = isinstance(raw.get("origin"), str)
    if first_fix:
        if raw["origin"] != FIRST_FIX:
            raise NespmError(f"{path}: key 'origin': {printable(repr(raw['origin']), 40)}: give an [origin] table "
                             f"(lat_deg, lon_deg, alt_m) or origin = \"{FIRST_FIX}\"")
        raw = {k: v for k, v in raw.items() if k != "origin"}
    top = _table(path, "", raw)
    spec = {"": {**DEFAULTS[""], **{k: v for k, v in top.items() if SCHEMA[""][k] != TABLE}}}
    for name in SCHEMA:
        if name in raw:
            spec[name] = {**DEFAULTS.get(name, {}), **_table(path, name, raw[name])}
        elif name in ("bag", "time"):
            spec[name] = dict(DEFAULTS[name])
    if first_fix:
        spec["origin"] = {"first_fix": True, "alt_m": 0.0, "model": "flat"}
    _check(path, spec)
    spec["bag"]["types"] = _msg_types(path, spec["bag"]["types"])
    return spec


def _table(path: Path, name: str, table) -> dict:
    """The keys of one table, each checked against :data:`SCHEMA` (the top level's sub-tables are
    checked by :func:`read_spec`)."""
    return checked_table(path, name, table, SCHEMA[name], skip=(TABLE,) if not name else ())


def _check(path: Path, spec: dict) -> None:
    """The rules between keys (:func:`read_spec`)."""
    def bad(key: str, what: str) -> NespmError:
        return NespmError(f"{path}: key '{key}' {what}")

    if spec[""]["track"] < 1:
        raise bad("track", f"must be at least 1, got {spec['']['track']}")
    for name in ("gt", "origin"):
        if name not in spec:
            raise NespmError(f"{path}: no [{name}] table (the ground truth and its origin are required; "
                             f"origin = \"{FIRST_FIX}\" takes it from the first GNSS fix)")
    frames = spec.get("frames", {})
    for key, choices in (("world", "enu or ned"), ("body", "flu or frd")):
        if key not in frames:
            raise NespmError(f"{path}: key 'frames.{key}' is missing: say the bag's {key} frame ({choices}); it has no "
                             "default (a NED/FRD bag read as ENU/FLU comes in mirrored; nespm import BAG --list shows "
                             "the frame_ids)")
    origin = spec["origin"]
    if origin.get("first_fix") and "fix" not in spec:
        raise bad("origin", f"= \"{FIRST_FIX}\" needs a [fix] table (the GNSS topic the origin is taken from)")
    for key, limit in (("lat_deg", 90.0), ("lon_deg", 180.0)):
        if origin.get("first_fix"):
            break
        if key not in origin:
            raise bad(f"origin.{key}", "is missing (the local pose's origin, degrees)")
        if abs(origin[key]) > limit:
            raise bad(f"origin.{key}", f"is outside ±{limit:g} degrees: {origin[key]!r}")
    gt = spec["gt"]
    pair = ("pose_topic" in gt, "twist_topic" in gt)
    if ("topic" in gt) == any(pair) or any(pair) and not all(pair):
        raise bad("gt.topic", "or gt.pose_topic with gt.twist_topic: give one of the two (an Odometry topic, "
                  "or a pose and a twist topic)")
    if all(pair) and "twist_frame" not in gt:
        raise bad("gt.twist_frame", "is missing: say whether the twist topic's velocity is in the body or the "
                  "world frame (body or world)")
    if gt["every"] < 1 or gt["sync_tolerance"] < 0:
        raise bad("gt.every" if gt["every"] < 1 else "gt.sync_tolerance", "must be positive")
    for name in CHANNELS[1:]:
        if name in spec and "topic" not in spec[name]:
            raise bad(f"{name}.topic", "is missing")
    if "depth" in spec:
        depth = spec["depth"]
        if "pressure" in depth and "depth" in depth:
            raise bad("depth.depth", "and depth.pressure are both given: a pressure or a depth field, not both")
        for key in ("density", "gravity"):
            if not depth[key] > 0:
                raise bad(f"depth.{key}", f"must be positive, got {depth[key]!r}")


def _msg_types(path: Path, types: dict) -> dict[str, str]:
    """``{type name: .msg text}`` of ``bag.types`` (``{"pkg/msg/Name" = "file.msg"}``, relative to the spec)."""
    out = {}
    for name, file in types.items():
        key = f"bag.types.{name}"
        if not isinstance(file, str) or name.count("/") != 2 or "/msg/" not in name:
            raise NespmError(f"{path}: key '{printable(key, 80)}': give \"pkg/msg/Name\" = \"path/to/Name.msg\"")
        msg_path = (path.parent / file).expanduser()
        try:
            out[name] = msg_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise NespmError(f"{path}: key '{printable(key, 80)}': cannot read {msg_path} "
                             f"({getattr(exc, 'strerror', None) or type(exc).__name__})") from None
    return out


def paths_for(spec_path: Path, key: str, table: dict, msgtype: str, topic: str, needed: tuple[str, ...],
              optional: tuple[str, ...] = ()) -> dict[str, str]:
    """The field paths ``{field: path}`` of topic key ``key`` (``"dvl.topic"``) whose messages are ``msgtype``:
    each ``needed`` field from ``table`` (the spec's) or else :data:`FIELD_PATHS`; ``optional`` ones only where
    one of them gives it. A needed field without a path is a wrong message type: one line naming the key."""
    known = FIELD_PATHS.get(key, {})
    defaults = known.get(msgtype, {})
    out = {f: table.get(f, defaults.get(f)) for f in needed + optional}
    missing = [f for f in needed if out[f] is None]
    if missing:
        channel = key.split(".")[0]
        types = " or ".join(known) or "a message type it knows"
        raise NespmError(f"{spec_path}: key '{key}': topic {topic!r} is {msgtype}, not {types} (for another type "
                         f"give the field paths {', '.join(f'{channel}.{f}' for f in missing)})")
    return {f: p for f, p in out.items() if p is not None}
