"""The Optuna studies of ``nespm tune``: their storage (``OUT/study.journal``, tuning.study_file), identity
(a digest of the configuration), the stale trials of a killed process, the default trial, the seeded samplers and the
table of every trial (docs/tuning.md)."""
from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec
from nespm_cli.tuning.study_file import SQLITE_FILE, study_path

CONFIG_ATTR = "nespm_config"  # the study's user attribute holding its configuration digest
STATS_ATTR = "stats"  # a trial's user attribute: its statistics ({name: float}, objective.summary)
PHASE_ATTR = "phase"  # a trial's user attribute: which phase ran it
PHASES = ("search", "refine", "check")  # the global search; the refinement (with the candidates); the checks after it


def trial_phase(trial) -> str:
    """The phase of a stored trial (:data:`PHASES`; the global search's trials before the phases existed:
    ``search``)."""
    return trial.user_attrs.get(PHASE_ATTR, "search")


SEARCH_STREAM = 0x73656172  # "sear": the stream of the searches after the first (--repeats)


def search_seed(t: TuneSpec, train: Spec, search: int = 0) -> int:
    """The root seed of search ``search`` (0 .. --repeats-1) of every filter: ``--search-seed``, else the
    training seed, for the first; its own stream of that for each other (0 .. 2⁶³-1)."""
    root = int(train.seed if t.search_seed is None else t.search_seed)
    if search == 0:
        return root
    state = np.random.SeedSequence([root, SEARCH_STREAM, int(search)]).generate_state(2, np.uint64)
    return int(state[0] >> np.uint64(1))


def study_name(name: str, search: int = 0) -> str:
    """The study of filter ``name``'s search ``search``: the filter's name for the first, ``NAME#sK`` after."""
    return name if search == 0 else f"{name}#s{search}"


def config_digest(train: Spec, name: str, params: list[Param], t: TuneSpec, search: int = 0) -> str:
    """The identity of filter ``name``'s study: the training study, the objective, the sampler, the space
    and, when set apart from the training seed, the search's seed."""
    d = {"spec": train.as_dict(), "filter": name, "objective": t.objective, "sampler": t.sampler,
         "space": [p.record() for p in params]}
    if t.level == "tracks":  # "off" keeps the identity of the studies written before the level existed
        d["level"] = t.level
    if t.search_seed is not None or search:  # none keeps the identity of the studies written before it existed
        d["search_seed"] = search_seed(t, train, search)
    return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


def storage(out: Path, url: str | None = None):
    """The Optuna storage of a tuning: the RDB storage at ``url`` (a database every worker reaches), else the
    study file of ``out`` (:func:`nespm_cli.tuning.study_file.study_path`, shared by the local workers and by a
    cluster's workers that mount ``out``): Optuna's journal file ``study.journal`` (each operation appended
    under its lock file and fsync'd: a finished trial survives a killed process and a power cut), or the
    SQLite ``study.db`` of a tuning written before it. A database that cannot be opened is one line naming
    it (a file that is not a study file is found first by
    :func:`nespm_cli.tuning.study_file.check_study_file`, which :func:`nespm_cli.tuning.run.run_tune` calls)."""
    import optuna

    if url is not None:
        import sqlalchemy.exc

        try:
            return optuna.storages.RDBStorage(url)
        except (sqlalchemy.exc.SQLAlchemyError, ImportError, ValueError) as exc:
            raise NespmError(f"--storage {url}: cannot be opened ({str(exc).splitlines()[0]})") from None
    path = study_path(out)
    if path.name == SQLITE_FILE:
        return sqlite_storage(path)
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    try:
        return JournalStorage(JournalFileBackend(str(path.resolve())))
    except (OSError, ValueError) as exc:  # unreadable, or damaged after run_tune's check
        raise NespmError(f"{path}: not a readable study journal ({exc}); delete it to start afresh or use another "
                         "--out") from None


def sqlite_storage(path: Path):
    """Optuna's RDB storage on the SQLite file ``path`` (a tuning's ``study.db`` from before the journal):
    write-ahead log with ``synchronous=NORMAL`` (a commit survives a killed process, not a power cut),
    opened through :func:`retried`. The file itself is checked once, by run_tune before anything opens
    it: read as an immutable file it must not change under the check, and here other workers may be
    writing it (a write-ahead log not yet checkpointed reads as "malformed" then)."""
    import sqlite3

    import optuna
    import sqlalchemy.exc

    where = str(Path(path).resolve())

    def connect():
        con = sqlite3.connect(where, timeout=120, check_same_thread=False)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA synchronous=NORMAL")
        return con

    try:
        return retried(lambda: optuna.storages.RDBStorage(f"sqlite:///{where}", engine_kwargs={"creator": connect}),
                       where)
    except sqlalchemy.exc.SQLAlchemyError as exc:
        raise NespmError(f"{where}: not a readable study database ({str(exc.orig if hasattr(exc, 'orig') else exc)}); "
                         "delete it to start afresh or use another --out") from None


RETRIES = 5  # attempts at opening a study while other workers write it (SQLite's transient errors)


def database_errors(name: str = "SQLAlchemyError") -> tuple:
    """``(sqlalchemy.exc.<name>,)`` where SQLAlchemy is loaded (an RDB storage is open), else ``()``: the
    journal storage does not load it, and ``except ()`` catches nothing."""
    import sys

    mod = sys.modules.get("sqlalchemy.exc")
    return (getattr(mod, name),) if mod is not None else ()


def retried(fn: Callable, path, attempts: int = RETRIES, wait: float = 0.5):
    """``fn()``, tried again after an SQLite operational error (``disk I/O error``, ``database is locked``:
    another worker writing the file as this one opens it), waiting 0.5, 1, 2, ... s; after ``attempts``
    one line naming ``path`` that says to run the command again (the stored trials are kept), not to delete
    it. Seen once: a 2-worker tune with 5 searches stopped after 12 minutes with "disk I/O error" as a
    worker opened the study; the same command resumed it."""
    import time

    transient = database_errors("OperationalError")
    for k in range(attempts):
        try:
            return fn()
        except transient as exc:
            if k == attempts - 1:
                raise NespmError(f"{path}: could not be opened now ({getattr(exc, 'orig', exc)}, {attempts} "
                                 "attempts); run the same command again to resume (the trials stored are kept)") from None
            time.sleep(wait * 2 ** k)


def open_study(store, name: str, digest: str, out: Path):
    """Filter ``name``'s study, created with ``digest`` or checked against it (one line if it differs)."""
    import optuna

    where = study_path(out)
    try:
        study = retried(lambda: optuna.create_study(storage=store, study_name=name, direction="minimize",
                                                    load_if_exists=True), where)
    except database_errors() as exc:
        raise NespmError(f"{where}: not a readable study database ({getattr(exc, 'orig', exc)}); delete "
                         "it to start afresh or use another --out") from None
    have = study.user_attrs.get(CONFIG_ATTR)
    if have is None:
        if study.trials:
            raise NespmError(f"{where}: study {name} was not written by nespm tune; use another --out")
        study.set_user_attr(CONFIG_ATTR, digest)
    elif have != digest:
        raise NespmError(f"{where}: study {name} comes from another configuration (tracks, runs, seed, "
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


def trial_seed(root: int, index: int, done: int, worker: int) -> int:
    """The sampler seed of a trial: from the search's root seed (:func:`search_seed`), the filter's index,
    the trials done, the worker."""
    return int(np.random.SeedSequence([root, index, done, worker]).generate_state(1)[0])


def quiet() -> None:
    """Optuna's per-trial log lines off (the command prints its own)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)


def trials_table(store, filters: tuple, repeats: int = 1) -> pd.DataFrame:
    """Every trial of every filter's studies (``store``, :func:`storage`): ``filter``, ``search`` (0 ..
    --repeats-1), ``trial``, ``phase`` (:data:`PHASES`), ``state``, ``score``, ``p_<key>`` and the
    statistics of :func:`nespm_cli.tuning.objective.summary`."""
    import optuna

    rows = []
    for f in filters:
        for k in range(repeats):
            study = optuna.load_study(study_name=study_name(f, k), storage=store)
            for tr in study.get_trials(deepcopy=False):
                rows.append({"filter": f, "search": k, "trial": tr.number, "phase": trial_phase(tr),
                             "state": tr.state.name, "score": tr.value if tr.value is not None else np.nan,
                             **{f"p_{key}": v for key, v in tr.params.items()},
                             **tr.user_attrs.get(STATS_ATTR, {})})
    return pd.DataFrame(rows)


__all__ = ["CONFIG_ATTR", "PHASES", "RETRIES", "PHASE_ATTR", "STATS_ATTR", "config_digest", "database_errors",
           "enqueue_default", "fail_stale", "make_sampler", "open_study", "quiet", "retried", "search_seed", "storage",
           "sqlite_storage", "study_name", "trial_phase", "trial_seed", "trials_table"]
