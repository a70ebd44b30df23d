"""The ``nespm`` command line: parse, call the library, print.

Every bad input ends in one line ``nespm: error: ...`` on stderr and exit code 2.
"""
from __future__ import annotations

import sys

import typer
from typer.exceptions import Abort, Exit, TyperException

from nespm_cli.cli.command_table import group
from nespm_cli.cli.config import expand_config, normalize_argv, set_argv
from nespm_cli.cli.messages import MAX_MESSAGE, interrupted, one_line, os_error_line, show_warning
from nespm_cli.errors import NespmError

__all__ = ["app", "main", "one_line", "os_error_line", "MAX_MESSAGE", "default", "DATA_DIR", "CORRUPTION_FIELDS",
           "FILTER_FIELDS", "COMMON", "CORRUPTION", "KERNELS", "PARALLEL", "RECORDED", "RUNNER", "build_spec",
           "expand_config", "normalize_argv"]

#: names this package gives on first use (their modules import the numeric stack): name -> (module, attribute);
#: the underscored ones are the names it had before it became a package (tests read them)
LAZY = {**{n: ("nespm_cli.cli.options", n) for n in ("COMMON", "CORRUPTION", "DATA_DIR", "KERNELS", "PARALLEL",
                                                      "RECORDED", "RUNNER", "default")},
        **{n: ("nespm_cli.cli.parsing", n) for n in ("CORRUPTION_FIELDS", "FILTER_FIELDS", "build_spec")},
        "_COMMON": ("nespm_cli.cli.options", "COMMON"), "_RUNNER": ("nespm_cli.cli.options", "RUNNER"),
        "_spec": ("nespm_cli.cli.parsing", "build_spec"), "_expand_config": ("nespm_cli.cli.config", "expand_config")}


def __getattr__(name: str):
    if name == "app":  # the Typer app with every command registered (imports them all)
        from nespm_cli.cli.command_table import full_app

        return full_app()
    if name in LAZY:
        import importlib

        module, attr = LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def main(argv: list[str] | None = None) -> int:
    import warnings

    warnings.showwarning = show_warning
    for stream in (sys.stdout, sys.stderr):  # an ASCII locale (LC_ALL=C) prints '?' for ±, σ, ², never fails
        if hasattr(stream, "reconfigure") and (stream.encoding or "").lower().replace("-", "") != "utf8":
            stream.reconfigure(errors="replace")
    try:
        argv = list(sys.argv[1:] if argv is None else [str(a) for a in argv])
        set_argv(argv)
        if not argv:
            argv = ["--help"]
        argv = normalize_argv(expand_config(argv))
        rv = group().main(args=argv, prog_name="nespm", standalone_mode=False)
        if rv == 130:  # typer turns Ctrl-C into a returned exit code 130
            typer.echo(interrupted(argv), err=True)
        return rv if isinstance(rv, int) else 0
    except NespmError as exc:
        typer.echo(f"nespm: error: {one_line(str(exc))}", err=True)
        return exc.exit_code
    except OSError as exc:  # the file system said no: name the path and what failed
        typer.echo(f"nespm: error: {os_error_line(exc)}", err=True)
        return 2
    except Exit as exc:
        return exc.exit_code
    except Abort:
        typer.echo("nespm: aborted", err=True)
        return 130
    except TyperException as exc:
        msg = exc.format_message().splitlines()
        typer.echo(f"nespm: error: {msg[0] if msg else exc}", err=True)
        return 2
    except KeyboardInterrupt:
        typer.echo(interrupted(argv if isinstance(argv, list) else []), err=True)
        return 130
