"""Fuzzing the track loader: random damage to a valid GT or DVL file must give either a Track or a
NespmError whose message is one short printable line, never any other exception."""
from __future__ import annotations

import shutil
import warnings as pywarnings
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from conftest import short_track  # noqa: E402
from nespm_cli.data.track import Track  # noqa: E402
from nespm_cli.data.tracks import load_track, write_akit  # noqa: E402
from nespm_cli.errors import NespmError  # noqa: E402

N = 5
EPOCHS = 40
MAX_LEN = 400  # characters of an error message


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> dict[str, bytes]:
    """The valid files of embedded track 5 cut to 40 epochs: {"GT"|"DVL": bytes}."""
    folder = tmp_path_factory.mktemp("fuzz-pristine")
    tdir = write_akit(short_track(N, EPOCHS), folder)
    return {k: (tdir / f"{k}_trajectory{N}.csv").read_bytes() for k in ("GT", "DVL")}


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder re-written by every example (Trajectory5 holding the damaged files)."""
    return tmp_path_factory.mktemp("fuzz-work")


_text = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e400", "abc", "1,2", '"', "0x10", " ", "--", "1e-400"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
)


@st.composite
def damage(draw, data: bytes) -> bytes:
    """One random damage of the CSV bytes ``data``."""
    lines = data.decode().splitlines() or [""]  # an earlier damage may have emptied the file
    header, rows = lines[0], lines[1:]
    kind = draw(st.sampled_from(["delete", "duplicate", "swap", "field", "truncate", "bytes", "scale",
                                 "shuffle", "noheader", "several"]))
    if kind == "several":
        out = data
        for _ in range(draw(st.integers(2, 4))):
            out = draw(damage(out)) if _decodes(out) else out
        return out
    if kind in ("delete", "duplicate", "swap") and rows:
        i = draw(st.integers(0, len(rows) - 1))
        j = draw(st.integers(0, len(rows) - 1))
        if kind == "delete":
            del rows[i]
        elif kind == "duplicate":
            rows.insert(i, rows[i])
        else:
            rows[i], rows[j] = rows[j], rows[i]
    elif kind == "field":
        i = draw(st.integers(-1, len(rows) - 1))  # -1: the header
        line = header if i < 0 else rows[i]
        parts = line.split(",")
        parts[draw(st.integers(0, len(parts) - 1))] = draw(_text)
        if i < 0:
            header = ",".join(parts)
        else:
            rows[i] = ",".join(parts)
    elif kind == "truncate":
        return data[: draw(st.integers(0, len(data)))]
    elif kind == "bytes":
        pos = draw(st.integers(0, len(data)))
        junk = draw(st.one_of(st.binary(min_size=1, max_size=20),
                              st.sampled_from([b"\x00", b"\x00" * 50, b"\xff\xfe", b"\xc3", b"\r", b"\n\n", b"\x1b[2J"])))
        return data[:pos] + junk + data[pos:]
    elif kind == "scale":
        ncol = len(header.split(","))
        c = draw(st.integers(0, ncol - 1))
        f = draw(st.sampled_from([-1.0, 0.0, 1e-3, 0.01, 0.1, 2.0, 10.0, 57.29577951308232, 1000.0, 1e7, 1e300]))
        new = []
        for r in rows:
            parts = r.split(",")
            try:
                parts[c] = repr(float(parts[c]) * f)
            except (ValueError, IndexError):
                pass
            new.append(",".join(parts))
        rows = new
    elif kind == "shuffle":
        ncol = len(header.split(","))
        perm = draw(st.permutations(list(range(ncol))))
        header = ",".join(header.split(",")[k] for k in perm)
        rows = [",".join((r.split(",") + [""] * ncol)[k] for k in perm) for r in rows]
    elif kind == "noheader":
        return ("\n".join(rows) + "\n").encode()
    return ("\n".join([header] + rows) + "\n").encode()


def _decodes(b: bytes) -> bool:
    try:
        b.decode()
        return True
    except UnicodeDecodeError:
        return False


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.data_too_large])
@given(data=st.data())
def test_damaged_track_gives_a_track_or_one_printable_error_line(pristine, work, data):
    which = data.draw(st.sampled_from(["GT", "DVL"]), label="file")
    damaged = data.draw(damage(pristine[which]), label="damage")
    tdir = work / f"Trajectory{N}"
    shutil.rmtree(tdir, ignore_errors=True)
    tdir.mkdir(parents=True)
    for k, b in pristine.items():
        (tdir / f"{k}_trajectory{N}.csv").write_bytes(damaged if k == which else b)
    try:
        with pywarnings.catch_warnings():
            pywarnings.simplefilter("ignore")  # numpy/pandas RuntimeWarnings and DataWarnings are allowed
            tr = load_track(N, work, warnings="warn")
    except NespmError as exc:
        msg = str(exc)
        assert msg, "empty error message"
        assert "\n" not in msg and "\r" not in msg, repr(msg)
        assert msg.isprintable(), repr(msg)
        assert len(msg) < MAX_LEN, (len(msg), msg)
        assert str(tdir) in msg, msg  # names the folder / file
    else:
        assert isinstance(tr, Track)
        assert len(tr.t) >= 2
