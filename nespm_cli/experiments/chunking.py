"""How many runs a chunk holds when ``--chunk-size`` is not given (``Spec.chunk_size = None``).

A chunk is ``chunk_size`` consecutive runs of one track (of one sweep value), one NumPy batch in one
worker. No number depends on it (every run is seeded per (track, run); tests/test_mc.py), but
it decides how many workers have something to do, and a chunk costs a fixed part whatever its
runs (docs/cluster.md: one filter over the 400 s track costs ~6-10 s almost whatever the batch
size), so the rule makes no more chunks than the workers need:

* **given** ``--chunk-size N`` (or ``Spec(chunk_size=N)``): N;
* **a folder that holds results** keeps the chunk size its manifest records
  (``options.chunk_size``), whatever ``--jobs`` is now: a resumed or extended study cuts its
  runs as it was started (the chunk files are named by their first run);
* **else** the ``units`` independent series of chunks (tracks x sweep values) are spread over the
  ``jobs`` workers: each run range is cut into ``ceil(jobs / units)`` parts,
  ``chunk = ceil(runs / parts)``, at most :data:`MAX_CHUNK` (the memory of one batch). So
  ``--tracks 5 --runs 8 --jobs 2`` runs 2 chunks of 4, ``--tracks 5 6 --runs 8 --jobs 2`` one chunk
  of 8 per track, and 100 runs of 2 tracks 4 chunks of 50.

The resolved number is what the manifest records, so the rule is applied once per folder.
"""
from __future__ import annotations

import json
from pathlib import Path

#: runs per chunk at most when --chunk-size is not given (what one worker's batch holds comfortably)
MAX_CHUNK = 50


def default_chunk_size(runs: int, units: int, jobs: int) -> int:
    """Runs per chunk for ``runs`` runs of ``units`` independent series on ``jobs`` workers (module
    docstring): ``min(MAX_CHUNK, ceil(runs / ceil(jobs / units)))``, at least 1."""
    parts = max(1, -(-max(int(jobs), 1) // max(int(units), 1)))
    return max(1, min(MAX_CHUNK, -(-int(runs) // parts)))


def recorded_chunk_size(out: str | Path) -> int | None:
    """The chunk size ``out/manifest.json`` records for a folder that holds results, else None
    (a new folder, or a manifest nespm cannot read: opening the folder then says what is wrong)."""
    from nespm_cli.experiments.store import has_results

    out = Path(out)
    try:
        if not has_results(out):
            return None
        old = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    value = old.get("options", {}).get("chunk_size") if isinstance(old, dict) and isinstance(old.get("options"), dict) \
        else None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 1 else None


def chunk_size_for(given: int | None, out: str | Path, runs: int, units: int, jobs: int) -> int:
    """The chunk size a study runs with: ``given``, else the one ``out`` was made with, else
    :func:`default_chunk_size` (module docstring)."""
    if given is not None:
        return int(given)
    old = recorded_chunk_size(out)
    return old if old is not None else default_chunk_size(runs, units, jobs)


def chunk_detail(runs: list[int]) -> str:
    """``of 4 runs`` (or ``of 2-4 runs``): the chunks' sizes, for the progress display."""
    if not runs:
        return ""
    lo, hi = min(runs), max(runs)
    return f"of {hi} run{'s' if hi != 1 else ''}" if lo == hi else f"of {lo}-{hi} runs"
