"""Chunking and the phases of ``mc`` (issue 30, item 6).

* Without ``--chunk-size`` the chunk size follows runs and jobs (experiments/chunking.py): ``--tracks 5
  --runs 8 --jobs 2`` runs 2 chunks of 4 (it ran one chunk of 50 on one worker), with the numbers of
  any other chunking; a given ``--chunk-size`` wins.
* A folder that holds results keeps the chunk size its manifest records, whatever ``--jobs`` is:
  a folder made with the old default (50) resumes and extends without ``--chunk-size``.
* The kernels' compilation is its own phase, said before the chunks' progress (and its ETA).
"""
from __future__ import annotations

import json

import pandas as pd
import pytest

from conftest import nespm
from nespm_cli.experiments.chunking import MAX_CHUNK, chunk_size_for, default_chunk_size, recorded_chunk_size

FAST = ["--tracks", "5", "--filters", "ins"]


def _mc(short_data_dir, out, *extra, progress=False):
    rc, _, stderr = nespm("mc", *FAST, "--data-dir", short_data_dir, "--out", out, *extra,
                          *([] if progress else ["--no-progress"]))
    assert rc == 0, stderr
    return stderr


def _firsts(out) -> list[int]:
    return sorted(int(p.stem.rsplit("-", 1)[1]) for p in (out / "chunks").glob("metrics-*.parquet"))


def _metrics(out) -> pd.DataFrame:
    return pd.read_parquet(out / "metrics.parquet").drop(columns="seconds")


@pytest.mark.parametrize("runs, units, jobs, size", [
    (8, 1, 2, 4),     # one track, two workers: two chunks
    (8, 2, 2, 8),     # two tracks already fill two workers: one chunk per track
    (7, 1, 3, 3),     # 3 + 3 + 1
    (100, 2, 2, 50),  # the papers' 100 runs: chunks of at most MAX_CHUNK
    (1000, 1, 1, MAX_CHUNK),
    (1, 1, 8, 1),
    (5, 12, 2, 5),    # a sweep of 6 values x 2 tracks: plenty of series, whole runs per chunk
])
def test_default_chunk_size(runs, units, jobs, size):
    assert default_chunk_size(runs, units, jobs) == size


def test_jobs_2_runs_8_uses_two_chunks_with_the_same_numbers(short_data_dir, tmp_path, monkeypatch):
    from nespm_cli.experiments import backend

    asked = []  # (chunks, jobs) given to the backend; the chunks run here, in order (no worker start-up)
    monkeypatch.setattr(backend, "parallel_map", lambda fn, args, jobs, *a: asked.append((len(args), jobs))
                        or (fn(*x) for x in args))
    auto, given = tmp_path / "auto", tmp_path / "given"
    _mc(short_data_dir, auto, "--runs", "8", "--jobs", "2")
    assert asked == [(2, 2)] and _firsts(auto) == [0, 4]  # 2 chunks of 4 for 2 workers
    assert json.loads((auto / "manifest.json").read_text())["options"]["chunk_size"] == 4  # recorded as resolved
    _mc(short_data_dir, given, "--runs", "8", "--jobs", "1", "--chunk-size", "3")
    assert _firsts(given) == [0, 3, 6]  # a given --chunk-size wins
    pd.testing.assert_frame_equal(_metrics(auto), _metrics(given), check_exact=True)


def test_a_folder_keeps_the_chunk_size_it_was_made_with(short_data_dir, tmp_path):
    out = tmp_path / "old"
    _mc(short_data_dir, out, "--runs", "3", "--jobs", "1", "--chunk-size", "50")  # as the old default made it
    assert chunk_size_for(None, out, 12, 1, 2) == 50
    _mc(short_data_dir, out, "--runs", "12", "--jobs", "2")  # extended, no --chunk-size, other --jobs
    assert _firsts(out) == [0, 3]  # the new block 3-11 in one chunk of up to 50 (the rule alone: 3, 9)
    m = json.loads((out / "manifest.json").read_text())
    assert m["options"]["chunk_size"] == 50 and m["run_blocks"] == [[0, 3], [3, 12]]
    assert sorted(_metrics(out)["run"]) == list(range(12))
    rc, _, stderr = nespm("mc", *FAST, "--data-dir", short_data_dir, "--out", out, "--runs", "12", "--chunk-size",
                          "4", "--no-progress")
    assert rc == 2 and "chunk_size" in stderr  # another explicit chunking of this folder: refused, as before


def test_recorded_chunk_size_of_new_and_unreadable_folders(tmp_path):
    assert recorded_chunk_size(tmp_path / "missing") is None
    (tmp_path / "chunks").mkdir()
    (tmp_path / "chunks" / "metrics-5-ins-000000.parquet").write_bytes(b"x")
    (tmp_path / "manifest.json").write_text("not json")
    assert recorded_chunk_size(tmp_path) is None  # opening the folder says what is wrong, in one line
    (tmp_path / "manifest.json").write_text(json.dumps({"options": {"chunk_size": 7}}))
    assert recorded_chunk_size(tmp_path) == 7 and chunk_size_for(None, tmp_path, 100, 1, 2) == 7
    assert chunk_size_for(5, tmp_path, 100, 1, 2) == 5


def test_compiling_the_kernels_is_its_own_phase_before_the_eta(short_data_dir, tmp_path, monkeypatch):
    """A machine whose kernel cache is empty: 'compiling ...' is said, and done, before the chunks'
    progress starts, so no ETA line waits on the compiler (it sat at 0 % for 45 s)."""
    from nespm_cli.filters import kernels

    if kernels.kernels_cached() is None:
        pytest.skip("the compiled kernels are not in use here (no numba, or no writable cache)")
    calls = []
    monkeypatch.setattr(kernels, "kernels_cached", lambda names=None: False)
    monkeypatch.setattr(kernels, "warm_up", lambda names=None: calls.append(1) or 0.0)
    stderr = _mc(short_data_dir, tmp_path / "o", "--runs", "2", "--jobs", "1", progress=True)
    lines = stderr.splitlines()
    assert calls == [1]
    assert lines[0].startswith("mc: compiling the filters' kernels (once per machine")
    assert lines[1] == "mc: kernels compiled in 0 s"
    assert lines[2] == "mc: 1 chunk of 2 runs, 79 filter-epochs to compute"
    assert all("compil" not in line for line in lines[2:]) and "ETA" not in " ".join(lines[:2])
    monkeypatch.setattr(kernels, "kernels_cached", lambda names=None: True)  # cached: nothing said, nothing compiled
    stderr = _mc(short_data_dir, tmp_path / "p", "--runs", "2", "--jobs", "1", progress=True)
    assert calls == [1] and "compil" not in stderr
