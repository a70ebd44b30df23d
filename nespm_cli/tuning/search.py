"""The search of ``nespm tune``: one filter's trials, suggested by its seeded sampler and scored on the
training realizations, until its study holds ``--trials`` of them (docs/tuning.md)."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.objective import REUSE_RUNS, score, summary, trial_statistics
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec
from nespm_cli.tuning.study import STATS_ATTR, config_digest, make_sampler, open_study, quiet, storage, trial_seed


def tune_filter(t: TuneSpec, train: Spec, index: int, params: list[Param], out: Path, worker: int = 0,
                report: Callable[[str, int, float], None] | None = None) -> None:
    """Run filter ``train.filters[index]``'s trials until its study holds ``t.trials`` completed ones."""
    from optuna.trial import TrialState

    name = train.filters[index]
    store = storage(out)
    study = open_study(store, name, config_digest(train, name, params, t), out)
    reuse = {} if train.runs * len(train.tracks) <= REUSE_RUNS else None  # the inputs built once per filter
    while True:
        trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING))
        done = sum(tr.state == TrialState.COMPLETE for tr in trials)
        if len(trials) >= t.trials:
            return
        study.sampler = make_sampler(t.sampler, trial_seed(train.seed, index, done, worker))
        trial = study.ask()
        values = {p.key: trial.suggest_float(p.key, p.low, p.high, log=p.log) for p in params}
        stats = trial_statistics(train, name, values, reuse)
        value = score(stats, t.objective, t.level)
        trial.set_user_attr(STATS_ATTR, summary(stats))  # one commit
        study.tell(trial, value)
        if report is not None:
            report(name, done + 1, study.best_value)


def worker_run(t: TuneSpec, train: Spec, space: dict, out: str, worker: int, only: int | None = None) -> None:
    """One ``--jobs`` worker: every filter's trials in turn (the studies are shared), or (``only``) that
    filter's alone, as worker 0: its study's one writer, so its values are those of ``--jobs 1``."""
    from nespm_cli.experiments.spec import load_filters
    from nespm_cli.experiments.suite import load_sensors

    load_sensors(load_filters(train))
    quiet()
    for i, f in enumerate(train.filters):
        if only is None or i == only:
            tune_filter(t, train, i, space[f], Path(out), worker)


__all__ = ["tune_filter", "worker_run"]
