"""Where results go (issue 30, minor defects of paths): ``--out ''`` is not the current folder; an
``--out`` link to someone's non-empty folder is not written into; a report never draws through an
``OUT/figures`` link; the memory refusal comes before anything is written; a track number beyond
int64 is one line."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from conftest import assert_one_error_line, nespm

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

RUN = ("--tracks", "5", "--runs", "2", "--filters", "ekf", "--no-progress", "--jobs", "1")


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_empty_out_is_refused_and_nothing_is_written(tmp_path, short_data_dir, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for cmd in ("mc", "sweep"):
        extra = ("--param", "misalignment-deg", "--values", "1") if cmd == "sweep" else ()
        rc, out, err = nespm(cmd, "--data-dir", str(short_data_dir), *RUN, *extra, "--out", "")
        assert_one_error_line(rc, out, err, "--out", "empty path")
    assert listing(tmp_path) == []


def test_empty_out_of_export_and_compare_is_refused(tmp_path, short_data_dir, monkeypatch):
    a = tmp_path / "a"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(a))
    assert rc == 0, err
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    assert_one_error_line(*nespm("export", str(a), "--out", ""), "--out", "empty path")
    assert_one_error_line(*nespm("compare", str(a), str(a), "--labels", "x,y", "--out", " ", "--n-boot", "20"),
                          "--out", "empty path")
    assert listing(work) == []


def test_out_link_to_a_foreign_folder_is_refused(tmp_path, short_data_dir):
    theirs = tmp_path / "thesis"
    theirs.mkdir()
    (theirs / "chapter1.tex").write_text("keep me", encoding="utf-8")
    link = tmp_path / "r"
    link.symlink_to(theirs)
    rc, out, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(link))
    assert_one_error_line(rc, out, err, str(link), "symbolic link", str(theirs), "chapter1.tex")
    assert listing(theirs) == ["chapter1.tex"]  # no .lock, manifest or chunks/


def test_out_link_to_an_empty_folder_is_followed(tmp_path, short_data_dir):
    target = tmp_path / "big-disk"
    target.mkdir()
    link = tmp_path / "r"
    link.symlink_to(target)
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(link))
    assert rc == 0, err
    assert (target / "metrics.parquet").is_file()
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(link))  # a results folder: resumed
    assert rc == 0, err


def test_report_does_not_draw_through_a_figures_link(tmp_path, short_data_dir):
    out = tmp_path / "r"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(out))
    assert rc == 0, err
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / "figures").symlink_to(elsewhere)
    rc, o, err = nespm("report", str(out), "--n-boot", "20")
    assert_one_error_line(rc, o, err, str(out / "figures"), "symbolic link")
    assert listing(elsewhere) == [] and not (out / "report.md").exists()
    (out / "figures").unlink()
    rc, _, err = nespm("report", str(out), "--n-boot", "20")
    assert rc == 0, err
    assert (out / "figures").is_dir() and not (out / "figures").is_symlink()


def test_compare_does_not_draw_through_a_figures_link(tmp_path, short_data_dir):
    a = tmp_path / "a"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(a))
    assert rc == 0, err
    b = tmp_path / "b"
    shutil.copytree(a, b)
    out, elsewhere = tmp_path / "c", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "figures").symlink_to(elsewhere)
    rc, o, err = nespm("compare", str(a), str(b), "--out", str(out), "--n-boot", "20")
    assert_one_error_line(rc, o, err, str(out / "figures"), "symbolic link")
    assert listing(elsewhere) == []


def test_memory_refusal_comes_before_anything_is_written(tmp_path, short_data_dir):
    out = tmp_path / "r"
    rc, o, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--filters", "ekf", "--runs",
                       "10000000", "--chunk-size", "10000000", "--no-progress", "--jobs", "1", "--out", str(out))
    assert_one_error_line(rc, o, err, "GB")
    assert not out.exists()  # no manifest.json, .lock or chunks/


@pytest.mark.parametrize("cmd", ["mc", "run"])
def test_track_number_beyond_int64_is_one_line(tmp_path, short_data_dir, cmd):
    big = str(2**64)  # a folder TrajectoryN whose N the tables' int64 column cannot hold
    data = tmp_path / "d" / f"Trajectory{big}"
    data.mkdir(parents=True)
    for f in (short_data_dir / "Trajectory5").iterdir():
        shutil.copy(f, data / f.name.replace("trajectory5", f"trajectory{big}"))
    argv = (("mc", "--tracks", big, "--runs", "1", "--filters", "ekf", "--no-progress", "--jobs", "1", "--out",
             str(tmp_path / "r")) if cmd == "mc" else ("run", "--track", big, "--filter", "ekf", "--json"))
    assert_one_error_line(*nespm(*argv, "--data-dir", str(tmp_path / "d")), big, "int64")
    assert not (tmp_path / "r").exists()
