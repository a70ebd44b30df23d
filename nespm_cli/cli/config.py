"""The command line before click parses it: ``--config FILE`` (TOML) expanded into options, and
``--tracks 5 6`` joined into one value."""
from __future__ import annotations

import re
from pathlib import Path

from nespm_cli.errors import NespmError


_REPEATED = ("--filter-plugin", "--sensor-plugin", "--sensor-option", "--filter-option")  # options given once per value


def _config_paths(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(config files, argv without them)``: every ``--config FILE`` and ``--config=FILE``, in order."""
    paths, rest, i = [], [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--config":
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                raise NespmError("--config needs a file")
            paths.append(argv[i + 1])
            i += 2
            continue
        if a.startswith("--config="):
            if not a[len("--config="):]:
                raise NespmError("--config needs a file")
            paths.append(a[len("--config="):])
            i += 1
            continue
        rest.append(a)
        i += 1
    return paths, rest


def _config_options(path: Path) -> list[str]:
    """The options of one TOML config file, as command-line words (one-line errors naming the file)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        text = path.read_bytes().decode("utf-8")
        cfg = tomllib.loads(text)
    except OSError as exc:
        raise NespmError(f"--config {path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise NespmError(f"--config {path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset "
                         f"{exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise NespmError(f"--config {path}: not valid TOML ({str(exc).splitlines()[0]})") from None
    except RecursionError:
        raise NespmError(f"--config {path}: nested too deeply") from None
    opts: list[str] = []
    for key, val in cfg.items():
        flag = "--" + key.replace("_", "-")
        if key == "sensors" and isinstance(val, dict):
            opts += _sensor_tables(path, val)
            continue
        if key == "filters" and isinstance(val, dict):
            opts += _filter_tables(path, val)
            continue
        if key == "tune" and isinstance(val, dict):  # nespm tune's ranges: "NAME.KEY" = [LOW, HIGH] or "off"
            opts += _tune_table(path, val)
            continue
        if isinstance(val, dict):
            raise NespmError(f"--config {path}: [{key}] is a table; options are top-level keys (runs = 100)")
        if isinstance(val, bool):
            opts += [flag] if val else []
        elif isinstance(val, list) and flag in _REPEATED:
            opts += [x for v in val for x in (flag, str(v))]
        elif isinstance(val, list):
            opts += [flag] + [str(v) for v in val]
        else:
            opts += [flag, str(val)]
    return opts


def _option_words(path: Path, kind: str, flag: str, tables: dict) -> list[str]:
    """``[KIND.NAME]`` tables as ``FLAG NAME.KEY=VALUE`` words (one-line errors naming the file)."""
    words = []
    for name, table in tables.items():
        if not isinstance(table, dict):
            raise NespmError(f"--config {path}: {kind}.{name} must be a table of options ([{kind}.{name}])")
        for k, v in table.items():
            if isinstance(v, dict):
                raise NespmError(f"--config {path}: {kind}.{name}.{k} is a table; give option values")
            text = ",".join(str(x) for x in v) if isinstance(v, list) else str(v).lower() if isinstance(v, bool) else str(v)
            words += [flag, f"{name}.{k}={text}"]
    return words


def _filter_tables(path: Path, tables: dict) -> list[str]:
    """``[filters.NAME]`` tables (in file order) as ``--filters`` and ``--filter-option`` words, as
    ``[sensors.NAME]`` (TOML cannot hold both ``filters = "..."`` and ``[filters.NAME]``; a filter
    without options is an empty table)."""
    return ["--filters", ",".join(tables)] + _option_words(path, "filters", "--filter-option", tables)


def _tune_table(path: Path, table: dict) -> list[str]:
    """A ``[tune]`` table (``"ekf.acc_noise_scale" = [0.5, 2]``, ``"*.p0_att_scale" = "off"``) as ``--tune-range`` words."""
    words = []
    for k, v in table.items():
        if isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            words += ["--tune-range", f"{k}={v[0]!r}:{v[1]!r}"]
        elif isinstance(v, str) and v.strip().lower() == "off":
            words += ["--tune-range", f"{k}=off"]
        else:
            raise NespmError(f"--config {path}: tune.{k} must be [LOW, HIGH] or \"off\", got {v!r}")
    return words


def _sensor_tables(path: Path, tables: dict) -> list[str]:
    """``[sensors.NAME]`` tables (in file order) as ``--sensors`` and ``--sensor-option`` words."""
    return ["--sensors", ",".join(tables)] + _option_words(path, "sensors", "--sensor-option", tables)


def expand_config(argv: list[str]) -> list[str]:
    """Replace every ``--config FILE`` (or ``--config=FILE``) by the options in the TOML file,
    in the order given, placed before the rest of the command line: a later file overrides an
    earlier one, and explicit options override both."""
    paths, rest = _config_paths(argv)
    if not paths:
        return argv
    opts = [w for p in paths for w in _config_options(Path(p))]
    cmd = 1 if rest and not rest[0].startswith("-") else 0
    return rest[:cmd] + opts + rest[cmd:]


def normalize_argv(argv: list[str]) -> list[str]:
    """Let ``--tracks 5 6`` mean ``--tracks '5 6'`` (click options take one value)."""
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a in ("--tracks", "--test-tracks"):
            vals = []
            i += 1
            while i < len(argv) and (not argv[i].startswith("-") or re.fullmatch(r"-\d+", argv[i])):
                vals.append(argv[i])
                i += 1
            out += [a, " ".join(vals)]
            continue
        out.append(a)
        i += 1
    return out


ARGV: list[str] = []  # the command line main() received, for the manifest
GIVEN: set[str] = set()  # the options given explicitly, on the command line or in a --config file ("alpha")


def set_argv(argv: list[str]) -> None:
    """Remember the command line (:data:`ARGV`) for the manifests that :func:`execution` feeds, and
    the options it gives explicitly (:data:`GIVEN`, with those of its ``--config`` files), which the
    library checks for an effect (``Spec.given``, experiments.spec.check_effective)."""
    ARGV[:] = list(argv)
    try:
        words = expand_config(list(argv))
    except NespmError:
        words = list(argv)  # main() reports the config error itself
    GIVEN.clear()
    GIVEN.update(w[2:].split("=", 1)[0].replace("-", "_") for w in words if w.startswith("--") and len(w) > 2)
