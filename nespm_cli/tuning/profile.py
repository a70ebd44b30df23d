"""What a tuning can see: each tuned parameter's importance and its score profile at the best setting.

* **Importance** (Optuna's fANOVA, seeded): the share of the score's variance over the completed
  trials that each parameter explains (they sum to 1). Near 0: the objective does not depend on it.
* **Profile**: the score at the best setting with one parameter at its tuned value x :data:`FACTOR`
  and / :data:`FACTOR` (within its range), the others held; the parameter is **flat** (the objective
  cannot see it: its tuned value means nothing) when neither moves the score by more than
  :data:`FLAT` (relative); **flat on one side** when one of them does not (only a bound of it is seen).
  Two trials per parameter, on the same training realizations.
* **Cross-check**: each filter scored with every other filter's searched values on the parameters
  they share (its own elsewhere, e.g. alpha). A filter another's values serve better than its own
  best by more than :data:`FLAT` stopped short of its optimum: an equal budget is not an equal
  search, and its rank among the tuned filters says so little until more trials are run. One
  trial per pair.
"""
from __future__ import annotations

import numpy as np

from typing import Callable

from nespm_cli.tuning.space import Param

FACTOR = 3.0  # the profile's step: x 3 and / 3 (linear ranges: ± a third of the range)
FLAT = 0.02  # a relative score change below this at both steps: the parameter is not seen
FLAT_RULES = ("default", "searched")  # --flat: what a flat parameter becomes (tuning.flat)


def importances(study) -> dict[str, float]:
    """``{key: share}`` of the study's completed trials (fANOVA, seed 0); ``{}`` with fewer than 3 trials
    or a constant score."""
    import optuna
    from optuna.trial import TrialState

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < 3 or len({t.value for t in done}) < 2:
        return {}
    try:
        got = optuna.importance.get_param_importances(
            study, evaluator=optuna.importance.FanovaImportanceEvaluator(seed=0))
    except (RuntimeError, ValueError):
        return {}
    return {k: float(v) for k, v in got.items()}


def steps(p: Param, value: float) -> tuple[float, float]:
    """The profile's two values of ``p`` around ``value``, clipped to its range."""
    if p.log:
        return max(p.low, value / FACTOR), min(p.high, value * FACTOR)
    span = (p.high - p.low) / FACTOR
    return max(p.low, value - span), min(p.high, value + span)


def profile(params: list[Param], best: dict, evaluate: Callable[[dict], float], best_score: float) -> dict:
    """``{key: {"low", "high", "score_low", "score_high", "change", "flat", "flat_side"}}`` at the best
    searched values ``best``, each point scored by ``evaluate`` (values -> score, as the trials were).
    ``flat_side``: ``both`` (flat), ``low`` or ``high`` where the score moves less than :data:`FLAT` on that
    side only (or the value sits at that end of its range): the objective bounds the parameter on one
    side only, so its tuned value is not identified (only a bound is), ``""`` where both steps move it."""
    out = {}
    for p in params:
        v = float(best[p.key])
        lo, hi = steps(p, v)
        s = [evaluate({**best, p.key: x}) for x in (lo, hi)]
        sides = np.abs(np.asarray(s) - best_score) / max(abs(best_score), 1e-300)
        change = float(np.max(sides))
        flat_side = {(True, True): "both", (True, False): "low", (False, True): "high"}.get(
            (bool(sides[0] < FLAT or lo == v), bool(sides[1] < FLAT or hi == v)), "")
        out[p.key] = {"low": lo, "high": hi, "score_low": float(s[0]), "score_high": float(s[1]),
                      "change": change, "flat": bool(change < FLAT), "flat_side": flat_side}
    return out


def cross_scores(best: dict, others: dict, evaluate: Callable[[dict], float], best_score: float) -> dict:
    """``{other: {"score", "gain"}}``: a filter (best searched values ``best``) scored by ``evaluate`` with
    each of ``others`` (``{filter: its searched values}``) over the keys they share; ``gain`` the
    relative score drop against ``best_score`` (> :data:`FLAT`: the search stopped short)."""
    out = {}
    for g, values in others.items():
        mixed = {k: float(values.get(k, v)) for k, v in best.items()}
        s = evaluate(mixed)
        out[g] = {"score": float(s), "gain": float((best_score - s) / max(abs(best_score), 1e-300))}
    return out


def stopped_short(best: dict) -> dict[str, tuple[str, dict]]:
    """``{filter: (other, its cross entry)}`` of ``best`` (``tune.json``'s, with ``cross``): the filters
    whose own best another filter's searched values beat by more than :data:`FLAT`, with the best such."""
    out = {}
    for f, b in best.items():
        win = min((b.get("cross") or {}).items(), key=lambda kv: kv[1]["score"], default=None)
        if win is not None and win[1]["gain"] > FLAT:
            out[f] = win
    return out


__all__ = ["FACTOR", "FLAT", "FLAT_RULES", "cross_scores", "importances", "profile", "steps", "stopped_short"]
