"""What a ``nespm tune`` is asked to do (:class:`TuneSpec`) and its one-line checks before anything is
written; the training seed (the training realizations' own stream of ``--seed``) and the keys the
fitted level scales (docs/tuning.md)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec, check_filter_domains, has_truth, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters.registry import get_filter
from nespm_cli.tuning.profile import FLAT_RULES
from nespm_cli.tuning.objective import LEVELS, OBJECTIVES
from nespm_cli.tuning.space import Param, apply_ranges, default_space, optional_space

SAMPLERS = ("tpe", "cmaes")
#: --pick: tuned.toml holds, per filter, the search with the lowest training score, or the first search
PICKS = ("best", "first")
TUNE_STREAM = 0x74756E65  # "tune": the training seed's stream


@dataclass(frozen=True)
class TuneSpec:
    """A tuning: ``spec`` the study (its ``tracks`` and ``runs`` the training realizations; its
    ``seed`` the held-out runs' seed), ``trials`` per filter, the ``objective``
    (:data:`nespm_cli.tuning.objective.OBJECTIVES`), the ``sampler`` (``tpe`` or
    ``cmaes``), ``level`` (:data:`nespm_cli.tuning.objective.LEVELS`: how rmse-consistent
    sets the common level of Q, R and P0; None: its default), ``ranges`` (``(NAME, KEY, LOW, HIGH)``,
    :func:`nespm_cli.tuning.space.apply_ranges`), the
    held-out ``test_tracks`` and ``test_runs``, ``allow_overlap`` (test tracks among the tuning
    tracks: flagged instead of refused); ``search_seed`` the samplers' seed (None: the training seed,
    so one ``--seed`` sets both; given, the search's luck is varied apart from the data's), ``repeats``
    independent searches per filter on the same training runs (search k's seed:
    :func:`nespm_cli.tuning.study.search_seed`), ``refine_trials`` the local refinement's budget per
    filter and search (0: none; None: :func:`nespm_cli.tuning.refine.auto_budget` of its space), ``storage`` an Optuna RDB storage URL every worker
    reaches (None: the study file of ``OUT``, tuning.study_file); ``flat`` what becomes of a parameter the objective
    cannot see (:data:`nespm_cli.tuning.flat.FLAT_RULES`); ``pick`` which search's values ``tuned.toml``
    holds per filter with ``repeats`` > 1 (:data:`PICKS`: the lowest training score, or the first search)."""

    spec: Spec
    trials: int = 50
    objective: str = OBJECTIVES[0]
    sampler: str = "tpe"
    ranges: tuple = ()
    test_tracks: tuple = ()
    test_runs: int = 100
    allow_overlap: bool = False
    profile: bool = True  # each tuned parameter's score profile at the best setting (tuning.profile)
    level: str | None = None  # LEVELS; None: "tracks" with rmse-consistent, "off" otherwise
    level_runs: int = 100  # training runs per track the best shape's level is fitted on (at least --runs)
    search_seed: int | None = None  # the samplers' seed; None: the training seed
    repeats: int = 1  # independent searches per filter (--repeats)
    refine_trials: int | None = None  # the local refinement's budget per filter and search (0: off; None: auto)
    storage: str | None = None  # an RDB storage URL (None: OUT/study.journal)
    flat: str = "default"  # tuning.flat.FLAT_RULES: a parameter the objective cannot see goes back to its default
    pick: str = "best"  # PICKS: which search's values tuned.toml holds per filter (--repeats)


def training_seed(seed: int) -> int:
    """The seed of the training realizations: its own stream of ``seed`` (0 .. 2⁶³-1), so the
    held-out runs (``seed``) never share a draw with them."""
    state = np.random.SeedSequence([int(seed), TUNE_STREAM]).generate_state(2, np.uint64)
    return int(state[0] >> np.uint64(1))


def check(t: TuneSpec) -> tuple[TuneSpec, Spec, dict[str, list[Param]]]:
    """Every option of the tuning checked before anything is written: ``(t, the validated training
    spec, {filter: [Param]})``. One-line errors."""
    if t.trials < 1:
        raise NespmError(f"--trials must be at least 1 (the budget per filter), got {t.trials}")
    if t.objective not in OBJECTIVES:
        raise NespmError(f"--objective: choose {', '.join(OBJECTIVES)}, got {t.objective!r}")
    if t.level is None:
        t = dataclasses.replace(t, level="tracks" if t.objective == "rmse-consistent" else "off")
    if t.level not in LEVELS:
        raise NespmError(f"--level: choose {' or '.join(LEVELS)}, got {t.level!r}")
    if t.level == "tracks" and t.objective != "rmse-consistent":
        raise NespmError(f"--level tracks acts on --objective rmse-consistent only (got {t.objective}): "
                         "drop --level or use --level off")
    if t.search_seed is not None and not 0 <= int(t.search_seed) < 2 ** 63:
        raise NespmError(f"--search-seed must be from 0 to 2^63-1, got {t.search_seed}")
    if not 1 <= t.repeats <= 100:
        raise NespmError(f"--repeats must be from 1 to 100 (independent searches per filter), got {t.repeats}")
    if t.refine_trials is not None and t.refine_trials < 0:
        raise NespmError(f"--refine-trials must be 0 (no refinement) or more, got {t.refine_trials}")
    if t.storage is not None and "://" not in t.storage:
        raise NespmError(f"--storage must be a database URL (e.g. postgresql://user@host/db or "
                         f"sqlite:////shared/study.db), got {t.storage!r}")
    if t.level_runs < 1:
        raise NespmError(f"--level-runs must be at least 1, got {t.level_runs}")
    if t.pick not in PICKS:
        raise NespmError(f"--pick: choose {' or '.join(PICKS)}, got {t.pick!r}")
    if t.flat not in FLAT_RULES:
        raise NespmError(f"--flat: choose {' or '.join(FLAT_RULES)}, got {t.flat!r}")
    if t.sampler not in SAMPLERS:
        raise NespmError(f"--sampler: choose {' or '.join(SAMPLERS)}, got {t.sampler!r}")
    if t.test_runs < 1:
        raise NespmError(f"--test-runs must be at least 1, got {t.test_runs}")
    overlap = sorted(set(t.test_tracks) & set(t.spec.tracks))
    if overlap and not t.allow_overlap:
        raise NespmError(f"--test-tracks {' '.join(map(str, overlap))}: also tuning tracks (--tracks); held-out "
                         "tracks must be others (or --allow-overlap: then the report flags it)")
    if t.sampler == "cmaes":
        try:
            import cmaes  # noqa: F401
        except ImportError:
            raise NespmError("--sampler cmaes needs the cmaes package (pip install cmaes); "
                             "or use --sampler tpe") from None
    train = validate(dataclasses.replace(t.spec, seed=training_seed(t.spec.seed), smooth=()))
    test = (validate(dataclasses.replace(t.spec, tracks=tuple(t.test_tracks), runs=t.test_runs, smooth=()))
            if t.test_tracks else None)
    if t.objective != "innovation":
        for s in (train, test):
            free = [n for n in (s.tracks if s is not None else ()) if not has_truth(s, (n,))]
            if free:
                raise NespmError(f"--objective {t.objective}: needs the ground truth, and track {free[0]} has none (its "
                                 "track spec has no [gt]); use --objective innovation (it reads no truth)")
    layout = train.filter_config.layout
    space = {f: default_space(f, get_filter(f), layout, train.sensors, train.filter_config.alpha)
             for f in train.filters}
    for f, ps in space.items():
        if not ps:
            raise NespmError(f"--filters {f}: has no noise parameters to tune (no covariance); drop it")
    levers = {sn.name: tuple(sn.opt.lever_arm) for sn in sensor_suite(train) if sn.has_lever}
    optional = {f: optional_space(f, get_filter(f), levers) for f in train.filters}
    space = apply_ranges(space, t.ranges, optional)
    check_option_ranges(train, space)
    return t, train, space


def check_option_ranges(train: Spec, space: dict[str, list[Param]]) -> None:
    """A filter's own searched option (``kind`` plugin: e.g. iae-ekf's window) at both ends of its
    range passes the filter's domain check on the training tracks before any trial runs; else one
    line naming the range (a trial must never fail on its options half-way through a study)."""
    ends = [(p, v) for ps in space.values() for p in ps if p.kind == "plugin" for v in (p.low, p.high)]
    if not ends:
        return
    span = min(track_inputs(train, n)[0].duration for n in train.tracks)
    for p, v in ends:
        try:
            check_filter_domains(dataclasses.replace(train, filter_options=train.filter_options + ((p.filter, p.key, v),)),
                                 span)
        except NespmError as exc:
            raise NespmError(f"tune space {p.name} = {p.low:g}..{p.high:g}: at {v:g}: {exc}; narrow it with "
                             f"--tune-range {p.name}=LOW:HIGH") from None


def level_bases(train: Spec, name: str) -> dict[str, float]:
    """``{key: factor}`` of every Q, R and P0 std factor of filter ``name`` in ``train``'s layout and
    sensors (searched or not): the keys the level scales, each with the value it has when not searched
    (the study's ``--filter-option``, else 1)."""
    layout = train.filter_config.layout
    given = {o[1]: o[2] for o in train.filter_options if o[0] == name}
    keys = [p.key for p in default_space(name, get_filter(name), layout, train.sensors, train.filter_config.alpha)
            if p.kind in ("Q", "R", "P0")]
    return {k: float(given.get(k, 1.0)) for k in keys}


__all__ = ["SAMPLERS", "TuneSpec", "check", "check_option_ranges", "level_bases", "training_seed"]
