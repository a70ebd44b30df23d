"""Reliability, round 2 (issue 21): nothing overwritten, mixed or silently wrong; one line instead of a
traceback. Each test reproduces one fault the issue found and asserts the exit code, the one line,
and that no result was lost, mixed or silently wrong.

(The faults of the data layer — simulate into a folder of real tracks, Trajectory07, corrections
files, ProcessNet weights — are in tests/test_input_hardening.py.)
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, console_script, env_without_data_dir, nespm

BASE = ("--tracks", "5", "--runs", "4", "--chunk-size", "2", "--no-progress", "--jobs", "1")
EKF = (*BASE, "--filters", "ekf")

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


def mc(out: Path, data: Path, *extra) -> tuple[int, str, str]:
    return nespm("mc", "--data-dir", str(data), *EKF, *extra, "--out", str(out))


def plugin(path: Path, body: str, name: str = "bad") -> Path:
    """A filter plugin file defining ``name``: the EKF with ``body`` (class body) on top."""
    path.write_text(textwrap.dedent(f"""
        from nespm_cli.filters.ekf import EKF
        from nespm_cli.filters.registry import register

        @register("{name}")
        class Bad(EKF):
        """) + textwrap.indent(textwrap.dedent(body), "    "), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def finished(tmp_path_factory, short_data_dir) -> Path:
    """A finished ekf folder (4 runs, 2 chunks) to copy."""
    out = tmp_path_factory.mktemp("finished") / "r"
    rc, _, err = mc(out, short_data_dir)
    assert rc == 0, err
    return out


def copy_of(finished: Path, dst: Path) -> Path:
    shutil.copytree(finished, dst)
    return dst


# --- severe 2: --config=FILE and repeated --config ---------------------------------------------

def test_config_equals_form_and_repeated_configs(tmp_path, short_data_dir):
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text("seed = 7\nruns = 2\n", encoding="utf-8")
    b.write_text("seed = 11\n", encoding="utf-8")
    rc, _, err = nespm("mc", f"--config={a}", "--data-dir", str(short_data_dir), "--tracks", "5", "--filters", "ekf",
                       "--no-progress", "--jobs", "1", "--out", str(tmp_path / "eq"))
    assert rc == 0, err
    opts = json.loads((tmp_path / "eq" / "manifest.json").read_text())["options"]
    assert opts["seed"] == 7 and opts["runs"] == 2
    rc, _, err = nespm("mc", "--config", str(a), f"--config={b}", "--data-dir", str(short_data_dir), "--tracks", "5",
                       "--filters", "ekf", "--no-progress", "--jobs", "1", "--out", str(tmp_path / "two"))
    assert rc == 0, err
    opts = json.loads((tmp_path / "two" / "manifest.json").read_text())["options"]
    assert opts["seed"] == 11 and opts["runs"] == 2  # the later file overrides, the earlier one still counts
    rc, out, err = nespm("mc", "--config=", "--out", str(tmp_path / "x"))
    assert_one_error_line(rc, out, err, "--config needs a file")


# --- severe 3: an input file edited while mc runs ----------------------------------------------

def test_input_edited_while_mc_runs_stops_it(tmp_path, short_data_dir):
    """A plugin filter edits the DVL file while the first chunk runs: the second chunk's worker
    reads the new file, and its hash is not the manifest's: one line, no assembled results."""
    data = tmp_path / "d"
    shutil.copytree(short_data_dir, data)
    dvl = data / "Trajectory5" / "DVL_trajectory5.csv"
    p = plugin(tmp_path / "editor.py", f"""
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            import pathlib
            f = pathlib.Path({str(dvl)!r})
            lines = f.read_text().splitlines()
            if not lines[-1].endswith("9"):
                lines[-1] = lines[-1] + "9"
                f.write_text("\\n".join(lines) + "\\n")
        """, name="editor")
    rc, out, err = nespm("mc", "--data-dir", str(data), *BASE, "--filters", "editor", "--filter-plugin", str(p),
                         "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, str(dvl), "changed while the experiment ran")
    assert not (tmp_path / "r" / "metrics.parquet").exists()


# --- severe 4: only the chunks the manifest expects --------------------------------------------

def test_leftover_chunk_of_another_experiment_is_ignored(tmp_path, finished):
    out = copy_of(finished, tmp_path / "r")
    src = out / "chunks" / "series-5-ekf-000000.parquet"
    shutil.copy(src, out / "chunks" / "series-5-iekf-000000.parquet")  # what a failed iekf run left
    shutil.copy(out / "chunks" / "metrics-5-ekf-000000.parquet",
                out / "chunks" / "metrics-5-ekf-000000 (conflicted copy).parquet")
    rc, _, err = mc(out, Path(json.loads((out / "manifest.json").read_text())["data_dir"]))
    assert rc == 0, err
    assert "ignored 2 file(s)" in err and "series-5-iekf-000000.parquet" in err
    m = pd.read_parquet(out / "metrics.parquet")
    e = pd.read_parquet(out / "epochs.parquet")
    assert len(m) == 4 and sorted(m["run"]) == [0, 1, 2, 3]  # not 6: the copy is not read
    assert set(e["filter"]) == {"ekf"} and (e["n_runs"] == 4).all()


def test_deleted_series_chunk_is_computed_again(tmp_path, finished):
    out = copy_of(finished, tmp_path / "r")
    before = pd.read_parquet(out / "epochs.parquet")
    (out / "chunks" / "series-5-ekf-000002.parquet").unlink()
    rc, _, err = mc(out, Path(json.loads((out / "manifest.json").read_text())["data_dir"]))
    assert rc == 0, err
    after = pd.read_parquet(out / "epochs.parquet")
    assert (after["n_runs"] == 4).all()
    pd.testing.assert_frame_equal(before, after)


@pytest.mark.parametrize("damage", ["zero-bytes", "truncated", "foreign"])
def test_damaged_chunk_is_named_and_computed_again(tmp_path, finished, damage):
    out = copy_of(finished, tmp_path / "r")
    before = pd.read_parquet(out / "metrics.parquet")
    victim = out / "chunks" / "metrics-5-ekf-000002.parquet"
    if damage == "zero-bytes":
        victim.write_bytes(b"")
    elif damage == "truncated":
        victim.write_bytes(victim.read_bytes()[:300])
    else:  # a valid Parquet file that nespm did not write for this experiment
        pd.read_parquet(victim).to_parquet(victim, index=False)
    rc, _, err = mc(out, Path(json.loads((out / "manifest.json").read_text())["data_dir"]))
    assert rc == 0, err
    assert str(victim) in err and "computing it again" in err
    after = pd.read_parquet(out / "metrics.parquet")
    pd.testing.assert_frame_equal(before.drop(columns="seconds"), after.drop(columns="seconds"))


def test_assembly_verifies_every_chunk(tmp_path, finished):
    from nespm_cli.errors import NespmError
    from nespm_cli.experiments.store import GROWABLE, ResultsFolder

    out = copy_of(finished, tmp_path / "r")
    options = json.loads((out / "manifest.json").read_text())["options"]
    folder = ResultsFolder(out, options, extendable=GROWABLE)
    names = ["metrics-5-ekf-000000.parquet", "metrics-5-ekf-000002.parquet"]
    assert [p.name for p in folder.verified(names)] == names
    (out / "chunks" / names[1]).write_bytes(b"PAR1")
    with pytest.raises(NespmError, match="metrics-5-ekf-000002.parquet: unreadable"):
        folder.verified(names)


# --- severe 6: a plugin given as a module name is hashed ----------------------------------------

def test_module_plugin_is_hashed(tmp_path, short_data_dir, monkeypatch):
    pkg = tmp_path / "site"
    pkg.mkdir()
    mod = plugin(pkg / "nespm_test_modplugin.py", "pass\n", name="modplug")
    monkeypatch.syspath_prepend(str(pkg))
    args = ("--filters", "modplug", "--filter-plugin", "nespm_test_modplugin")
    out = tmp_path / "r"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *BASE, *args, "--out", str(out))
    assert rc == 0, err
    assert str(mod.resolve()) in json.loads((out / "manifest.json").read_text())["inputs"]
    mod.write_text(mod.read_text() + "\n# edited\n", encoding="utf-8")
    rc, o, err = nespm("mc", "--data-dir", str(short_data_dir), *BASE, *args, "--runs", "6",
                       "--jobs", "1", "--out", str(out))
    assert_one_error_line(rc, o, err, str(mod.resolve()), "changed since")
    assert len(pd.read_parquet(out / "metrics.parquet")) == 4


# --- severe 7: the lock never follows a link --------------------------------------------------

def test_lock_refuses_a_symlink(tmp_path, short_data_dir):
    target = tmp_path / "precious.txt"
    target.write_text("keep me", encoding="utf-8")
    out = tmp_path / "r"
    out.mkdir()
    (out / ".lock").symlink_to(target)
    rc, o, err = mc(out, short_data_dir)
    assert_one_error_line(rc, o, err, ".lock", "symbolic link")
    assert target.read_text() == "keep me" and not (out / "metrics.parquet").exists()


def test_lock_refuses_a_fifo(tmp_path, short_data_dir):
    out = tmp_path / "r"
    out.mkdir()
    os.mkfifo(out / ".lock")
    rc, o, err = mc(out, short_data_dir)
    assert_one_error_line(rc, o, err, ".lock", "not a regular file")


# --- tracebacks that become one line ---------------------------------------------------------

PLUGIN_FAULTS = {
    "raises-in-propagate": ("""
        def propagate(self, j0, j1, k=0):
            raise ZeroDivisionError("boom")
        """, ["filter bad-raises-in-propagate (", "propagate raised ZeroDivisionError: boom"]),
    "wrong-covariance-shape": ("""
        def covariance(self):
            return self.P[:, :6, :6]
        """, ["filter bad-wrong-covariance-shape (", "covariance() returned shape", "expected (4, 12, 12)"]),
}


@pytest.mark.parametrize("case", list(PLUGIN_FAULTS))
def test_plugin_fault_is_one_line(tmp_path, short_data_dir, case):
    body, words = PLUGIN_FAULTS[case]
    p = plugin(tmp_path / "bad.py", body, name=f"bad-{case}")  # one name per file: the registry is per process
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *BASE, "--chunk-size", "4", "--filters", f"bad-{case}",
                         "--filter-plugin", str(p), "--out", str(tmp_path / "r"))
    line = assert_one_error_line(rc, out, err, *words)
    assert str(p.resolve()) in line


def test_plugin_without_methods_is_one_line(tmp_path, short_data_dir):
    p = tmp_path / "empty.py"
    p.write_text("from nespm_cli.filters.protocol import Filter\nfrom nespm_cli.filters.registry import register\n\n"
                 "@register('empty')\nclass Empty(Filter):\n    pass\n", encoding="utf-8")
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *BASE, "--filters", "empty", "--filter-plugin",
                         str(p), "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, "filter empty (", "__init__ is not implemented")


def test_killed_worker_is_one_line(tmp_path, short_data_dir):
    """A worker killed by the system (here: SIGKILL from the filter, as the OOM killer would) ends
    the command with one line naming the chunk; the other chunk's files are kept."""
    flag = tmp_path / "killed"
    p = plugin(tmp_path / "killer.py", f"""
        def propagate(self, j0, j1, k=0):
            import os, signal
            try:  # the first worker here (only one: O_EXCL) dies as the OOM killer would do it
                os.close(os.open({str(flag)!r}, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                os.kill(os.getpid(), signal.SIGKILL)
            except FileExistsError:
                pass
            super().propagate(j0, j1, k)
        """, name="killer")
    r = subprocess.run([*console_script(), "mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "4",
                        "--chunk-size", "2", "--filters", "killer", "--filter-plugin", str(p), "--jobs", "2",
                        "--no-progress", "--out", str(tmp_path / "r")], capture_output=True, text=True,
                       env=env_without_data_dir(), timeout=600)
    assert_one_error_line(r.returncode, r.stdout, r.stderr, "a worker process died while computing chunk 5-00000",
                          "memory may be the cause")


def test_huge_chunk_is_refused_with_its_estimate(tmp_path):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "100000", "--chunk-size", "100000", "--filters", "ekf",
                         "--no-progress", "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, "--chunk-size 100000", "GB per worker")
    assert not (tmp_path / "r" / "chunks").exists() or not any((tmp_path / "r" / "chunks").iterdir())


@pytest.mark.parametrize("manifest,words", [
    ([], "not a nespm manifest"),
    ({"options": None}, "not a nespm manifest"),
    ("RUN_BLOCKS", "bad run_blocks"),
])
def test_broken_manifest_is_one_line(tmp_path, finished, manifest, words):
    out = copy_of(finished, tmp_path / "r")
    if manifest == "RUN_BLOCKS":
        m = json.loads((out / "manifest.json").read_text())
        m["run_blocks"] = [[0, 4], [2, "x"]]
        manifest = m
    (out / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    rc, o, err = mc(out, Path(json.loads((finished / "manifest.json").read_text())["data_dir"]))
    assert_one_error_line(rc, o, err, "manifest.json", words)


def test_non_utf8_config_is_one_line(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_bytes(b"runs = 2\n# caf\xe9\n")
    rc, out, err = nespm("mc", "--config", str(cfg), "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, str(cfg), "not UTF-8")


def test_kernel_cache_falls_back_when_not_writable(monkeypatch):
    """numba without a writable cache location raises at decoration; the kernels then compile
    uncached, with one warning (a read-only install with no writable NUMBA_CACHE_DIR)."""
    import numba

    from nespm_cli.nav import kernels as nk

    real = numba.njit

    def refusing(*a, **k):
        if k.get("cache"):
            raise RuntimeError("cannot cache function 'f': no locator available for file 'x.py'")
        return real(*a, **k)

    monkeypatch.setattr(numba, "njit", refusing)
    monkeypatch.setattr(nk, "NO_CACHE", [])
    with pytest.warns(nk.KernelCacheWarning, match="NUMBA_CACHE_DIR"):
        f = nk.njit(cache=True)(lambda x: 2.0 * x)
    assert f(1.5) == 3.0 and nk.NO_CACHE


def test_c_locale_prints_without_failing(tmp_path, finished):
    """LC_ALL=C with UTF-8 mode off: stdout is ASCII; the report (±, σ, ²) prints with '?' instead."""
    out = copy_of(finished, tmp_path / "r")
    env = {**env_without_data_dir(), "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0"}
    env.pop("PYTHONIOENCODING", None)
    r = subprocess.run([*console_script(), "report", str(out), "--n-boot", "50"], capture_output=True, env=env,
                       timeout=600)  # 50 resamples: the same text and symbols as 2000
    assert r.returncode == 0, r.stderr.decode("ascii", "replace")[-500:]
    assert b"Traceback" not in r.stderr and (out / "report.md").exists()


# --- messages ---------------------------------------------------------------------------------

def test_long_or_newline_path_keeps_its_reason(tmp_path):
    long = tmp_path / ("x" * 200) / ("y" * 200) / "no-such-data"
    rc, out, err = nespm("mc", "--data-dir", str(long), "--out", str(tmp_path / "r"))
    line = assert_one_error_line(rc, out, err, "data directory not found")
    assert len(line) <= 420
    nl = tmp_path / "bad\nname"
    rc, out, err = nespm("mc", "--data-dir", str(nl), "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, "bad name", "data directory not found")


def test_full_disk_names_the_file(tmp_path, finished, monkeypatch):
    import pyarrow.parquet as pq

    def full(*a, **k):
        raise OSError(28, "Error writing bytes to file. Detail: [errno 28] No space left on device")

    out = copy_of(finished, tmp_path / "r")
    (out / "chunks" / "metrics-5-ekf-000002.parquet").unlink()
    monkeypatch.setattr(pq, "write_table", full)
    monkeypatch.setattr(pq.ParquetWriter, "write_table", full)  # chunks are written through a ParquetWriter
    rc, o, err = mc(out, Path(json.loads((out / "manifest.json").read_text())["data_dir"]))
    assert_one_error_line(rc, o, err, "series-5-ekf-000002.parquet", "no space left on the device")


# --- lenient inputs: refused, never ignored ----------------------------------------------------

def test_scheduler_with_loky_is_refused(tmp_path, short_data_dir):
    rc, out, err = mc(tmp_path / "r", short_data_dir, "--scheduler", "tcp://127.0.0.1:8786")
    assert_one_error_line(rc, out, err, "--scheduler", "--backend dask")
    assert not (tmp_path / "r").exists()


def test_weights_without_adaptive_filter_are_refused(tmp_path, short_data_dir):
    rc, out, err = mc(tmp_path / "r", short_data_dir, "--weights", str(tmp_path / "nope.npz"))
    assert_one_error_line(rc, out, err, "--weights", "adaptive filters")


def test_folder_with_only_metrics_is_not_overwritten(tmp_path, short_data_dir):
    out = tmp_path / "r"
    out.mkdir()
    (out / "metrics.parquet").write_bytes(b"someone else's results")
    rc, o, err = mc(out, short_data_dir)
    assert_one_error_line(rc, o, err, "metrics.parquet", "no manifest.json")
    assert (out / "metrics.parquet").read_bytes() == b"someone else's results"


def test_report_on_a_folder_being_written_says_so(tmp_path, finished):
    """report on a folder another process holds (its lock) warns that it is being written; else not."""
    from nespm_cli.experiments.store import FolderLock

    out = copy_of(finished, tmp_path / "r")
    lock = FolderLock(out)  # another process extending the folder holds this
    try:
        rc, o, err = nespm("report", str(out), "--n-boot", "50")
    finally:
        lock.release()
    assert rc == 0
    assert f"pid {os.getpid()}" in err and "is writing this folder now" in err
    rc, o, err = nespm("report", str(out), "--n-boot", "50")
    assert rc == 0 and "writing this folder" not in err
