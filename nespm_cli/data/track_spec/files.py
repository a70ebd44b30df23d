"""The files of a track spec's tracks: which track numbers a spec's file patterns find in the data folder
(:func:`spec_tracks`) and the file of each table for one track (:func:`spec_file`, :func:`spec_files`).
docs/data.md, "A track spec: your own files". Refusals are one line naming the spec file and its key.
"""
from __future__ import annotations

import glob
import re
from pathlib import Path

from nespm_cli.data.track_spec.schema import TrackSpec
from nespm_cli.errors import NespmError



def _matches(spec: TrackSpec, name: str) -> dict[int, list[str]]:
    """``{N: [relative paths]}`` of the files table ``name``'s pattern finds in the data folder."""
    pat = spec.tables[name]["file"]
    if "{N}" not in pat:
        p = spec.folder / pat
        return {spec.track: [pat]} if p.is_file() or p.is_symlink() else {}  # a looped link: named on reading
    parts = pat.split("{N}")
    rx = re.compile(r"(\d+)".join(re.escape(p) for p in parts))
    out: dict[int, list[str]] = {}
    for p in sorted(spec.folder.glob("*".join(glob.escape(p) for p in parts))):
        rel = p.relative_to(spec.folder).as_posix()
        m = rx.fullmatch(rel)
        if m and (p.is_file() or p.is_symlink()) and len({int(g) for g in m.groups()}) == 1:
            out.setdefault(int(m.group(1)), []).append(rel)
    return out


def spec_tracks(spec: TrackSpec) -> list[int]:
    """The track numbers whose GT file the spec's ``gt.file`` finds (without ``[gt]``: its DVL files), sorted;
    none is one line."""
    a = spec.anchor
    found = sorted(_matches(spec, a))
    if not found:
        raise NespmError(f"{spec.path}: key '{a}.file': no file matches {spec.tables[a]['file']!r} in {spec.folder}")
    return found


def spec_file(spec: TrackSpec, name: str, number: int) -> Path | None:
    """The file of table ``name`` for track ``number``; None when it is missing and ``optional``. Refused: no
    GT file (no such track; without ``[gt]`` no DVL file), a missing file of another table (a truth-free
    spec's IMU file too, whatever its ``optional``), two files of one track (``run7``, ``run07``)."""
    pat = spec.tables[name]["file"]
    found = _matches(spec, name).get(number, [])
    if len(found) > 1:
        raise NespmError(f"{spec.path}: key '{name}.file': {found[0]} and {found[1]} are both track {number}; keep one")
    if found:
        return spec.folder / found[0]
    if name == spec.anchor:
        have = ", ".join(map(str, sorted(_matches(spec, name)))) or "none"
        raise NespmError(f"{spec.path}: no track {number} (key '{name}.file' {pat!r} finds tracks: {have})")
    if spec.tables[name]["optional"] and not (name == "imu" and spec.init is not None):
        return None
    raise NespmError(f"{spec.path}: key '{name}.file': no file {pat.replace('{N}', str(number))!r} for track {number} "
                     f"in {spec.folder} (set {name}.optional = true if some tracks have none)")


def spec_files(spec: TrackSpec, number: int, imu: bool = False) -> list[Path]:
    """The files track ``number`` is read from: the spec itself, the GT and DVL file, the IMU file with
    ``imu`` (required then: no ``[imu]`` table or no file is one line), then the depth and fix files found.
    Without ``[gt]``: the spec, the DVL and the IMU file (always: the track is read with it), then the others."""
    if spec.init is not None:
        return [spec.path, spec_file(spec, "dvl", number), spec_file(spec, "imu", number)] + \
            [p for n in ("depth", "fix") if n in spec.tables and (p := spec_file(spec, n, number))]
    files = [spec.path, spec_file(spec, "gt", number), spec_file(spec, "dvl", number)]
    if imu:
        if "imu" not in spec.tables:
            raise NespmError(f"{spec.path}: no [imu] table (--imu recorded reads the IMU file it names)")
        p = spec_file(spec, "imu", number)
        if p is None:
            raise NespmError(f"{spec.path}: key 'imu.file': no file {spec.tables['imu']['file']!r} for track "
                             f"{number} (--imu recorded needs it)")
        files.append(p)
    return files + [p for n in ("depth", "fix") if n in spec.tables and (p := spec_file(spec, n, number))]
