"""The lazy ``nespm`` group (cli/command_table.py) is the full Typer app, loaded one command at a time.

``nespm --help`` lists the commands from the table without importing a command module (issue 41,
item 3); ``nespm NAME`` loads NAME's module and runs it with the same options and help as the app
with every command registered. Module sets and texts only: no timing here (benchmarks/ measures it).
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
import typer
from click.testing import CliRunner

from nespm_cli.cli.command_table import COMMANDS, full_app, group, load_command


def help_of(cmd, argv: list[str]) -> str:
    r = CliRunner().invoke(cmd, argv, prog_name="nespm")
    assert r.exit_code == 0, r.output
    return r.output


def test_group_help_is_the_full_apps_help():
    full = typer.main.get_command(full_app())
    assert help_of(group(), ["--help"]) == help_of(full, ["--help"])
    assert list(full.list_commands(None)) == list(COMMANDS)


@pytest.mark.parametrize("name", list(COMMANDS))
def test_each_command_loads_with_the_full_apps_options(name):
    full = typer.main.get_command(full_app())
    lazy = group()
    assert help_of(lazy, [name, "--help"]) == help_of(full, [name, "--help"])
    assert [p.name for p in load_command(name).params] == [p.name for p in full.get_command(None, name).params]


def test_unknown_command_is_one_line():
    p = subprocess.run([sys.executable, "-m", "nespm_cli.cli", "nope"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "nope" in p.stderr


def test_group_help_imports_no_command_module_and_no_numpy():
    code = ("import contextlib, io, json, sys\nfrom nespm_cli.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n    rc = main(['--help'])\n"
            "print(json.dumps({'rc': rc, 'modules': sorted(sys.modules)}))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    r = json.loads(p.stdout.splitlines()[-1])
    assert r["rc"] == 0
    loaded = set(r["modules"])
    assert "numpy" not in loaded
    assert not loaded & {module for module, _, _ in COMMANDS.values()}
