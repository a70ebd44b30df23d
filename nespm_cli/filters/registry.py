"""Registry of the filters by name: the built-ins and user plugins.

* ``@register("name")`` on a :class:`~nespm_cli.filters.protocol.Filter` subclass (or
  ``register_filter("name", cls)``) makes it available to ``run_filter`` / ``--filters``.
* ``load_plugin(path_or_module)`` imports a user's Python file (``examples/ckf_filter.py``)
  or an installed module (``mypkg.filters``); the module registers its classes when imported.
* Installed distributions may declare an entry point in the group ``nespm.filters``
  (``[project.entry-points."nespm.filters"] myfilter = "mypkg.filters"``); they are
  imported on the first look-up of an unknown name, or by :func:`discover_plugins`.

Rules: a name is unique. A plugin may not take a built-in's name. Registering a name again
from the same source (the same plugin file or module imported twice, e.g. by a worker
process) replaces the entry harmlessly; the same name from a different source is an error.
Every error is a one-line :class:`~nespm_cli.errors.NespmError`.
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Callable

from nespm_cli.errors import NespmError
from nespm_cli.filters.protocol import Filter

ENTRY_POINT_GROUP = "nespm.filters"

_FILTERS: dict[str, type] = {}
_SOURCES: dict[str, str] = {}  # name -> source: the defining module's file (or its name)
_LOADED: dict[str, object] = {}  # plugin key -> module (or entry-point object)
_registered_while_loading: list[list[str]] = []
_discovered = False


def _source(cls: type) -> str:
    """Where ``cls`` comes from: its module's resolved file, else the module name."""
    f = getattr(sys.modules.get(cls.__module__), "__file__", None)
    try:
        return str(Path(f).resolve()) if f else cls.__module__
    except OSError:  # pragma: no cover
        return cls.__module__


def _is_builtin(name: str) -> bool:
    return _FILTERS[name].__module__.startswith("nespm_cli.") if name in _FILTERS else False


def register_filter(name: str, cls: type) -> type:
    """Register filter class ``cls`` under ``name``; returns ``cls``. See the module docstring."""
    if not isinstance(name, str) or not name or any(c in name for c in ", \t\n"):
        raise NespmError(f"filter name {name!r}: give a non-empty name without commas or spaces")
    if not (isinstance(cls, type) and issubclass(cls, Filter)):
        raise NespmError(f"filter {name!r}: {cls!r} is not a subclass of nespm_cli.filters.protocol.Filter")
    source = _source(cls)
    old = _SOURCES.get(name)
    if old is not None and old != source:
        if _is_builtin(name):
            raise NespmError(f"filter name {name!r} of {source} clashes with the built-in filter {name!r}")
        raise NespmError(f"filter name {name!r} of {source} is already registered by {old}")
    cls.name = name
    _FILTERS[name] = cls
    _SOURCES[name] = source
    if _registered_while_loading:
        _registered_while_loading[-1].append(name)
    return cls


def register(name: str) -> Callable[[type], type]:
    """Class decorator: ``@register("ckf-example") class CKF(ErrorStateFilter): ...``."""
    def deco(cls: type) -> type:
        return register_filter(name, cls)
    return deco


def get_filter(name: str) -> type:
    """The class registered as ``name``; unknown names first trigger entry-point discovery."""
    if name not in _FILTERS and not _discovered:
        discover_plugins()
    try:
        return _FILTERS[name]
    except KeyError:
        raise NespmError(f"--filters: unknown filter {name!r}; choose from {', '.join(filter_names())}") from None


def filter_names(builtin_only: bool = False) -> tuple[str, ...]:
    """Registered names, built-ins first (in registration order), then plugins."""
    b = tuple(n for n in _FILTERS if _is_builtin(n))
    return b if builtin_only else b + tuple(n for n in _FILTERS if not _is_builtin(n))


def filter_source(name: str) -> str:
    """Where filter ``name`` is defined: its module's file (or module name)."""
    return _SOURCES.get(name, "?")


def is_builtin(name: str) -> bool:
    """Whether ``name`` is one of nespm's own filters."""
    return _is_builtin(name)


def plugin_files(name: str) -> list[Path]:
    """The source files of filter ``name``'s code when it is a plugin (empty for a built-in):
    the plugin file, or every ``.py`` file of the top-level package its module belongs to (a
    module plugin or an entry point), sorted. Their hashes identify the code of an experiment."""
    if name not in _FILTERS or _is_builtin(name):
        return []
    module = sys.modules.get(_FILTERS[name].__module__)
    top = sys.modules.get(_FILTERS[name].__module__.split(".")[0])
    roots = [Path(p) for p in getattr(top, "__path__", None) or []]
    if roots and top is not None and not top.__name__.startswith("nespm_plugin_"):
        return sorted({f.resolve() for r in roots for f in r.rglob("*.py") if "__pycache__" not in f.parts})
    f = getattr(module, "__file__", None)
    return [Path(f).resolve()] if f else []


def _one_line(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    return f"{type(e).__name__}: {msg}" if not isinstance(e, NespmError) else msg


def _defines_filters(module) -> bool:
    """Whether a registered class comes from ``module`` (or a submodule of it)."""
    name = module.__name__ if isinstance(module, ModuleType) else getattr(module, "__module__", None)
    return bool(name) and any(c.__module__ == name or c.__module__.startswith(name + ".") for c in _FILTERS.values())


def _import(key: str, label: str, do_import: Callable[[], ModuleType]) -> ModuleType:
    """Import a plugin under the registration context; roll back its registrations on failure."""
    if key in _LOADED:
        return _LOADED[key]
    snapshot = (dict(_FILTERS), dict(_SOURCES))
    _registered_while_loading.append([])
    try:
        try:
            module = do_import()
        except NespmError as e:
            raise NespmError(f"filter plugin {label}: {_one_line(e)}") from None
        except Exception as e:
            raise NespmError(f"filter plugin {label} failed to import: {_one_line(e)}") from None
        if not _registered_while_loading[-1] and not _defines_filters(module):
            raise NespmError(f"filter plugin {label} registers no filter "
                             f"(decorate a Filter subclass with @nespm_cli.filters.registry.register(name))")
    except NespmError:
        _FILTERS.clear(), _FILTERS.update(snapshot[0])
        _SOURCES.clear(), _SOURCES.update(snapshot[1])
        raise
    finally:
        _registered_while_loading.pop()
    _LOADED[key] = module
    return module


def load_plugin(path_or_module: str | Path) -> ModuleType:
    """Import a filter plugin (a ``.py`` file path, or an importable module name); return the module.

    Idempotent: loading the same file (same resolved path) or module again returns the
    already imported module. The module is kept in ``sys.modules`` (so its classes pickle).
    Raises a one-line NespmError naming the file when it does not exist, fails to import or
    registers no filter, or when a name clashes.
    """
    s = str(path_or_module)
    looks_like_path = isinstance(path_or_module, Path) or s.endswith(".py") or "/" in s or "\\" in s
    if not looks_like_path:
        return _import(f"module:{s}", s, lambda: importlib.import_module(s))
    p = Path(s).expanduser()
    if not p.is_file():
        raise NespmError(f"filter plugin {s}: no such file")
    p = p.resolve()
    key = str(p)
    mod_name = f"nespm_plugin_{p.stem.replace('-', '_')}_{hashlib.sha1(key.encode()).hexdigest()[:10]}"

    def do_import() -> ModuleType:
        spec = importlib.util.spec_from_file_location(mod_name, p)
        if spec is None or spec.loader is None:
            raise NespmError("not a Python file")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            sys.modules.pop(mod_name, None)
            raise
        return module

    return _import(f"file:{key}", s, do_import)


def discover_plugins() -> list[str]:
    """Import every entry point of the group ``nespm.filters``; return their names. Runs once."""
    global _discovered
    _discovered = True
    names = []
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        _import(f"entry:{ep.value}", f"entry point {ep.name} = {ep.value}", ep.load)
        names.append(ep.name)
    return names


__all__ = ["ENTRY_POINT_GROUP", "discover_plugins", "filter_names", "filter_source", "get_filter", "is_builtin",
           "filter_source", "load_plugin", "plugin_files", "register", "register_filter"]
