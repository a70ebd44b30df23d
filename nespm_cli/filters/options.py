"""Per-filter options: ``--filter-option NAME.KEY=VALUE`` and ``[filters.NAME]`` config tables.

A filter takes two kinds of option:

* **its own** (a plugin's tuning): the class attribute ``option_defaults`` (``{"q_scale": 1.0}``)
  names them with their defaults, whose types (float, int, bool, str) convert the given text; the
  filter reads the values from ``cfg.options`` (:func:`option_values`);
* **a tuning field of** :class:`~nespm_cli.filters.model.FilterConfig` it declares in ``tunable``
  (the sigma-point filters: ``alpha``, ``beta``, ``kappa``): given for that filter alone, the
  filter runs with its own FilterConfig (:func:`configure`).

The options are part of the experiment (``Spec.filter_options``): recorded in the manifest, in
the experiment's identity (a folder is never resumed with another value) and sweepable
(``sweep --param NAME.KEY``). An unknown filter, key or value is a one-line error.
"""
from __future__ import annotations

import dataclasses

from nespm_cli.errors import NespmError
from nespm_cli.filters.model import FilterConfig


def option_defaults(cls: type) -> dict:
    """``{key: default}`` of every option the filter class takes: its own, then its ``tunable``
    FilterConfig fields (with FilterConfig's defaults)."""
    own = dict(getattr(cls, "option_defaults", {}) or {})
    base = FilterConfig()
    return {**own, **{k: getattr(base, k) for k in getattr(cls, "tunable", ()) or ()}}


def typed(value, default, where: str):
    """``value`` (text from the command line, or a TOML value) as the type of ``default``."""
    text = str(value).strip()
    try:
        if isinstance(default, bool):
            if isinstance(value, bool):
                return value
            low = text.lower()
            if low in ("true", "yes", "1", "on"):
                return True
            if low in ("false", "no", "0", "off"):
                return False
            raise ValueError
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float) or default is None:
            v = float(text)
            if v != v or v in (float("inf"), float("-inf")):
                raise ValueError
            return v
        return text
    except ValueError:
        kind = type(default).__name__ if default is not None else "number"
        raise NespmError(f"{where}: expected a {kind}, got {text!r}") from None


def check_filter_options(pairs, filters, get_filter) -> tuple:
    """Check ``(filter, key, value)`` triples against the study's ``filters`` (the classes from
    ``get_filter``); return them with typed values, in the given order, the last of a repeated
    key winning. One-line errors naming ``--filter-option NAME.KEY``."""
    out: dict = {}
    for name, key, value in pairs:
        where = f"--filter-option {name}.{key}"
        if name not in filters:
            raise NespmError(f"{where}: {name} is not in --filters ({', '.join(filters)})")
        allowed = option_defaults(get_filter(name))
        if key not in allowed:
            takes = ", ".join(sorted(allowed)) or "no options"
            raise NespmError(f"{where}: unknown option; {name} takes {takes}")
        out[(name, key)] = typed(value, allowed[key], where)
    return tuple((n, k, v) for (n, k), v in out.items())


def configure(cfg: FilterConfig, name: str, cls: type, pairs) -> FilterConfig:
    """The FilterConfig filter ``name`` runs with: its ``tunable`` fields of ``pairs`` (checked
    triples) set on ``cfg``, and its own options in ``cfg.options`` (``((key, value), ...)``)."""
    mine = [(k, v) for n, k, v in pairs if n == name]
    if not mine:
        return cfg
    tunable = set(getattr(cls, "tunable", ()) or ())
    fields = {k: v for k, v in mine if k in tunable}
    own = tuple((k, v) for k, v in mine if k not in tunable)
    return dataclasses.replace(cfg, **fields, options=own)


def option_values(cls: type, cfg: FilterConfig) -> dict:
    """``{key: value}`` of the filter's own options: its defaults, with those given in ``cfg.options``."""
    return {**dict(getattr(cls, "option_defaults", {}) or {}), **dict(cfg.options)}


__all__ = ["check_filter_options", "configure", "option_defaults", "option_values", "typed"]
