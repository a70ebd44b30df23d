"""The Dask backend of the Monte Carlo runner (nespm_cli.experiments.backend, docs/cluster.md).

Checked: ``nespm mc --backend dask`` on a 2-worker LocalCluster gives the loky numbers bit
for bit; a worker killed mid-chunk costs only that chunk, which the scheduler re-runs, and
the final tables are complete, duplicate-free and unchanged; a chunk left half-written
(series file without its metrics file, a stale temporary file) is recomputed without
duplicates; a NespmError raised on a worker (its data folder missing) reaches the client as
that one-line NespmError; without ``distributed``, an unknown backend, or a bogus or
silent scheduler address, the command fails with one line and exit code 2 (how soon it fails is
a benchmark, benchmarks/bench_claims.py, not a test).

Cost: the experiments run on a 40 s cut of embedded track 5 (written to a temporary data
folder, so a fresh clone suffices): one chunk of 2 runs x (ekf, ukf-nespm) is ~2-4 s. The
full 400 s track costs ~23 s per chunk, too much for three experiments here; the result
identity on it was checked by hand (docs/cluster.md).
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import WAIT_BOUND, assert_one_error_line, chunk_mtimes, console_script, nespm, wait_until, write_short_tracks
from nespm_cli.experiments.backend import check_backend, parallel_map
from nespm_cli.errors import NespmError
from nespm_cli.filters.kernels import numba_installed
from nespm_cli.experiments.mc import Cell, run_chunk
from nespm_cli.experiments.spec import Spec

KEY = ["track", "filter", "run"]
EPOCHS = 40
RUNS = 8
FILTERS = ("ekf", "ukf-nespm")
CHUNKS = [f"metrics-5-{f}-{first:06d}.parquet" for f in FILTERS for first in range(0, RUNS, 2)]
# Dask keys of the chunk tasks: nespm-<function>-<chunk index>-<token>, the function being
# experiment.run_chunk_keyed (run_chunk before it)
CHUNK_TASK = "nespm-run_chunk"


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch):
    for name in ("NESPM_DATA_DIR", "NESPM_DASK_SCHEDULER", "NESPM_DASK_TIMEOUT", "NESPM_DASK_WAIT"):
        monkeypatch.delenv(name, raising=False)


def metrics(d: Path) -> pd.DataFrame:
    m = pd.read_parquet(d / "metrics.parquet").drop(columns="seconds")
    return m.sort_values(KEY, kind="stable").reset_index(drop=True)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    """The first 40 epochs of embedded track 5 as an A-KIT folder."""
    return write_short_tracks(tmp_path_factory.mktemp("short-data"), (5,), EPOCHS)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("backend")


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker LocalCluster (one process, one thread each) and a client for inspecting it."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as lc:
        with distributed.Client(lc, set_as_default=False) as client:
            yield lc, client


@pytest.fixture(scope="module")
def argv(data_dir) -> list[str]:
    return ["mc", "--tracks", "5", "--runs", str(RUNS), "--filters", ",".join(FILTERS), "--chunk-size", "2",
            "--no-progress", "--data-dir", str(data_dir)]


def mc(out: Path, *argv) -> Path:
    rc, stdout, stderr = nespm(*argv, "--out", out)
    assert rc == 0, stderr
    assert "Traceback" not in stdout + stderr
    return out


@pytest.fixture(scope="module")
def mc_loky(root, argv) -> Path:
    return mc(root / "B", *argv, "--backend", "loky", "--jobs", "2")


@pytest.fixture(scope="module")
def mc_dask(root, argv, cluster) -> Path:
    return mc(root / "A", *argv, "--backend", "dask", "--scheduler", cluster[0].scheduler_address)


# --------------------------------------------------------------------------- identical results


def test_dask_equals_loky_bit_for_bit(mc_dask, mc_loky):
    """mc on a 2-worker Dask cluster gives the loky backend's metrics and epochs bit for bit."""
    a, b = metrics(mc_dask), metrics(mc_loky)
    assert len(a) == RUNS * len(FILTERS) and not a.duplicated(KEY).any()
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    pd.testing.assert_frame_equal(pd.read_parquet(mc_dask / "epochs.parquet"),
                                  pd.read_parquet(mc_loky / "epochs.parquet"), check_exact=True)
    assert sorted(p.name for p in (mc_dask / "chunks").glob("metrics-*.parquet")) == sorted(CHUNKS)
    if numba_installed():  # the Dask workers ran the compiled loop, as the loky ones
        assert (a["kernels"] == "numba").all() and (b["kernels"] == "numba").all()


def test_client_is_closed_after_the_run(mc_dask, cluster):
    lc, client = cluster
    # the scheduler drops a closed client's entry on its own loop: wait for that event (the
    # bound is a hang-guard; a client left connected never goes and fails it)
    wait_until(lambda: not set(lc.scheduler.clients) - {"fire-and-forget", client.id},
               "nespm's client to leave the scheduler (nespm left its client connected?)", bound=120, step=0.1)


def test_worker_killed_mid_chunk(root, argv, cluster, mc_dask):
    """SIGKILL a worker while it holds a chunk: the scheduler re-runs that chunk elsewhere,
    the command succeeds, and the tables equal the uninterrupted run's.

    The kill does not race the run: a worker plugin holds the first worker that starts a
    second-wave chunk (index >= 2, so a first-wave chunk is written by then) in that task's
    transition to "executing" and names its pid and key in a file; the test kills that pid.
    Every other start (the other worker, the restarted one) passes, so the verdict is the
    same on a fast or a loaded machine."""
    from distributed.diagnostics.plugin import WorkerPlugin

    lc, client = cluster
    out = root / "K"
    hold = root / "K-hold"
    hold.mkdir()
    bound = WAIT_BOUND

    class HoldOneChunk(WorkerPlugin):
        """Hold the first second-wave chunk task's worker until it is killed (or ``bound`` s)."""

        def setup(self, worker):
            self.pid = os.getpid()

        def transition(self, key, start, finish, **kwargs):
            import time
            name = str(key)
            if finish != "executing" or not name.startswith(CHUNK_TASK) or int(name.split("-")[-2]) < 2:
                return
            try:
                os.close(os.open(hold / "claim", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            except FileExistsError:
                return  # a chunk was held already: this one runs
            (hold / "tmp").write_text(f"{self.pid} {name}\n")
            os.replace(hold / "tmp", hold / "held")
            give_up = time.monotonic() + bound
            while time.monotonic() < give_up:
                time.sleep(0.05)

    client.register_plugin(HoldOneChunk(), name="nespm-test-hold-one-chunk")
    env = {**os.environ, "NESPM_DASK_SCHEDULER": lc.scheduler_address}  # the variable instead of --scheduler
    env.pop("NESPM_DATA_DIR", None)
    proc = subprocess.Popen(console_script() + argv + ["--backend", "dask", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    killed_key, written_at_kill = None, None

    def kill_the_held_worker() -> bool:
        nonlocal killed_key, written_at_kill
        if not (hold / "held").exists():
            return False
        pid, killed_key = (hold / "held").read_text().split()
        written_at_kill = len(list((out / "chunks").glob("metrics-*.parquet")))
        os.kill(int(pid), signal.SIGKILL)
        return True

    try:
        wait_until(kill_the_held_worker, "a worker holding a chunk was killed", proc=proc)
        stdout, stderr = proc.communicate(timeout=WAIT_BOUND)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        if killed_key is None and (hold / "held").exists():  # failed before the kill: free the held worker
            os.kill(int((hold / "held").read_text().split()[0]), signal.SIGKILL)
        client.unregister_worker_plugin("nespm-test-hold-one-chunk")
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stdout + stderr
    assert sorted(p.name for p in (out / "chunks").glob("metrics-*.parquet")) == sorted(CHUNKS)
    m = metrics(out)
    assert len(m) == RUNS * len(FILTERS) and not m.duplicated(KEY).any()
    pd.testing.assert_frame_equal(m, metrics(mc_dask), check_exact=True)
    pd.testing.assert_frame_equal(pd.read_parquet(out / "epochs.parquet"), pd.read_parquet(mc_dask / "epochs.parquet"),
                                  check_exact=True)
    assert 1 <= written_at_kill < len(CHUNKS), written_at_kill  # killed mid-run, a chunk written before
    starts = [t for t in lc.scheduler.story(killed_key) if t[0] == killed_key and t[2] == "processing"]
    assert len(starts) >= 2, f"{killed_key} was not re-run after its worker died"
    client.wait_for_workers(2, timeout=WAIT_BOUND)  # the nanny restarts the killed worker for the next tests


def test_half_written_chunk_is_recomputed_without_duplicates(root, argv, cluster, mc_dask):
    """The state a worker killed between its file writes leaves: a series file without its
    metrics file, and a temporary file. Re-running computes that filter's chunk again."""
    d = root / "P"
    shutil.copytree(mc_dask, d)
    (d / "metrics.parquet").unlink()
    (d / "chunks" / "metrics-5-ukf-nespm-000002.parquet").unlink()  # its series file stays
    (d / "chunks" / ".metrics-5-ukf-nespm-000002.parquet.12345.tmp").write_bytes(b"half a parquet file")
    redone = {"metrics-5-ukf-nespm-000002.parquet", "series-5-ukf-nespm-000002.parquet"}
    before = chunk_mtimes(d)
    mc(d, *argv, "--backend", "dask", "--scheduler", cluster[0].scheduler_address)
    after = chunk_mtimes(d)
    assert set(after) == set(before) | redone
    assert {k: v for k, v in after.items() if k not in redone} == {k: v for k, v in before.items() if k not in redone}
    m = metrics(d)
    assert len(m) == RUNS * len(FILTERS) and not m.duplicated(KEY).any()
    pd.testing.assert_frame_equal(m, metrics(mc_dask), check_exact=True)
    pd.testing.assert_frame_equal(pd.read_parquet(d / "epochs.parquet"), pd.read_parquet(mc_dask / "epochs.parquet"),
                                  check_exact=True)


# --------------------------------------------------------------------------- errors on workers


def test_worker_without_data_folder(tmp_path, cluster):
    """What a worker lacking --data-dir does: load_track's NespmError, one line, at the client."""
    spec = Spec(tracks=(5,), runs=2, filters=("ekf",), chunk_size=2, data_dir=str(tmp_path / "no-such-data"))
    (tmp_path / "out" / "chunks").mkdir(parents=True)
    it = parallel_map(run_chunk, [(Cell(spec), 5, 0, str(tmp_path / "out"))], 1, "dask", cluster[0].scheduler_address)
    with pytest.raises(NespmError) as info:
        list(it)  # how soon: benchmarks/bench_claims.py (dask-worker-error)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1
    assert "no-such-data: data directory not found" in msg and "on Dask worker host" in msg
    assert not list((tmp_path / "out" / "chunks").iterdir())


def test_worker_cannot_write_out_folder(tmp_path, cluster, data_dir):
    """A worker that does not see --out (not a shared filesystem): one-line NespmError."""
    spec = Spec(tracks=(5,), runs=2, filters=("ekf",), chunk_size=2, data_dir=str(data_dir))
    it = parallel_map(run_chunk, [(Cell(spec), 5, 0, str(tmp_path / "not-shared"))], 1, "dask",
                      cluster[0].scheduler_address)
    with pytest.raises(NespmError) as info:
        list(it)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1
    assert "not-shared" in msg and "on Dask worker host" in msg and "same path" in msg


def test_own_local_cluster_is_started_and_closed():
    """No scheduler anywhere: parallel_map starts a LocalCluster of ``jobs`` workers and stops it."""
    psutil = pytest.importorskip("psutil")
    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    it = parallel_map(pow, [(2, i) for i in range(6)], 2, "dask", None)
    during = {p.pid for p in me.children(recursive=True)} - before
    assert len(during) >= 2  # the workers (and their nannies' processes) exist before iteration
    assert sorted(it) == [2 ** i for i in range(6)]

    def left() -> set[int]:
        return {p.pid for p in me.children(recursive=True) if p.is_running() and p.status() != psutil.STATUS_ZOMBIE}

    # the processes end once the iterator is exhausted (the bound is a hang-guard: a leaked
    # process never ends and fails it)
    wait_until(lambda: not (left() & during), "the local cluster's processes to end after the iterator "
               "(they outlived it?)", bound=120, step=0.1)


# --------------------------------------------------------------------------- eager validation


def test_unknown_backend_fails_at_call_time():
    with pytest.raises(NespmError, match="--backend must be one of loky, dask"):
        parallel_map(pow, [(2, 1)], 1, "ray")  # a plain call, not yet iterated


def test_without_distributed_the_call_fails_before_anything_starts(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(NespmError, match=r"pip install 'nespm\[dask\]'"):
        check_backend("dask")
    with pytest.raises(NespmError, match=r"pip install 'nespm\[dask\]'"):
        parallel_map(pow, [(2, 1)], 1, "dask", None)


def test_without_distributed_cli_exits_2(tmp_path, argv):
    code = "import sys; sys.modules['distributed'] = None; from nespm_cli.cli import main; sys.exit(main())"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NESPM_")}
    r = subprocess.run([sys.executable, "-c", code, *argv, "--backend", "dask", "--out", str(tmp_path / "X")],
                       capture_output=True, text=True, env=env, timeout=WAIT_BOUND)
    assert_one_error_line(r.returncode, r.stdout, r.stderr, "--backend dask", "pip install 'nespm[dask]'")
    assert not list((tmp_path / "X" / "chunks").glob("*.parquet")), "chunks were computed"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_bogus_scheduler_address(tmp_path, argv):
    """No scheduler at the address: one line naming it, exit 2 (how soon: benchmarks/bench_claims.py)."""
    for address in (f"tcp://127.0.0.1:{_free_port()}", "no-port-here"):
        rc, out, err = nespm(*argv, "--backend", "dask", "--scheduler", address, "--out", tmp_path / "X")
        assert_one_error_line(rc, out, err, f"--scheduler {address}")
        assert not (tmp_path / "X" / "chunks").exists() or not list((tmp_path / "X" / "chunks").glob("*.parquet"))


def test_silent_scheduler_address_times_out(tmp_path, argv, monkeypatch):
    """A port that accepts connections but never speaks: the connect timeout (NESPM_DASK_TIMEOUT,
    named in the message), not a hang. How soon it returns: benchmarks/bench_claims.py."""
    monkeypatch.setenv("NESPM_DASK_TIMEOUT", "2")
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        address = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        rc, out, err = nespm(*argv, "--backend", "dask", "--scheduler", address, "--out", tmp_path / "X")
    assert_one_error_line(rc, out, err, f"--scheduler {address}", "within 2 s")
