"""A filter's training score at given values, run once and kept in its study: the evaluations the
refinement, the profile and the cross-check ask for (docs/tuning.md).

Every evaluation is added to the study as a completed trial (``study.add_trial``: no trial is left
running if the process is killed mid-evaluation; the evaluation is then simply made again), with its
statistics and its phase (:data:`PHASES`). Values already scored in the study (by the global search
or an earlier evaluation, this process's or a killed one's) are not run again: a resumed refinement
replays from the stored scores.
"""
from __future__ import annotations

from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.objective import REUSE_RUNS, score, summary, trial_statistics
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.study import PHASE_ATTR, STATS_ATTR


def values_key(values: dict) -> tuple:
    """The cache key of a setting: its ``(key, value)`` pairs, sorted, each value to 12 significant digits
    (a point reached by two paths, e.g. x / 3 x 3, is one point)."""
    return tuple(sorted((str(k), float(f"{float(v):.12g}")) for k, v in values.items()))


class Evaluator:
    """``evaluator(values, phase)`` -> the score of filter ``name`` at ``values`` ({key: value} over every
    parameter of ``params``) on ``train``'s training runs under ``objective`` and ``level``; each new
    score added to ``study`` as a completed trial of ``phase``. ``evaluations`` counts the calls that ran
    a Monte Carlo."""

    def __init__(self, train: Spec, name: str, params: list[Param], study, objective: str, level: str):
        from optuna.trial import TrialState

        self.train, self.name, self.params, self.study = train, name, params, study
        self.objective, self.level = objective, level
        self.cache = {values_key(tr.params): float(tr.value)
                      for tr in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
                      if set(tr.params) == {p.key for p in params}}
        self.reuse = {} if train.runs * len(train.tracks) <= REUSE_RUNS else None
        self.evaluations = 0

    def __call__(self, values: dict, phase: str = "refine") -> float:
        import optuna

        key = values_key(values)
        if key in self.cache:
            return self.cache[key]
        stats = trial_statistics(self.train, self.name, values, self.reuse)
        value = float(score(stats, self.objective, self.level))
        self.cache[key] = value
        self.evaluations += 1
        if not all(p.low <= float(values[p.key]) <= p.high for p in self.params):
            return value  # outside the space (another filter's value in the cross-check): not a trial of it
        dists = {p.key: optuna.distributions.FloatDistribution(p.low, p.high, log=p.log) for p in self.params}
        self.study.add_trial(optuna.trial.create_trial(
            params={p.key: float(values[p.key]) for p in self.params}, distributions=dists, value=value,
            user_attrs={STATS_ATTR: summary(stats), PHASE_ATTR: phase}))
        return value


__all__ = ["Evaluator", "values_key"]
