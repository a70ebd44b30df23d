"""``nespm tune``: every filter's noise parameters searched with the same budget on training
realizations, the result written as a config ``mc``, ``sweep`` and ``compare`` take unchanged
(docs/tuning.md).

The folder ``OUT`` holds:

* ``study.db``: the Optuna studies (SQLite), one per filter (study name = the filter), each
  carrying the digest of its configuration (the training study, the objective, the sampler, the
  space): a killed tuning resumes where it stopped, ``--jobs`` workers share the studies, and a
  rerun with other options is refused in one line. ``--trials`` is not part of the identity: a
  rerun with more trials continues the same studies.
* ``trials.parquet``: every trial of every filter: its number, state, score, parameters
  (``p_<key>``) and statistics (:func:`nespm_cli.experiments.tune_objective.summary`).
* ``tuned.toml``: one ``[filters.NAME]`` table per filter with its best trial's values
  (``nespm mc --config OUT/tuned.toml ...``).
* ``tune.json``: what was tuned on (tracks, runs, the training seed), the space, the objective,
  the defaults and tuned values, the scores.

Reproducibility: trial k of a filter is suggested by a sampler seeded from the training seed,
the filter and the number of trials completed before it, from the history in ``study.db`` alone,
so one worker gives bit-identical values run after run, and a run killed mid-trial (its trial is
marked failed on restart and ignored) continues to the values of an uninterrupted one. The
first trial of every filter is its default setting (the score to beat). Every trial of every
filter runs on the same training realizations (common random numbers): tracks ``--tracks``,
runs ``0 .. --runs-1``, drawn from :func:`training_seed` (not ``--seed``: the held-out runs of
``--test-tracks`` use ``--seed``, as ``mc`` does).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec, check_filter_domains, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.experiments.tune_progress import watch_studies
from nespm_cli.experiments.tune_objective import (LEVELS, OBJECTIVES, REUSE_RUNS, fit_level, leveled, score,
                                                  summary, trial_statistics)
from nespm_cli.experiments.tune_space import Param, apply_ranges, default_space, optional_space
from nespm_cli.filters.options import TUNED_ON, tuned_on_text
from nespm_cli.filters.registry import get_filter

SAMPLERS = ("tpe", "cmaes")
STUDY_FILE = "study.db"
CONFIG_ATTR = "nespm_config"  # the study's user attribute holding its configuration digest
STATS_ATTR = "stats"  # a trial's user attribute: its statistics ({name: float}, tune_objective.summary)
TUNE_STREAM = 0x74756E65  # "tune": the training seed's stream
LEVEL_TOLERANCE = 0.02  # the fitted level is refitted while the tracks' geometric-mean ANEES is > 2 % off 6
LEVEL_ITERATIONS = 3  # at most this many refits (an EKF needs none: it is homogeneous in the level)


@dataclass(frozen=True)
class TuneSpec:
    """A tuning: ``spec`` the study (its ``tracks`` and ``runs`` the training realizations; its
    ``seed`` the held-out runs' seed), ``trials`` per filter, the ``objective``
    (:data:`nespm_cli.experiments.tune_objective.OBJECTIVES`), the ``sampler`` (``tpe`` or
    ``cmaes``), ``level`` (:data:`nespm_cli.experiments.tune_objective.LEVELS`: how rmse-consistent
    sets the common level of Q, R and P0; None: its default), ``ranges`` (``(NAME, KEY, LOW, HIGH)``,
    :func:`tune_space.apply_ranges`), the
    held-out ``test_tracks`` and ``test_runs``, ``allow_overlap`` (test tracks among the tuning
    tracks: flagged instead of refused)."""

    spec: Spec
    trials: int = 50
    objective: str = OBJECTIVES[0]
    sampler: str = "tpe"
    ranges: tuple = ()
    test_tracks: tuple = ()
    test_runs: int = 100
    allow_overlap: bool = False
    profile: bool = True  # each tuned parameter's score profile at the best setting (tune_profile)
    level: str | None = None  # LEVELS; None: "tracks" with rmse-consistent, "off" otherwise
    level_runs: int = 100  # training runs per track the best shape's level is fitted on (at least --runs)


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
    if t.level_runs < 1:
        raise NespmError(f"--level-runs must be at least 1, got {t.level_runs}")
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
    if t.test_tracks:
        validate(dataclasses.replace(t.spec, tracks=tuple(t.test_tracks), runs=t.test_runs, smooth=()))
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


def config_digest(train: Spec, name: str, params: list[Param], t: TuneSpec) -> str:
    """The identity of filter ``name``'s study: the training study, the objective, the sampler and the space."""
    d = {"spec": train.as_dict(), "filter": name, "objective": t.objective, "sampler": t.sampler,
         "space": [p.record() for p in params]}
    if t.level == "tracks":  # "off" keeps the identity of the studies written before the level existed
        d["level"] = t.level
    return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


def storage(out: Path):
    """The SQLite storage of ``out/study.db`` (shared by the workers). Write-ahead log with
    ``synchronous=NORMAL``: a commit survives a killed process (not a power cut) without an fsync."""
    import sqlite3

    import optuna

    path = str((out / STUDY_FILE).resolve())

    def connect():
        con = sqlite3.connect(path, timeout=120, check_same_thread=False)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA synchronous=NORMAL")
        return con

    return optuna.storages.RDBStorage(f"sqlite:///{path}", engine_kwargs={"creator": connect})


def open_study(store, name: str, digest: str, out: Path):
    """Filter ``name``'s study, created with ``digest`` or checked against it (one line if it differs)."""
    import optuna

    study = optuna.create_study(storage=store, study_name=name, direction="minimize", load_if_exists=True)
    have = study.user_attrs.get(CONFIG_ATTR)
    if have is None:
        if study.trials:
            raise NespmError(f"{out / STUDY_FILE}: study {name} was not written by nespm tune; use another --out")
        study.set_user_attr(CONFIG_ATTR, digest)
    elif have != digest:
        raise NespmError(f"{out / STUDY_FILE}: study {name} comes from another configuration (tracks, runs, seed, "
                         "sensors, objective, sampler or space differ); use another --out or the same options")
    return study


def fail_stale(store, study) -> int:
    """Mark the trials left running by a killed process as failed (ignored by the samplers); their count."""
    from optuna.trial import TrialState

    stale = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    for tr in stale:
        store.set_trial_state_values(tr._trial_id, TrialState.FAIL)
    return len(stale)


def enqueue_default(study, params: list[Param]) -> None:
    """The first trial of a study: its defaults (when inside the ranges), queued before any worker
    starts (so ``--jobs`` workers cannot skip it) and again after a kill that failed it."""
    from optuna.trial import TrialState

    states = {tr.state for tr in study.get_trials(deepcopy=False)}
    if TrialState.COMPLETE in states or TrialState.WAITING in states:
        return
    if all(p.low <= p.default <= p.high for p in params):
        study.enqueue_trial({p.key: p.default for p in params}, skip_if_exists=False)


def make_sampler(kind: str, seed: int):
    """The sampler of one trial (seeded TPE, multivariate; or CMA-ES)."""
    import optuna

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        if kind == "cmaes":
            return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
        return optuna.samplers.TPESampler(seed=seed, multivariate=True, n_startup_trials=10)


def trial_seed(train_seed: int, index: int, done: int, worker: int) -> int:
    """The sampler seed of a trial: from the training seed, the filter's index, the trials done, the worker."""
    return int(np.random.SeedSequence([train_seed, index, done, worker]).generate_state(1)[0])


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


def quiet() -> None:
    """Optuna's per-trial log lines off (the command prints its own)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)


def trials_table(out: Path, filters: tuple) -> pd.DataFrame:
    """Every trial of every filter's study: ``filter``, ``trial``, ``state``, ``score``, ``p_<key>``
    and the statistics of :func:`tune_objective.summary`."""
    import optuna

    rows = []
    store = storage(out)
    for f in filters:
        study = optuna.load_study(study_name=f, storage=store)
        for tr in study.get_trials(deepcopy=False):
            rows.append({"filter": f, "trial": tr.number, "state": tr.state.name,
                         "score": tr.value if tr.value is not None else np.nan,
                         **{f"p_{k}": v for k, v in tr.params.items()},
                         **tr.user_attrs.get(STATS_ATTR, {})})
    return pd.DataFrame(rows)


def best_values(out: Path, filters: tuple, trials: int, space: dict | None = None,
                bases: dict | None = None) -> dict[str, dict]:
    """``{filter: {"trial", "score", "values", "shape", "level", "default_score"}}``: each filter's best
    of its first ``trials`` completed trials (ties: the earlier trial); ``shape`` its searched values,
    ``level`` the variance factor fitted to it (``bases`` given: ``{filter: level_bases}``, the fitted
    level applies; else 1) and ``values`` the shape at that level (what ``tuned.toml`` writes);
    ``default_score`` that of the first trial at the defaults of ``space`` (None if there is none)."""
    import optuna
    from optuna.trial import TrialState

    store = storage(out)
    res = {}
    for f in filters:
        done = optuna.load_study(study_name=f, storage=store).get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        done = sorted(done, key=lambda tr: tr.number)[:trials]
        best = min(done, key=lambda tr: (tr.value, tr.number))
        defaults = {p.key: p.default for p in (space or {}).get(f, [])}
        first = next((tr for tr in done if defaults and tr.params == defaults), None)
        c = float(best.user_attrs.get(STATS_ATTR, {}).get("level", 1.0)) if bases else 1.0
        shape = dict(best.params)
        res[f] = {"trial": best.number, "score": best.value, "shape": shape, "level": c,
                  "values": leveled(shape, bases[f], c) if bases else shape,
                  "default_score": first.value if first is not None else None,
                  "default_trial": first.number if first is not None else None}
    return res


def add_profiles(best: dict, out: Path, train: Spec, space: dict, t: TuneSpec) -> None:
    """Add each filter's ``importance`` and (``t.profile``) ``profile`` and, with two filters or more,
    ``cross`` (its score with the others' searched values) to ``best``, reusing those of ``tune.json``
    when the best trials are the same (a rerun costs nothing)."""
    import optuna

    from nespm_cli.experiments.tune_profile import cross_scores, importances, profile

    try:
        old = json.loads((out / "tune.json").read_text(encoding="utf-8")).get("best", {})
    except (OSError, ValueError):
        old = {}
    store = storage(out)
    for i, (f, b) in enumerate(best.items()):
        b["importance"] = importances(optuna.load_study(study_name=f, storage=store))
        if not t.profile:
            continue
        prev = old.get(f, {})
        if prev.get("trial") == b["trial"] and prev.get("values") == b["values"] and "profile" in prev:
            b["profile"] = prev["profile"]
        else:
            b["profile"] = profile(train, f, space[f], b["shape"], t.objective, b["score"], t.level)
        others = {g: o["shape"] for g, o in best.items() if g != f}
        if not others:
            continue
        same = prev.get("trial") == b["trial"] and all(old.get(g, {}).get("shape") == v for g, v in others.items())
        b["cross"] = prev["cross"] if same and "cross" in prev else cross_scores(
            train, f, b["shape"], others, t.objective, b["score"], t.level)


def add_leveled(best: dict, out: Path, train: Spec, t: TuneSpec) -> None:
    """With the fitted level (``t.level == "tracks"``): each filter's best shape run on
    ``max(--runs, --level-runs)`` training runs per track (the trials' runs first, then more of the
    same stream), its level fitted on them (``level``, ``values``: a level fitted on few runs carries
    their sampling spread; refitted at the level while it is more than :data:`LEVEL_TOLERANCE` off,
    as a sigma-point filter's spread moves with it), and the leveled values run once more on the same runs: ``at_level`` their
    statistics (:func:`tune_objective.summary`: the ANEES the closed form gives, the RMSE it keeps),
    ``at_level_tracks`` each track's ANEES (6 dof) there ({track: value}: how far a held-out track may land).
    Reused from ``tune.json`` when the shape and the runs are the same."""
    if t.level != "tracks":
        return
    try:
        old = json.loads((out / "tune.json").read_text(encoding="utf-8")).get("best", {})
    except (OSError, ValueError):
        old = {}
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


def tuned_toml(best: dict, train: Spec, t: TuneSpec) -> str:
    """``tuned.toml``: a ``[filters.NAME]`` table per filter with its tuned values (exact round trip)."""
    lines = ["# nespm tune: the best settings of every filter, each searched with the same budget",
             f"# ({t.trials} trials, objective {t.objective}) on tracks {' '.join(map(str, train.tracks))}, "
             f"runs 0-{train.runs - 1} of the training seed {train.seed} (tune.json).",
             "# Use: nespm mc --config tuned.toml --tracks ... (with the study's other options).", ""]
    if train.filter_config.state != "12":  # the layout and the sensors the R and P0 scales name
        lines += [f'state = "{train.filter_config.state}"', ""]
    on = tuned_on_text(train.seed, train.tracks, 0, train.runs)
    for f, b in best.items():
        if b.get("level", 1.0) != 1.0:
            lines.append(f"# {f}: the searched factors x {np.sqrt(b['level']):.6g} (the level fitted over the "
                         "tracks: every Q, R and P0 std; docs/tuning.md)")
        lines.append(f"[filters.{f}]")
        lines += [f"{k} = {float(v)!r}" for k, v in b["values"].items()]
        lines += [f'{TUNED_ON} = "{on}"', ""]
    if tuple(train.sensors) != ("dvl",):
        lines += [f"[sensors.{n}]" for n in train.sensors] + [""]
    return "\n".join(lines)


def run_tune(t: TuneSpec, out: str | Path, jobs: int = 1, report: Callable[[str, int, float], None] | None = None,
             argv=None) -> dict:
    """Tune every filter of ``t.spec`` into ``out`` (resuming what is there); write ``trials.parquet``,
    ``tuned.toml`` and ``tune.json``; return the ``tune.json`` record."""
    from nespm_cli.data.atomic import write_text_atomic
    from nespm_cli.experiments.store import FolderLock, write_json_atomic, write_parquet_atomic

    t, train, space = check(t)
    out = Path(out)
    lock = FolderLock(out)
    try:
        quiet()
        store = storage(out)
        for f in train.filters:  # identity first (a foreign study file stops here), then stale trials
            study = open_study(store, f, config_digest(train, f, space[f], t), out)
            fail_stale(store, study)
            enqueue_default(study, space[f])
        if jobs <= 1:
            for i, f in enumerate(train.filters):
                tune_filter(t, train, i, space[f], out, 0, report)
        else:
            from joblib import Parallel, delayed

            watch = None if report is None else watch_studies(storage(out), train.filters, t.trials, report)
            try:
                if len(train.filters) >= jobs:  # a process per filter: each study has one writer (= --jobs 1)
                    calls = (delayed(worker_run)(t, train, space, str(out.resolve()), 0, i)
                             for i in range(len(train.filters)))
                else:  # fewer filters than workers: they share each study (values depend on the interleaving)
                    calls = (delayed(worker_run)(t, train, space, str(out.resolve()), w) for w in range(jobs))
                Parallel(n_jobs=jobs, backend="loky")(calls)
            finally:
                if watch is not None:
                    watch()
        table = trials_table(out, train.filters)
        write_parquet_atomic(table, out / "trials.parquet")
        bases = {f: level_bases(train, f) for f in train.filters} if t.level == "tracks" else None
        best = best_values(out, train.filters, t.trials, space, bases)
        if report is not None and (t.level == "tracks" or t.profile):
            import sys

            what = " and ".join(w for w, on in (("fitting each filter's level", t.level == "tracks"),
                                                ("profiling its best settings", t.profile)) if on)
            print(f"tune: {what} on the training runs", file=sys.stderr, flush=True)
        add_leveled(best, out, train, t)
        add_profiles(best, out, train, space, t)
        write_text_atomic(out / "tuned.toml", tuned_toml(best, train, t))
        record = {"command": list(argv) if argv is not None else None, "objective": t.objective, "level": t.level,
                  "sampler": t.sampler, "trials": t.trials, "jobs": jobs,
                  "tuned_on": {"tracks": list(train.tracks), "runs": [0, train.runs], "seed": train.seed,
                               "seed_of": t.spec.seed},
                  "test": {"tracks": list(t.test_tracks), "runs": t.test_runs, "seed": t.spec.seed,
                           "overlap": sorted(set(t.test_tracks) & set(train.tracks))},
                  "space": {f: [p.record() for p in ps] for f, ps in space.items()},
                  "best": best, "spec": train.as_dict()}
        write_json_atomic(record, out / "tune.json")
        return record
    finally:
        lock.release()


__all__ = ["SAMPLERS", "STUDY_FILE", "TuneSpec", "best_values", "check", "config_digest", "run_tune",
           "training_seed", "trials_table", "tuned_toml"]
