"""reports: the report of a results folder (layer above experiments, below cli).

Small modules, each one concept, listed from the bottom up (a module imports only modules above it
in this list; none imports one that imports it back). docs/report.md defines what a report shows.

* toolkit: :mod:`~nespm_cli.reports.results` (reading a folder, facts of the results: filters,
  RTS-smoother floors, sensors' measurement sizes), :mod:`~nespm_cli.reports.markdown` (tables and
  number / interval formatting), :mod:`~nespm_cli.reports.stats` (eqs 50-52, improvement, bootstrap,
  paired comparisons, intervals), :mod:`~nespm_cli.reports.published` (the papers' tables),
  :mod:`~nespm_cli.reports.figures` (saving, colours, styles, what a figure drew);
* analysis: :mod:`~nespm_cli.reports.tables` (per-filter tables), :mod:`~nespm_cli.reports.comparisons`
  (head-to-head paired comparisons), :mod:`~nespm_cli.reports.block_consistency` (consistency per block
  and sensor from the share of epochs inside the bounds), :mod:`~nespm_cli.reports.verdict` (one row per
  metric);
* words and markdown: :mod:`~nespm_cli.reports.wording`, :mod:`~nespm_cli.reports.caveats` (each said
  once), :mod:`~nespm_cli.reports.verdict_markdown`;
* figures: :mod:`~nespm_cli.reports.axes_figures` (per-axis error and ±3σ),
  :mod:`~nespm_cli.reports.consistency` (ANEES, NCI, ANIS), :mod:`~nespm_cli.reports.position_figures`
  (error against distance travelled, final scatter with CEP);
* Monte Carlo report: :mod:`~nespm_cli.reports.mc_figures`, :mod:`~nespm_cli.reports.mc_markdown`,
  :mod:`~nespm_cli.reports.mc` (``write_mc_report``, and the names above re-exported);
* sweep report: :mod:`~nespm_cli.reports.sweep_data`, :mod:`~nespm_cli.reports.sweep_tables`,
  :mod:`~nespm_cli.reports.sweep_figures`, :mod:`~nespm_cli.reports.sweep_markdown`,
  :mod:`~nespm_cli.reports.sweep` (``write_sweep_report``, re-exports);
* other experiments: :mod:`~nespm_cli.reports.gp_ukf`, :mod:`~nespm_cli.reports.training`,
  :mod:`~nespm_cli.reports.check`, :mod:`~nespm_cli.reports.export`;
* :mod:`~nespm_cli.reports.dispatch`: ``write_report``, which picks the module by the manifest's experiment.
"""
