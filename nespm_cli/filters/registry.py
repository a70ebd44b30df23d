"""Registry of the filters by name: the built-ins and user plugins (:class:`nespm_cli.plugins.Registry`).

* ``@register("name")`` on a :class:`~nespm_cli.filters.protocol.Filter` subclass (or
  ``register_filter("name", cls)``) makes it available to ``run_filter`` / ``--filters``.
* ``load_plugin(path_or_module)`` imports a user's Python file (``examples/ckf_filter.py``)
  or an installed module (``mypkg.filters``); the module registers its classes when imported.
* Installed distributions may declare an entry point in the group ``nespm.filters``
  (``[project.entry-points."nespm.filters"] myfilter = "mypkg.filters"``); they are
  imported on the first look-up of an unknown name, or by :func:`discover_plugins`.

Oracles: for every registered filter with a covariance that does not adapt its own noise
(:func:`nespm_cli.filters.oracle.oracle_able`), ``NAME-oracle`` is that filter told the true noise of
each realization (:mod:`nespm_cli.filters.oracle`, docs/adapting.md). Their classes are made on the
first look-up, not registered: :func:`filter_names` lists them after the registered names, but the
built-ins of ``builtin_only`` (``FILTERS``) do not include them.

Rules: a name is unique. A plugin may not take a built-in's name. Registering a name again
from the same source (the same plugin file or module imported twice, e.g. by a worker
process) replaces the entry harmlessly; the same name from a different source is an error.
Every error is a one-line :class:`~nespm_cli.errors.NespmError`.
"""
from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Callable

from nespm_cli.errors import NespmError
from nespm_cli.filters.oracle import ORACLE_SUFFIX, oracle_able, oracle_class
from nespm_cli.filters.protocol import Filter
from nespm_cli.plugins import Registry

ENTRY_POINT_GROUP = "nespm.filters"
FILTER_REGISTRY = Registry("filter", Filter, ENTRY_POINT_GROUP, "--filters")
ORACLES: dict[tuple[str, type], type] = {}  # (base name, base class) -> its oracle's class


def register_filter(name: str, cls: type) -> type:
    """Register filter class ``cls`` under ``name``; returns ``cls``. See the module docstring."""
    return FILTER_REGISTRY.register(name, cls)


def register(name: str) -> Callable[[type], type]:
    """Class decorator: ``@register("ckf-example") class CKF(ErrorStateFilter): ...``."""
    return FILTER_REGISTRY.decorator(name)


def oracle_base(name: str) -> str | None:
    """The base filter's name of an oracle name (``ekf-oracle`` -> ``ekf``), else None."""
    if name.endswith(ORACLE_SUFFIX) and name not in FILTER_REGISTRY.classes and len(name) > len(ORACLE_SUFFIX):
        return name[:-len(ORACLE_SUFFIX)]
    return None


def get_filter(name: str) -> type:
    """The class registered as ``name``; unknown names first trigger entry-point discovery. ``BASE-oracle``:
    the oracle of ``BASE`` (made once per base class), or a one-line error where ``BASE`` has none."""
    base = oracle_base(name)
    if base is None:
        return FILTER_REGISTRY.get(name)
    try:
        cls = FILTER_REGISTRY.get(base)
    except NespmError:
        raise NespmError(f"--filters: unknown filter {name!r}; choose from {', '.join(filter_names())}") from None
    if not oracle_able(cls, base):
        raise NespmError(f"--filters {name}: {base} has no oracle (it adapts its own noise or has no covariance); "
                         f"oracles: {', '.join(n for n in filter_names() if oracle_base(n))} (docs/adapting.md)")
    key = (base, cls)
    if key not in ORACLES:
        ORACLES[key] = oracle_class(cls, base, FILTER_REGISTRY.is_builtin(base))
    return ORACLES[key]


def filter_names(builtin_only: bool = False) -> tuple[str, ...]:
    """Registered names, built-ins first (in registration order), then plugins; without ``builtin_only``
    followed by the oracles (``NAME-oracle`` of every filter that has one)."""
    names = FILTER_REGISTRY.names(builtin_only)
    if builtin_only:
        return names
    return names + tuple(n + ORACLE_SUFFIX for n in names
                         if oracle_able(FILTER_REGISTRY.classes[n], n) and n + ORACLE_SUFFIX not in names)


def plugin_files(name: str) -> list[Path]:
    """The source files of filter ``name``'s code when it is a plugin (empty for a built-in): the
    plugin file, or every ``.py`` file of the top-level package its module belongs to (a module
    plugin or an entry point), sorted. Their hashes identify the code of an experiment."""
    return FILTER_REGISTRY.files(name)


def filter_source(name: str) -> str:
    """Where filter ``name`` is defined: its module's file (or module name)."""
    return FILTER_REGISTRY.sources.get(name, "?")


def is_builtin(name: str) -> bool:
    """Whether ``name`` is one of nespm's own filters."""
    return FILTER_REGISTRY.is_builtin(name)


def load_plugin(path_or_module: str | Path) -> ModuleType:
    """Import a filter plugin (a ``.py`` file path, or an importable module name); return the module.

    Idempotent: loading the same file (same resolved path) or module again returns the
    already imported module. The module is kept in ``sys.modules`` (so its classes pickle).
    Raises a one-line NespmError naming the file when it does not exist, fails to import or
    registers no filter, or when a name clashes.
    """
    return FILTER_REGISTRY.load_plugin(path_or_module)


def discover_plugins() -> list[str]:
    """Import every entry point of the group ``nespm.filters``; return their names. Runs once."""
    return FILTER_REGISTRY.discover()


__all__ = ["ENTRY_POINT_GROUP", "FILTER_REGISTRY", "ORACLES", "discover_plugins", "filter_names", "filter_source",
           "get_filter", "is_builtin", "load_plugin", "oracle_base", "plugin_files", "register", "register_filter"]
