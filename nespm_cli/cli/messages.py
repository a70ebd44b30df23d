"""One-line messages of the ``nespm`` command: errors, OS errors, warnings, the interrupt line."""
from __future__ import annotations

import typer

INTERRUPTED = "nespm: interrupted; finished chunks are kept, re-run the same command to resume"
#: the interrupt line of ``nespm tune``: its unit is a trial of a study, not a chunk
TUNE_INTERRUPTED = ("nespm: interrupted; the finished trials are kept in {study} (a trial cut short is "
                    "dropped; the held-out runs' finished chunks in {out}/heldout-*), re-run the same command to "
                    "continue the study")


def interrupted(argv: list[str]) -> str:
    """The interrupt line of the command ``argv`` (after --config expansion): a tune study's trials, or a
    resumable experiment's chunks."""
    words = [w for w in argv if not w.startswith("-")]
    if not words or words[0] != "tune":
        return INTERRUPTED
    out = "results/tune"
    for i, w in enumerate(argv):
        if w == "--out" and i + 1 < len(argv):
            out = argv[i + 1]
        elif w.startswith("--out="):
            out = w[len("--out="):]
    if any(w == "--storage" or w.startswith("--storage=") for w in argv):
        return TUNE_INTERRUPTED.format(study="the --storage database", out=out)
    from pathlib import Path

    from nespm_cli.tuning.study_file import study_path

    return TUNE_INTERRUPTED.format(study=study_path(Path(out)).as_posix(), out=out)

MAX_MESSAGE = 400  # characters of an error line


def one_line(text: str) -> str:
    """``text`` as one printable line (:func:`nespm_cli.data.plausibility.printable`: a newline in a
    path becomes a space), at most :data:`MAX_MESSAGE` characters, cut in the middle so that both
    the start and the reason at the end survive a long path."""
    from nespm_cli.data.plausibility import printable

    return printable(str(text), MAX_MESSAGE, cut="middle")


def os_error_line(exc: OSError) -> str:
    """``PATH: what failed`` of an OSError (permission denied, not a directory, read-only ...)."""
    path = exc.filename if exc.filename is not None else ""
    what = exc.strerror or exc.__class__.__name__
    if exc.filename2 is not None:
        path = f"{path} -> {exc.filename2}"
    return one_line(f"{path}: {what}" if path else f"{what} ({exc})")


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings print as one line ``nespm: warning: ...`` (NumPy's RuntimeWarnings not at all:
    the checks that matter raise their own one-line errors)."""
    if issubclass(category, RuntimeWarning):
        return
    typer.echo(f"nespm: warning: {one_line(str(message))}", err=True)
