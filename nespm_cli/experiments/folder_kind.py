"""What a results folder holds, by the files each command writes: a ``nespm tune`` study or the
results of ``mc``/``sweep``/``gp-ukf`` (:mod:`nespm_cli.experiments.store`). One command never writes
into the other's folder: ``tune`` into an ``mc`` folder (or the reverse) is refused before anything is
written, since the tune report could then no longer be written (issue 39)."""
from __future__ import annotations

from pathlib import Path

from nespm_cli.errors import NespmError

#: what ``nespm tune`` writes into its folder (docs/tuning.md); a folder holding one is a tune study
TUNE_NAMES = ("tune.json", "tuned.toml", "trials.parquet", "study.journal", "study.db")
#: what ``mc``, ``sweep`` and ``gp-ukf`` write first (:class:`nespm_cli.experiments.store.ResultsFolder`)
RESULTS_NAMES = ("manifest.json", "metrics.parquet", "chunks")
TUNE = "a nespm tune study"


def folder_holds(out: str | Path) -> tuple[str, str] | None:
    """``(kind, file)`` of the nespm results in folder ``out``: ``(TUNE, "tune.json")``,
    ``("results of nespm mc, sweep or gp-ukf", "manifest.json")``, or None (new, empty or foreign)."""
    out = Path(out)
    for kind, names in ((TUNE, TUNE_NAMES), ("results of nespm mc, sweep or gp-ukf", RESULTS_NAMES)):
        for name in names:
            if (out / name).exists():
                return kind, name
    return None


def refuse_other_kind(out: str | Path, command: str) -> None:
    """Refuse ``--out`` of ``nespm COMMAND`` (``tune``, ``mc``, ``sweep``, ``gp-ukf``) when it holds the
    other kind's results: one line naming the folder and what it holds; nothing is written."""
    held = folder_holds(out)
    if held is not None and (command == "tune") != (held[0] == TUNE):
        mine = "a tune study goes into a folder of its own" if command == "tune" else \
            "results of mc, sweep or gp-ukf go into a folder of their own"
        raise NespmError(f"--out {out}: holds {held[0]} ({held[1]}); {mine}: give a new --out folder")


__all__ = ["RESULTS_NAMES", "TUNE_NAMES", "folder_holds", "refuse_other_kind"]
