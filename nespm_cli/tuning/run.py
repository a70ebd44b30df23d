"""``nespm tune``: every filter's noise parameters searched with the same budget on training
realizations, the result written as a config ``mc``, ``sweep`` and ``compare`` take unchanged
(docs/tuning.md).

The folder ``OUT`` holds:

* ``study.journal``: the Optuna studies (Optuna's journal file; ``study.db``, SQLite, in a tuning written
  before it: tuning.study_file), one per filter (study name = the filter), each
  carrying the digest of its configuration (the training study, the objective, the sampler, the
  space): a killed tuning resumes where it stopped, ``--jobs`` workers share the studies, and a
  rerun with other options is refused in one line. ``--trials`` is not part of the identity: a
  rerun with more trials continues the same studies.
* ``trials.parquet``: every trial of every filter: its number, state, score, parameters
  (``p_<key>``) and statistics (:func:`nespm_cli.tuning.objective.summary`).
* ``tuned.toml``: one ``[filters.NAME]`` table per filter with its best trial's values
  (``nespm mc --config OUT/tuned.toml ...``).
* ``tune.json``: what was tuned on (tracks, runs, the training seed), the space, the objective,
  the defaults and tuned values, the scores; ``"ground_truth": false`` when the tracks have none (a track
  spec without ``[gt]``: only ``--objective innovation`` runs there, docs/tuning.md).

Reproducibility: trial k of a filter is suggested by a sampler seeded from the training seed,
the filter and the number of trials completed before it, from the history in the study file alone,
so one worker gives bit-identical values run after run, and a run killed mid-trial (its trial is
marked failed on restart and ignored) continues to the values of an uninterrupted one. The
first trial of every filter is its default setting (the score to beat). Every trial of every
filter runs on the same training realizations (common random numbers): tracks ``--tracks``,
runs ``0 .. --runs-1``, drawn from :func:`training_seed` (not ``--seed``: the held-out runs of
``--test-tracks`` use ``--seed``, as ``mc`` does).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from nespm_cli.experiments.spec import Spec, has_truth
from nespm_cli.filters.options import SCALE_LIMITS, TUNED_ON, tuned_on_text
from nespm_cli.errors import NespmError
from nespm_cli.tuning.best import add_checks, add_leveled, best_values, plugin_lines
from nespm_cli.tuning.flat import add_flat, training_score
from nespm_cli.tuning.objective import beyond_limits
from nespm_cli.tuning.progress import watch_studies
from nespm_cli.tuning.refine import auto_budget
from nespm_cli.tuning.search import refine_filter, tune_filter, worker_run
from nespm_cli.tuning.spec import TuneSpec, check, level_bases
from nespm_cli.tuning.study_file import check_study_file, study_path
from nespm_cli.tuning.study import (config_digest, enqueue_default, fail_stale, open_study, quiet, search_seed, storage,
                                    study_name, trials_table)


def tuned_toml(best: dict, train: Spec, t: TuneSpec, picked: dict | None = None) -> str:
    """``tuned.toml``: a ``[filters.NAME]`` table per filter with its tuned values (exact round trip); with
    ``--repeats``, ``picked`` ({filter: search}) says in a comment which search's they are."""
    lines = ["# nespm tune: the best settings of every filter, each searched with the same budget",
             f"# ({t.trials} trials, objective {t.objective}) on tracks {' '.join(map(str, train.tracks))}, "
             f"runs 0-{train.runs - 1} of the training seed {train.seed} (tune.json).",
             "# Use: nespm mc --config tuned.toml --tracks ... (with the study's other options).", ""]
    lines += plugin_lines(train)
    if train.filter_config.state != "12":  # the layout and the sensors the R and P0 scales name
        lines += [f'state = "{train.filter_config.state}"', ""]
    on = tuned_on_text(train.seed, train.tracks, 0, train.runs)
    for f, b in best.items():
        if t.repeats > 1 and picked is not None:
            why = "the lowest training score" if t.pick == "best" else "--pick first"
            lines.append(f"# {f}: search {picked[f]} of {t.repeats} ({why}: {training_score(b):.6g}; every search in "
                         "tune.json)")
        if b.get("level", 1.0) != 1.0:
            lines.append(f"# {f}: the searched factors x {np.sqrt(b['level']):.6g} (the level fitted over the "
                         "tracks: every Q, R and P0 std; docs/tuning.md)")
            for k, raw in beyond_limits(b["shape"], level_bases(train, f), b["level"]).items():
                lines.append(f"# {f}.{k}: {raw:.6g} at the level, outside the noise-scale limits {SCALE_LIMITS[0]:g} "
                             f"to {SCALE_LIMITS[1]:g} that --config accepts: written (and run) at {b['values'][k]!r}")
        lines.append(f"[filters.{f}]")
        lines += [f"{k} = {float(v)!r}" for k, v in b["values"].items()]
        lines += [f'{TUNED_ON} = "{on}"', ""]
    if tuple(train.sensors) != ("dvl",):
        lines += [f"[sensors.{n}]" for n in train.sensors] + [""]
    return "\n".join(lines)


def run_tasks(fn: Callable, args: list[tuple], jobs: int, backend: str, scheduler: str | None) -> list:
    """``fn(*a)`` for every ``a`` of ``args``: in this process (loky with one job), else as one task each
    on ``jobs`` local processes or the Dask cluster (experiments.backend.parallel_map: a worker lost
    mid-task is replaced and the task run again); the results in completion order."""
    if backend == "loky" and jobs <= 1:
        return [fn(*a) for a in args]
    from nespm_cli.experiments.backend import parallel_map

    return list(parallel_map(fn, args, jobs, backend, scheduler))


def global_search(t: TuneSpec, train: Spec, space: dict, out: Path, jobs: int, backend: str, scheduler: str | None,
                  report: Callable[[str, int, float], None] | None, store=None) -> None:
    """Every filter's global search, for every search (``--repeats``): in this process (one job, on
    ``store`` where given), one task per filter and search (each study one writer: the values of one
    job, bit for bit), or, with fewer of those than local workers, the workers sharing each study."""
    tasks = [(i, k) for k in range(t.repeats) for i in range(len(train.filters))]
    if backend == "loky" and jobs <= 1:
        for i, k in tasks:
            tune_filter(t, train, i, space[train.filters[i]], out, 0, report, k, store)
        return
    where = str(out.resolve())
    watch = None if report is None else watch_studies(storage(out, t.storage), train.filters, t.trials, report)
    try:
        if len(tasks) >= jobs or backend == "dask":
            run_tasks(worker_run, [(t, train, space, where, 0, i, k) for i, k in tasks], jobs, backend, scheduler)
        else:  # fewer studies than workers: they share each study (values depend on the interleaving)
            for k in range(t.repeats):
                run_tasks(worker_run, [(t, train, space, where, w, None, k) for w in range(jobs)], jobs, backend,
                          scheduler)
    finally:
        if watch is not None:
            watch()


def refinements(t: TuneSpec, train: Spec, space: dict, out: Path, store, jobs: int, backend: str,
                scheduler: str | None) -> list[dict]:
    """Every filter's local refinement (tuning.refine), per search: ``[{filter: {"start", "evaluations",
    "finished"}}]`` (one dict per search; empty dicts with ``--refine-trials 0``). Each filter starts from
    the best of its own global best and the other filters' (their searched values on the keys it has)."""
    if t.refine_trials == 0:
        return [{} for _ in range(t.repeats)]
    tasks = []
    for k in range(t.repeats):
        starts = best_values(store, train.filters, t.trials, space, None, k, refined=False)
        for i, f in enumerate(train.filters):
            tasks.append((t, train, space, str(out.resolve()), i, k, {"values": starts[f]["shape"],
                                                                     "score": starts[f]["score"]},
                          {g: b["shape"] for g, b in starts.items() if g != f}))
    done = run_tasks(refine_filter, tasks, jobs, backend, scheduler)
    out_ = [{} for _ in range(t.repeats)]
    for r in done:
        out_[r["search"]][r["filter"]] = {k: r[k] for k in ("start", "evaluations", "finished")}
    return out_


def previous_record(out: Path) -> dict:
    """The ``tune.json`` of an earlier run into ``out`` ({} if none): what its level fits can be reused from."""
    import json

    try:
        return json.loads((out / "tune.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def previous_searches(old: dict, repeats: int) -> list[dict]:
    """``[{filter: its record}]`` per search 0 .. ``repeats``-1 of an earlier ``tune.json`` (``old``, {} if none):
    the full record (its level fit, reused when the shape is the same) where ``tuned.toml`` held that search's
    values (``best``), else the search's summary in ``searches``."""
    picked = old.get("picked") or {}
    out = []
    for k in range(repeats):
        d = {f: v[k] for f, v in old.get("searches", {}).items() if len(v) > k}
        d.update({f: b for f, b in old.get("best", {}).items() if int(picked.get(f, 0)) == k})
        out.append(d)
    return out


def searches_record(t: TuneSpec, train: Spec, searches: list[dict]) -> dict:
    """``{filter: [{"search", "search_seed", "score", "values", "shape", "convergence"}]}`` over the searches."""
    return {f: [{"search": k, "search_seed": search_seed(t, train, k), "score": b[f]["score"], "values": b[f]["values"],
                 "shape": b[f]["shape"], "convergence": b[f].get("convergence")} for k, b in enumerate(searches)]
            for f in train.filters}


def pick_searches(searches: list[dict], pick: str) -> dict:
    """``{filter: search}``: the search whose values ``tuned.toml`` holds for each filter: with ``pick`` ``best``
    the one with the lowest training score of the setting it writes (:func:`nespm_cli.tuning.flat.training_score`:
    the objective the searches minimized, on the same runs; the first of equal ones), with ``first`` search 0."""
    if pick == "first":
        return {f: 0 for f in searches[0]}
    return {f: min(range(len(searches)), key=lambda k: (training_score(searches[k][f]), k)) for f in searches[0]}


def run_tune(t: TuneSpec, out: str | Path, jobs: int = 1, report: Callable[[str, int, float], None] | None = None,
             argv=None, backend: str = "loky", scheduler: str | None = None) -> dict:
    """Tune every filter of ``t.spec`` into ``out`` (resuming what is there): the global search, the local
    refinement, the level, the checks and the verdict, for every search (``--repeats``); write
    ``trials.parquet``, ``tuned.toml`` (per filter the values of the search :func:`pick_searches` picks) and
    ``tune.json``; return the ``tune.json`` record. ``backend`` ``loky`` (``jobs`` local processes) or ``dask`` (``scheduler``, else a
    local cluster of ``jobs`` workers; docs/cluster.md)."""
    import sys

    from nespm_cli.data.atomic import write_text_atomic
    from nespm_cli.experiments.backend import check_backend, check_scheduler
    from nespm_cli.data.parquet_files import write_parquet_atomic
    from nespm_cli.experiments.store import FolderLock, write_json_atomic

    t, train, space = check(t)
    check_backend(backend)
    check_scheduler(backend, scheduler)
    if jobs < 1:
        raise NespmError(f"--jobs must be at least 1, got {jobs}")
    out = Path(out)
    if t.storage is None:
        check_study_file(study_path(out))  # before the lock: a bad file leaves nothing behind
    lock = FolderLock(out)
    try:
        quiet()
        store = storage(out, t.storage)
        for k in range(t.repeats):  # identity first (a foreign study file stops here), then stale trials
            for f in train.filters:
                study = open_study(store, study_name(f, k), config_digest(train, f, space[f], t, k), out)
                fail_stale(store, study)
                enqueue_default(study, space[f])
        global_search(t, train, space, out, jobs, backend, scheduler, report, store)
        if report is not None and t.refine_trials != 0:
            most = {f: auto_budget(space[f]) if t.refine_trials is None else t.refine_trials for f in train.filters}
            print(f"tune: refining each filter's best (a model, then polls; up to {max(most.values())} trials)",
                  file=sys.stderr, flush=True)
        refined = refinements(t, train, space, out, store, jobs, backend, scheduler)
        bases = {f: level_bases(train, f) for f in train.filters} if t.level == "tracks" else None
        if report is not None and (t.level == "tracks" or t.profile):
            what = " and ".join(w for w, on in (("fitting each filter's level", t.level == "tracks"),
                                                ("checking its best settings", t.profile)) if on)
            print(f"tune: {what} on the training runs", file=sys.stderr, flush=True)
        old_searches = previous_searches(previous_record(out), t.repeats)
        searches = []
        for k in range(t.repeats):
            best = best_values(store, train.filters, t.trials, space, bases, k)
            add_leveled(best, old_searches[k], train, t)
            add_checks(best, store, out, train, space, t, refined[k], k)
            before = {f: dict(b) for f, b in best.items()}
            if add_flat(best, store, train, space, t, k) and t.level == "tracks":
                add_leveled(best, before, train, t)  # a reset shape: its level fitted again
            searches.append(best)
        write_parquet_atomic(trials_table(store, train.filters, t.repeats), out / "trials.parquet")
        picked = pick_searches(searches, t.pick)
        best = {f: searches[k][f] for f, k in picked.items()}
        write_text_atomic(out / "tuned.toml", tuned_toml(best, train, t, picked))
        record = {"command": list(argv) if argv is not None else None, "objective": t.objective, "level": t.level,
                  "sampler": t.sampler, "trials": t.trials, "jobs": jobs, "backend": backend,
                  "refine_trials": t.refine_trials, "flat": t.flat, "search_seed": search_seed(t, train, 0), "repeats": t.repeats,
                  "tuned_on": {"tracks": list(train.tracks), "runs": [0, train.runs], "seed": train.seed,
                               "seed_of": t.spec.seed},
                  "test": {"tracks": list(t.test_tracks), "runs": t.test_runs, "seed": t.spec.seed,
                           "overlap": sorted(set(t.test_tracks) & set(train.tracks))},
                  "space": {f: [p.record() for p in ps] for f, ps in space.items()},
                  "best": best, "spec": train.as_dict()}
        if t.repeats > 1:
            record["searches"] = searches_record(t, train, searches)
            record["pick"], record["picked"] = t.pick, picked
        if not has_truth(train):  # a track spec without [gt]: --objective innovation, innovations only
            record["ground_truth"] = False
        write_json_atomic(record, out / "tune.json")
        return record
    finally:
        lock.release()


__all__ = ["global_search", "pick_searches", "previous_record", "previous_searches", "refinements", "run_tasks",
           "run_tune", "searches_record", "tuned_toml"]
