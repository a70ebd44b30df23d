"""The search of ``nespm tune``: one filter's global search (its trials, suggested by its seeded sampler
and scored on the training realizations, until its study holds ``--trials`` of them), then its local
refinement from the best of its own and the other filters' values (tuning.refine; docs/tuning.md).
Each function runs in the process (or Dask task) that owns the study it writes."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.evaluate import Evaluator
from nespm_cli.tuning.objective import REUSE_RUNS, score, summary, trial_statistics
from nespm_cli.tuning.refine import auto_budget, refine
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec
from nespm_cli.tuning.study import (PHASE_ATTR, STATS_ATTR, config_digest, fail_stale, make_sampler, open_study, quiet,
                                    search_seed, storage, study_name, trial_phase, trial_seed)


def tune_filter(t: TuneSpec, train: Spec, index: int, params: list[Param], out: Path, worker: int = 0,
                report: Callable[[str, int, float], None] | None = None, search: int = 0, store=None) -> None:
    """Run filter ``train.filters[index]``'s global search ``search`` until its study holds ``t.trials``
    trials of the search phase (completed or running in another worker). ``store``: the study's storage
    where the caller has it open in this process (None: opened here; about 0.5 CPU-s for SQLite)."""
    from optuna.trial import TrialState

    name = train.filters[index]
    store = storage(out, t.storage) if store is None else store
    study = open_study(store, study_name(name, search), config_digest(train, name, params, t, search), out)
    reuse = {} if train.runs * len(train.tracks) <= REUSE_RUNS else None  # the inputs built once per filter
    root = search_seed(t, train, search)
    while True:
        trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING))
        done = sum(tr.state == TrialState.COMPLETE for tr in trials)
        if sum(trial_phase(tr) == "search" for tr in trials) >= t.trials:
            return
        study.sampler = make_sampler(t.sampler, trial_seed(root, index, done, worker))
        trial = study.ask()
        values = {p.key: trial.suggest_float(p.key, p.low, p.high, log=p.log) for p in params}
        stats = trial_statistics(train, name, values, reuse)
        value = score(stats, t.objective, t.level)
        trial.set_user_attr(STATS_ATTR, summary(stats))
        trial.set_user_attr(PHASE_ATTR, "search")
        study.tell(trial, value)
        if report is not None:
            report(study_name(name, search), done + 1, study.best_value)


def worker_run(t: TuneSpec, train: Spec, space: dict, out: str, worker: int, only: int | None = None,
               search: int = 0) -> None:
    """One worker of the global search: every filter's trials in turn (the studies are shared), or
    (``only``) that filter's alone, as worker 0: its study's one writer (a trial left running by a
    killed worker, e.g. a Dask worker lost mid-trial, is failed first), so its values are those of
    ``--jobs 1``."""
    from nespm_cli.experiments.spec import load_filters
    from nespm_cli.experiments.suite import load_sensors

    load_sensors(load_filters(train))
    quiet()
    for i, f in enumerate(train.filters):
        if only is None or i == only:
            if only is not None:
                store = storage(Path(out), t.storage)
                fail_stale(store, open_study(store, study_name(f, search),
                                             config_digest(train, f, space[f], t, search), Path(out)))
            tune_filter(t, train, i, space[f], Path(out), worker, search=search)


def mixed(own: dict, other: dict, params: list[Param]) -> dict:
    """``own`` values with ``other``'s on the keys they share, clipped to ``params``' ranges."""
    out = {}
    for p in params:
        v = float(other.get(p.key, own[p.key]))
        out[p.key] = min(max(v, p.low), p.high)
    return out


def refine_filter(t: TuneSpec, train: Spec, space: dict, out: str, index: int, search: int, start: dict,
                  candidates: dict) -> dict:
    """Refine filter ``train.filters[index]``'s search ``search``: score ``candidates`` (``{filter: its
    searched values}``: the other filters' bests on the keys they share), start from the best of those
    and its own best ``start`` (``{"values", "score"}``), and run :func:`nespm_cli.tuning.refine.refine` within
    ``t.refine_trials`` evaluations (None: :func:`nespm_cli.tuning.refine.auto_budget`; the candidates'
    included). Returns ``{"filter", "search", "start",
    "evaluations", "finished", "score", "values"}``."""
    from nespm_cli.experiments.spec import load_filters
    from nespm_cli.experiments.suite import load_sensors

    load_sensors(load_filters(train))
    quiet()
    name = train.filters[index]
    params = space[name]
    store = storage(Path(out), t.storage)
    study = open_study(store, study_name(name, search), config_digest(train, name, params, t, search), Path(out))
    ev = Evaluator(train, name, params, study, t.objective, t.level)
    x0, f0, origin = dict(start["values"]), float(start["score"]), "own"
    budget = auto_budget(params) if t.refine_trials is None else t.refine_trials
    used = 0
    for g, values in candidates.items():
        if used >= budget:
            break
        y = mixed(start["values"], values, params)
        used += 1
        fy = ev(y, "refine")
        if fy < f0:
            x0, f0, origin = y, fy, f"{g}'s values"
    res = refine(lambda v: ev(v, "refine"), x0, f0, params, budget - used)
    return {"filter": name, "search": search, "start": origin, "evaluations": used + res["evaluations"],
            "finished": res["finished"], "score": res["score"], "values": res["values"]}


__all__ = ["mixed", "refine_filter", "tune_filter", "worker_run"]
