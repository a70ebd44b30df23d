"""A results folder is read as one consistent state (issue 30, severe): ``compare`` and ``export`` read
exactly what the manifest's last assembly recorded, each chunk verified by its content hash, never a
folder being written, never a table with fewer runs than its manifest, never a stray file of
``chunks/``; a manifest that is not a JSON object is one line."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from conftest import assert_one_error_line, nespm

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

RUN = ("--tracks", "5", "--runs", "4", "--chunk-size", "2", "--no-progress", "--jobs", "1", "--filters", "ekf")


@pytest.fixture(scope="module")
def finished(tmp_path_factory, short_data_dir) -> Path:
    """A finished ekf folder (track 5, 4 runs in 2 chunks) to copy."""
    out = tmp_path_factory.mktemp("snapshot") / "r"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(out))
    assert rc == 0, err
    return out


def copy_of(finished: Path, dst: Path) -> Path:
    shutil.copytree(finished, dst)
    return dst


def hand_edit(path: Path, column: str = "vrmse", factor: float = 2.0) -> None:
    """Change one column of a chunk keeping its Parquet metadata (the chunk identity) as it was."""
    meta = pq.ParquetFile(path).metadata.metadata
    t = pq.read_table(path)
    i = t.schema.get_field_index(column)
    t = t.set_column(i, column, pa.array(t.column(column).to_numpy() * factor))
    w = pq.ParquetWriter(path, t.schema)
    w.write_table(t)
    w.add_key_value_metadata({k: v for k, v in meta.items() if k == b"nespm.chunk"})
    w.close()


def test_hand_edited_chunk_is_named_and_computed_again(tmp_path, finished, short_data_dir):
    out = copy_of(finished, tmp_path / "r")
    before = pd.read_parquet(out / "metrics.parquet")
    victim = out / "chunks" / "metrics-5-ekf-000002.parquet"
    hand_edit(victim)
    assert pd.read_parquet(victim)["vrmse"].iloc[0] == 2 * before["vrmse"].iloc[2]  # the edit is there, rows equal
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(out))
    assert rc == 0, err
    assert str(victim) in err and "edited after it was written" in err and "computing it again" in err
    after = pd.read_parquet(out / "metrics.parquet")
    pd.testing.assert_frame_equal(before.drop(columns="seconds"), after.drop(columns="seconds"))


@pytest.mark.parametrize("text", ["{not json", "[]", '{"options": []}'])
def test_compare_manifest_not_a_json_object_is_one_line(tmp_path, finished, text):
    a, b = copy_of(finished, tmp_path / "a"), copy_of(finished, tmp_path / "b")
    (b / "manifest.json").write_text(text, encoding="utf-8")
    rc, out, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
    assert_one_error_line(rc, out, err, str(b / "manifest.json"))


def test_compare_refuses_a_folder_being_written(tmp_path, finished):
    from nespm_cli.experiments.store import FolderLock

    a, b = copy_of(finished, tmp_path / "a"), copy_of(finished, tmp_path / "b")
    lock = FolderLock(b)  # what an `mc` extending b holds (flock: another open file, so it counts here too)
    try:
        rc, out, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
        assert_one_error_line(rc, out, err, str(b), "is writing this folder now", "compare")
    finally:
        lock.release()
    assert not (tmp_path / "c" / "compare.md").exists()
    rc, _, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
    assert rc == 0, err


def test_compare_refuses_metrics_with_fewer_runs_than_the_manifest(tmp_path, finished):
    a, b = copy_of(finished, tmp_path / "a"), copy_of(finished, tmp_path / "b")
    m = pd.read_parquet(b / "metrics.parquet")
    m[m["run"] < 3].to_parquet(b / "metrics.parquet", index=False)
    rc, out, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
    assert_one_error_line(rc, out, err, str(b / "metrics.parquet"), "not the table nespm assembled")
    # a folder of an older nespm has no record of its tables: the run count itself is checked
    mf = json.loads((b / "manifest.json").read_text())
    mf.pop("assembled")
    (b / "manifest.json").write_text(json.dumps(mf), encoding="utf-8")
    rc, out, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
    assert_one_error_line(rc, out, err, str(b / "metrics.parquet"), "holds 3 runs", "asks for 4")


def test_compare_refuses_an_unfinished_run(tmp_path, finished):
    a, b = copy_of(finished, tmp_path / "a"), copy_of(finished, tmp_path / "b")
    mf = json.loads((b / "manifest.json").read_text())
    mf["finished"] = None  # an extension that was interrupted: the tables are the old ones
    (b / "manifest.json").write_text(json.dumps(mf), encoding="utf-8")
    rc, out, err = nespm("compare", str(a), str(b), "--out", str(tmp_path / "c"), "--n-boot", "20")
    assert_one_error_line(rc, out, err, str(b), "did not finish")


def test_export_series_reads_exactly_the_assembled_chunks(tmp_path, finished):
    out = copy_of(finished, tmp_path / "r")
    chunks = out / "chunks"
    shutil.copy(chunks / "series-5-ekf-000000.parquet", chunks / "series-5-ekf-000000 (conflicted copy).parquet")
    shutil.copy(chunks / "series-5-ekf-000002.parquet", chunks / "series-5-ekf-000000 (2).parquet")
    shutil.copy(chunks / "series-5-ekf-000000.parquet", chunks / "series-5-iekf-000000.parquet")  # another study's
    rc, _, err = nespm("export", str(out), "--series", "--out", str(tmp_path / "csv"))
    assert rc == 0, err
    s = pd.read_csv(tmp_path / "csv" / "series.csv")
    epochs = pd.read_parquet(out / "epochs.parquet")
    assert len(s) == 4 * len(epochs)  # 4 runs x the epochs of one filter: no copy read
    assert sorted(s["run"].unique()) == [0, 1, 2, 3] and set(s["filter"]) == {"ekf"}
    assert (s.groupby("run").size() == len(epochs)).all()


def test_export_refuses_a_hand_edited_series_chunk(tmp_path, finished):
    out = copy_of(finished, tmp_path / "r")
    victim = out / "chunks" / "series-5-ekf-000002.parquet"
    hand_edit(victim, "vel_err")
    rc, o, err = nespm("export", str(out), "--series", "--out", str(tmp_path / "csv"))
    assert_one_error_line(rc, o, err, str(victim), "edited after it was written")


def test_export_and_mc_exclude_each_other(tmp_path, finished, short_data_dir):
    from nespm_cli.experiments.snapshot import ReadLock
    from nespm_cli.experiments.store import FolderLock

    out = copy_of(finished, tmp_path / "r")
    lock = FolderLock(out)  # an mc extending the folder
    try:
        rc, o, err = nespm("export", str(out), "--out", str(tmp_path / "x"))
        assert_one_error_line(rc, o, err, str(out), "is writing this folder now", "export")
    finally:
        lock.release()
    assert not (tmp_path / "x" / "metrics.csv").exists()
    with ReadLock(out, "export"):  # an export reading: mc may not extend the folder under it
        rc, o, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN[:3], "6", *RUN[4:], "--out", str(out))
        assert_one_error_line(rc, o, err, "busy")
    assert json.loads((out / "manifest.json").read_text())["options"]["runs"] == 4


def test_export_refuses_an_interrupted_extension_and_a_replaced_table(tmp_path, finished):
    out = copy_of(finished, tmp_path / "r")
    mf = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**mf, "finished": None}), encoding="utf-8")
    rc, o, err = nespm("export", str(out), "--out", str(tmp_path / "x"))
    assert_one_error_line(rc, o, err, str(out), "did not finish")
    (out / "manifest.json").write_text(json.dumps(mf), encoding="utf-8")
    e = pd.read_parquet(out / "epochs.parquet")
    e.iloc[:3].to_parquet(out / "epochs.parquet", index=False)
    rc, o, err = nespm("export", str(out), "--out", str(tmp_path / "x"))
    assert_one_error_line(rc, o, err, str(out / "epochs.parquet"), "not the table nespm assembled")


def test_folder_of_an_older_version_exports_its_tables_but_not_its_chunks(tmp_path, finished, short_data_dir):
    out = copy_of(finished, tmp_path / "r")
    mf = json.loads((out / "manifest.json").read_text())
    mf.pop("assembled")  # what a folder of the previous version holds
    (out / "manifest.json").write_text(json.dumps(mf), encoding="utf-8")
    rc, _, err = nespm("export", str(out), "--out", str(tmp_path / "x"))
    assert rc == 0, err
    assert len(pd.read_csv(tmp_path / "x" / "metrics.csv")) == 4
    rc, o, err = nespm("export", str(out), "--series", "--out", str(tmp_path / "y"))
    assert_one_error_line(rc, o, err, "no record of the assembled chunks", "re-run the same command")
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), *RUN, "--out", str(out))  # records it, computes nothing
    assert rc == 0, err
    rc, _, err = nespm("export", str(out), "--series", "--out", str(tmp_path / "y"))
    assert rc == 0, err
    assert len(pd.read_csv(tmp_path / "y" / "series.csv")) == 4 * len(pd.read_parquet(out / "epochs.parquet"))
