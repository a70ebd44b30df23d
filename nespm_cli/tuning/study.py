"""The Optuna studies of ``nespm tune``: their storage (``OUT/study.db``), identity (a digest of the
configuration), the stale trials of a killed process, the default trial, the seeded samplers and the
table of every trial (docs/tuning.md)."""
from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec

STUDY_FILE = "study.db"
CONFIG_ATTR = "nespm_config"  # the study's user attribute holding its configuration digest
STATS_ATTR = "stats"  # a trial's user attribute: its statistics ({name: float}, objective.summary)


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


def quiet() -> None:
    """Optuna's per-trial log lines off (the command prints its own)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)


def trials_table(out: Path, filters: tuple) -> pd.DataFrame:
    """Every trial of every filter's study: ``filter``, ``trial``, ``state``, ``score``, ``p_<key>``
    and the statistics of :func:`nespm_cli.tuning.objective.summary`."""
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


__all__ = ["CONFIG_ATTR", "STATS_ATTR", "STUDY_FILE", "config_digest", "enqueue_default", "fail_stale", "make_sampler",
           "open_study", "quiet", "storage", "trial_seed", "trials_table"]
