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
  (``p_<key>``) and statistics (:func:`nespm_cli.tuning.objective.summary`).
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

from pathlib import Path
from typing import Callable

import numpy as np

from nespm_cli.experiments.spec import Spec
from nespm_cli.filters.options import TUNED_ON, tuned_on_text
from nespm_cli.tuning.best import add_leveled, add_profiles, best_values
from nespm_cli.tuning.progress import watch_studies
from nespm_cli.tuning.search import tune_filter, worker_run
from nespm_cli.tuning.spec import TuneSpec, check, level_bases
from nespm_cli.tuning.study import config_digest, enqueue_default, fail_stale, open_study, quiet, storage, trials_table


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


__all__ = ["run_tune", "tuned_toml"]
