"""reports: the report of a results folder (layer above experiments, below cli).

A toolkit of small modules, each one concept, and one module per experiment type:

* :mod:`~nespm_cli.reports.results`: reading a results folder, column checks, facts of the results;
* :mod:`~nespm_cli.reports.published`: the published values of the papers' tables;
* :mod:`~nespm_cli.reports.stats`: eqs 50-52, improvement, bootstrap resampling, paired comparisons,
  percentile and Wilson intervals, the NEES band word;
* :mod:`~nespm_cli.reports.markdown`: markdown tables and number / interval formatting;
* :mod:`~nespm_cli.reports.figures`: saving figures, filter colours, DVL-outage spans;
* :mod:`~nespm_cli.reports.mc`, :mod:`~nespm_cli.reports.sweep`, :mod:`~nespm_cli.reports.gp_ukf`,
  :mod:`~nespm_cli.reports.training`: the report (or figures) of one experiment type;
* :mod:`~nespm_cli.reports.dispatch`: ``write_report``, which picks the module by the manifest's
  experiment.

Modules import only downward in that list; none imports a sibling that imports it back.
"""
