"""Checking the keys of a TOML table against a schema: what the track spec (``nespm-data.toml``) and
the ROS-bag import spec share. One printable line naming the file and key for any refusal."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

from nespm_cli.data.plausibility import printable
from nespm_cli.errors import NespmError

#: the value kinds of a schema (a tuple of strings instead: the allowed choices)
STR, INT, NUM, BOOL, TABLE = "a string", "an integer", "a number", "true or false", "a table"


def read_toml(path: Path, what: str) -> dict:
    """The TOML file ``path`` as a dict; one line naming it (``what``: "the spec", "the track spec") if it
    is missing, unreadable, not UTF-8 or not TOML."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        return tomllib.loads(Path(path).read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise NespmError(f"{path}: {what} file not found") from None
    except OSError as exc:
        raise NespmError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise NespmError(f"{path}: {what} is not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise NespmError(f"{path}: not a valid TOML file ({printable(exc, 120)})") from None


def checked_table(path: Path, name: str, table, known: dict, special: Callable | None = None,
                  skip: tuple = ()) -> dict:
    """``table`` (the ``[name]`` table of the file ``path``; ``name`` "" for the top level) with every key
    checked against ``known`` (key -> kind or tuple of choices): unknown keys, wrong types, empty
    strings, non-finite numbers and values outside the choices are refused. ``special(key, value,
    full)`` handles the kinds it knows (returns True; e.g. a unit) before the generic ones; keys of a
    kind in ``skip`` are left to the caller (e.g. the top level's sub-tables)."""
    if not isinstance(table, dict):
        raise NespmError(f"{path}: key '{name}' must be a table ([{name}])")
    for key, value in table.items():
        full = f"{name}.{key}" if name else key
        if key not in known:
            where = f" in [{name}]" if name else ""
            raise NespmError(f"{path}: unknown key '{printable(full, 60)}' (known{where}: {', '.join(known)})")
        want = known[key]
        if want in skip or (special is not None and special(key, value, full)):
            continue
        if isinstance(want, tuple):
            if value not in want:
                raise NespmError(f"{path}: key '{full}': {printable(repr(value), 40)} is not one of {', '.join(want)}")
            continue
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        ok = {STR: isinstance(value, str), BOOL: isinstance(value, bool), TABLE: isinstance(value, dict),
              INT: number and isinstance(value, int), NUM: number}[want]
        if not ok:
            raise NespmError(f"{path}: key '{full}' must be {want}, got {printable(repr(value), 40)}")
        if want == STR and not value.strip():
            raise NespmError(f"{path}: key '{full}' is empty")
        if want == NUM and not math.isfinite(value):
            raise NespmError(f"{path}: key '{full}' must be a finite number, got {value!r}")
    return dict(table)


__all__ = ["BOOL", "INT", "NUM", "STR", "TABLE", "checked_table", "read_toml"]
