"""One-line messages of the ``nespm`` command: errors, OS errors, warnings, the interrupt line."""
from __future__ import annotations

import typer

INTERRUPTED = "nespm: interrupted; finished chunks are kept, re-run the same command to resume"

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
