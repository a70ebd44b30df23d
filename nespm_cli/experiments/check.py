"""``nespm check``: the consistency check of every track of a folder (docs/checking-data.md)."""
from __future__ import annotations

import warnings

from typing import Callable

from nespm_cli.checks.verdict import check_track
from nespm_cli.data.corrections import Corrections, write_corrections
from nespm_cli.data.plausibility import DataWarning
from nespm_cli.data.tracks import available_tracks, load_track, resolve_data_dir


def check_folder(data_dir: str | None, tracks=None, status: Callable[[str], None] | None = None) -> dict:
    """Check ``tracks`` (default: all) of ``data_dir`` (None: $NESPM_DATA_DIR, else the embedded tracks).

    Returns ``{"data_dir", "tracks": [check_track dicts], "corrections": corrections.json text,
    "summary": {verdict: count}}``.
    """
    d = resolve_data_dir(data_dir)
    numbers = list(tracks) if tracks else available_tracks(d)
    say = status or (lambda text: None)
    results = []
    for i, n in enumerate(numbers, 1):
        say(f"checking track {n} ({i}/{len(numbers)})")
        with warnings.catch_warnings():  # check reports the conventions' findings itself: load with the refusal off
            warnings.filterwarnings("ignore", message=".*accepted", category=DataWarning)
            track = load_track(int(n), d, accept_residual=True)
        results.append(check_track(track))
    corr = {}
    for r in results:
        c = dict(r["corrections"])
        c["window"] = tuple(c["window"]) if c["window"] is not None else None
        corr[r["track"]] = Corrections(**c)
    summary: dict[str, int] = {}
    for r in results:
        summary[r["verdict"]] = summary.get(r["verdict"], 0) + 1
    return {"data_dir": str(d) if d is not None else None, "tracks": results,
            "corrections": write_corrections(corr), "summary": summary}
