"""The ``nespm tune`` report: the tuning folder's report (:mod:`~nespm_cli.reports.tune.report`), its held-out
part (:mod:`~nespm_cli.reports.tune.heldout`) and the searches' verdicts and spread
(:mod:`~nespm_cli.reports.tune.searches`)."""
