"""``nespm tune --backend dask`` with a worker killed mid-trial (issue 38's must-hold): the study continues
on the restarted worker, no trial is lost or counted twice, and the values are those of ``--jobs 1`` bit for
bit (docs/tuning.md, "Tuning on a Dask cluster")."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import pandas as pd
import pytest

from conftest import WAIT_BOUND, console_script, env_without_data_dir
from nespm_cli.cli import main

TRIALS = 8
FILTERS = ["ekf", "ukf"]
ARGS = ["tune", "--tracks", "5", "--runs", "2", "--filters", ",".join(FILTERS), "--dvl", "synthetic", "--window", "0:60",
        "--no-progress", "--no-profile", "--trials", str(TRIALS), "--refine-trials", "0"]


def study_states(path) -> dict[str, dict[str, int]]:
    """``{filter: {state: count}}`` of the trials in the journal ``path``, read without a lock ({} before it
    exists)."""
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    if not path.exists():
        return {}
    store = JournalStorage(JournalFileBackend(str(path)))
    out = {}
    for s in store.get_all_studies():
        trials = store.get_all_trials(s._study_id, deepcopy=False)
        out[s.study_name] = {st.name: sum(t.state == st for t in trials) for st in optuna.trial.TrialState}
    return out


def task_index(key) -> int | None:
    """The index of a task of ``experiments.backend.parallel_map`` (key ``nespm-<function>-<index>-<token>``):
    for tune's global search with one search, the filter's index."""
    parts = str(key).split("-")
    return int(parts[-2]) if len(parts) >= 4 and parts[-2].isdigit() else None


def test_a_worker_killed_mid_trial_loses_no_trial(tmp_path, monkeypatch):
    """Both workers are stopped (SIGSTOP) at every poll, so they move only between polls and a trial spans
    many of them on any machine; once a filter's study holds a finished trial and a running one, the worker
    the scheduler has that filter's task on (task ``nespm-worker_run-<filter index>-...``) is killed
    (SIGKILL) there, mid-trial, and the other continued: the kill does not race the study."""
    distributed = pytest.importorskip("distributed")
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)
    assert main(ARGS + ["--jobs", "1", "--out", str(tmp_path / "one")]) == 0
    out = tmp_path / "killed"
    journal = out / "study.journal"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as lc, distributed.Client(lc, set_as_default=False) as client:
        pid_of = client.run(os.getpid)  # {worker address: pid}
        pids = sorted(pid_of.values())
        proc = subprocess.Popen(console_script() + ARGS + ["--backend", "dask", "--scheduler", lc.scheduler_address,
                                                           "--out", str(out)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=env_without_data_dir())
        killed, at_kill = None, None
        give_up = time.monotonic() + WAIT_BOUND  # a hang-guard, not a speed verdict
        try:
            while killed is None and proc.poll() is None and time.monotonic() < give_up:
                time.sleep(0.02)
                for p in pids:
                    os.kill(p, signal.SIGSTOP)
                states = study_states(journal)
                ready = {FILTERS.index(f) for f, c in states.items() if c.get("COMPLETE", 0) >= 1 and c.get("RUNNING", 0) == 1}
                for addr, keys in client.processing().items():
                    if killed is None and addr in pid_of and {task_index(k) for k in keys} & ready:
                        killed, at_kill = pid_of[addr], states
                        os.kill(killed, signal.SIGKILL)
                for p in pids:
                    if p != killed:
                        os.kill(p, signal.SIGCONT)
            stdout, stderr = proc.communicate(timeout=WAIT_BOUND)
        finally:
            for p in pids:
                try:
                    os.kill(p, signal.SIGCONT)
                except ProcessLookupError:
                    pass
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert killed is not None, f"no kill: the tune ended first ({stdout}, {stderr})"
    assert proc.returncode == 0 and "Traceback" not in stdout + stderr, stderr
    done = pd.read_parquet(out / "trials.parquet")
    one = pd.read_parquet(tmp_path / "one" / "trials.parquet")
    for f in FILTERS:
        d = done[done["filter"] == f]
        # every trial of the search counted once: TRIALS completed, the killed one (if its) failed, none running
        assert (d["state"] == "COMPLETE").sum() == TRIALS and (d["state"] == "RUNNING").sum() == 0, d
        assert (d["state"] == "FAIL").sum() <= 1
    assert (done["state"] == "FAIL").sum() == 1, (at_kill, done)  # exactly the trial cut short
    cols = [c for c in one.columns if c.startswith("p_")] + ["score"]
    key = ["filter", "trial"]
    got = done[done["state"] == "COMPLETE"].sort_values(key)
    want = one[one["state"] == "COMPLETE"].sort_values(key)
    # the killed filter's trials after the failed one are numbered one higher: compare in order
    for f in FILTERS:
        pd.testing.assert_frame_equal(got[got["filter"] == f][cols].reset_index(drop=True),
                                      want[want["filter"] == f][cols].reset_index(drop=True), check_exact=True)
