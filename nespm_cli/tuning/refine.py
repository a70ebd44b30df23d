"""The local refinement of ``nespm tune``: a quadratic model's trust-region search (Powell's BOBYQA)
from the global search's best, then a pattern (compass) search at the smallest steps until no step
improves the score, and the convergence verdict (docs/tuning.md, "A search that converges").

With common random numbers the training score is a deterministic function of the parameters, so a
local search can finish what the global one (TPE, CMA-ES) leaves. :func:`model_search` fits a
quadratic model of the score to the points it evaluates and steps to the model's minimum in a trust
region: it follows a ridge across the parameters' axes. :func:`pattern_search` then polls each
parameter a step up and a step down (a factor on a log range, a share of the range on a linear one),
moves to any point that scores lower, follows a pass that moved with a pattern move, and halves the
step after a pass with no move; it ends when the step falls below each parameter's smallest size
(:func:`last_level`), or when its budget is used up. It then polls the first (largest) step once
more, so that a converged search has seen the profile's steps (tuning.profile, x3 and /3) at its end
point too.

Both are pure functions of their start point and the scores they are given (they ask ``evaluate`` and
nothing else; the model draws no random directions), so a killed refinement replays to the same point
from the scores stored in the study (tuning.evaluate caches them).

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
LEVELS = 3  # halvings of the step: the smallest is a factor 3^(1/8) = 1.147 on a log range
# A linear range (a lever arm) halves twice more, polled alone at those levels: its smallest step is a 96th
# of the range (0.0625 m on the lever arm's 6 m). At a 24th (0.25 m) make tune-main's searches ended
# between -1.56 and -1.65 m, a spread the held-out error follows.
LINEAR_LEVELS = 5
CHECK_PASSES = 3  # refine: the budget kept for the polls after the model (the first step, the smallest, the first again)
AUTO_PER_PARAM = 15  # the default budget: this many evaluations per parameter, and the model's 2n + 1 first points
TOLERANCE = 0.005  # a gain below 0.5 % of the score is not a better point (the verdict's tolerance)
# A poll moves only on a sufficient decrease: a gain above a tenth of the tolerance. Moves of less (a
# crawl along a flat valley, 0.01 % at a time) spent the whole budget in make tune-main's setup (every
# search "stopped short: the budget ran out" at 140 of 154 trials) without ever reaching the tolerance.
MOVE = TOLERANCE / 10


def auto_budget(params: list[Param]) -> int:
    """The refinement's default budget for ``params`` (n of them): :data:`AUTO_PER_PARAM` evaluations per
    parameter and the 2n + 1 points that :func:`model_search`'s first quadratic model interpolates.
    Measured: on a two-parameter study with one flat parameter (tests/test_tune_refine.py) the model and
    the polls need 34 evaluations; 14 per parameter (the budget of the polls alone) leaves them short."""
    return AUTO_PER_PARAM * len(params) + 2 * len(params) + 1


def first_step(p: Param) -> float:
    """The first step of ``p`` in its search coordinate (log of the value on a log range)."""
    return math.log(FIRST_FACTOR) if p.log else FIRST_SHARE * (p.high - p.low)


def last_level(p: Param) -> int:
    """The last step level of ``p``: :data:`LEVELS` on a log range, :data:`LINEAR_LEVELS` on a linear one."""
    return LEVELS if p.log else LINEAR_LEVELS


def coordinate(p: Param, value: float) -> float:
    """``value`` in ``p``'s search coordinate: its log on a log range, itself on a linear one."""
    return math.log(value) if p.log else value


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
        if level > last_level(p):
            continue
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


def pattern_move(evaluate: Callable[[dict], float], base: dict, x: dict, fx: float, params: list[Param],
                 budget: list[int]) -> tuple[dict, float]:
    """Hooke and Jeeves' pattern move: after a pass that took ``base`` to ``x``, go on along ``x - base``
    (in the search coordinates, clipped to the ranges), doubling the stride after each point that scores
    lower by more than :data:`MOVE`, until one does not. A ridge that the parameters' axes cross at an
    angle (make tune-main's accelerometer noise, R and P0 of attitude, scaled together) is followed in
    a few evaluations instead of a zig-zag of polls. Returns ``(x, f(x))``."""
    d = {p.key: coordinate(p, float(x[p.key])) - coordinate(p, float(base[p.key])) for p in params}
    stride = 1.0
    while budget[0] > 0:
        y = {**x, **{p.key: moved(p, float(x[p.key]), stride * d[p.key]) for p in params if d[p.key] != 0.0}}
        if y == x:
            break
        budget[0] -= 1
        fy = evaluate(y)
        if not fy < fx - MOVE * abs(fx):
            break
        x, fx, stride = y, fy, 2.0 * stride
    return x, fx


def model_search(evaluate: Callable[[dict], float], x0: dict, f0: float, params: list[Param],
                 budget: int) -> tuple[dict, float, int]:
    """Powell's BOBYQA (a quadratic model of the score in a trust region, refit from the points it
    evaluates; Py-BOBYQA, Cartis, Fiala, Marteau & Roberts 2019) from ``x0`` within ``budget``
    evaluations, in the search coordinates scaled so that each parameter's first step is 1, the trust
    radius from 1 down to ``2 ** -LEVELS`` (the polls then go finer on a linear range), its first directions the parameters' axes (no random
    draw: a pure function of the scores, like the polls). Why: the model learns a ridge across the axes
    (make tune-main's accelerometer noise, R and P0 of attitude, scaled together), where polls along the
    axes crawl. Returns the best point seen, its score and the evaluations made."""
    import numpy as np
    import pybobyqa

    if budget < len(params) + 2 or not params:
        return dict(x0), float(f0), 0
    z0 = np.array([coordinate(p, float(x0[p.key])) for p in params])
    unit = np.array([first_step(p) for p in params])
    lo = (np.array([coordinate(p, p.low) for p in params]) - z0) / unit
    hi = (np.array([coordinate(p, p.high) for p in params]) - z0) / unit
    best = {"x": dict(x0), "f": float(f0), "n": 0}

    def at(u) -> dict:
        z = z0 + np.clip(u, lo, hi) * unit
        return {**x0, **{p.key: min(max(math.exp(v) if p.log else float(v), p.low), p.high) for p, v in zip(params, z)}}

    def score(u) -> float:
        x = at(u)
        f = float(evaluate(x))
        best["n"] += 1
        if f < best["f"]:
            best["x"], best["f"] = x, f
        return f if math.isfinite(f) else 1e30

    rhobeg = min(1.0, 0.49 * float(np.min(hi - lo)))
    pybobyqa.solve(score, np.zeros(len(params)), bounds=(lo, hi), maxfun=int(budget), rhobeg=rhobeg,
                   rhoend=min(2.0 ** -LEVELS, rhobeg / 2), do_logging=False, print_progress=False,
                   user_params={"init.random_initial_directions": False})
    return best["x"], best["f"], best["n"]


def pattern_search(evaluate: Callable[[dict], float], x0: dict, f0: float, params: list[Param],
                   budget: int, first_level: int = 0) -> dict:
    """Refine ``x0`` (score ``f0``) with at most ``budget`` evaluations: polls along the parameters
    (:func:`poll`) from step level ``first_level``, each pass that moved followed by a pattern move
    (:func:`pattern_move`), the step halved after a pass with no move, down to each parameter's last
    level (:func:`last_level`), then a last pass at the first step. Returns ``{"values", "score",
    "evaluations", "finished"}``: ``finished`` when the smallest steps and the last pass found no
    better point (else the budget ran out first)."""
    left = [int(budget)]
    x, fx = dict(x0), float(f0)
    last = max((last_level(p) for p in params), default=LEVELS)
    level = min(first_level, last)

    def out(finished: bool) -> dict:
        return {"values": x, "score": fx, "evaluations": budget - left[0], "finished": finished}

    while True:
        while level <= last:
            base = x
            x, fx, any_move = poll(evaluate, x, fx, params, level, left)
            if any_move:
                x, fx = pattern_move(evaluate, base, x, fx, params, left)
            if left[0] <= 0:
                return out(False)
            if not any_move:
                level += 1
        x, fx, any_move = poll(evaluate, x, fx, params, 0, left)  # the profile's steps at the end point
        if not any_move:
            return out(True)
        if left[0] <= 0:
            return out(False)
        level = 1  # the first step just moved: go on from the next size down


def refine(evaluate: Callable[[dict], float], x0: dict, f0: float, params: list[Param], budget: int) -> dict:
    """The refinement: :func:`model_search` with the budget less :data:`CHECK_PASSES` polls; then a pass
    at the first step (the profile's x3 and /3, which the verdict checks: a model that stopped short of
    one is caught while budget is left); then :func:`pattern_search` with the rest, from the smallest
    step, or from the second where the first step moved (the polls are the checkable end: no step of
    the smallest size and none of the first improves the score by more than :data:`MOVE`). Returns
    pattern_search's record with ``evaluations`` the total and ``model`` the model stage's.

    Why the first step right after the model: make tune-main's EKF searched alone at 10 training
    runs (5 searches) ended twice "stopped short by 2.0 % / 2.7 % (a profile step)" with the budget
    spent at the smallest steps before the last pass at the first step."""
    reserve = CHECK_PASSES * 2 * len(params)
    x, fx, n = model_search(evaluate, x0, f0, params, max(int(budget) - reserve, 0))
    left = [int(budget) - n]
    y, fy, moved_first = poll(evaluate, x, fx, params, 0, left)
    if moved_first:
        y, fy = pattern_move(evaluate, x, y, fy, params, left)
    used = int(budget) - n - left[0]
    res = pattern_search(evaluate, y, fy, params, left[0], first_level=1 if moved_first else LEVELS)
    return {**res, "evaluations": n + used + res["evaluations"], "model": n}


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


__all__ = ["AUTO_PER_PARAM", "FIRST_FACTOR", "FIRST_SHARE", "LEVELS", "LINEAR_LEVELS", "MOVE", "TOLERANCE", "auto_budget",
           "CHECK_PASSES", "coordinate", "first_step", "last_level", "model_search", "moved", "pattern_move",
           "pattern_search", "poll", "refine", "verdict"]
