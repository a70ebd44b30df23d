"""What a ROS bag says about itself, for ``nespm import``: the topics (``nespm import BAG --list``), the
``frame_id`` of each topic's messages checked against the import spec's ``[frames]``, and the import origin
taken from the first GNSS fix (``origin = "first-fix"``). docs/rosbags.md.

Frames: a ``frame_id`` (or an Odometry's ``child_frame_id``) is split into words at every character that is
not a letter or digit (``odom_ned`` -> ``odom``, ``ned``); the words ``enu``/``ned`` name a world frame and
``flu``/``frd`` a body frame (the PX4/MAVROS and REP-103/105 spellings: ``odom_ned``, ``base_link_frd``). A
frame word that contradicts the spec's frame for that message is refused in one line naming the spec key, the
topic and the frame_id; a frame_id without such a word says nothing (``base_link``, ``odom``).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from nespm_cli.data.plausibility import printable
from nespm_cli.errors import NespmError

WORLD_WORDS, BODY_WORDS = ("enu", "ned"), ("flu", "frd")


def frame_words(frame_id: str, words: tuple) -> set[str]:
    """The frame words of ``words`` that ``frame_id`` holds (``"odom_ned"`` -> ``{"ned"}``)."""
    return set(re.split(r"[^a-z0-9]+", str(frame_id).lower())) & set(words)


def first_frame_ids(reader, topics: dict[str, str]) -> dict[str, tuple[str | None, str | None]]:
    """``{spec key: (header.frame_id, child_frame_id)}`` of the first message of each topic of ``topics``
    (``{spec key: topic}``); None where the message has no such field or cannot be read."""
    out: dict[str, tuple] = {}
    want = {t for t in topics.values()}
    got: dict[str, tuple] = {}
    conns = [c for c in reader.connections if c.topic in want]
    for conn, _, raw in reader.messages(connections=conns):
        if conn.topic in got:
            if len(got) == len(want):
                break
            continue
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:  # noqa: BLE001 - read_requests names an unreadable message
            got[conn.topic] = (None, None)
            continue
        header = getattr(msg, "header", None)
        got[conn.topic] = (getattr(header, "frame_id", None), getattr(msg, "child_frame_id", None))
    for key, topic in topics.items():
        out[key] = got.get(topic, (None, None))
    return out


def check_frames(spec_path: Path, spec: dict, ids: dict) -> None:
    """Refuse a bag whose frame_ids contradict the spec's frames (module docstring). ``ids`` from
    :func:`first_frame_ids` keyed by the spec's topic keys (``gt.topic``, ``imu.topic``, ...)."""
    frames = spec["frames"]

    def body_of(channel: str) -> tuple[str, str]:
        if "body" in spec.get(channel, {}):
            return spec[channel]["body"], f"{channel}.body"
        return frames["body"], "frames.body"

    for key, (fid, child) in ids.items():
        channel, what = key.split(".")
        checks = []  # (frame_id field, the id, expected value, spec key, words)
        if channel == "gt":
            twist_world = spec["gt"].get("twist_frame", "body") == "world"
            if what in ("topic", "pose_topic") or (what == "twist_topic" and twist_world):
                checks.append(("header.frame_id", fid, frames["world"], "frames.world", WORLD_WORDS))
            else:
                checks.append(("header.frame_id", fid, *body_of("gt"), BODY_WORDS))
            if what == "topic":
                checks.append(("child_frame_id", child, *body_of("gt"), BODY_WORDS))
        elif channel in ("imu", "dvl"):
            checks.append(("header.frame_id", fid, *body_of(channel), BODY_WORDS))
        for field, value, expected, spec_key, words in checks:
            if value is None:
                continue
            said = frame_words(value, words)
            if said and expected not in said:
                other = sorted(said)[0]
                raise NespmError(
                    f"{spec_path}: key '{spec_key}' is {expected!r} but topic {spec[channel][what]!r} (key {key}) has "
                    f"{field} {printable(repr(value), 60)}, which says {other.upper()}: set {spec_key} = {other!r} "
                    f"(or check the bag; a {other.upper()} bag read as {expected.upper()} comes in mirrored)")


def list_bag(reader) -> list[dict]:
    """One row per topic of the open bag ``reader``: ``topic``, ``type``, ``count``, ``rate_hz`` (messages
    per second of bag time over the topic's span; None below 2 messages), ``frame_id`` and ``child_frame_id``
    of its first message (None when it has none), sorted by topic."""
    times: dict[str, list[int]] = {}
    first: dict[str, tuple] = {}
    for conn, ns, raw in reader.messages():
        times.setdefault(conn.topic, []).append(int(ns))
        if conn.topic not in first:
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                header = getattr(msg, "header", None)
                first[conn.topic] = (getattr(header, "frame_id", None), getattr(msg, "child_frame_id", None))
            except Exception:  # noqa: BLE001 - a type without a definition: no frame_id shown
                first[conn.topic] = (None, None)
    rows = []
    for topic, info in sorted(reader.topics.items()):
        ns = np.asarray(times.get(topic, []), dtype=np.int64)
        span = (int(ns.max()) - int(ns.min())) / 1e9 if len(ns) > 1 else 0.0
        fid, child = first.get(topic, (None, None))
        rows.append({"topic": topic, "type": info.msgtype or "(several)", "count": int(len(ns)),
                     "rate_hz": (len(ns) - 1) / span if span > 0 else None, "frame_id": fid,
                     "child_frame_id": child})
    return rows


def list_text(bag: Path, kind: str, rows: list[dict]) -> str:
    """The table ``nespm import BAG --list`` prints (plain text, one row per topic)."""
    head = ("topic", "type", "messages", "rate [Hz]", "frame_id", "child_frame_id")
    cells = [[printable(r["topic"], 60), r["type"], str(r["count"]),
              "" if r["rate_hz"] is None else f"{r['rate_hz']:.4g}",
              "" if r["frame_id"] is None else printable(repr(r["frame_id"]), 40),
              "" if r["child_frame_id"] is None else printable(repr(r["child_frame_id"]), 40)] for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(head)]
    line = lambda c: "  ".join(x.ljust(w) for x, w in zip(c, widths)).rstrip()  # noqa: E731
    return "\n".join([f"{bag} ({kind}): {len(rows)} topics", line(head), line(["-" * w for w in widths])]
                     + [line(c) for c in cells])


def first_fix_origin(spec: dict, data: dict, W: np.ndarray, local_to_geodetic) -> dict:
    """``{"lat_deg", "lon_deg", "alt_m", "model", "from"}``: the origin of the GT's local frame such that
    the GT position at the first valid fix inside the GT span (status >= 0, finite; the local pose
    interpolated at its stamp) is that fix. ``alt_m``: from the fix's altitude with ``fix.vertical``, else
    0 (the sea surface, as without ``first-fix``). ``W`` the world -> NED rotation; ``local_to_geodetic`` the
    conversion the import uses (three fixed-point steps: the flat model is linear to 1e-12)."""
    fix = data["fix.topic"]
    pose = data.get("gt.topic") or data["gt.pose_topic"]
    order = np.argsort(pose.stamp_ns, kind="stable")
    p_ns, p = pose.stamp_ns[order], pose.values["position"][order] @ W.T
    f_order = np.argsort(fix.stamp_ns, kind="stable")
    lat, lon = fix.values["latitude"][f_order], fix.values["longitude"][f_order]
    ok = np.isfinite(lat) & np.isfinite(lon) & (fix.stamp_ns[f_order] >= p_ns[0]) & (fix.stamp_ns[f_order] <= p_ns[-1])
    if "status" in fix.values:
        ok &= fix.values["status"][f_order] >= 0
    if not ok.any():
        raise NespmError(f"spec key origin: origin = \"first-fix\" but topic {fix.topic!r} has no valid fix (status >= 0, "
                         "finite) inside the GT span; give an [origin] table")
    i = int(np.flatnonzero(ok)[0])
    ns = int(fix.stamp_ns[f_order][i])
    dt = (p_ns - p_ns[0]).astype(float)
    ned = np.array([np.interp(float(ns - p_ns[0]), dt, p[:, j]) for j in range(3)])
    alt = 0.0
    if spec["fix"].get("vertical") and "altitude" in fix.values and np.isfinite(fix.values["altitude"][f_order][i]):
        alt = float(fix.values["altitude"][f_order][i]) + float(ned[2])  # alt = alt0 - D
    target = np.array([np.radians(lat[i]), np.radians(lon[i])])
    origin = np.array([target[0], target[1], alt])
    for _ in range(3):
        pos = local_to_geodetic(ned[None], origin, "flat")[0]
        origin[:2] += target - pos[:2]
    return {"lat_deg": float(np.degrees(origin[0])), "lon_deg": float(np.degrees(origin[1])), "alt_m": alt,
            "model": "flat", "from": f"first fix of {fix.topic!r} at stamp {ns} ns"}
