"""The ``nespm`` command line: parse, call the library, print.

Every bad input ends in one line ``nespm: error: ...`` on stderr and exit code 2.
"""
from __future__ import annotations

import sys

import typer
from typer.exceptions import Abort, Exit, TyperException

from nespm_cli.cli.config import expand_config, normalize_argv
from nespm_cli.cli.data_commands import check, corrupt, simulate, tracks
from nespm_cli.cli.experiment_commands import gp_ukf_cmd, mc, run, sweep
from nespm_cli.cli.import_command import import_cmd
from nespm_cli.cli.messages import MAX_MESSAGE, interrupted, one_line, os_error_line, show_warning
from nespm_cli.cli.options import COMMON, CORRUPTION, DATA_DIR, KERNELS, PARALLEL, RECORDED, RUNNER, default
from nespm_cli.cli.parsing import CORRUPTION_FIELDS, FILTER_FIELDS, build_spec, set_argv
from nespm_cli.cli.result_commands import compare, export, report
from nespm_cli.cli.train_command import train
from nespm_cli.cli.tune_command import tune
from nespm_cli.cli.warmup_command import warm_up_cmd
from nespm_cli.errors import NespmError

__all__ = ["app", "main", "one_line", "os_error_line", "MAX_MESSAGE", "default", "DATA_DIR", "CORRUPTION_FIELDS",
           "FILTER_FIELDS", "COMMON", "CORRUPTION", "KERNELS", "PARALLEL", "RECORDED", "RUNNER", "build_spec",
           "expand_config", "normalize_argv"]

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    help="Monte Carlo experiments for nonlinear INS/DVL navigation filters (EKF, UKF, UKF-NESPM and their "
    "adaptive ProcessNet versions ANEKF, ANUKF, ANUKF-NESPM).\n\n"
    "Tracks come from --data-dir (A-KIT layout: TrajectoryN/{GT,DVL}_trajectoryN.csv), else "
    "$NESPM_DATA_DIR, else six embedded Snapir-like tracks.",
)

# the commands, in the order of ``nespm --help``
for command in (tracks, check, corrupt, run, mc, sweep, tune, report, compare, export, train, simulate):
    app.command()(command)
app.command("import")(import_cmd)
app.command("gp-ukf")(gp_ukf_cmd)
app.command("warm-up")(warm_up_cmd)
del command

# the names this module had before it became a package (tests read them)
_COMMON, _RUNNER, _spec, _expand_config = COMMON, RUNNER, build_spec, expand_config


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
        rv = typer.main.get_command(app).main(args=argv, prog_name="nespm", standalone_mode=False)
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
