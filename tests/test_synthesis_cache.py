"""The synthesized truth and IMU kept in the per-user cache (data/synthesis_cache.py): the very bits of the
synthesis, keyed by the track's content, least recently used files removed beyond the size cap, and a cache
that cannot be used is only a miss."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from nespm_cli.data import synthesis_cache as sc
from nespm_cli.data.embedded import embedded_track
from nespm_cli.nav.synthesis import synthesize


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NESPM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def short(number: int = 5, epochs: int = 40, shift: float = 0.0):
    tr = embedded_track(number)
    s = slice(0, epochs)
    return dataclasses.replace(tr, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s] + shift, euler=tr.euler[s], dvl=tr.dvl[s])


def same(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) and getattr(a, k).dtype == getattr(b, k).dtype
               for k in sc.ARRAYS) and (a.exact, a.known) == (b.exact, b.known)


def test_kept_and_read_back_with_the_same_bits(cache):
    tr = short()
    ref = synthesize(tr, 100)
    first = sc.synthesized(tr, 100)  # computed and kept
    path = sc.cache_file(tr, 100)
    assert path.is_file() and path.parent.parent == cache and same(first, ref)
    inode = path.stat().st_ino
    again = sc.synthesized(tr, 100)  # read back
    assert same(again, ref) and again.f_b is not first.f_b
    assert path.stat().st_ino == inode  # read (and marked used), not written again


def test_the_key_is_the_content_and_the_substeps(cache):
    a, b = short(), short(shift=1e-9)
    assert sc.content_key(a, 100) != sc.content_key(b, 100) != sc.content_key(a, 50)
    assert sc.content_key(a, 100) == sc.content_key(short(), 100)  # the same arrays read again
    sc.synthesized(a, 100)
    got = sc.synthesized(b, 100)  # an edited track: synthesized afresh, not a's
    assert same(got, synthesize(b, 100)) and len(list(sc.cache_file(a, 100).parent.glob("*.npz"))) == 2


@pytest.mark.parametrize("content", [b"", b"not an npz", b"PK\x03\x04truncated"])
def test_a_damaged_file_is_a_miss_and_is_replaced(cache, content):
    tr = short()
    path = sc.cache_file(tr, 100)
    path.parent.mkdir(parents=True)
    path.write_bytes(content)
    assert same(sc.synthesized(tr, 100), synthesize(tr, 100))
    assert sc.load(path) is not None  # replaced by a good one


def test_least_recently_used_files_go_beyond_the_cap(cache, monkeypatch):
    tracks = [short(shift=k * 1e-6) for k in range(4)]
    sc.synthesized(tracks[0], 100)
    size = sc.cache_file(tracks[0], 100).stat().st_size
    monkeypatch.setattr(sc, "MAX_BYTES", int(2.5 * size))  # room for two
    paths = [sc.cache_file(t, 100) for t in tracks]
    sc.synthesized(tracks[1], 100)
    os.utime(paths[0], (1, 1))  # track 0 the least recently used
    os.utime(paths[1], (2, 2))
    sc.synthesized(tracks[2], 100)
    assert [p.exists() for p in paths[:3]] == [False, True, True]
    sc.synthesized(tracks[1], 100)  # a load marks it used: track 2 is now the oldest
    sc.synthesized(tracks[3], 100)
    assert [p.exists() for p in paths] == [False, True, False, True]


def test_a_cache_folder_that_cannot_be_written_only_synthesizes(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("NESPM_CACHE_DIR", str(blocker))
    tr = short()
    assert same(sc.synthesized(tr, 100), synthesize(tr, 100))


def test_a_track_without_truth_is_refused_as_before(cache):
    from types import SimpleNamespace

    from nespm_cli.errors import NespmError

    with pytest.raises(NespmError, match="no ground truth"):
        sc.synthesized(SimpleNamespace(truth=False, number=7), 100)
    assert not cache.exists()
