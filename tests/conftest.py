"""Shared test helpers and fixtures.

Real Snapir data (A-KIT layout, 13 tracks) is never part of the repository. It is looked for,
once, when this file is imported (before any test can ``monkeypatch.delenv`` the variable):

1. ``$NESPM_DATA_DIR``, if set and an existing folder;
2. ``<repo>/../shared/data/snapir-akit``.

Tests that need it take the session fixture ``real_data_dir`` (skipped, with the reason naming
both places, when neither exists), or, for module-scoped fixtures, parametrize marks and
``skipif`` uses, the module-level ``REAL_DATA`` (a Path or None) and ``needs_real_data`` marker.

Everything else runs on the embedded tracks, or on short cuts of them written as an A-KIT
folder: the session fixture ``short_data_dir`` holds embedded tracks 5 and 6 cut to their first
``SHORT_EPOCHS`` epochs, to be passed as ``--data-dir``.

Helpers (import them with ``from conftest import ...``): ``nespm`` (in-process CLI run ->
``(rc, stdout, stderr)``), ``cli`` (the same, for tests that hold ``capsys``),
``assert_one_error_line``, ``short_track``, ``write_short_tracks``, ``console_script``,
``env_without_data_dir``, ``chunk_mtimes``, ``wait_until`` (event waits with a hang-guard bound).
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from nespm_cli.cli import main
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import ENV_DATA_DIR, Track, write_akit

REPO = Path(__file__).resolve().parents[1]
SIBLING_REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "snapir-akit"


def find_real_data() -> tuple[Path | None, str]:
    """``(folder, reason)``: the real data folder (or None) and, if None, why (both places named)."""
    env = os.environ.get(ENV_DATA_DIR, "").strip()
    if env:
        p = Path(env).expanduser()
        if p.is_dir():
            return p, ""
        env_note = f"${ENV_DATA_DIR}={env} is not an existing folder"
    else:
        env_note = f"${ENV_DATA_DIR} is not set"
    if SIBLING_REAL_DATA.is_dir():
        return SIBLING_REAL_DATA, ""
    return None, f"real Snapir data not found: {env_note}, and {SIBLING_REAL_DATA} does not exist"


def pytest_configure(config) -> None:
    """Under pytest-xdist (``make test`` runs ``-n 2``), compile the numba kernels once in the
    controller, before the workers start, so that they load them from the on-disk cache instead of
    each compiling the same kernels at once (a fresh clone's ~6 s, paid once, not per worker)."""
    if getattr(config, "workerinput", None) is None and getattr(config.option, "numprocesses", None):
        from nespm_cli.filters.kernels import numba_installed, warm_up

        if numba_installed():
            warm_up()


#: The real data folder, resolved at import time (None: not available), and why it is missing.
REAL_DATA, REAL_DATA_REASON = find_real_data()
#: Mark for tests (or ``pytest.param``) that need the real data.
needs_real_data = pytest.mark.skipif(REAL_DATA is None, reason=REAL_DATA_REASON or "real data found")


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """The real Snapir data folder; skips the test (saying where it looked) when there is none."""
    if REAL_DATA is None:
        pytest.skip(REAL_DATA_REASON)
    return REAL_DATA


@pytest.fixture
def no_env_data_dir(monkeypatch):
    """No ``$NESPM_DATA_DIR``: the library's default (no --data-dir) is the embedded tracks,
    whatever the caller's shell has. (REAL_DATA was resolved before this runs.)"""
    monkeypatch.delenv(ENV_DATA_DIR, raising=False)


# --------------------------------------------------------------------------- short tracks

#: Epochs of the short tracks in ``short_data_dir`` (~79 s at the tracks' 400/399 s spacing).
SHORT_EPOCHS = 80
SHORT_TRACKS = (5, 6)


def short_track(number: int = 1, epochs: int = 31) -> Track:
    """The first ``epochs`` epochs of embedded track ``number`` (all fields sliced alike)."""
    tr = embedded_track(number)
    s = slice(0, epochs)
    return Track(number=tr.number, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=tr.euler[s],
                 dvl=tr.dvl[s], imu=None, source="short")


def write_short_tracks(folder: Path, numbers=SHORT_TRACKS, epochs: int = SHORT_EPOCHS) -> Path:
    """Write the short cuts of embedded ``numbers`` into ``folder`` (A-KIT layout); return it."""
    folder = Path(folder)
    for n in numbers:
        write_akit(short_track(n, epochs), folder)
    return folder


@pytest.fixture(scope="session")
def short_data_dir(tmp_path_factory) -> Path:
    """An A-KIT folder with embedded tracks 5 and 6 cut to ``SHORT_EPOCHS`` epochs. Read-only."""
    return write_short_tracks(tmp_path_factory.mktemp("short-data"))


# --------------------------------------------------------------------------- running nespm


def nespm(*argv) -> tuple[int, str, str]:
    """Run ``nespm argv...`` in-process; ``(exit code, stdout, stderr)``. Usable from
    module-scoped fixtures (unlike capsys)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def cli(capsys, *argv) -> tuple[int, str, str]:
    """``nespm argv...`` in-process under capsys; ``(exit code, stdout, stderr)``."""
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_error_line(rc: int, out: str, err: str, *must_contain: str) -> str:
    """Exit code 2, no traceback, exactly one stderr line ``nespm: error: ...`` holding every
    string of ``must_contain``; returns that line."""
    assert rc == 2, (rc, out, err)
    assert "Traceback" not in out + err
    lines = err.splitlines()
    assert len(lines) == 1, f"expected exactly one stderr line, got {lines!r}"
    assert lines[0].startswith("nespm: error: "), lines[0]
    for s in must_contain:
        assert s in lines[0], f"{s!r} not in {lines[0]!r}"
    return lines[0]


def console_script() -> list[str]:
    """The installed ``nespm`` entry point (or ``python -m nespm_cli.cli``) as argv prefix."""
    script = Path(sys.executable).with_name("nespm")
    return [str(script)] if script.exists() else [sys.executable, "-m", "nespm_cli.cli"]


def env_without_data_dir() -> dict[str, str]:
    """``os.environ`` without ``$NESPM_DATA_DIR``, for subprocesses that must use the embedded default."""
    return {k: v for k, v in os.environ.items() if k != ENV_DATA_DIR}


def slow_env() -> dict[str, str]:
    """:func:`env_without_data_dir` with the NumPy reference loop (``NESPM_KERNELS=numpy``): a
    chunk then lasts seconds instead of milliseconds, so a test's signal lands mid-run."""
    return {**env_without_data_dir(), "NESPM_KERNELS": "numpy"}


#: Bound of :func:`wait_until` [s]: a hang-guard, far above anything a loaded machine needs.
WAIT_BOUND = 600.0


def wait_until(condition, what: str, proc=None, bound: float = WAIT_BOUND, step: float = 0.05) -> None:
    """Poll ``condition()`` every ``step`` s until it is true. Fails if ``proc`` (a Popen) ends
    first (saying ``what`` was awaited, with its output) or after ``bound`` seconds: a guard
    against a hang, not a verdict on speed (the test proceeds the moment the event happens).
    Wall-clock speed statements live in benchmarks/, never in tests."""
    import time

    give_up = time.monotonic() + bound
    while not condition():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the process ended before {what}: {proc.communicate()}")
        if time.monotonic() > give_up:
            raise AssertionError(f"hang: still waiting for {what} after {bound:.0f} s")
        time.sleep(step)


def chunk_mtimes(d: Path) -> dict[str, int]:
    """``{file name: mtime_ns}`` of the chunk Parquet files of results folder ``d``."""
    return {p.name: p.stat().st_mtime_ns for p in (Path(d) / "chunks").glob("*.parquet")}


def exact_imu_table(track) -> np.ndarray:
    """(M + 1, 7) IMU file rows ``[t, f_b, w_ib_b]`` of ``track``'s synthesized (exact) IMU, as a
    recorded file holds them: row k > 0 the step ending at t[k]; row 0 repeats the first step."""
    from nespm_cli.nav.synthesis import synthesize

    ref = synthesize(track)
    return np.column_stack([ref.t, np.vstack([ref.f_b[:1], ref.f_b]), np.vstack([ref.w_ib_b[:1], ref.w_ib_b])])
