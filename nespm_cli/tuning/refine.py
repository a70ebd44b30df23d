"""The local refinement of ``nespm tune``: a pattern (compass) search from the global search's best,
run until no step of the smallest size improves the score, and the convergence verdict
(docs/tuning.md, "A search that converges").

With common random numbers the training score is a deterministic function of the parameters, so a
local search can finish what the global one (TPE, CMA-ES) leaves: from a start point it polls each
parameter a step up and a step down (a factor on a log range, a share of the range on a linear one),
moves to any point that scores lower, and halves the step after a pass with no move; it ends when the
step falls below the smallest size (:data:`LEVELS` halvings of the first), or when its budget is used
up. It then polls the first (largest) step once more, so that a converged search has seen the
profile's steps (tuning.profile, x3 and /3) at its end point too.

The search is a pure function of its start point and the scores it is given (:func:`pattern_search`
asks ``evaluate`` and nothing else), so a killed refinement replays to the same point from the scores
stored in the study (tuning.evaluate caches them).

The verdict (:func:`verdict`): a filter **converged** when no profile step at its best and no other
filter's searched values (the cross-check) score better than its best by more than the tolerance
(:data:`TOLERANCE`); else it **stopped short** by the largest such gain, and the report says by what.
"""
from __future__ import annotations

import math
from typing import Callable

from nespm_cli.tuning.space import Param

FIRST_FACTOR = 3.0  # the first step on a log range: x 3 and / 3 (the profile's step)
FIRST_SHARE = 1.0 / 3.0  # the first step on a linear range: a third of the range (the profile's)
LEVELS = 3  # halvings of the step: the smallest is a factor 3^(1/8) = 1.147 (linear: a 24th of the range)
AUTO_PER_PARAM = 14  # the default budget: this many evaluations per parameter (a pass polls two per level)
TOLERANCE = 0.005  # a gain below 0.5 % of the score is not a better point (the verdict's tolerance)
# A poll moves only on a sufficient decrease: a gain above a tenth of the tolerance. Moves of less (a
# crawl along a flat valley, 0.01 % at a time) spent the whole budget in make tune-main's setup (every
# search "stopped short: the budget ran out" at 140 of 154 trials) without ever reaching the tolerance.
MOVE = TOLERANCE / 10


def auto_budget(params: list[Param]) -> int:
    """The refinement's default budget for ``params``: :data:`AUTO_PER_PARAM` evaluations per parameter
    (the 4 step sizes and the last pass at the first poll 2 points per parameter each: 10 per parameter
    when nothing moves; the rest for the moves)."""
    return AUTO_PER_PARAM * len(params)


def first_step(p: Param) -> float:
    """The first step of ``p`` in its search coordinate (log of the value on a log range)."""
    return math.log(FIRST_FACTOR) if p.log else FIRST_SHARE * (p.high - p.low)


def moved(p: Param, value: float, step: float) -> float:
    """``value`` moved by ``step`` in ``p``'s search coordinate, clipped to ``[p.low, p.high]``."""
    x = value * math.exp(step) if p.log else value + step
    return min(max(x, p.low), p.high)


def poll(evaluate: Callable[[dict], float], x: dict, fx: float, params: list[Param], level: int,
         budget: list[int]) -> tuple[dict, float, bool]:
    """One pass over the parameters at step level ``level`` (0: the first step): each parameter up, then
    down; move to every point that scores lower than the current one by more than :data:`MOVE` (relative).
    ``budget`` is a one-element list of evaluations left (decremented). Returns ``(x, f(x), moved)``."""
    any_move = False
    for p in params:
        step = first_step(p) / 2 ** level
        for sign in (1.0, -1.0):
            if budget[0] <= 0:
                return x, fx, any_move
            y = {**x, p.key: moved(p, float(x[p.key]), sign * step)}
            if y[p.key] == x[p.key]:
                continue
            budget[0] -= 1
            fy = evaluate(y)
            if fy < fx - MOVE * abs(fx):
                x, fx, any_move = y, fy, True
                break  # this parameter moved: on to the next
    return x, fx, any_move


def pattern_search(evaluate: Callable[[dict], float], x0: dict, f0: float, params: list[Param],
                   budget: int) -> dict:
    """Refine ``x0`` (score ``f0``) with at most ``budget`` evaluations. Returns ``{"values", "score",
    "evaluations", "finished"}``: ``finished`` when the smallest step and a last pass at the first step
    found no better point (else the budget ran out first)."""
    left = [int(budget)]
    x, fx = dict(x0), float(f0)
    level = 0
    while True:
        while level <= LEVELS:
            x, fx, any_move = poll(evaluate, x, fx, params, level, left)
            if left[0] <= 0:
                return {"values": x, "score": fx, "evaluations": budget - left[0], "finished": False}
            if not any_move:
                level += 1
        x, fx, any_move = poll(evaluate, x, fx, params, 0, left)  # the profile's steps at the end point
        if not any_move:
            return {"values": x, "score": fx, "evaluations": budget - left[0], "finished": True}
        if left[0] <= 0:
            return {"values": x, "score": fx, "evaluations": budget - left[0], "finished": False}
        level = 1  # the first step just moved: go on from the next size down


def verdict(best_score: float, profile: dict | None, cross: dict | None, refine: dict | None,
            tolerance: float = TOLERANCE) -> dict:
    """The convergence verdict of one filter's search: ``{"status", "short_by", "by", "refine_trials",
    "start", "tolerance"}``. ``profile`` (tuning.profile.profile's ``{key: {"low", "high", "score_low",
    "score_high", ...}}``) and ``cross`` (``{filter: {"score", "gain"}}``) at the best; ``refine`` the
    refinement's record (``{"evaluations", "finished", "start"}``; None: not refined). Without a
    refinement the checks alone decide; with neither checks nor a refinement: ``not checked``."""
    gains = []
    scale = max(abs(best_score), 1e-300)
    for key, pr in (profile or {}).items():
        for side, factor in (("low", "/3"), ("high", "x3")):
            gains.append(((best_score - pr[f"score_{side}"]) / scale, f"profile {key} {factor}"))
    for g, c in (cross or {}).items():
        gains.append(((best_score - c["score"]) / scale, f"{g}'s values"))
    gain, by = max(gains, default=(0.0, ""))
    out = {"refine_trials": int(refine["evaluations"]) if refine else 0,
           "start": refine.get("start", "own") if refine else "own", "tolerance": float(tolerance)}
    if gain > tolerance:
        return {"status": "stopped short", "short_by": float(gain), "by": by, **out}
    if refine is not None and not refine["finished"]:
        return {"status": "stopped short", "short_by": float(max(gain, 0.0)),
                "by": f"the refinement budget ({out['refine_trials']} trials) ran out", **out}
    if refine is None and not gains:
        return {"status": "not checked", "short_by": 0.0, "by": "", **out}
    return {"status": "converged", "short_by": 0.0, "by": "", **out}


__all__ = ["AUTO_PER_PARAM", "FIRST_FACTOR", "FIRST_SHARE", "LEVELS", "MOVE", "TOLERANCE", "auto_budget", "first_step", "moved", "pattern_search", "poll",
           "verdict"]
