"""Opening a study while other workers write it: SQLite's transient operational errors are tried again
(tuning.study.retried), and when they persist the line says to run the command again, not to delete."""
from __future__ import annotations

import pytest
import sqlalchemy.exc

from nespm_cli.errors import NespmError
from nespm_cli.tuning import study as study_mod
from nespm_cli.tuning.study_file import SQLITE_FILE, check_study_file


def flaky(failures: int):
    calls = {"n": 0}

    def fn():
        calls["n"] += 1
        if calls["n"] <= failures:
            raise sqlalchemy.exc.OperationalError("PRAGMA journal_mode=WAL", {}, Exception("disk I/O error"))
        return "opened"
    return fn, calls


def test_a_transient_error_is_tried_again(monkeypatch):
    monkeypatch.setattr("time.sleep", lambda s: None)
    fn, calls = flaky(2)
    assert study_mod.retried(fn, "x/study.db") == "opened" and calls["n"] == 3


def test_a_persistent_error_says_to_resume_not_to_delete(monkeypatch):
    waits = []
    monkeypatch.setattr("time.sleep", waits.append)
    fn, calls = flaky(99)
    with pytest.raises(NespmError) as err:
        study_mod.retried(fn, "x/study.db")
    msg = str(err.value)
    assert calls["n"] == study_mod.RETRIES and waits == [0.5, 1.0, 2.0, 4.0]
    assert msg.startswith("x/study.db: could not be opened now (disk I/O error") and "run the same command again" in msg
    assert "delete" not in msg and "\n" not in msg


def test_storage_opens_through_the_retry(tmp_path, monkeypatch):
    """The SQLite storage (a study.db of a tuning from before the journal) after two transient failures of
    the RDB storage: opened, tables made."""
    import optuna

    real = optuna.storages.RDBStorage
    fails = {"n": 0}

    def rdb(*a, **k):
        if fails["n"] < 2:
            fails["n"] += 1
            raise sqlalchemy.exc.OperationalError("stmt", {}, Exception("database is locked"))
        return real(*a, **k)
    monkeypatch.setattr(optuna.storages, "RDBStorage", rdb)
    monkeypatch.setattr("time.sleep", lambda s: None)
    store = study_mod.sqlite_storage(tmp_path / SQLITE_FILE)
    assert fails["n"] == 2 and (tmp_path / SQLITE_FILE).stat().st_size > 0
    assert store.get_all_studies() == []


def test_the_file_check_would_misread_a_live_study_so_storage_does_not_run_it(tmp_path):
    """check_study_file reads the file as immutable: with a write-ahead log not yet checkpointed (another
    worker writing) it reads as damaged. So only run_tune calls it, before anything opens the file, and
    storage() opening a live study works."""
    import sqlite3

    import optuna

    path = tmp_path / SQLITE_FILE
    a = sqlite3.connect(path, isolation_level=None)  # a worker in a read transaction
    a.execute("PRAGMA journal_mode=WAL")
    a.execute("create table busy(x)")
    for i in range(100):
        a.execute("insert into busy values (?)", (i,))
    a.execute("begin")
    a.execute("select count(*) from busy").fetchone()
    b = sqlite3.connect(path, isolation_level=None, timeout=0.1)  # another writing and checkpointing
    b.execute("insert into busy values (1)")
    assert b.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0] == 1  # busy: a partial checkpoint
    with pytest.raises(NespmError, match="damaged"):
        check_study_file(path)
    a.execute("commit")
    store = study_mod.storage(tmp_path)  # the folder's study.db (its only study file), through SQLite's locks
    assert isinstance(store, optuna.storages.RDBStorage) and store.get_all_studies() == []
    a.close()
    b.close()
