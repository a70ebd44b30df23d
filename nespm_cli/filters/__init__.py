"""Closed-loop error-state INS/DVL filters, batched over Monte Carlo runs.

Filters are classes of the protocol in :mod:`nespm_cli.filters.protocol`, registered by name
in :mod:`nespm_cli.filters.registry` (built-ins and plugins, docs/plugins.md).

The engine's names (``FILTERS``, ``FilterOutput``, ``run_filter``) are imported on first use
(PEP 562), so that importing :class:`FilterConfig` (an option default of the ``nespm`` command)
does not import every filter and sensor.
"""
from nespm_cli.filters.model import FilterConfig, NavState, initial_nav

__all__ = ["FILTERS", "FilterConfig", "FilterOutput", "NavState", "initial_nav", "run_filter"]

_ENGINE = ("FILTERS", "FilterOutput", "run_filter")


def __getattr__(name: str):
    if name in _ENGINE:
        from nespm_cli.filters import engine

        return getattr(engine, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
