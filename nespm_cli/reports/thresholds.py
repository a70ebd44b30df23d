"""The reports' default thresholds, in a module without pandas: the ``nespm`` command reads them as
option defaults when it starts (``nespm report --help`` must not import the report's stack);
:mod:`nespm_cli.reports.stats` re-exports them."""

#: Default practical threshold [%]: an improvement smaller than this in magnitude is "no practical
#: difference" even when its interval excludes 0 (``write_report(..., practical_pct=...)``).
PRACTICAL_PCT = 1.0
