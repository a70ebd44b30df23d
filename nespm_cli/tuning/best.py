"""What a finished search gives: each filter's best trial, its fitted level (``--level tracks``), and
what the search can see around it (importance, profile, the cross-check; docs/tuning.md)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.evaluate import Evaluator
from nespm_cli.tuning.objective import fit_level, leveled, summary, trial_statistics
from nespm_cli.tuning.refine import verdict
from nespm_cli.tuning.spec import TuneSpec, level_bases
from nespm_cli.tuning.study import STATS_ATTR, study_name, trial_phase

LEVEL_TOLERANCE = 0.02  # the fitted level is refitted while the tracks' geometric-mean ANEES is > 2 % off 6
LEVEL_ITERATIONS = 3  # at most this many refits (an EKF needs none: it is homogeneous in the level)


def best_values(store, filters: tuple, trials: int, space: dict | None = None, bases: dict | None = None,
                search: int = 0, refined: bool = True) -> dict[str, dict]:
    """``{filter: {"trial", "score", "values", "shape", "level", "default_score"}}``: each filter's best
    (search ``search``, :func:`nespm_cli.tuning.study.study_name`) of its first ``trials`` completed
    trials of the global search and every trial of its refinement (ties: the earlier trial); ``shape``
    its searched values, ``level`` the variance factor fitted to it (``bases`` given: ``{filter:
    level_bases}``, the fitted level applies; else 1) and ``values`` the shape at that level (what
    ``tuned.toml`` writes); ``default_score`` that of the first trial at the defaults of ``space``
    (None if there is none). ``refined`` False: the global search's best alone (where the refinement
    starts)."""
    import optuna
    from optuna.trial import TrialState

    res = {}
    for f in filters:
        done = optuna.load_study(study_name=study_name(f, search), storage=store).get_trials(
            deepcopy=False, states=(TrialState.COMPLETE,))
        done = sorted(done, key=lambda tr: tr.number)
        glob = [tr for tr in done if trial_phase(tr) == "search"][:trials]
        local = [tr for tr in done if trial_phase(tr) == "refine"] if refined else []
        best = min(glob + local, key=lambda tr: (tr.value, tr.number))
        defaults = {p.key: p.default for p in (space or {}).get(f, [])}
        first = next((tr for tr in glob if defaults and tr.params == defaults), None)
        c = float(best.user_attrs.get(STATS_ATTR, {}).get("level", 1.0)) if bases else 1.0
        shape = dict(best.params)
        res[f] = {"trial": best.number, "score": best.value, "shape": shape, "level": c,
                  "values": leveled(shape, bases[f], c) if bases else shape,
                  "default_score": first.value if first is not None else None,
                  "default_trial": first.number if first is not None else None,
                  "phase": trial_phase(best)}
    return res


def add_checks(best: dict, store, out: Path, train: Spec, space: dict, t: TuneSpec, refined: dict | None = None,
               search: int = 0) -> None:
    """Add (``t.profile``) each filter's ``importance`` and ``profile`` and, with two filters or more,
    ``cross`` (its score with the others' searched values) to ``best``, and its convergence verdict
    (``convergence``, :func:`nespm_cli.tuning.refine.verdict`; ``refined``: ``{filter: the
    refinement's record}``, None where none ran). The checks' points are scored once and kept in the
    study (phase ``check``; a converged refinement has scored them already: no new run)."""
    import optuna

    from nespm_cli.tuning.profile import cross_scores, importances, profile

    for f, b in best.items():
        study = optuna.load_study(study_name=study_name(f, search), storage=store)
        if t.profile:  # fANOVA: about 1.5 CPU-s (scikit-learn and scipy.stats imported), no run
            b["importance"] = importances(study)
        ev = Evaluator(train, f, space[f], study, t.objective, t.level)

        def check_point(values: dict, ev=ev) -> float:
            return ev(values, "check")
        if t.profile:
            b["profile"] = profile(space[f], b["shape"], check_point, b["score"])
            others = {g: o["shape"] for g, o in best.items() if g != f}
            if others:
                b["cross"] = cross_scores(b["shape"], others, check_point, b["score"])
        b["convergence"] = verdict(b["score"], b.get("profile"), b.get("cross"), (refined or {}).get(f))


def add_leveled(best: dict, old: dict, train: Spec, t: TuneSpec) -> None:
    """With the fitted level (``t.level == "tracks"``): each filter's best shape run on
    ``max(--runs, --level-runs)`` training runs per track (the trials' runs first, then more of the
    same stream), its level fitted on them (``level``, ``values``: a level fitted on few runs carries
    their sampling spread; refitted at the level while it is more than :data:`LEVEL_TOLERANCE` off,
    as a sigma-point filter's spread moves with it), and the leveled values run once more on the same runs: ``at_level`` their
    statistics (:func:`nespm_cli.tuning.objective.summary`: the ANEES the closed form gives, the RMSE it keeps),
    ``at_level_tracks`` each track's ANEES (6 dof) there ({track: value}: how far a held-out track may land).
    Reused from ``old`` (the same search's ``best`` of the previous ``tune.json``; {} if none) when the
    shape and the runs are the same."""
    if t.level != "tracks":
        return
    big = dataclasses.replace(train, runs=max(train.runs, t.level_runs))
    for f, b in best.items():
        prev = old.get(f, {})
        if prev.get("shape") == b["shape"] and prev.get("level_runs") == big.runs and "at_level" in prev:
            b.update({k: prev[k] for k in ("level", "values", "at_level", "at_level_tracks")}, level_runs=big.runs)
            continue
        c = fit_level(trial_statistics(big, f, b["shape"]))
        values = leveled(b["shape"], level_bases(train, f), c)
        stats = trial_statistics(big, f, values)
        for _ in range(LEVEL_ITERATIONS):  # a sigma-point filter is not exactly homogeneous: refit at the level
            again = fit_level(stats)
            if abs(np.log(again)) <= np.log1p(LEVEL_TOLERANCE):
                break
            c *= again
            values = leveled(b["shape"], level_bases(train, f), c)
            stats = trial_statistics(big, f, values)
        b.update(level=c, values=values, at_level=summary(stats), level_runs=big.runs,
                 at_level_tracks={str(n): a for n, a in zip(train.tracks, stats["anees6_tracks"])})


def plugin_lines(train: Spec) -> list[str]:
    """The top-level ``tuned.toml`` lines naming the study's plugins (``filter_plugin = [...]``,
    ``sensor_plugin = [...]``: the config keys of ``--filter-plugin`` and ``--sensor-plugin``, as the
    study resolved them), each followed by nothing else: ``nespm mc --config tuned.toml`` then loads
    the filters and sensors its tables name. [] without plugins. TOML needs them before the first table."""
    lines = [f"{key} = [{', '.join(json.dumps(str(p)) for p in items)}]"
             for key, items in (("filter_plugin", train.filter_plugins), ("sensor_plugin", train.sensor_plugins))
             if items]
    return lines + [""] if lines else []


__all__ = ["LEVEL_ITERATIONS", "LEVEL_TOLERANCE", "add_checks", "add_leveled", "best_values", "plugin_lines"]
