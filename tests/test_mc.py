"""End-to-end tests of ``nespm mc`` (nespm_cli.experiments.mc.run_mc through nespm_cli.cli.main).

Checked: results do not depend on --jobs (bit for bit) nor on --chunk-size (to 1e-12); an
interrupted experiment (a deleted chunk, or a process killed mid-run) resumes by computing
only the missing chunks and ends with the uninterrupted numbers; a different command on an
existing folder is refused; metrics/epochs/manifest follow docs/results-schema.md; every
filter sees the same realization; the outage scenario switches the DVL off exactly for
[start, start + length); ``nespm report`` renders the tables.

The experiments run on ``short_data_dir`` (conftest): embedded track 5 cut to its first
SHORT_EPOCHS (80) epochs, written as an A-KIT folder, so a fresh clone suffices. One filter
over it is ~1-2 s whatever the number of runs in the batch (the full 400 s track: ~6 s ins,
~10 s ekf), so the experiments are tiny (track 5, 4 runs, ins and ekf) and each one is
computed once per module (module-scoped fixtures) and shared by the tests that read it.
One test (``test_mc_on_real_track``) runs mc on the real Snapir track 5 and is skipped
without the real data (conftest.real_data_dir).
"""
from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import (SHORT_EPOCHS, WAIT_BOUND, assert_one_error_line, chunk_mtimes, console_script, nespm,
                      short_track, slow_env, wait_until)
from nespm_cli.data.tracks import load_track, write_akit

SCHEMA_DOC = Path(__file__).resolve().parents[1] / "docs" / "results-schema.md"
KEY = ["track", "filter", "run"]
N = SHORT_EPOCHS  # epochs of the short track 5
# the outage window [OUTAGE_START, OUTAGE_START + OUTAGE_LENGTH) s, inside the ~79 s short track with
# 20 s of steady aided navigation before it and ~19 s after it
OUTAGE_START, OUTAGE_LENGTH = 40.0, 20.0

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

RUNS = 4


@pytest.fixture(scope="module")
def base(short_data_dir) -> list[str]:
    return ["mc", "--tracks", "5", "--runs", str(RUNS), "--data-dir", str(short_data_dir), "--no-progress"]


@pytest.fixture(scope="module")
def ins_ekf(base) -> list[str]:
    return base + ["--filters", "ins,ekf"]


@pytest.fixture(scope="module")
def ins(base) -> list[str]:
    return base + ["--filters", "ins"]


def mc(out: Path, *argv) -> Path:
    rc, stdout, stderr = nespm(*argv, "--out", out)
    assert rc == 0, stderr
    assert "Traceback" not in stdout + stderr
    assert "metrics.parquet" in stdout and f"nespm report {out}" in stdout
    return out


def metrics(d: Path) -> pd.DataFrame:
    return pd.read_parquet(d / "metrics.parquet")


def epochs(d: Path) -> pd.DataFrame:
    return pd.read_parquet(d / "epochs.parquet")


def no_seconds(df: pd.DataFrame) -> pd.DataFrame:
    """``seconds`` (wall time) and ``kernels`` (which loop computed the same numbers) are the only
    columns allowed to differ between equal experiments."""
    return df.drop(columns=["seconds", "kernels"])


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("mc")


@pytest.fixture(scope="module")
def mc_a(root, ins_ekf) -> Path:
    """ins + ekf, 2 chunks of 2 runs, 2 worker processes."""
    return mc(root / "A", *ins_ekf, "--chunk-size", "2", "--jobs", "2")


@pytest.fixture(scope="module")
def mc_b(root, ins_ekf) -> Path:
    """The same experiment as A, in-process (--jobs 1). Read-only for the tests using it."""
    return mc(root / "B", *ins_ekf, "--chunk-size", "2", "--jobs", "1")


@pytest.fixture(scope="module")
def mc_c(root, ins_ekf) -> Path:
    """The same experiment as A, one chunk of 4 runs."""
    return mc(root / "C", *ins_ekf, "--chunk-size", "4", "--jobs", "1")


@pytest.fixture(scope="module")
def mc_ins(root, ins) -> Path:
    """ins alone, chunking as in C (one chunk of 4 runs)."""
    return mc(root / "E", *ins, "--chunk-size", "4", "--jobs", "1")


# --------------------------------------------------------------------------- determinism


def test_jobs_do_not_change_results(mc_a, mc_b):
    """--jobs 2 (two loky workers) and --jobs 1 give the same metrics, epochs and series bit for bit."""
    a, b = metrics(mc_a), metrics(mc_b)
    assert len(a) == 2 * RUNS
    pd.testing.assert_frame_equal(no_seconds(a), no_seconds(b), check_exact=True)
    pd.testing.assert_frame_equal(epochs(mc_a), epochs(mc_b), check_exact=True)
    for p in (mc_a / "chunks").glob("series-*.parquet"):
        pd.testing.assert_frame_equal(pd.read_parquet(p), pd.read_parquet(mc_b / "chunks" / p.name), check_exact=True)
    assert not a.loc[a["filter"] == "ekf", "diverged"].any()


def test_chunk_size_does_not_change_results(mc_a, mc_c):
    """Chunk size changes only how many runs share a batch, and each run's numbers come from
    its own streams, so the results agree, but not bit for bit: numpy's SIMD loops for the
    transcendental functions (sin, cos, exp, sqrt...) handle the tail elements that do not fill a
    vector register with another code path, and the batched matrix products may take other
    kernels, so the same run at another position / in another batch length can round
    differently in the last ulp, and the closed-loop filters carry that over the track."""
    a, c = metrics(mc_a), metrics(mc_c)
    assert len(c) == len(a) == 2 * RUNS
    m = a.merge(c, on=KEY, suffixes=("_a", "_c"), validate="one_to_one")
    assert len(m) == len(a)
    for col in ("vrmse", "mrmse", "nees", "sse_vel", "sse_att", "max_vel_err", "max_att_err"):
        x, y = m[f"{col}_a"].to_numpy(), m[f"{col}_c"].to_numpy()
        assert np.array_equal(np.isnan(x), np.isnan(y)), col
        ok = ~np.isnan(x)
        np.testing.assert_allclose(y[ok], x[ok], rtol=1e-12, atol=0, err_msg=col)
    assert (m["n_samples_a"] == m["n_samples_c"]).all()
    assert (m["diverged_a"] == m["diverged_c"]).all()
    # the ins filter has no covariance: NaN NEES; the ekf one is finite
    assert m.loc[m["filter"] == "ins", "nees_a"].isna().all()
    assert m.loc[m["filter"] == "ekf", "nees_a"].notna().all()
    # the runs are different realizations
    assert m.loc[m["filter"] == "ekf", "vrmse_a"].nunique() == RUNS


def test_same_realization_for_every_filter(mc_c, mc_ins):
    """The ins errors depend only on the realization: running ins alone or next to ekf gives
    identical ins rows, per-epoch means and per-run per-epoch errors (the chunk series files,
    which also hold the runs that metrics.parquet marks diverged, i.e. NaN)."""
    alone = metrics(mc_ins)
    both = metrics(mc_c)
    assert set(alone["filter"]) == {"ins"} and len(alone) == RUNS
    pd.testing.assert_frame_equal(no_seconds(alone),
                                  no_seconds(both[both["filter"] == "ins"].reset_index(drop=True)),
                                  check_exact=True)
    ea, ec = epochs(mc_ins), epochs(mc_c)
    pd.testing.assert_frame_equal(ea, ec[ec["filter"] == "ins"].reset_index(drop=True), check_exact=True)
    name = "series-5-ins-000000.parquet"
    pd.testing.assert_frame_equal(pd.read_parquet(mc_ins / "chunks" / name),
                                  pd.read_parquet(mc_c / "chunks" / name), check_exact=True)


def test_run_matches_mc_row(mc_b, short_data_dir):
    """`nespm run --run r` is run r of `nespm mc` (same realization; batch of 1 instead of 2).

    A diverged run has NaN metrics, so the comparison uses the last run that did not diverge
    (free INS is only marked diverged on a non-finite solution: all of them here)."""
    m = metrics(mc_b)
    m = m[m["filter"] == "ins"].set_index("run")
    ok = m.index[~m["diverged"]]
    assert len(ok) >= 1
    run = int(ok[-1])
    rc, out, err = nespm("run", "--track", "5", "--filter", "ins", "--run", run, "--json", "--data-dir",
                         short_data_dir)
    assert rc == 0, err
    s = json.loads(out)
    row = m.loc[run]
    assert s["run"] == run and s["diverged"] is False
    for col in ("vrmse", "mrmse", "max_vel_err", "max_att_err"):
        assert s[col] == pytest.approx(row[col], rel=1e-12, abs=0), col


# --------------------------------------------------------------------------- resume


def test_resume_recomputes_only_the_deleted_chunk(mc_b, root, ins_ekf):
    d = root / "D"
    shutil.copytree(mc_b, d)  # a completed run of the same command
    started = json.loads((d / "manifest.json").read_text())["started"]
    gone = ["metrics-5-ins-000002.parquet", "series-5-ins-000002.parquet"]
    for name in gone:
        (d / "chunks" / name).unlink()
    (d / "metrics.parquet").unlink()
    before = chunk_mtimes(d)
    assert len(before) == 6

    # --jobs is not part of the experiment's identity: another value resumes
    mc(d, *ins_ekf, "--chunk-size", "2", "--jobs", "2")
    after = chunk_mtimes(d)
    assert set(after) == set(before) | set(gone)
    assert {k: after[k] for k in before} == before, "an existing chunk file was rewritten"

    m = metrics(d)
    assert not m.duplicated(KEY).any()
    assert len(m) == 2 * RUNS
    pd.testing.assert_frame_equal(no_seconds(m), no_seconds(metrics(mc_b)), check_exact=True)
    pd.testing.assert_frame_equal(epochs(d), epochs(mc_b), check_exact=True)
    man = json.loads((d / "manifest.json").read_text())
    assert man["started"] == started and man["finished"] is not None

    # a second re-run has nothing to compute and changes nothing
    mtimes = chunk_mtimes(d)
    mc(d, *ins_ekf, "--chunk-size", "2", "--jobs", "1")
    assert chunk_mtimes(d) == mtimes
    pd.testing.assert_frame_equal(no_seconds(metrics(d)), no_seconds(m), check_exact=True)


def test_resume_after_killed_process(mc_b, root, ins):
    """Kill a real `nespm mc` (SIGTERM) after its first of two chunks, re-run the same command.

    The uninterrupted reference is B's ins rows: same realizations and chunking, and the ins
    results do not depend on the other filters (test_same_realization_for_every_filter)."""
    f = root / "F"
    argv = ins + ["--chunk-size", "2", "--jobs", "1", "--out", str(f)]
    proc = subprocess.Popen(console_script() + argv[:], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=slow_env())  # the NumPy loop: chunks of seconds, so the kill lands between them
    try:
        wait_until(lambda: list((f / "chunks").glob("metrics-*.parquet")), "its first chunk file", proc=proc)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=WAIT_BOUND)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode != 0
    assert not (f / "metrics.parquet").exists(), "the process finished before it was killed"
    done = sorted(p.name for p in (f / "chunks").glob("metrics-*.parquet"))
    assert done == ["metrics-5-ins-000000.parquet"]
    assert json.loads((f / "manifest.json").read_text())["finished"] is None
    before = chunk_mtimes(f)

    mc(f, *argv[:-2])
    after = chunk_mtimes(f)
    assert {k: after[k] for k in before} == before, "a finished chunk was recomputed"
    assert sorted(p.name for p in (f / "chunks").glob("metrics-*.parquet")) == [
        "metrics-5-ins-000000.parquet", "metrics-5-ins-000002.parquet"]
    m = metrics(f)
    assert not m.duplicated(KEY).any() and len(m) == RUNS
    mb, eb = metrics(mc_b), epochs(mc_b)
    pd.testing.assert_frame_equal(no_seconds(m), no_seconds(mb[mb["filter"] == "ins"].reset_index(drop=True)),
                                  check_exact=True)
    pd.testing.assert_frame_equal(epochs(f), eb[eb["filter"] == "ins"].reset_index(drop=True), check_exact=True)
    for first in (0, 2):
        name = f"series-5-ins-{first:06d}.parquet"
        pd.testing.assert_frame_equal(pd.read_parquet(f / "chunks" / name), pd.read_parquet(mc_b / "chunks" / name),
                                      check_exact=True)
    assert json.loads((f / "manifest.json").read_text())["finished"] is not None


@pytest.mark.parametrize("extra,differs", [
    (["--seed", "1"], ["seed"]),
    (["--seed", "1", "--chunk-size", "4"], ["chunk_size", "seed"]),
    # more runs extend a folder (test_extend.py): with another seed, only the seed is named
    (["--seed", "1", "--runs", "5"], ["seed"]),
    (["--chunk-size", "4"], ["chunk_size"]),
    # the default window [180, 200) s does not fit the short track: its start differs too
    (["--scenario", "outage", "--outage-start", "40"], ["outage_start", "scenario"]),
])
def test_different_command_on_existing_folder(mc_b, ins_ekf, extra, differs):
    manifest = (mc_b / "manifest.json").read_bytes()
    mtimes = chunk_mtimes(mc_b)
    argv = ins_ekf + ["--chunk-size", "2", "--jobs", "1"]
    for i in range(0, len(extra), 2):  # later options override earlier ones
        argv += extra[i:i + 2]
    rc, out, err = nespm(*argv, "--out", mc_b)
    line = assert_one_error_line(rc, out, err, "differs in: ")
    named = re.search(r"differs in: ([^)]*)\)", line)
    assert named, line
    assert sorted(x.strip() for x in named.group(1).split(",")) == differs
    assert (mc_b / "manifest.json").read_bytes() == manifest
    assert chunk_mtimes(mc_b) == mtimes


# --------------------------------------------------------------------------- schema


def _doc_columns(title: str) -> dict[str, str]:
    """Column -> documented type of the table under the heading containing ``title``."""
    text = SCHEMA_DOC.read_text()
    section = text.split(f"## `DIR/{title}`", 1)[1].split("\n## ", 1)[0]
    cols: dict[str, str] = {}
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        for name in re.findall(r"`([^`]+)`", cells[0]):
            cols[name] = cells[1]
    return cols


def _check_dtypes(df: pd.DataFrame, documented: dict[str, str], inherited: dict[str, str]) -> None:
    for col, typ in documented.items():
        typ = typ or inherited[col]
        dt = df[col].dtype
        if typ == "string":
            assert pd.api.types.is_string_dtype(dt), (col, dt)
        elif typ == "bool":
            assert dt == np.bool_, (col, dt)
        else:
            assert dt == np.dtype(typ), (col, dt, typ)


def test_metrics_schema(mc_b):
    documented = _doc_columns("metrics.parquet")
    assert "vrmse" in documented and "seconds" in documented
    m = metrics(mc_b)
    # a per-sensor column pattern stands for one column per sensor of the run (the DVL here)
    documented = {c.replace("<sensor>", "dvl"): t for c, t in documented.items()}
    # the robust update's counts: only in a folder where some filter has one (tests/test_robust_counts.py)
    documented = {c: t for c, t in documented.items() if not c.startswith(("rejected_", "applied_", "downweighted_"))}
    assert sorted(m.columns) == sorted(documented)
    _check_dtypes(m, documented, {})
    assert len(m) == 1 * 2 * RUNS
    assert not m.duplicated(KEY).any()
    assert sorted(zip(m["track"], m["filter"], m["run"])) == [(5, f, r) for f in ("ekf", "ins") for r in range(RUNS)]
    assert (m["scenario"] == "nominal").all() and (m["schedule"] == "constant").all() and (m["seed"] == 0).all()
    assert (m["n_samples"] == N).all()
    np.testing.assert_allclose(m["vrmse"], np.sqrt(m["sse_vel"] / m["n_samples"]), rtol=1e-15)
    np.testing.assert_allclose(m["mrmse"], np.sqrt(m["sse_att"] / m["n_samples"]), rtol=1e-15)
    assert (m["seconds"] > 0).all()
    # a diverged run's error sums are NaN, every other run's are finite
    for col in ("vrmse", "mrmse", "sse_vel", "sse_att", "max_vel_err", "max_att_err"):
        np.testing.assert_array_equal(m[col].isna().to_numpy(), m["diverged"].to_numpy(), err_msg=col)
    ok = ~m["diverged"]
    assert (m.loc[ok, "max_vel_err"] >= m.loc[ok, "vrmse"]).all()
    # every run counts: a lost run keeps its errors up to the point it was lost, with that time
    np.testing.assert_allclose(m.loc[ok, "vrmse_alive"], m.loc[ok, "vrmse"], rtol=1e-12)
    assert m.loc[ok, "lost_at"].isna().all()
    lost = m[m["diverged"]]
    assert np.isfinite(lost["lost_at"]).all() and np.isfinite(lost["vrmse_alive"]).all()  # (unit: test_metrics)
    ekf = m[m["filter"] == "ekf"]
    assert not ekf["diverged"].any() and np.isfinite(ekf["nees"]).all()
    # the filter helps: the DVL-aided ekf beats free-running ins (diverged or not) on every realization
    piv = m.pivot(index="run", columns="filter", values="vrmse")
    assert (piv["ekf"] < piv["ins"].fillna(np.inf)).all()


def test_epochs_schema(mc_b, short_data_dir):
    documented = _doc_columns("epochs.parquet")
    assert "vel_err_mean" in documented and "north_true" in documented
    # a per-sensor column pattern stands for one column per sensor of the run (the DVL here)
    documented = {c.replace("<sensor>", "dvl"): t for c, t in documented.items()}
    # the per-component columns exist with --save-series axes only (tests/test_consistency.py)
    documented = {c: t for c, t in documented.items() if "<label>" not in c and "<block>" not in c}
    e = epochs(mc_b)
    # the bound's pcrb_<label>: one per component of the 12 states (docs/pcrb.md)
    assert sorted(c for c in e.columns if c.startswith("pcrb_")) == sorted(
        f"pcrb_{lab}" for lab in ("dvN", "dvE", "dvD", "dpsiN", "dpsiE", "dpsiD", "baX", "baY", "baZ", "bgX", "bgY", "bgZ"))
    e = e[[c for c in e.columns if not c.startswith("pcrb_")]]
    assert sorted(e.columns) == sorted(documented)
    _check_dtypes(e, documented, _doc_columns("metrics.parquet"))
    m = metrics(mc_b)
    track = load_track(5, short_data_dir)
    n = len(track.t)
    assert n == N
    assert len(e) == 1 * 2 * n
    assert not e.duplicated(["track", "filter", "epoch"]).any()
    for filt, g in e.groupby("filter"):
        np.testing.assert_array_equal(g["epoch"].to_numpy(), np.arange(n))
        np.testing.assert_allclose(g["t"].to_numpy(), track.t - track.t[0], rtol=0, atol=1e-6)
        assert (g["n_runs"] == RUNS - m.loc[m["filter"] == filt, "diverged"].sum()).all()
        assert g["north_true"].iloc[0] == 0.0 and g["east_true"].iloc[0] == 0.0
        if filt == "ins":  # free inertial: never aided
            assert not g["dvl_used"].any()
        else:
            assert not g["dvl_used"].iloc[0] and g["dvl_used"].iloc[1:].all()
    # per-epoch means (over non-diverged runs) agree with the per-run sums of metrics.parquet
    for filt, g in e.groupby("filter"):
        runs = m[(m["filter"] == filt) & ~m["diverged"]]
        mean_sq = (g["vel_err_std"] ** 2 + g["vel_err_mean"] ** 2).sum()  # sum over epochs of mean over runs of err²
        assert mean_sq == pytest.approx(runs["sse_vel"].mean(), rel=1e-9)


def test_manifest(mc_b, short_data_dir):
    man = json.loads((mc_b / "manifest.json").read_text())
    for key in ("command", "options", "seed", "versions", "git_commit", "started", "finished", "wall_seconds",
                "chunks", "chunk_seconds", "data_dir"):
        assert key in man, key
    assert isinstance(man["command"], list) and all(isinstance(a, str) for a in man["command"])
    assert man["seed"] == 0 and man["options"]["seed"] == 0
    opts = man["options"]
    assert opts["tracks"] == [5] and opts["runs"] == RUNS and opts["filters"] == ["ins", "ekf"]
    assert opts["chunk_size"] == 2 and opts["scenario"] == "nominal" and opts["data_dir"] == str(short_data_dir)
    assert man["data_dir"] == str(short_data_dir)
    for lib in ("python", "nespm", "numpy", "scipy", "pandas", "pyarrow", "joblib"):
        assert isinstance(man["versions"].get(lib), str) and man["versions"][lib], lib
    assert man["versions"]["numpy"] == np.__version__
    assert man["git_commit"] is None or re.fullmatch(r"[0-9a-f]{40}", man["git_commit"])
    from datetime import datetime

    started = datetime.fromisoformat(man["started"])
    finished = datetime.fromisoformat(man["finished"])
    assert started.utcoffset().total_seconds() == 0 and started <= finished
    assert man["wall_seconds"] > 0
    assert man["chunks"] == 2 and len(man["chunk_seconds"]) == 2 * 2


def test_manifest_command_is_the_nespm_command(mc_b):
    command = json.loads((mc_b / "manifest.json").read_text())["command"]
    assert "mc" in command and "--runs" in command


# --------------------------------------------------------------------------- outage


@pytest.fixture(scope="module")
def mc_outage(root, short_data_dir) -> Path:
    """ekf, runs 0 and 1 (B's first chunk), DVL off for [40, 60) s of the ~79 s short track."""
    return mc(root / "G", "mc", "--tracks", "5", "--runs", "2", "--data-dir", short_data_dir, "--no-progress",
              "--filters", "ekf", "--chunk-size", "2", "--jobs", "1",
              "--scenario", "outage", "--outage-start", OUTAGE_START, "--outage-length", OUTAGE_LENGTH)


def test_outage(mc_outage, mc_b):
    start, end = OUTAGE_START, OUTAGE_START + OUTAGE_LENGTH
    e = epochs(mc_outage)
    assert set(e["filter"]) == {"ekf"} and len(e) == N
    t = e["t"].to_numpy()
    assert t[-1] > end + 10.0  # the window lies well inside the track
    used = e["dvl_used"].to_numpy()
    expected = ~((t >= start) & (t < end))
    expected[0] = False
    np.testing.assert_array_equal(used, expected)
    assert 15 <= (~used[1:]).sum() <= 21  # ~20 epochs at ~1 Hz
    err = e["vel_err_mean"].to_numpy()
    during = err[(t >= start) & (t < end)].mean()
    before = err[(t >= start - 20) & (t < start)].mean()
    assert during > before, (during, before)
    m = metrics(mc_outage)
    assert (m["scenario"] == "outage").all() and len(m) == 2
    # the outage changes nothing before it starts: same runs, same batch as B's first chunk
    sb = pd.read_parquet(mc_b / "chunks" / "series-5-ekf-000000.parquet")
    so = pd.read_parquet(mc_outage / "chunks" / "series-5-ekf-000000.parquet")
    assert len(sb) == len(so) == 2 * N
    pre = so["t"] < start
    np.testing.assert_array_equal(so.loc[pre, "vel_err"].to_numpy(), sb.loc[pre, "vel_err"].to_numpy())
    assert not np.array_equal(so.loc[~pre, "vel_err"].to_numpy(), sb.loc[~pre, "vel_err"].to_numpy())


# --------------------------------------------------------------------------- report


def test_report(mc_b, root):
    """nespm report of a finished mc folder writes report.md with a table row per filter and names its path."""
    d = root / "R"
    shutil.copytree(mc_b, d)
    rc, out, err = nespm("report", d, "--n-boot", "200")
    assert rc == 0, err
    assert "Traceback" not in out + err
    md = (d / "report.md").read_text()
    table = [line for line in md.splitlines() if line.startswith("|")]
    assert any(re.fullmatch(r"\|(\s*:?-{3,}:?\s*\|)+", line.replace(" ", "")) for line in table), "no table separator"
    for filt in ("ins", "ekf"):
        assert any(re.search(rf"\|\s*{filt}\s*\|", line) for line in table), f"no table row for {filt}"
    assert str(d / "report.md") in out


# --------------------------------------------------------------------------- every run diverged


def test_every_run_diverged(tmp_path):
    """A free INS fed an absurd accelerometer bias (1e200 m/s²) overflows to a non-finite
    solution: every run is marked diverged and mc still finishes with its tables."""
    write_akit(short_track(1, 31), tmp_path / "data")
    rc, out, err = nespm("mc", "--tracks", "1", "--runs", "2", "--filters", "ins", "--acc-bias", "1e200",
                         "--chunk-size", "2", "--jobs", "1", "--no-progress", "--data-dir", tmp_path / "data",
                         "--out", tmp_path / "out")
    assert rc == 0, err
    assert "Traceback" not in out + err
    assert metrics(tmp_path / "out")["diverged"].all()
    assert (tmp_path / "out" / "epochs.parquet").exists()


# --------------------------------------------------------------------------- the real data


def test_mc_on_real_track(real_data_dir, tmp_path):
    """The one end-to-end mc on recorded files (skipped without them): real Snapir track 5,
    2 runs of ekf in one chunk; every other test here runs on the short embedded track."""
    out = mc(tmp_path / "real", "mc", "--tracks", "5", "--runs", "2", "--filters", "ekf", "--chunk-size", "2",
             "--jobs", "1", "--no-progress", "--data-dir", real_data_dir)
    m = metrics(out)
    track = load_track(5, real_data_dir)
    n = len(track.t)
    assert n == 400 and track.source == str(real_data_dir / "Trajectory5")
    assert sorted(zip(m["track"], m["filter"], m["run"])) == [(5, "ekf", 0), (5, "ekf", 1)]
    assert (m["n_samples"] == n).all() and not m["diverged"].any()
    assert np.isfinite(m["nees"]).all() and (m["nees"] > 0).all()
    assert (m["vrmse"] > 0).all() and (m["vrmse"] < 1.0).all()  # DVL-aided: well below the 0.3 m/s² free drift
    np.testing.assert_allclose(m["vrmse"], np.sqrt(m["sse_vel"] / m["n_samples"]), rtol=1e-15)
    e = epochs(out)
    assert len(e) == n and (e["n_runs"] == 2).all()
    np.testing.assert_allclose(e["t"].to_numpy(), track.t - track.t[0], rtol=0, atol=1e-6)
    assert not e["dvl_used"].iloc[0] and e["dvl_used"].iloc[1:].all()
    assert json.loads((out / "manifest.json").read_text())["data_dir"] == str(real_data_dir)


# --------------------------------------------------------------------------- issue 16's filters

def test_invariant_and_cubature_filters_do_not_depend_on_jobs_or_chunks(tmp_path, short_data_dir):
    """iekf, ckf and ckf-nespm through mc: 2 chunks of 2 runs on 2 workers against one chunk of
    4 runs in-process. Each run is its own iteration of the compiled loop, so the numbers are
    the same bits (the NumPy reference would allow last-ulp differences, see above)."""
    base = ["mc", "--data-dir", short_data_dir, "--tracks", "5", "--runs", "4", "--filters", "iekf,ckf,ckf-nespm",
            "--no-progress", "--seed", "5"]
    a = metrics(mc(tmp_path / "a", *base, "--chunk-size", "2", "--jobs", "2"))
    c = metrics(mc(tmp_path / "c", *base, "--chunk-size", "4", "--jobs", "1"))
    assert len(a) == 12 and not a["diverged"].any()
    pd.testing.assert_frame_equal(no_seconds(a), no_seconds(c), check_exact=True)


def test_drift_rate_is_the_final_error_per_hour(mc_b):
    """drift_m_per_h = hpe_final / duration x 3600, the duration the last epoch's time."""
    m, ep = metrics(mc_b), epochs(mc_b)
    for tr, g in m.groupby("track"):
        duration = float(ep.loc[ep["track"] == tr, "t"].max())
        np.testing.assert_allclose(g["drift_m_per_h"], g["hpe_final"] / duration * 3600.0, rtol=1e-12)
    assert (m["drift_m_per_h"] > 0).all()
