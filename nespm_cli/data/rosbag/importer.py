"""``nespm import``: a ROS 1 or ROS 2 bag -> an A-KIT track folder (docs/rosbags.md, docs/data-format.md).

:func:`import_bag` reads the topics an import spec names (:mod:`nespm_cli.data.rosbag.spec`) with
``rosbags`` (:mod:`nespm_cli.data.rosbag.messages`), converts them to the bench's frames and units and
writes ``OUT/TrajectoryN``: the GT file (``[lon, lat rad, alt m]``, NED velocity [m/s], ZYX Euler angles
body FRD -> NED [rad]), the DVL file (body FRD [m/s], on the GT epochs when its stamps are the GT's, else
at its own), the IMU file (specific force [m/s²] and rate [rad/s], body FRD) and the DEPTH (m, down) and
FIX (``lat, lon`` rad, ``alt`` m up) files at their own stamps; beside them the spec (``import-spec.toml``)
and what was taken from where (``IMPORT.md``, ``import.json``).

Time: stamps (``header.stamp`` unless the spec says otherwise) are int64 ns; each channel is sorted by
stamp and a repeated stamp keeps its first message; the file time is ``(stamp − zero) / 1e9`` s with
``zero`` the first GT stamp (``time.zero``), exact in integer ns before the one division. DVL, depth and
fix samples outside the GT span are left out, the IMU keeps one sample beyond each end.

The folder is written beside ``OUT/TrajectoryN`` first and checked with :func:`~nespm_cli.data.tracks.load_track`
(any refusal is one line and nothing is installed), then moved into place; an existing track is refused
unless ``overwrite``. The bag is only read.
"""
from __future__ import annotations

import json
import re
import shutil
import uuid
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.data.conventions import ACCEPT_HINT
from nespm_cli.data.rosbag.messages import (BODY_TO_FRD, WORLD_TO_NED, Request, bag_kind, local_to_geodetic,
                                            open_bag, pressure_to_depth, quat_to_dcm, read_requests)
from nespm_cli.data.rosbag.inspect_bag import check_frames, first_fix_origin, first_frame_ids
from nespm_cli.data.rosbag.spec import paths_for, read_spec
from nespm_cli.data.sensor_files import dvl_at_epochs
from nespm_cli.data.track import Track
from nespm_cli.data.track_spec.schema import SPEC_NAME, find_spec
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import dcm_to_euler

SPEC_COPY, NOTE_MD, NOTE_JSON = "import-spec.toml", "IMPORT.md", "import.json"
NS = 1_000_000_000


@dataclass
class ImportResult:
    """What :func:`import_bag` wrote: the track folder, the per-channel records (as in ``import.json``)
    and the data warnings the bench's checks gave on it (one line each)."""

    track_dir: Path
    record: dict
    warnings: list[str] = field(default_factory=list)


def import_bag(bag: str | Path, spec_path: str | Path, out: str | Path, *, track: int | None = None,
               overwrite: bool = False) -> ImportResult:
    """Import ``bag`` per the spec ``spec_path`` into the data folder ``out`` as track ``track`` (None: the
    spec's ``track``); raises :class:`NespmError` (one line naming the file, topic or key) on bad input."""
    bag, spec_path, out = Path(bag).expanduser(), Path(spec_path).expanduser(), Path(out).expanduser()
    spec = read_spec(spec_path)
    number = spec[""]["track"] if track is None else int(track)
    if number < 1:
        raise NespmError(f"--track must be at least 1, got {number}")
    bag, kind = bag_kind(bag)
    existing = _check_out(out, number, bag, overwrite)
    reader = open_bag(bag, spec["bag"]["typestore"], spec["bag"]["types"])
    try:
        topics = {key: reader.topics.get(req.topic) for key, req in _topic_keys(spec).items()}
        data = read_requests(reader, _requests(spec, spec_path, topics), bag)
        start_ns = int(reader.start_time)
        check_frames(spec_path, spec, first_frame_ids(reader, {k: r.topic for k, r in _topic_keys(spec).items()}))
    finally:
        reader.close()
    if spec["origin"].get("first_fix"):
        spec["origin"] = first_fix_origin(spec, data, WORLD_TO_NED[spec["frames"]["world"]], local_to_geodetic)
    ctx = {"spec": spec, "data": data}
    gt_t, pos, v_n, euler, rec = _gt(ctx)
    zero = {"gt": int(gt_t[0]), "bag": start_ns, "none": 0}[spec["time"]["zero"]]
    seconds = lambda ns: (ns - zero) / NS  # noqa: E731 - exact integer ns, one rounding
    channels, records, dvl = {}, [rec], np.full((len(gt_t), 3), np.nan)
    imu = None
    if "imu" in spec:
        ns, f_w, rec = _imu(ctx, gt_t)
        imu = np.column_stack([seconds(ns), f_w])
        records.append(rec)
    if "dvl" in spec:
        ns, v, rec = _dvl(ctx, gt_t)
        records.append(rec)
        if len(ns) == len(gt_t) and np.array_equal(ns, gt_t):
            dvl = v
        else:
            channels["dvl"] = (seconds(ns), v)
            dvl = dvl_at_epochs(seconds(ns), v, seconds(gt_t)) if len(ns) > 1 else dvl
    for name, convert in (("depth", _depth), ("fix", _fix)):
        if name in spec:
            ns, z, rec = convert(ctx, gt_t)
            channels[name] = (seconds(ns), z)
            records.append(rec)
    for rec in records:
        rec["span_s"] = [float(seconds(rec.pop("first_ns"))), float(seconds(rec.pop("last_ns")))] \
            if "first_ns" in rec else None
    result = Track(number=number, t=seconds(gt_t), pos=pos, v_n=v_n, euler=euler, dvl=dvl, imu=imu,
                   source=str(bag), channels=channels)
    record = {"bag": str(bag.resolve()), "bag_kind": kind, "spec": str(spec_path.resolve()), "track": number,
              "time_zero_ns": zero, "time_zero": spec["time"]["zero"], "frames": spec["frames"],
              "origin": spec["origin"], "channels": records, "rosbags": _version("rosbags")}
    return _install(result, record, spec_path, out, existing, dvl_file="dvl" in spec)


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "unknown"


def _topic_keys(spec: dict) -> dict[str, Request]:
    """``{spec key: Request without fields}`` of every topic the spec names."""
    out = {}
    for name in ("gt", "imu", "dvl", "depth", "fix"):
        table = spec.get(name, {})
        for key in ("topic", "pose_topic", "twist_topic"):
            if key in table:
                stamp = table.get("stamp", spec["time"]["stamp"])
                out[f"{name}.{key}"] = Request(f"{name}.{key}", table[key], {}, stamp)
    return out


#: the fields every topic key needs, with their kinds (:data:`nespm_cli.data.rosbag.messages.KINDS`)
NEEDED = {"gt.topic": {"position": "vec3", "orientation": "quat", "velocity": "vec3"},
          "gt.pose_topic": {"position": "vec3", "orientation": "quat"}, "gt.twist_topic": {"velocity": "vec3"},
          "imu.topic": {"angular_velocity": "vec3", "linear_acceleration": "vec3"}, "dvl.topic": {"velocity": "vec3"},
          "fix.topic": {"latitude": "scalar", "longitude": "scalar"}}


def _requests(spec: dict, spec_path: Path, topics: dict) -> list[Request]:
    """The :class:`Request` of every topic key, its field paths from the spec or the known types."""
    reqs = []
    for key, req in _topic_keys(spec).items():
        info = topics[key]
        if info is None or info.msgtype is None:
            reqs.append(req)  # read_requests names the missing topic / mixed types
            continue
        table = spec[key.split(".")[0]]
        need, optional = dict(NEEDED.get(key, {})), {}
        if key == "dvl.topic":
            optional = {"valid": "scalar"}
        elif key == "fix.topic":
            optional = {"status": "scalar"}
            (need if table["vertical"] else optional)["altitude"] = "scalar"
        elif key == "depth.topic":
            need = {"depth" if "depth" in table else "pressure": "scalar"}
        paths = paths_for(spec_path, key, table, info.msgtype, req.topic, tuple(need), tuple(optional))
        kinds = {**need, **optional}
        req.fields = {f: (p, kinds[f]) for f, p in paths.items()}
        reqs.append(req)
    return reqs


def _order(ns: np.ndarray) -> tuple[np.ndarray, int]:
    """Indices that sort the stamps ``ns`` (stable), each stamp once (its first message); and the number left out."""
    order = np.argsort(ns, kind="stable")
    keep = np.r_[True, np.diff(ns[order]) > 0]
    return order[keep], int((~keep).sum())


def _record(name: str, file: str, d, written: int, **extra) -> dict:
    """One channel's entry of ``import.json``: where it came from and how many rows were written."""
    return {"channel": name, "file": file, "topic": d.topic, "type": d.msgtype, "messages": d.count,
            "written": written, **extra}


def _finite(key: str, d, arrays: dict) -> None:
    """Refuse a non-finite value in ``arrays`` (bag order), naming the topic, the message and its stamp."""
    for name, a in arrays.items():
        bad = np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise NespmError(f"spec key {key}: message {i + 1} of topic {d.topic!r} (stamp {int(d.stamp_ns[i])} ns): "
                             f"{name} is not finite ({a[i]})")


def _gt(ctx: dict):
    """GT epochs (K,) [ns], ``pos`` (K, 3) ``[lat, lon rad, alt m]``, ``v_n`` (K, 3) NED [m/s], ``euler`` (K, 3)
    [rad] and the channel's record."""
    spec, data = ctx["spec"], ctx["data"]
    gt, frames = spec["gt"], spec["frames"]
    W, B = WORLD_TO_NED[frames["world"]], BODY_TO_FRD[gt.get("body", frames["body"])]
    pose = data.get("gt.topic") or data["gt.pose_topic"]
    key = "gt.topic" if "gt.topic" in data else "gt.pose_topic"
    _finite(key, pose, pose.values)
    norm = np.linalg.norm(pose.values["orientation"], axis=1)
    if np.any(norm < 0.5):
        i = int(np.flatnonzero(norm < 0.5)[0])
        raise NespmError(f"spec key {key}: message {i + 1} of topic {pose.topic!r}: orientation quaternion of "
                         f"norm {norm[i]:.3g} (not a rotation)")
    idx, dups = _order(pose.stamp_ns)
    idx = idx[::gt["every"]]
    ns = pose.stamp_ns[idx]
    twist, unmatched, frame = pose, 0, gt.get("twist_frame", "body")
    velocity = pose.values["velocity"][idx] if "velocity" in pose.values else None
    if velocity is None:  # a separate twist topic: the twist nearest each pose stamp, within sync_tolerance
        twist = data["gt.twist_topic"]
        _finite("gt.twist_topic", twist, twist.values)
        tidx, _ = _order(twist.stamp_ns)
        tns = twist.stamp_ns[tidx]
        after = np.searchsorted(tns, ns)
        lo, hi = np.clip(after - 1, 0, len(tns) - 1), np.clip(after, 0, len(tns) - 1)
        j = np.where(np.abs(tns[lo] - ns) <= np.abs(tns[hi] - ns), lo, hi)
        ok = np.abs(tns[j] - ns) <= round(gt["sync_tolerance"] * NS)
        unmatched = int((~ok).sum())
        idx, ns, velocity = idx[ok], ns[ok], twist.values["velocity"][tidx[j[ok]]]
    if len(ns) < 2:
        raise NespmError(f"spec key {key}: topic {pose.topic!r} gives {len(ns)} GT epoch(s); at least 2 are needed")
    R = quat_to_dcm(pose.values["orientation"][idx])
    C_bn = W @ R @ B
    v_n = (W @ R @ velocity[..., None])[..., 0] if frame == "body" else velocity @ W.T
    origin = np.array([np.radians(spec["origin"]["lat_deg"]), np.radians(spec["origin"]["lon_deg"]),
                       float(spec["origin"]["alt_m"])])
    pos = local_to_geodetic(pose.values["position"][idx] @ W.T, origin, spec["origin"]["model"])
    body = gt.get("body", frames["body"]).upper()
    conv = [f"position: local metres {_turn(frames['world'], 'NED')} about the origin -> lat, lon, alt "
            f"({spec['origin']['model']})",
            f"orientation: quaternion (body {body} -> world {frames['world'].upper()}) -> C_bn (body FRD -> NED) "
            "-> roll, pitch, yaw (ZYX)",
            f"velocity: {frame} frame" + (f" {body}, rotated by the orientation to NED" if frame == "body"
                                          else f" {_turn(frames['world'], 'NED')}")]
    rec = _record("gt", "GT", pose, len(ns), duplicates=dups, every=gt["every"], first_ns=int(ns[0]),
                  last_ns=int(ns[-1]), conversions=conv, max_quaternion_norm_error=float(np.abs(norm - 1).max()))
    if twist is not pose:
        rec.update(twist_topic=twist.topic, twist_type=twist.msgtype, twist_messages=twist.count,
                   unmatched_poses=unmatched)
    return ns, pos, v_n, dcm_to_euler(C_bn), rec


def _in_span(ns: np.ndarray, gt_ns: np.ndarray, idx: np.ndarray, bracket: bool = False) -> np.ndarray:
    """``idx`` (sorted stamps) kept inside the GT span; with ``bracket`` one sample beyond each end too."""
    s = ns[idx]
    lo, hi = np.searchsorted(s, gt_ns[0], "left"), np.searchsorted(s, gt_ns[-1], "right")
    if bracket:
        lo = lo - 1 if lo > 0 and (lo == len(s) or s[lo] > gt_ns[0]) else lo
        hi = hi + 1 if hi < len(s) and s[hi - 1] < gt_ns[-1] else hi
    return idx[lo:hi]


def _turn(src: str, dst: str) -> str:
    """``"FLU -> FRD"``, or ``"FRD (as is)"`` when the frames are the same."""
    return f"{src.upper()} -> {dst}" if src.upper() != dst else f"{dst} (as is)"


def _channel(ctx, name: str, gt_ns, bracket: bool = False, required: bool = False):
    """(topic data, indices kept inside the GT span, the record's counts) of channel ``name``; ``required``:
    refuse a channel without a sample inside the span."""
    d = ctx["data"][f"{name}.topic"]
    idx, dups = _order(d.stamp_ns)
    kept = _in_span(d.stamp_ns, gt_ns, idx, bracket)
    if required and len(kept) < 2:
        span = f"{d.stamp_ns[idx[0]]} .. {d.stamp_ns[idx[-1]]} ns"
        raise NespmError(f"spec key {name}.topic: topic {d.topic!r} has {len(kept)} message(s) in the GT span "
                         f"{gt_ns[0]} .. {gt_ns[-1]} ns (its stamps: {span}; at least 2 are needed)")
    counts = {"duplicates": dups, "outside_gt_span": int(len(idx) - len(kept))}
    if len(kept):
        counts.update(first_ns=int(d.stamp_ns[kept[0]]), last_ns=int(d.stamp_ns[kept[-1]]))
    return d, kept, counts


def _imu(ctx: dict, gt_ns: np.ndarray):
    """IMU stamps (M,) [ns] and ``[f_b m/s², w_ib_b rad/s]`` (M, 6) in FRD."""
    spec = ctx["spec"]
    body = spec["imu"].get("body", spec["frames"]["body"])
    d, k, counts = _channel(ctx, "imu", gt_ns, bracket=True, required=True)
    _finite("imu.topic", d, d.values)
    B = BODY_TO_FRD[body]
    f_w = np.hstack([d.values["linear_acceleration"][k] @ B.T, d.values["angular_velocity"][k] @ B.T])
    conv = [f"linear_acceleration (specific force) and angular_velocity: body {_turn(body, 'FRD')}",
            "samples as recorded (row i taken as the step (t[i-1], t[i]])"]
    return d.stamp_ns[k], f_w, _record("imu", "IMU", d, len(k), conversions=conv, **counts)


def _dvl(ctx: dict, gt_ns: np.ndarray):
    """DVL stamps (K,) [ns] and body FRD velocity (K, 3) [m/s]: a NaN row where ``valid`` is false or a value
    is NaN."""
    spec = ctx["spec"]
    body = spec["dvl"].get("body", spec["frames"]["body"])
    d, k, counts = _channel(ctx, "dvl", gt_ns, required=True)
    v = d.values["velocity"][k] @ BODY_TO_FRD[body].T
    bad = ~np.isfinite(v).all(axis=1)
    if "valid" in d.values:
        bad |= d.values["valid"][k] == 0
    v[bad] = np.nan
    conv = [f"velocity: body {_turn(body, 'FRD')}"] + (["valid false -> NaN row"] if "valid" in d.values else [])
    rec = _record("dvl", "DVL", d, len(k), no_measurement=int(bad.sum()), conversions=conv, **counts)
    return d.stamp_ns[k], v, rec


def _depth(ctx: dict, gt_ns: np.ndarray):
    """Depth stamps (K,) [ns] and depth (K, 1) [m, positive down]."""
    t = ctx["spec"]["depth"]
    d, k, counts = _channel(ctx, "depth", gt_ns)
    if "pressure" in d.values:
        z = pressure_to_depth(d.values["pressure"][k], t["density"], t["atmospheric"], t["gravity"])
        conv = [f"depth = (pressure - {t['atmospheric']:g} Pa) / ({t['density']:g} kg/m^3 x "
                f"{t['gravity']:g} m/s^2)"]
    else:
        z = d.values["depth"][k] * (1.0 if t["positive"] == "down" else -1.0)
        conv = [f"depth field, positive {t['positive']}" + (" (sign changed)" if t["positive"] == "up" else "")]
    z = z.reshape(-1, 1)
    return d.stamp_ns[k], z, _record("depth", "DEPTH", d, len(k), no_measurement=int(np.isnan(z).sum()),
                                     conversions=conv, **counts)


def _fix(ctx: dict, gt_ns: np.ndarray):
    """Fix stamps (K,) [ns] and ``[lat, lon rad(, alt m)]`` (K, 2|3); a NaN row for no fix (status < 0, NaN)."""
    t = ctx["spec"]["fix"]
    d, k, counts = _channel(ctx, "fix", gt_ns)
    cols = [np.radians(d.values["latitude"][k]), np.radians(d.values["longitude"][k])]
    if t["vertical"]:
        cols.append(d.values["altitude"][k])
    z = np.column_stack(cols)
    bad = ~np.isfinite(z).all(axis=1)
    if "status" in d.values:
        bad |= d.values["status"][k] < 0
    z[bad] = np.nan
    conv = ["latitude, longitude: degrees -> rad"]
    if t["vertical"]:
        conv.append("altitude: m above the WGS-84 ellipsoid, positive up")
    if "status" in d.values:
        conv.append("status < 0 (no fix) -> NaN row")
    return d.stamp_ns[k], z, _record("fix", "FIX", d, len(k), no_measurement=int(bad.sum()), conversions=conv,
                                     **counts)


# ----------------------------------------------------------------------------- the track folder


def _check_out(out: Path, number: int, bag: Path, overwrite: bool) -> list[Path]:
    """The existing folders of track ``number`` in ``out`` (refused without ``overwrite``); refuses an ``out``
    that is a file or lies inside the bag, and replacing a folder that holds the bag."""
    if out.exists() and not out.is_dir():
        raise NespmError(f"--out {out}: exists and is not a folder")
    if out.is_dir() and find_spec(out) is not None:
        raise NespmError(f"--out {out}: holds a track spec ({SPEC_NAME}), through which the folder is read: an imported "
                         "TrajectoryN there would be hidden by it; import into another folder")
    bag_r, out_r = bag.resolve(), out.resolve()
    if bag_r.is_dir() and (out_r == bag_r or bag_r in out_r.parents):
        raise NespmError(f"--out {out}: is inside the bag folder {bag}; choose another folder")
    pat = re.compile(rf"Trajectory0*{number}")
    existing = sorted(p for p in out.iterdir() if pat.fullmatch(p.name)) if out.is_dir() else []
    if existing and not overwrite:
        raise NespmError(f"{existing[0]}: track {number} exists already; --overwrite replaces it")
    for p in existing:
        if p.resolve() == bag_r or p.resolve() in bag_r.parents:
            raise NespmError(f"{p}: holds the bag {bag}; it is not replaced (choose another --out or track)")
    return existing


def _install(track: Track, record: dict, spec_path: Path, out: Path, existing: list[Path],
             dvl_file: bool) -> ImportResult:
    """Write ``track`` into a staging folder in ``out``, check it with ``load_track``, add the spec and the
    notes, then move it to ``out/TrajectoryN`` (replacing ``existing``)."""
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    stage = out / f".nespm-import-{uuid.uuid4().hex[:8]}"
    final = out / f"Trajectory{track.number}"
    installed = False
    try:
        tdir = write_akit(track, stage)
        with _warnings.catch_warnings(record=True) as caught:
            _warnings.simplefilter("always")
            try:
                load_track(track.number, stage, warnings="warn")
            except NespmError as exc:
                text = str(exc).replace(str(tdir), str(final)).replace(  # the IMU's units: the bag's topic, not a file
                    "the A-KIT columns are", "sensor_msgs/Imu is rad/s and m/s^2 (REP-103); spec key imu.topic's "
                    "messages are not, the columns written are")
                if "upside down" in text:  # the roll test of data.conventions: the body frame declared wrong
                    text = text.replace("(a bag's frames.body)", f"(set key 'frames.body' of {spec_path.name} to "
                                        "the other of flu, frd)").replace(f"; {ACCEPT_HINT}", "")
                raise NespmError(f"{text} (the imported track is refused; nothing written)") from None
        found = [str(w.message).replace(str(tdir), str(final)) for w in caught]
        record["warnings"] = found
        if not dvl_file:
            record["channels"].append({"channel": "dvl", "file": "DVL", "topic": None, "written": len(track.t),
                                       "conversions": ["no [dvl] in the spec: NaN rows (no measurement) on the "
                                                       "GT epochs"]})
        shutil.copyfile(spec_path, tdir / SPEC_COPY)
        write_text_atomic(tdir / NOTE_JSON, json.dumps(record, indent=2, default=str) + "\n")
        write_text_atomic(tdir / NOTE_MD, note_markdown(record))
        trash = [(p, p.rename(out / f".nespm-replaced-{uuid.uuid4().hex[:8]}")) for p in existing]
        try:
            tdir.rename(final)
        except OSError:
            for old, moved in trash:  # put the old track back
                moved.rename(old)
            raise
        installed = True
        for _, moved in trash:
            remove_tree(moved)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not installed and not any(out.iterdir()):
            out.rmdir()  # a refused import leaves no trace
    return ImportResult(final, record, found)


def remove_tree(path: Path) -> None:
    """Remove a replaced track ``path``: a symbolic link itself (never what it points to), else the folder with
    its read-only files and folders made writable first; what cannot be removed is one line (no leftover
    ``.nespm-replaced-*`` without a word)."""
    import os
    import stat

    if path.is_symlink() or not path.is_dir():
        path.unlink()
        return

    def writable(func, p, _exc):
        os.chmod(p, stat.S_IRWXU)
        parent = os.path.dirname(p)
        os.chmod(parent, os.stat(parent).st_mode | stat.S_IWUSR | stat.S_IXUSR)
        func(p)

    for root, dirs, _ in os.walk(path):
        for d in dirs:
            q = os.path.join(root, d)
            if not os.path.islink(q):
                os.chmod(q, os.stat(q).st_mode | stat.S_IRWXU)
    os.chmod(path, os.stat(path).st_mode | stat.S_IRWXU)
    try:
        shutil.rmtree(path, onerror=writable)
    except OSError as exc:
        raise NespmError(f"{path}: the replaced track could not be removed ({exc.strerror}); the new one is installed, "
                         "remove this folder by hand") from None


def note_markdown(record: dict) -> str:
    """``IMPORT.md``: the bag, the spec, the time zero, frames and origin, and one row per channel."""
    from datetime import datetime, timezone

    zero, o = record["time_zero_ns"], record["origin"]
    utc = datetime.fromtimestamp(zero // NS, timezone.utc).strftime("%Y-%m-%d %H:%M:%S") + f".{zero % NS:09d} UTC"
    lines = [f"# Track {record['track']} imported from a ROS bag", "",
             f"- bag: `{record['bag']}` ({record['bag_kind']}, read with rosbags {record['rosbags']}; not modified)",
             f"- spec: `{record['spec']}` (copied here as `{SPEC_COPY}`; the same record as JSON: `{NOTE_JSON}`)",
             f"- time: file time [s] = (stamp − {zero} ns) / 1e9, zero = {utc} ({record['time_zero']})",
             f"- frames: world {record['frames']['world'].upper()}, body {record['frames']['body'].upper()} "
             "(a channel's own `body` below); written: NED, body FRD (docs/conventions.md)",
             f"- origin: lat {o['lat_deg']!r} deg, lon {o['lon_deg']!r} deg, alt {o['alt_m']!r} m "
             f"({o['model']} local frame{'; ' + o['from'] if o.get('from') else ''})", "",
             "| channel | file | topic | type | messages | rows written | duplicates | outside GT span | "
             "no measurement | span [s] | conversions |", "| --- " * 11 + "|"]
    for c in record["channels"]:
        span = "" if not c.get("span_s") else f"{c['span_s'][0]:.10g} .. {c['span_s'][1]:.10g}"
        topic = c["topic"] if "twist_topic" not in c else f"{c['topic']} + {c['twist_topic']}"
        typ = c.get("type", "") if "twist_type" not in c else f"{c['type']} + {c['twist_type']}"
        cells = [c["channel"], c["file"], f"`{topic}`" if topic else "", typ, c.get("messages", ""), c["written"],
                 c.get("duplicates", ""), c.get("outside_gt_span", ""), c.get("no_measurement", ""), span,
                 "; ".join(c["conversions"])]
        lines.append("| " + " | ".join(str(x) for x in cells) + " |")
    gt = record["channels"][0]
    if gt.get("unmatched_poses") is not None:
        lines += ["", f"GT: {gt['unmatched_poses']} pose(s) without a twist within the sync tolerance left out."]
    if gt.get("every", 1) > 1:
        lines += ["", f"GT: one message in every {gt['every']} kept (gt.every)."]
    found = record.get("warnings", [])
    lines += ["", "The bench's checks of the written track (load_track): " + ("passed, no warnings." if not found
                                                                           else "passed, with these warnings:")]
    lines += [f"- {w}" for w in found]
    return "\n".join(lines) + "\n"
