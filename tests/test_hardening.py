"""Hardening (issue 14): file-system errors, option domains, divergence, data hashes, failed starts,
orphan workers, the folder lock and printable one-line messages."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import (REPO, WAIT_BOUND, assert_one_error_line, chunk_mtimes, console_script, env_without_data_dir, nespm,
                      slow_env, wait_until)
from nespm_cli.cli import one_line
from nespm_cli.experiments.metrics import DivergenceRule, EpochErrors, divergence
from nespm_cli.experiments.store import FolderLock

EKF = ("--tracks", "5", "--runs", "2", "--filters", "ekf", "--no-progress", "--jobs", "1")


def deny(monkeypatch, method: str, when) -> None:
    """Make ``Path.<method>`` raise PermissionError for the paths where ``when(path)`` holds, as a
    read-only or unreadable file system would (as root, permissions are not enforced)."""
    real = getattr(Path, method)

    def denied(path, *a, **k):
        if when(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real(path, *a, **k)

    monkeypatch.setattr(Path, method, denied)


def copy_data(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# --- 1. file-system errors: one line naming the path, exit 2 -----------------------------------

def test_out_below_a_regular_file(tmp_path, short_data_dir):
    (tmp_path / "afile").write_text("x")
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(tmp_path / "afile" / "r"))
    assert_one_error_line(rc, out, err, str(tmp_path / "afile"), "Not a directory")


def test_out_in_proc(short_data_dir):
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", "/proc/nespm-x")
    assert_one_error_line(rc, out, err, "/proc/nespm-x")


def test_unreadable_gt_file(tmp_path, short_data_dir, monkeypatch):
    """As root nothing is unreadable, so the file system's answer is given by a patched reader too."""
    data = copy_data(short_data_dir, tmp_path / "d")
    gt = data / "Trajectory5" / "GT_trajectory5.csv"
    with monkeypatch.context() as m:
        deny(m, "read_bytes", lambda p: p == gt)
        rc, out, err = nespm("tracks", "--data-dir", str(data), "--no-progress")
    assert_one_error_line(rc, out, err, str(gt), "Permission denied")
    if os.geteuid() != 0:  # and for real where permissions apply
        gt.chmod(0)
        rc, out, err = nespm("tracks", "--data-dir", str(data), "--no-progress")
        assert_one_error_line(rc, out, err, str(gt))


def test_report_that_cannot_be_written(tmp_path, short_data_dir):
    out_dir = tmp_path / "r"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(out_dir))
    assert rc == 0, err
    (out_dir / "report.md").mkdir()  # the report's place is taken by a folder
    rc, out, err = nespm("report", str(out_dir), "--n-boot", "50")  # fewer resamples: the same write path
    assert_one_error_line(rc, out, err, "report.md")


def test_results_folder_that_cannot_be_written(tmp_path, short_data_dir):
    out_dir = tmp_path / "r"
    out_dir.mkdir()
    (out_dir / "chunks").write_text("not a folder")
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(out_dir))
    assert_one_error_line(rc, out, err, str(out_dir / "chunks"))


# --- 5. option domains: one line, exit 2, nothing written ---------------------------------------

@pytest.mark.parametrize("opts,msg", [
    (("--seed", "-5"), "--seed"), (("--alpha", "0"), "--alpha"), (("--dvl-r-std", "-1"), "--dvl-r-std"),
    (("--dvl-r-std", "0"), "--dvl-r-std"), (("--acc-bias-rw", "-1"), "--acc-bias-rw"),
    (("--gyro-bias-rw", "nan"), "--gyro-bias-rw"), (("--dvl-lever-arm", "nan", "0", "0"), "--dvl-lever-arm"),
    (("--misalignment-deg", "1e9"), "--misalignment-deg"), (("--tracks", "5,5"), "more than once"),
    (("--tracks", "-1"), "positive"), (("--diverge-nees", "0"), "--diverge-nees"),
    (("--diverge-after", "-1"), "--diverge-after"), (("--seed", "1e23"), "--seed"),
])
def test_option_domains(tmp_path, short_data_dir, opts, msg):
    out_dir = tmp_path / "r"
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), "--runs", "1", "--filters", "ukf", *opts,
                         "--out", str(out_dir), "--no-progress")
    assert_one_error_line(rc, out, err, msg)
    assert not out_dir.exists()


def test_corrupt_checks_its_seed(tmp_path):
    rc, out, err = nespm("corrupt", "--seed", "-5", "--out", str(tmp_path / "c"))
    assert_one_error_line(rc, out, err, "--seed")


# --- 3. divergence from the filter's own consistency ---------------------------------------------

def errors(att_deg, nees):
    att, nees = np.radians(np.asarray(att_deg, float)), np.asarray(nees, float)
    z = np.zeros_like(att)
    return EpochErrors(vel=z, att=att, nees=nees, ne=np.zeros(att.shape + (2,)))


def test_divergence_rule():
    t = np.arange(200.0)
    base_att, base_nees = np.full((5, 200), 1.0), np.full((5, 200), 6.0)
    att, nees = base_att.copy(), base_nees.copy()
    att[1, 100] = 50.0  # beyond 45 deg after 60 s: attitude
    att[2, 30] = 80.0  # large, but before --diverge-after: fine
    nees[3, 100:131] = 2000.0  # a 30 s window above 1000: nees
    nees[4, 100:110] = 2000.0  # 10 s of it: mean over any 30 s window 672 -> fine
    lost, why, inconsistent = divergence(errors(att, nees), np.array([True, False, False, False, False]), t)
    assert why.tolist() == ["numeric", "attitude", "", "", ""]
    assert lost.tolist() == [True, True, False, False, False]  # the NEES test does not lose a run ...
    assert inconsistent.tolist() == [False, False, False, True, False]  # ... it marks it inconsistent
    nan_nees = np.full((1, 200), np.nan)  # a filter without covariance (ins): no NEES test
    assert not divergence(errors(base_att[:1], nan_nees), np.array([False]), t)[2][0]
    strict = DivergenceRule(nees=500.0)
    assert divergence(errors(att, nees), np.zeros(5, bool), t, strict)[2][4]


def test_large_misalignment_runs_are_counted_diverged(tmp_path, short_data_dir):
    out_dir = tmp_path / "r"
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "3", "--filters", "ekf",
                         "--misalignment-deg", "60", "--diverge-after", "20", "--out", str(out_dir),
                         "--no-progress", "--jobs", "1")
    assert rc == 0, err
    m = pd.read_parquet(out_dir / "metrics.parquet")
    assert m["diverged"].all() and set(m["diverged_reason"]) <= {"numeric", "attitude", "nees"}
    assert "3 diverged" in out
    rc, text, err = nespm("report", str(out_dir))
    assert rc == 0, err
    assert "ekf 3 (" in (out_dir / "report.md").read_text()


# --- 4. data hashes: an edited input refuses the resume ------------------------------------------

def test_changed_data_refuses_resume(tmp_path, short_data_dir):
    data = copy_data(short_data_dir, tmp_path / "d")
    out_dir = tmp_path / "r"
    args = ("mc", "--data-dir", str(data), *EKF, "--out", str(out_dir))
    rc, _, err = nespm(*args)
    assert rc == 0, err
    man = json.loads((out_dir / "manifest.json").read_text())
    dvl = (data / "Trajectory5" / "DVL_trajectory5.csv").resolve()
    assert len(man["inputs"][str(dvl)]) == 64
    rc, _, err = nespm("report", str(out_dir), "--n-boot", "50")
    assert "input files; sha256" in (out_dir / "report.md").read_text()
    df = pd.read_csv(dvl)
    df.iloc[10, 1] += 0.5
    df.to_csv(dvl, index=False)
    before = (out_dir / "metrics.parquet").read_bytes()
    rc, out, err = nespm(*args)
    assert_one_error_line(rc, out, err, str(dvl), "changed since")
    assert (out_dir / "metrics.parquet").read_bytes() == before  # nothing mixed


# --- 6. a failed start leaves no obstacle; relative and absolute paths are the same folder -------

def test_manifest_without_results_is_no_experiment(tmp_path, short_data_dir):
    out_dir = tmp_path / "r"
    out_dir.mkdir()
    (out_dir / "manifest.json").write_text(json.dumps({"options": {"runs": 7, "filters": ["ukf"]}}))
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(out_dir))
    assert rc == 0, err


def test_relative_and_absolute_data_dir_are_one_experiment(tmp_path, short_data_dir, monkeypatch):
    out_dir = tmp_path / "r"
    monkeypatch.chdir(short_data_dir.parent)
    rc, _, err = nespm("mc", "--data-dir", short_data_dir.name, *EKF, "--out", str(out_dir))
    assert rc == 0, err
    before = chunk_mtimes(out_dir)
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir.resolve()), *EKF, "--out", str(out_dir))
    assert rc == 0, err
    assert chunk_mtimes(out_dir) == before


# --- 8. the folder lock ------------------------------------------------------------------------------

def test_busy_folder_is_refused(tmp_path, short_data_dir):
    out_dir = tmp_path / "r"
    lock = FolderLock(out_dir)  # another process's lock (flock: per open file, so this one counts too)
    try:
        rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(out_dir))
        assert_one_error_line(rc, out, err, "busy", str(os.getpid()))
    finally:
        lock.release()
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(out_dir))
    assert rc == 0, err


def children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                fields = (p / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(p.name))
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the worker processes")
def test_kill_9_leaves_no_workers_and_resume_is_complete(tmp_path, short_data_dir):
    """kill -9 of mc: its workers end (none outlives it), a second mc meanwhile finds the
    folder busy, and the resumed run's manifest times every chunk.

    No race with the run's end: the killed mc runs the NumPy loop (chunks of seconds) and its
    workers are stopped (SIGSTOP) the moment both are seen, so it cannot finish while the
    second mc looks; they are continued (SIGCONT) after the kill, to notice their parent's death."""
    out_dir = tmp_path / "r"
    cmd = [sys.executable, "-m", "nespm_cli.cli", "mc", "--data-dir", str(short_data_dir), "--tracks", "5", "6",
           "--runs", "8", "--chunk-size", "2", "--filters", "ekf,ukf-nespm", "--jobs", "2", "--no-progress",
           "--out", str(out_dir)]
    proc = subprocess.Popen(cmd, cwd=REPO, env=slow_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    workers: list[int] = []

    def started() -> bool:
        workers[:] = [c for c in children(proc.pid) if "loky" in Path(f"/proc/{c}/cmdline").read_text(errors="replace")]
        return len(workers) >= 2 and (out_dir / "chunks" / ".progress").exists()

    wait_until(started, "two loky workers and the first progress file", proc=proc, step=0.02)
    for w in workers:
        os.kill(w, signal.SIGSTOP)
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "6", "--runs", "8",
                         "--chunk-size", "2", "--filters", "ekf,ukf-nespm", "--out", str(out_dir))
    assert_one_error_line(rc, out, err, "busy", str(proc.pid))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    for w in workers:
        if alive(w):
            os.kill(w, signal.SIGCONT)
    # the workers notice their parent's death and end (a hang-guard bound, not a speed verdict)
    wait_until(lambda: not any(alive(w) for w in workers), "the workers to end after their parent", step=0.1)
    # resumed in-process (--jobs is not part of the experiment: the same chunks, no worker start-up)
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "6", "--runs", "8",
                       "--chunk-size", "2", "--filters", "ekf,ukf-nespm", "--out", str(out_dir), "--no-progress",
                       "--jobs", "1")
    assert rc == 0, err
    man = json.loads((out_dir / "manifest.json").read_text())
    assert len(man["chunk_seconds"]) == 2 * 4 * 2  # tracks x chunks x filters
    assert len(pd.read_parquet(out_dir / "metrics.parquet")) == 2 * 8 * 2


# --- 9. printable one-line messages ------------------------------------------------------------------

def test_one_line_is_printable_and_short():
    text = one_line("bad value '" + "\x00" * 2000 + "' in\nsecond line")
    assert "\n" not in text and text.isprintable() and len(text) < 120
    assert "?x2000" in text  # the run of 2000 NULs, counted


def test_all_nul_file_is_one_printable_line(tmp_path, short_data_dir):
    data = copy_data(short_data_dir, tmp_path / "d")
    (data / "Trajectory5" / "GT_trajectory5.csv").write_bytes(b"\x00" * 2000)
    rc, out, err = nespm("tracks", "--data-dir", str(data), "--no-progress")
    line = assert_one_error_line(rc, out, err, "GT_trajectory5.csv")
    assert line.isprintable() and len(line) < 400


def test_unreadable_track_folder(tmp_path, short_data_dir, monkeypatch):
    data = copy_data(short_data_dir, tmp_path / "d")
    deny(monkeypatch, "iterdir", lambda p: p == data)
    rc, out, err = nespm("mc", "--data-dir", str(data), *EKF, "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, str(data), "Permission denied")
    assert not (tmp_path / "r").exists()


def test_out_inside_a_read_only_folder(tmp_path, short_data_dir, monkeypatch):
    """As root a read-only folder is writable, so its refusal is given by a patched mkdir too."""
    ro = tmp_path / "ro"
    ro.mkdir()
    with monkeypatch.context() as m:
        deny(m, "mkdir", lambda p: ro in p.parents)
        rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(ro / "r"))
    assert_one_error_line(rc, out, err, str(ro / "r"), "Permission denied")
    if os.geteuid() != 0:
        ro.chmod(0o555)
        rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *EKF, "--out", str(ro / "r2"))
        assert_one_error_line(rc, out, err, str(ro / "r2"))


def test_overflowing_dvl_gives_the_error_line_only(tmp_path, short_data_dir):
    """A DVL value of 1e308 overflows the speed (a NumPy RuntimeWarning): only the error line prints."""
    data = copy_data(short_data_dir, tmp_path / "d")
    dvl = data / "Trajectory5" / "DVL_trajectory5.csv"
    df = pd.read_csv(dvl)
    df.iloc[7, 1:4] = 1e308
    df.to_csv(dvl, index=False)
    r = subprocess.run([*console_script(), "mc", "--data-dir", str(data), *EKF, "--out", str(tmp_path / "r")],
                       capture_output=True, text=True, env=env_without_data_dir(), timeout=WAIT_BOUND)
    assert_one_error_line(r.returncode, r.stdout, r.stderr, str(dvl), "data row 8")  # a real process's stderr
