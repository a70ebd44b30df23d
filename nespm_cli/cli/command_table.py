"""The ``nespm`` command group: the command table, each command's module imported only when it runs.

``nespm --help`` lists the commands from :data:`COMMANDS` alone (no command module, no numpy: it
starts in about the interpreter's own time); ``nespm NAME ...`` imports NAME's module, turns its
function into a click command through a one-command Typer app (the same options, defaults, help and
errors as a command registered on a Typer group) and runs it. :func:`full_app` builds the classic
Typer app with every command registered (the tests compare the two helps).
"""
from __future__ import annotations

import importlib

import typer
from typer.core import TyperGroup

#: the group's help (``nespm --help``)
APP_HELP = (
    "Monte Carlo experiments for nonlinear INS/DVL navigation filters (EKF, UKF, UKF-NESPM and their "
    "adaptive ProcessNet versions ANEKF, ANUKF, ANUKF-NESPM).\n\n"
    "Tracks come from --data-dir (A-KIT layout: TrajectoryN/{GT,DVL}_trajectoryN.csv), else "
    "$NESPM_DATA_DIR, else six embedded Snapir-like tracks."
)

#: name -> (module, function, the one line of ``nespm --help``), in the order of ``nespm --help``
COMMANDS: dict[str, tuple[str, str, str]] = {
    "tracks": ("nespm_cli.cli.tracks_command", "tracks", "List the tracks: duration, distance, speed, depth."),
    "check": ("nespm_cli.cli.data_commands", "check", "Check a track folder's IMU and DVL against its truth."),
    "corrupt": ("nespm_cli.cli.data_commands", "corrupt", "Draw the realizations into DIR/realizations.parquet."),
    "run": ("nespm_cli.cli.experiment_commands", "run", "Run one realization of one filter on one track."),
    "mc": ("nespm_cli.cli.experiment_commands", "mc", "Monte Carlo: every filter on the same realizations."),
    "sweep": ("nespm_cli.cli.experiment_commands", "sweep", "Paired Monte Carlo per value of one parameter."),
    "tune": ("nespm_cli.cli.tune_command", "tune", "Tune every filter's noise with the same budget."),
    "report": ("nespm_cli.cli.result_commands", "report", "Write DIR/report.md: verdict, tables, figures."),
    "compare": ("nespm_cli.cli.result_commands", "compare", "Compare cases run on the same realizations."),
    "export": ("nespm_cli.cli.result_commands", "export", "Export metrics and epochs as CSV or MATLAB .mat."),
    "train": ("nespm_cli.cli.train_command", "train", "Train the accelerometer and gyro ProcessNets."),
    "simulate": ("nespm_cli.cli.data_commands", "simulate", "Simulate REMUS 100 helix runs (gp-ukf.md)."),
    "import": ("nespm_cli.cli.import_command", "import_cmd", "Import a ROS bag as a track folder."),
    "gp-ukf": ("nespm_cli.cli.experiment_commands", "gp_ukf_cmd", "GP-UKF vs ideal UKF (gp-ukf.md Tables 3-4)."),
    "warm-up": ("nespm_cli.cli.warmup_command", "warm_up_cmd", "Compile the filters' kernels into the cache."),
}

#: the Typer settings of every command (no rich markup, no pretty tracebacks: one line per error)
TYPER_SETTINGS = dict(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)


def command_function(name: str):
    """The function of command ``name`` (its module imported now)."""
    module, attr, _ = COMMANDS[name]
    return getattr(importlib.import_module(module), attr)


def load_command(name: str):
    """Command ``name`` as a click command: its function registered on a one-command Typer app."""
    sub = typer.Typer(**TYPER_SETTINGS)
    sub.command(name)(command_function(name))
    cmd = typer.main.get_command(sub)
    cmd.name = name
    cmd.short_help = COMMANDS[name][2]
    return cmd


class LazyGroup(TyperGroup):
    """The ``nespm`` group: lists :data:`COMMANDS` without importing them; loads one on use."""

    def list_commands(self, ctx) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx, cmd_name: str):
        return load_command(cmd_name) if cmd_name in COMMANDS else None

    def format_commands(self, ctx, formatter) -> None:
        with formatter.section("Commands"):
            formatter.write_dl([(name, short) for name, (_, _, short) in COMMANDS.items()])


def group() -> LazyGroup:
    """The ``nespm`` command group (what :func:`nespm_cli.cli.main` runs)."""
    return LazyGroup(name="nespm", help=APP_HELP, no_args_is_help=True, rich_markup_mode=None)


def full_app():
    """The Typer app with every command registered (imports every command module)."""
    app = typer.Typer(no_args_is_help=True, help=APP_HELP, **TYPER_SETTINGS)
    for name, (_, _, short) in COMMANDS.items():
        app.command(name, short_help=short)(command_function(name))
    return app


__all__ = ["APP_HELP", "COMMANDS", "LazyGroup", "command_function", "full_app", "group", "load_command"]
