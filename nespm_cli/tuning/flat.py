"""What a tuning does with a parameter its objective cannot see (``--flat``; docs/tuning.md, "Flat
parameters").

A parameter is **flat** when the score profile at the best setting moves by less than
:data:`nespm_cli.tuning.profile.FLAT` at both of its steps (x 3 and / 3): the objective has no
information on it, and the searched value is wherever the sampler happened to leave it. Written to
``tuned.toml`` as it is, that value is luck, and on held-out tracks it can cost what the objective
never saw: on the real A-KIT split the innovation objective left the DVL's R and the gyro noise far
from their defaults, the held-out VRMSE went from 0.080 (default) to 0.265 m/s; those flat factors at
their defaults gave 0.074/0.070 (issue 38).

Rule ``default`` (the default): each flat parameter, smallest profile change first, is set back to its
default (the space's, i.e. the filter's nominal noise) where the training score with it there stays
within ``FLAT`` of the best trial's score; a parameter whose default the score does see stays
searched. Without evidence the prior stands. Rule ``searched``: the best trial's values as they are
(what the search found, as before this rule). Without a profile (``--no-profile``) no parameter is
known flat and nothing changes (the record says so).

Each reset point is scored once on the training runs (phase ``check``), one trial per flat parameter.
"""
from __future__ import annotations

from typing import Callable

from nespm_cli.tuning.profile import FLAT, FLAT_RULES
from nespm_cli.tuning.space import Param



def flat_keys(profile: dict | None) -> list[str]:
    """The keys of ``profile`` (:func:`nespm_cli.tuning.profile.profile`'s record) flat at both steps,
    smallest profile change first."""
    rows = [(pr["change"], k) for k, pr in (profile or {}).items() if pr.get("flat")]
    return [k for _, k in sorted(rows)]


def reset_flat(shape: dict, score: float, profile: dict | None, space: list[Param],
               evaluate: Callable[[dict], float]) -> dict:
    """The flat parameters of ``shape`` (best searched values, training score ``score``) set to their
    defaults in turn while the score stays within :data:`FLAT` (relative) of ``score``: ``{"shape"``:
    the values to keep, ``"reset"``: keys set to their default, ``"kept"``: flat keys whose default
    moves the score (``{key: that score}``), ``"score"``: the training score of ``shape``}``."""
    defaults = {p.key: float(p.default) for p in space}
    limit = score + FLAT * max(abs(score), 1e-300)
    cur, cur_score, reset, kept = dict(shape), score, [], {}
    for k in flat_keys(profile):
        if k not in defaults or float(cur[k]) == defaults[k]:
            continue
        trial = {**cur, k: defaults[k]}
        s = float(evaluate(trial))
        if s <= limit:
            cur, cur_score = trial, s
            reset.append(k)
        else:
            kept[k] = s
    return {"shape": cur, "reset": reset, "kept": kept, "score": cur_score}


def apply_flat_rule(b: dict, rule: str, space: list[Param], evaluate: Callable[[dict], float]) -> bool:
    """Apply ``rule`` (:data:`FLAT_RULES`) to one filter's ``best`` entry ``b`` (with ``profile``) in
    place: ``b["flat"]`` records what was done (``rule``, ``reset``, ``kept``, ``searched``: the searched
    values of the reset keys, ``score``) and, where keys are reset, ``b["shape"]``/``b["values"]`` hold
    the kept setting (``b["searched_shape"]`` the best trial's). True where the shape changed."""
    if rule == "searched" or "profile" not in b:
        b["flat"] = {"rule": rule if "profile" in b else "none (no profile)", "reset": [], "kept": {}}
        return False
    got = reset_flat(b["shape"], b["score"], b["profile"], space, evaluate)
    b["flat"] = {"rule": rule, "reset": got["reset"], "kept": got["kept"], "score": got["score"],
                 "searched": {k: float(b["shape"][k]) for k in got["reset"]}}
    if not got["reset"]:
        return False
    b["searched_shape"] = dict(b["shape"])
    b["shape"] = got["shape"]
    if b.get("level", 1.0) == 1.0:
        b["values"] = {**b["values"], **{k: got["shape"][k] for k in got["reset"]}}
    return True


def add_flat(best: dict, store, train, space: dict, t, search: int = 0) -> bool:
    """:func:`apply_flat_rule` with ``t.flat`` (a :class:`nespm_cli.tuning.spec.TuneSpec`) to every filter
    of ``best`` (search ``search``'s, after ``add_checks``), each reset point scored on ``train``'s runs
    and kept in the filter's study (phase ``check``). True where any filter's shape changed."""
    import optuna

    from nespm_cli.tuning.evaluate import Evaluator
    from nespm_cli.tuning.study import study_name

    changed = False
    for f, b in best.items():
        study = optuna.load_study(study_name=study_name(f, search), storage=store)
        ev = Evaluator(train, f, space[f], study, t.objective, t.level)
        changed |= apply_flat_rule(b, t.flat, space[f], lambda v, ev=ev: ev(v, "check"))
    return changed


def training_score(entry: dict) -> float:
    """The training score of the setting a filter's search wrote (``tuned.toml``): the kept shape's where the
    flat rule reset a parameter (``entry["flat"]["score"]``), else the best trial's."""
    flat = entry.get("flat") or {}
    return float(flat["score"]) if flat.get("reset") and flat.get("score") is not None else float(entry["score"])


__all__ = ["add_flat", "apply_flat_rule", "flat_keys", "reset_flat", "training_score"]
