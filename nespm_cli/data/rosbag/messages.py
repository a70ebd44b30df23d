"""Reading ROS bags for ``nespm import``: open a bag, pull named fields of topics into arrays, and
the frame and unit conversions from ROS conventions to the bench's (docs/rosbags.md).

The bag is read with ``rosbags`` (pure Python): a ROS 1 ``.bag`` file, or a ROS 2 bag folder
(``metadata.yaml`` with sqlite3 or mcap storage). It is opened read-only and never written.

A :class:`Request` names a topic and the fields to take from each of its messages, as dotted field
paths (``twist.twist.linear``) of one of three kinds: ``vec3`` (a message with ``x, y, z`` or a
3-array), ``quat`` (``x, y, z, w``) and ``scalar`` (a number or a bool). :func:`read_requests` makes
one pass over the bag and returns, per topic, the stamps (int64 ns) and one float array per field,
built once from the per-message tuples.

Conversions (batched over the samples): :func:`quat_to_dcm` (ROS quaternion ``x, y, z, w`` ->
rotation body -> world), :data:`WORLD_TO_NED` (``enu``: ``[x, y, z]_ENU -> [y, x, -z]``),
:data:`BODY_TO_FRD` (``flu``: ``[x, y, z]_FLU -> [x, -y, -z]``), :func:`local_to_geodetic` (local
NED metres about an origin -> ``[lat rad, lon rad, alt m]``), :func:`pressure_to_depth` [Pa -> m].
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from operator import attrgetter
from pathlib import Path

import numpy as np

from nespm_cli.data.plausibility import printable
from nespm_cli.errors import NespmError
from nespm_cli.nav.earth import A, E2
from nespm_cli.nav.state import position_plus

#: world frame of a local pose -> the rotation to NED (a signed permutation, its own inverse)
WORLD_TO_NED = {"enu": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), "ned": np.eye(3)}
#: body axes of a message -> the rotation to the bench's FRD body (x forward, y starboard, z down)
BODY_TO_FRD = {"flu": np.diag([1.0, -1.0, -1.0]), "frd": np.eye(3)}
KINDS = {"vec3": ("x", "y", "z"), "quat": ("x", "y", "z", "w"), "scalar": ()}


@dataclass
class Request:
    """The fields to take from one topic: ``fields`` ``{name: (path, kind)}``; ``stamp`` ``"header"``
    (``header.stamp``), ``"bag"`` (the bag's receive time) or a path to a time with ``sec``, ``nanosec``.
    ``key`` is the spec key that named the topic (for messages)."""

    key: str
    topic: str
    fields: dict[str, tuple[str, str]]
    stamp: str = "header"


@dataclass
class TopicData:
    """One topic's samples in bag order: ``stamp_ns`` (K,) int64 [ns], ``bag_ns`` (K,) int64 [ns],
    ``values`` ``{name: (K,) or (K, 3|4) float}``, its message type and message count."""

    topic: str
    msgtype: str
    count: int
    stamp_ns: np.ndarray
    bag_ns: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)


def bag_kind(path: Path) -> tuple[Path, str]:
    """``(bag path to open, description)``: a ``.bag`` file is ROS 1; a folder with ``metadata.yaml`` (or a
    ``.db3`` / ``.mcap`` file inside one) is ROS 2. Raises :class:`NespmError` on anything else."""
    if path.is_file() and path.suffix == ".bag":
        return path, "ROS 1 bag"
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        path = path.parent
    if path.is_dir() and (path / "metadata.yaml").is_file():
        try:
            text = (path / "metadata.yaml").read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            raise NespmError(f"{path / 'metadata.yaml'}: cannot read ({exc.strerror})") from None
        m = re.search(r"storage_identifier:\s*['\"]?([\w.-]+)", text)
        return path, f"ROS 2 bag ({m.group(1) if m else 'unknown'} storage)"
    if not path.exists():
        raise NespmError(f"{path}: bag not found")
    raise NespmError(f"{path}: not a ROS bag (expected a ROS 1 .bag file or a ROS 2 bag folder with metadata.yaml)")


def open_bag(path: Path, typestore: str | None, msg_types: dict[str, str]):
    """An open ``rosbags.highlevel.AnyReader`` on the bag ``path`` (from :func:`bag_kind`).

    ``typestore`` (a ``rosbags.typesys.Stores`` value, e.g. ``ros2_humble``; None: ``ros1_noetic`` for ROS 1,
    ``ros2_humble`` for ROS 2) supplies the definitions of standard types the bag does not carry;
    ``msg_types`` ``{type name: .msg text}`` those of custom types. The caller closes the reader."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros1 = path.suffix == ".bag" and path.is_file()
    name = typestore or ("ros1_noetic" if ros1 else "ros2_humble")
    try:
        default = get_typestore(Stores(name))
    except ValueError:
        known = ", ".join(s.value for s in Stores if s.value not in ("empty", "latest"))
        raise NespmError(f"spec key bag.typestore: unknown type store {name!r} (known: {known})") from None
    try:
        reader = AnyReader([path], default_typestore=default)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises many types on a damaged or foreign file
        raise NespmError(f"{path}: cannot read the bag ({type(exc).__name__}: {printable(exc, 160)})") from None
    try:
        have = reader.typestore.fielddefs
        missing = {k: v for k, v in default.fielddefs.items() if k not in have}
        if missing:  # standard types the bag has no definition for
            reader.typestore.register(missing)
        for type_name, text in msg_types.items():
            if type_name not in reader.typestore.fielddefs:
                reader.typestore.register(get_types_from_msg(text, type_name))
    except Exception as exc:  # noqa: BLE001
        reader.close()
        raise NespmError(f"spec key bag.types: cannot register the message definitions "
                         f"({printable(exc, 160)})") from None
    return reader


def read_requests(reader, requests: list[Request], bag: Path) -> dict[str, TopicData]:
    """One pass over ``reader``'s messages on the requested topics; ``{request key: TopicData}``.

    Raises :class:`NespmError` naming the spec key and topic: a topic missing from the bag, a topic of
    several types, a type without a definition, a field path its messages do not have, no messages."""
    topics = reader.topics
    by_topic: dict[str, list[Request]] = {}
    for req in requests:
        info = topics.get(req.topic)
        if info is None:
            names = ", ".join(sorted(topics)) or "none"
            raise NespmError(f"spec key {req.key}: topic {req.topic!r} is not in {bag} "
                             f"(its topics: {printable(names, 200)})")
        if info.msgtype is None:
            raise NespmError(f"spec key {req.key}: topic {req.topic!r} of {bag} carries several message types")
        if info.msgtype not in reader.typestore.fielddefs:
            raise NespmError(f"spec key {req.key}: {bag} has no definition of {info.msgtype} (topic "
                             f"{req.topic!r}); give its .msg file in [bag.types]")
        if not info.msgcount:
            raise NespmError(f"spec key {req.key}: topic {req.topic!r} of {bag} has no messages")
        by_topic.setdefault(req.topic, []).append(req)
    rows: dict[str, list] = {t: [] for t in by_topic}
    getters: dict[str, list] = {}
    conns = [c for c in reader.connections if c.topic in by_topic]
    for conn, bag_ns, raw in reader.messages(connections=conns):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # noqa: BLE001
            n = len(rows[conn.topic]) + 1
            raise NespmError(f"spec key {by_topic[conn.topic][0].key}: message {n} of topic {conn.topic!r} in "
                             f"{bag} cannot be read ({printable(exc, 120)})") from None
        if conn.topic not in getters:
            getters[conn.topic] = [_getters(req, msg, conn.msgtype) for req in by_topic[conn.topic]]
        rows[conn.topic].append((bag_ns, [[g(msg) for g in gs] for gs in getters[conn.topic]]))
    out = {}
    for topic, reqs in by_topic.items():
        got = rows[topic]
        if not got:
            raise NespmError(f"spec key {reqs[0].key}: topic {topic!r} of {bag} has no messages")
        bag_ns = np.array([r[0] for r in got], dtype=np.int64)
        for i, req in enumerate(reqs):
            cols = [list(c) for c in zip(*[r[1][i] for r in got])]
            if req.stamp == "bag":
                stamp = bag_ns.copy()
            else:
                stamp, cols = _ns(np.array(cols[0], dtype=np.int64).reshape(-1, 2)), cols[1:]
            values = {name: np.array(c, dtype=float) for name, c in zip(req.fields, cols)}
            out[req.key] = TopicData(topic, topics[topic].msgtype, len(got), stamp, bag_ns, values)
    return out


def _ns(sec_nanosec: np.ndarray) -> np.ndarray:
    """(K,) int64 [ns] of (K, 2) ``sec, nanosec``."""
    return sec_nanosec[:, 0] * np.int64(1_000_000_000) + sec_nanosec[:, 1]


def _getters(req: Request, msg, msgtype: str) -> list:
    """The getters of ``req`` (the stamp first, then each field), checked on its first message ``msg``."""
    where = f"topic {req.topic!r} ({msgtype})"
    gs = []
    if req.stamp != "bag":
        path = "header.stamp" if req.stamp == "header" else req.stamp
        key = req.key.rsplit(".", 1)[0] + ".stamp"
        target = _resolve(msg, path, key, where)
        if not (hasattr(target, "sec") and hasattr(target, "nanosec")):
            raise NespmError(f"spec key {key}: field {path!r} of {where} is not a time (sec, nanosec); use "
                             "stamp = \"bag\" for a message without a header")
        gs.append(attrgetter(f"{path}.sec", f"{path}.nanosec"))
    for name, (path, kind) in req.fields.items():
        key = f"{req.key.rsplit('.', 1)[0]}.{name}"
        target = _resolve(msg, path, key, where)
        parts = KINDS[kind]
        if parts and all(hasattr(target, p) for p in parts):
            gs.append(attrgetter(*(f"{path}.{p}" for p in parts)))
        elif parts and isinstance(target, np.ndarray) and target.shape == (len(parts),):
            gs.append(lambda m, get=attrgetter(path): tuple(get(m)))
        elif not parts and isinstance(target, (int, float, bool, np.number, np.bool_)):
            gs.append(attrgetter(path))
        else:
            want = f"a message with {', '.join(parts)}" if parts else "a number"
            what = getattr(target, "__msgtype__", type(target).__name__)
            raise NespmError(f"spec key {key}: field {path!r} of {where} is {what}, not {want}")
    return gs


def _resolve(msg, path: str, key: str, where: str):
    """The value at the dotted ``path`` of ``msg``; a missing field names ``key`` and the fields there."""
    obj = msg
    for i, part in enumerate(path.split(".")):
        if not hasattr(obj, part) or part.startswith("_"):
            fields = [f for f in getattr(obj, "__dataclass_fields__", {}) if not f.startswith("_")]
            at = ".".join(path.split(".")[:i]) or "the message"
            raise NespmError(f"spec key {key}: {where} has no field {path!r} "
                             f"(fields of {at}: {', '.join(fields) or 'none'})")
        obj = getattr(obj, part)
    return obj


# ----------------------------------------------------------------------------- conversions


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (K, 3, 3) of quaternions ``q`` (K, 4) ``[x, y, z, w]`` (ROS order), normalized
    first: ``R v_body = v_world`` for a ROS orientation (the body frame's attitude in the world frame)."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[..., 0, 1] = 2.0 * (x * y - z * w)
    R[..., 0, 2] = 2.0 * (x * z + y * w)
    R[..., 1, 0] = 2.0 * (x * y + z * w)
    R[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[..., 1, 2] = 2.0 * (y * z - x * w)
    R[..., 2, 0] = 2.0 * (x * z - y * w)
    R[..., 2, 1] = 2.0 * (y * z + x * w)
    R[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return R


def local_to_geodetic(ned: np.ndarray, origin: np.ndarray, model: str = "flat") -> np.ndarray:
    """``[lat rad, lon rad, alt m]`` (K, 3) of local NED offsets ``ned`` (K, 3) [m] from ``origin``
    ``[lat rad, lon rad, alt m]``.

    ``flat``: the bench's small-offset pair (``nav.state.position_plus``, the inverse of
    ``nav.earth.ned_offset``): north/east metres scaled by the WGS-84 radii at the origin, altitude =
    origin altitude − down. ``tangent``: the WGS-84 local tangent plane at the origin (a point of the
    plane -> ECEF -> geodetic), as GeographicLib's LocalCartesian."""
    ned = np.asarray(ned, dtype=float)
    origin = np.asarray(origin, dtype=float)
    if model == "flat":
        return position_plus(np.broadcast_to(origin, ned.shape), ned)
    lat0, lon0 = origin[0], origin[1]
    sl, cl, so, co = np.sin(lat0), np.cos(lat0), np.sin(lon0), np.cos(lon0)
    C_ne = np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])  # NED -> ECEF
    return ecef_to_geodetic(geodetic_to_ecef(origin) + ned @ C_ne.T)


def geodetic_to_ecef(pos: np.ndarray) -> np.ndarray:
    """ECEF ``[x, y, z]`` (..., 3) [m] of WGS-84 ``[lat rad, lon rad, h m]`` (..., 3)."""
    lat, lon, h = np.moveaxis(np.asarray(pos, dtype=float), -1, 0)
    N = A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
    return np.stack([(N + h) * np.cos(lat) * np.cos(lon), (N + h) * np.cos(lat) * np.sin(lon),
                     (N * (1.0 - E2) + h) * np.sin(lat)], axis=-1)


def ecef_to_geodetic(xyz: np.ndarray, iterations: int = 6) -> np.ndarray:
    """WGS-84 ``[lat rad, lon rad, h m]`` (..., 3) of ECEF ``xyz`` (..., 3) [m]: fixed-point iteration on the
    latitude (each step shrinks the error by ~e² h/N; 6 steps reach round-off within ~100 km of the surface)."""
    x, y, z = np.moveaxis(np.asarray(xyz, dtype=float), -1, 0)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(iterations):
        N = A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
        h = p * np.cos(lat) + z * np.sin(lat) - A * np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
        lat = np.arctan2(z, p * (1.0 - E2 * N / (N + h)))
    h = p * np.cos(lat) + z * np.sin(lat) - A * np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
    return np.stack([lat, np.arctan2(y, x), h], axis=-1)


def pressure_to_depth(p: np.ndarray, density: float, atmospheric: float, gravity: float) -> np.ndarray:
    """Depth [m, positive down] of absolute pressure ``p`` [Pa]: ``(p − atmospheric) / (density · gravity)``
    with ``density`` [kg/m³], ``atmospheric`` [Pa] and ``gravity`` [m/s²] (hydrostatic, constant density)."""
    return (np.asarray(p, dtype=float) - atmospheric) / (density * gravity)
