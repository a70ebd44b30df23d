"""``nespm tune``: every filter's parameters searched with the same budget on training realizations
(docs/tuning.md). One module per concept: ``spec`` (what is asked, its checks), ``space`` (what is
searched), ``objective`` (how a trial is scored, the fitted level), ``study`` (the Optuna studies and
their storage), ``study_file`` (the file in ``OUT`` that holds them, checked before it is opened),
``search`` (a filter's trials), ``best`` (the best trial, its level, profile and cross-check),
``profile`` (importance, profile, cross-check), ``heldout`` (the held-out mc folders), ``progress``
(progress lines) and ``run`` (``run_tune``: all of it, written into ``OUT``)."""
