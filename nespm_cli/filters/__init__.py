"""Closed-loop error-state INS/DVL filters, batched over Monte Carlo runs.

Filters are classes of the protocol in :mod:`nespm_cli.filters.protocol`, registered by name
in :mod:`nespm_cli.filters.registry` (built-ins and plugins, docs/plugins.md).
"""
from nespm_cli.filters.engine import FILTERS, FilterOutput, run_filter
from nespm_cli.filters.model import FilterConfig, NavState, initial_nav

__all__ = ["FILTERS", "FilterConfig", "FilterOutput", "NavState", "initial_nav", "run_filter"]
