"""The per-user kernel cache (nav.kernel_cache.cache_folder, filters.kernels.kernels_cached / warm_up):
a second command with the cache warm neither says nor does any compiling; the cache folder is named
by the kernels' text (a clone elsewhere shares it, an edit does not); an unwritable folder falls back
without a traceback; the kernels a command needs per filter and layout; the common-error Φ kernel
(split from the iekf's branch for its compile time) gives the generic loop's bits."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import console_script, env_without_data_dir
from nespm_cli.experiments.progress import kernels_for
from nespm_cli.filters import kernels
from nespm_cli.nav.state import LAYOUT_15

PACKAGE = Path(kernels.__file__).resolve().parents[1]

needs_numba = pytest.mark.skipif(not kernels.numba_installed(), reason="numba not installed")


def _folder_files(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` with its mtime [ns]: what a compile would add to or rewrite."""
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@needs_numba
def test_warm_cache_no_compile_line_and_nothing_compiled(tmp_path):
    """First `mc` on an empty NESPM_CACHE_DIR says it compiles (and fills the folder); the same
    command again says nothing about compiling and writes nothing into the cache folder."""
    env = {**env_without_data_dir(), "NESPM_CACHE_DIR": str(tmp_path / "cache"), "NESPM_KERNELS": "auto"}
    argv = [*console_script(), "mc", "--tracks", "5", "--runs", "1", "--window", "0:20", "--filters", "ekf", "--jobs", "1"]
    first = subprocess.run([*argv, "--out", str(tmp_path / "a")], env=env, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    assert "mc: compiling the filters' kernels" in first.stderr
    folders = list((tmp_path / "cache").glob("kernels-*"))
    assert len(folders) == 1
    before = _folder_files(folders[0])
    assert any(name.endswith(".nbi") for name in before) and any(name.startswith("ready") for name in before)
    second = subprocess.run([*argv, "--out", str(tmp_path / "b")], env=env, capture_output=True, text=True)
    assert second.returncode == 0, second.stderr
    assert "compil" not in second.stderr, second.stderr
    assert _folder_files(folders[0]) == before  # loaded, not compiled: no index or machine code rewritten
    # what the parent of an mc does before its workers start (the cache check, the manifest's versions)
    # does not import numba (~0.2 s): the workers that run the kernels do
    code = ("import sys; from nespm_cli.experiments.progress import compile_kernels; "
            "from nespm_cli.experiments.store import versions; "
            "print(compile_kernels('mc', stream=None, kernels=('transition',)), versions()['numba'], 'numba' in sys.modules); "
            "import numba; print(numba.__version__)")
    parent = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert parent.returncode == 0, parent.stderr
    checked, version = parent.stdout.split("\n")[:2]
    assert checked == f"None {version} False"


def _folder_of(package_parent: Path, env: dict) -> str:
    code = "from nespm_cli.nav.kernel_cache import cache_folder; print(cache_folder())"
    out = subprocess.run([sys.executable, "-c", code], cwd=package_parent, env={**env, "PYTHONPATH": str(package_parent)},
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@needs_numba
def test_cache_folder_named_by_kernel_text_not_path(tmp_path):
    """A copy of the package elsewhere (a clone, a reinstall) maps to the same cache folder; an edit
    of a kernel source (here a constant's module) maps to another."""
    env = {**env_without_data_dir(), "NESPM_CACHE_DIR": str(tmp_path / "cache")}
    clone = tmp_path / "clone"
    shutil.copytree(PACKAGE, clone / "nespm_cli", ignore=shutil.ignore_patterns("__pycache__"))
    here = _folder_of(PACKAGE.parent, env)
    assert here.startswith(str(tmp_path / "cache" / "kernels-"))
    assert _folder_of(clone, env) == here
    earth = clone / "nespm_cli" / "nav" / "earth.py"
    earth.write_text(earth.read_text() + "\n# edited\n")
    assert _folder_of(clone, env) != here


def test_unwritable_cache_folder_falls_back(tmp_path, monkeypatch):
    """NESPM_CACHE_DIR under a regular file: no folder, no ready marks, kernels_cached None (every
    process compiles or uses numba's own place), and the compile check says nothing; no exception."""
    from nespm_cli.experiments.progress import compile_kernels
    from nespm_cli.nav import kernel_cache as kc

    if not kernels.compiled_enabled():
        pytest.skip("the compiled kernels are not in use here")
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("NESPM_CACHE_DIR", str(blocker / "cache"))
    assert kc.cache_base() == blocker / "cache"
    assert kc.cache_folder() is None and kc.ready_mark("transition") is None
    assert kernels.kernels_cached(("transition",)) is None
    assert compile_kernels("mc", stream=None, kernels=("transition",)) is None


def test_platform_default_and_override(monkeypatch, tmp_path):
    """NESPM_CACHE_DIR wins over NUMBA_CACHE_DIR, which wins over $XDG_CACHE_HOME/nespm."""
    from nespm_cli.nav import user_cache as nk

    for var in ("NESPM_CACHE_DIR", "NUMBA_CACHE_DIR"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if sys.platform.startswith("linux"):
        assert nk.cache_base() == tmp_path / "xdg" / "nespm"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert nk.cache_base() == tmp_path / "numba"
    monkeypatch.setenv("NESPM_CACHE_DIR", str(tmp_path / "nespm"))
    assert nk.cache_base() == tmp_path / "nespm"


def test_kernels_per_filter_and_layout():
    assert kernels_for(["ekf", "ukf", "ukf-nespm"]) == ("transition", "points")
    assert kernels_for(["ekf", "anekf", "iae-ekf", "sh-ekf", "vb-ekf", "ckf"]) == ("transition",)
    assert kernels_for(["ins"]) == ("strapdown", "transition")  # + the PCRB's Φ
    assert kernels_for(["iekf"]) == ("transition", "transition-invariant")
    assert kernels_for(["iekf", "ckf-nespm"], LAYOUT_15) == (
        "transition-position", "transition-invariant-position", "points")
    assert kernels_for(["no-such-filter"]) == ("transition",)
    # batches from LANES_MIN runs: the 12-state Φ with the runs in lanes, beside the PCRB's run by run
    assert kernels_for(["ekf", "ukf-nespm"], runs=kernels.LANES_MIN) == ("transition", "transition-lanes", "points")
    assert kernels_for(["ekf"], runs=kernels.LANES_MIN - 1) == ("transition",)
    assert kernels_for(["ukf-nespm", "ins"], runs=100) == ("strapdown", "transition", "points")  # no Φ of theirs
    assert kernels_for(["ekf"], LAYOUT_15, runs=100) == ("transition-position", "transition-position-lanes")
    assert kernels_for(["ekf"], LAYOUT_15, runs=kernels.LANES_MIN) == ("transition-position",)  # 15 states: from 12
    assert kernels_for(["ekf"], runs=None) == ("transition", "transition-lanes")  # nespm warm-up: any batch
    with pytest.raises(Exception, match="unknown kernel"):
        kernels.warm_up(["no-such-kernel"])


def test_kernel_sources_list_every_compiled_module():
    """The cache key hashes nav.kernel_cache.KERNEL_SOURCES: every module that compiles with njit is in it."""
    from nespm_cli.nav.kernel_cache import KERNEL_SOURCES

    compiled = {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py")
                if re.search(r"^@njit", p.read_text(encoding="utf-8"), re.M)}
    assert compiled <= set(KERNEL_SOURCES)
    assert all((PACKAGE / rel).is_file() for rel in KERNEL_SOURCES)
