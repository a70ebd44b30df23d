"""The options of the data commands that need no library default: ``--data-dir`` and the flag and help
of ``--accept-residual``. Light on purpose (typer only): ``nespm tracks`` takes its options from here, so
it never imports the option tables of :mod:`nespm_cli.cli.options`, whose defaults come from the
experiment spec and the filters (numpy, the filter engine, the sensors)."""
from __future__ import annotations

import typer

#: the help of ``--data-dir`` (every command that reads tracks)
DATA_DIR_HELP = ("Folder in the A-KIT layout, or with a track spec nespm-data.toml (docs/data.md) (default: "
                 "$NESPM_DATA_DIR, else the embedded tracks).")

DATA_DIR = typer.Option(None, "--data-dir", help=DATA_DIR_HELP)

#: ``--accept-residual``'s flag and help (its default is the Spec's: options.ACCEPT_RESIDUAL)
ACCEPT_RESIDUAL_FLAG = "--accept-residual"
ACCEPT_RESIDUAL_HELP = ("Run a track whose data contradict its declared attitude or frame conventions (a DVL "
                        "residual or a heading far above the noise: nespm tracks shows it) instead of refusing it; "
                        "its sentence is then a warning, recorded in the manifest (accepted_residuals) and the "
                        "report's caveats. The track spec key gt.accept_residual = true does the same per track "
                        "(the numbers may be wrong: fix the key the refusal names if you can).")
