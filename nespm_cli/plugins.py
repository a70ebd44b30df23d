"""Registries of named classes with plugins: the filters and the sensors.

A :class:`Registry` holds the classes of one kind (``filter`` or ``sensor``) by name: the
built-ins (modules under ``nespm_cli.``) and user plugins —

* ``register(name)`` on a subclass of the kind's base class makes it available by name;
* ``load_plugin(path_or_module)`` imports a user's Python file or an installed module, which
  registers its classes when imported (idempotent: the same file or module again is harmless);
* installed distributions may declare entry points in the kind's group (``nespm.filters``,
  ``nespm.sensors``); they are imported on the first look-up of an unknown name.

Rules: a name is unique; a plugin may not take a built-in's name; registering a name again from
the same source (a worker process importing the plugin too) replaces the entry harmlessly. Every
error is a one-line :class:`~nespm_cli.errors.NespmError`.
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


def _one_line(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    return f"{type(e).__name__}: {msg}" if not isinstance(e, NespmError) else msg


class Registry:
    """Named classes of one kind (see the module docstring).

    Args:
        kind: ``"filter"`` or ``"sensor"`` (in messages); ``base``: the class every entry subclasses;
        group: the entry-point group; ``option``: the command-line option that names them.
    """

    def __init__(self, kind: str, base: type, group: str, option: str) -> None:
        self.kind, self.base, self.group, self.option = kind, base, group, option
        self.classes: dict[str, type] = {}
        self.sources: dict[str, str] = {}  # name -> the defining module's file (or its name)
        self.loaded: dict[str, object] = {}  # plugin key -> module
        self.loading: list[list[str]] = []
        self.discovered = False

    # --- registration ----------------------------------------------------------------------------
    def source_of(self, cls: type) -> str:
        """Where ``cls`` comes from: its module's resolved file, else the module name."""
        f = getattr(sys.modules.get(cls.__module__), "__file__", None)
        try:
            return str(Path(f).resolve()) if f else cls.__module__
        except OSError:  # pragma: no cover
            return cls.__module__

    def is_builtin(self, name: str) -> bool:
        """Whether ``name`` is one of nespm's own."""
        return self.classes[name].__module__.startswith("nespm_cli.") if name in self.classes else False

    def register(self, name: str, cls: type) -> type:
        """Register ``cls`` under ``name``; returns ``cls``."""
        if not isinstance(name, str) or not name or any(c in name for c in ", \t\n."):
            raise NespmError(f"{self.kind} name {name!r}: give a non-empty name without commas, dots or spaces")
        if not (isinstance(cls, type) and issubclass(cls, self.base)):
            raise NespmError(f"{self.kind} {name!r}: {cls!r} is not a subclass of {self.base.__module__}."
                             f"{self.base.__name__}")
        source = self.source_of(cls)
        old = self.sources.get(name)
        if old is not None and old != source:
            if self.is_builtin(name):
                raise NespmError(f"{self.kind} name {name!r} of {source} clashes with the built-in {self.kind} {name!r}")
            raise NespmError(f"{self.kind} name {name!r} of {source} is already registered by {old}")
        cls.name = name
        self.classes[name] = cls
        self.sources[name] = source
        if self.loading:
            self.loading[-1].append(name)
        return cls

    def decorator(self, name: str) -> Callable[[type], type]:
        """Class decorator ``@register("name")``."""
        def deco(cls: type) -> type:
            return self.register(name, cls)
        return deco

    # --- look-up ---------------------------------------------------------------------------------
    def get(self, name: str) -> type:
        """The class registered as ``name``; unknown names first trigger entry-point discovery."""
        if name not in self.classes and not self.discovered:
            self.discover()
        try:
            return self.classes[name]
        except KeyError:
            raise NespmError(f"{self.option}: unknown {self.kind} {name!r}; choose from {', '.join(self.names())}") from None

    def names(self, builtin_only: bool = False) -> tuple[str, ...]:
        """Registered names, built-ins first (in registration order), then plugins."""
        b = tuple(n for n in self.classes if self.is_builtin(n))
        return b if builtin_only else b + tuple(n for n in self.classes if not self.is_builtin(n))

    def files(self, name: str) -> list[Path]:
        """The source files of ``name``'s code when it is a plugin (empty for a built-in): the plugin
        file, or every ``.py`` file of the top-level package its module belongs to, sorted."""
        if name not in self.classes or self.is_builtin(name):
            return []
        module = sys.modules.get(self.classes[name].__module__)
        top = sys.modules.get(self.classes[name].__module__.split(".")[0])
        roots = [Path(p) for p in getattr(top, "__path__", None) or []]
        if roots and top is not None and not top.__name__.startswith("nespm_plugin_"):
            return sorted({f.resolve() for r in roots for f in r.rglob("*.py") if "__pycache__" not in f.parts})
        f = getattr(module, "__file__", None)
        return [Path(f).resolve()] if f else []

    # --- plugins ---------------------------------------------------------------------------------
    def _defines(self, module) -> bool:
        name = module.__name__ if isinstance(module, ModuleType) else getattr(module, "__module__", None)
        return bool(name) and any(c.__module__ == name or c.__module__.startswith(name + ".")
                                  for c in self.classes.values())

    def _import(self, key: str, label: str, do_import: Callable[[], ModuleType]) -> ModuleType:
        """Import a plugin under the registration context; roll back its registrations on failure."""
        if key in self.loaded:
            return self.loaded[key]
        snapshot = (dict(self.classes), dict(self.sources))
        self.loading.append([])
        try:
            try:
                module = do_import()
            except NespmError as e:
                raise NespmError(f"{self.kind} plugin {label}: {_one_line(e)}") from None
            except SystemExit as e:
                raise NespmError(f"{self.kind} plugin {label} called sys.exit({e.code!r}) while imported; a plugin "
                                 "raises nespm_cli.errors.NespmError to stop with a message") from None
            except Exception as e:
                raise NespmError(f"{self.kind} plugin {label} failed to import: {_one_line(e)}") from None
            if not self.loading[-1] and not self._defines(module):
                raise NespmError(f"{self.kind} plugin {label} registers no {self.kind} (decorate a "
                                 f"{self.base.__name__} subclass with @register(name))")
        except NespmError:
            self.classes.clear(), self.classes.update(snapshot[0])
            self.sources.clear(), self.sources.update(snapshot[1])
            raise
        finally:
            self.loading.pop()
        self.loaded[key] = module
        return module

    def load_plugins(self, plugins) -> tuple[str, ...]:
        """Discover the entry points, then import every plugin of ``plugins`` (files or modules;
        idempotent: in the parent and again in every worker); return them as recorded: files as
        absolute paths, module names as given."""
        self.discover()
        out = []
        for p in plugins:
            self.load_plugin(p)
            path = Path(str(p)).expanduser()
            out.append(str(path.resolve()) if path.is_file() else str(p))
        return tuple(out)

    def load_plugin(self, path_or_module: str | Path) -> ModuleType:
        """Import a plugin (a ``.py`` file path, or an importable module name); return the module."""
        s = str(path_or_module)
        looks_like_path = isinstance(path_or_module, Path) or s.endswith(".py") or "/" in s or "\\" in s
        if not looks_like_path:
            return self._import(f"module:{s}", s, lambda: importlib.import_module(s))
        p = Path(s).expanduser()
        if not p.is_file():
            raise NespmError(f"{self.kind} plugin {s}: no such file")
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

        return self._import(f"file:{key}", s, do_import)

    def discover(self) -> list[str]:
        """Import every entry point of the group; return their names. Runs once."""
        self.discovered = True
        names = []
        for ep in importlib.metadata.entry_points(group=self.group):
            self._import(f"entry:{ep.value}", f"entry point {ep.name} = {ep.value}", ep.load)
            names.append(ep.name)
        return names


__all__ = ["Registry"]
