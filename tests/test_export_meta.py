"""Export for MATLAB and CSV users (issue 30, item 7): every column's unit and the study's metadata in
the .mat (a ``meta`` struct, ``meta.units.<table>.<field>``) and beside the CSVs; texts as char /
cellstr, booleans as logical; the units come from the one copy in code (reports/schema.py), which
docs/results-schema.md's tables must agree with."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.io import loadmat, savemat, whosmat

from conftest import nespm
from nespm_cli.reports.schema import AXIS_UNITS, UNITS, unit_of

DOC = Path(__file__).resolve().parents[1] / "docs" / "results-schema.md"

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


def doc_units() -> dict[str, dict[str, str]]:
    """``{table: {column: unit}}`` from the unit column of docs/results-schema.md's tables."""
    out: dict[str, dict[str, str]] = {}
    table = None
    for line in DOC.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            table = ("metrics" if "metrics.parquet" in line else "epochs" if "epochs.parquet" in line
                     else "series" if "Series chunks" in line else "sweep" if "Sweep folders" in line else None)
            continue
        if table and line.startswith("| `"):
            cells = [c.strip() for c in line.strip().strip("|").split("|", 3)]
            cols = re.findall(r"`([^`]*)`", cells[0])
            units = [u.strip() for u in cells[2].split(",")] if "," in cells[2] else [cells[2]] * len(cols)
            assert len(units) == len(cols), line
            for c, u in zip(cols, units):
                out.setdefault(table, {})[c] = u
    return out


def test_doc_units_are_the_code_units():
    from nespm_cli.reports.schema import SWEEP_UNITS

    doc = doc_units()
    assert doc.pop("sweep") == SWEEP_UNITS
    assert doc == UNITS  # every column of every table, in both, with the same unit
    text = DOC.read_text(encoding="utf-8")
    for prefix, unit in AXIS_UNITS.items():  # the labels' units, as the doc lists them
        axes = "XYZ" if prefix in ("ba", "bg") else "NED"
        assert f"`{' '.join(prefix + a for a in axes)}` {unit}" in text


def test_unit_of_resolves_families():
    assert unit_of("metrics", "vrmse") == "m/s" and unit_of("metrics", "nis_usbl") == ""
    assert unit_of("epochs", "rms_dpsiN") == "rad" and unit_of("epochs", "sig_dpE") == "m"
    assert unit_of("epochs", "sig_baY") == "m/s²" and unit_of("series", "e_bgZ") == "rad/s"
    assert unit_of("epochs", "nci_att") == "dB" and unit_of("epochs", "nis_fix_n") == ""
    assert unit_of("series", "cover2_vel") == "" and unit_of("metrics", "value") == ""
    assert unit_of("metrics", "my_plugin_column") is None


@pytest.fixture(scope="module")
def folder(tmp_path_factory, short_data_dir) -> Path:
    out = tmp_path_factory.mktemp("meta") / "mc"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "3", "--filters", "ekf",
                       "--state", "15", "--sensors", "dvl,depth", "--seed", "7", "--save-series", "axes",
                       "--out", str(out), "--no-progress", "--jobs", "1")
    assert rc == 0, err
    return out


def test_mat_holds_units_meta_cellstr_and_logical(folder, tmp_path):
    rc, _, err = nespm("export", str(folder), "--format", "mat", "--series", "--out", str(tmp_path))
    assert rc == 0, err
    m = loadmat(tmp_path / "mc.mat", squeeze_me=True, struct_as_record=False, chars_as_strings=True)
    metrics = pd.read_parquet(folder / "metrics.parquet")
    # texts: a cellstr of the values (not empty arrays), as N x 1 in the file
    assert list(m["metrics"].filter) == ["ekf"] * 3 and list(m["metrics"].kernels) == metrics["kernels"].tolist()
    raw = loadmat(tmp_path / "mc.mat", squeeze_me=False)["metrics"][0, 0]
    assert raw["filter"].shape == (3, 1) and raw["filter"].dtype == object and str(raw["filter"][0, 0][0]) == "ekf"
    assert raw["vrmse"].shape == (3, 1)
    # booleans: logical (scipy reads a logical back as uint8; the old export wrote double)
    assert raw["diverged"].dtype == np.uint8 and raw["diverged"].ravel().tolist() == [0, 0, 0]
    # meta: the study and the units of every field
    meta = m["meta"]
    assert meta.seed == 7 and meta.options.runs == 3 and meta.options.seed == 7
    assert list(np.atleast_1d(meta.options.sensors)) == ["dvl", "depth"] and meta.options.filters == "ekf"
    assert meta.experiment == "mc" and "nespm" in meta.command and meta.versions.nespm
    assert meta.sensors.all.depth.interval is not None  # the sensors with their resolved options
    assert meta.units.metrics.vrmse == "m/s" and meta.units.metrics.sse_vel == "(m/s)²"
    assert meta.units.epochs.rms_dpsiN == "rad" and meta.units.series.e_dvE == "m/s"
    for empty in (meta.units.metrics.nis_depth, meta.units.metrics.filter):  # '' : a char of size 0 in MATLAB
        assert np.asarray(empty).dtype.kind == "U" and np.size(empty) == 0
    assert len(np.atleast_1d(meta.inputs.path)) == len(np.atleast_1d(meta.inputs.sha256)) >= 2
    fields = set(m["metrics"]._fieldnames)
    assert fields == set(meta.units.metrics._fieldnames)  # a unit for every field


def test_bool_columns_are_written_as_matlab_logical(tmp_path):
    from nespm_cli.reports.export import mat_struct

    s = mat_struct(pd.DataFrame({"lost": [True, False], "x": [1.0, 2.0], "why": ["", "numeric"]}))
    savemat(tmp_path / "t.mat", s, oned_as="column")
    kinds = {name: (shape, kind) for name, shape, kind in whosmat(tmp_path / "t.mat")}
    assert kinds == {"lost": ((2, 1), "logical"), "x": ((2, 1), "double"), "why": ((2, 1), "cell")}


def test_csv_has_units_and_meta_beside(folder, tmp_path):
    rc, _, err = nespm("export", str(folder), "--out", str(tmp_path))
    assert rc == 0, err
    units = pd.read_csv(tmp_path / "units.csv", keep_default_na=False)
    metrics = pd.read_csv(tmp_path / "metrics.csv")
    got = dict(zip(units.loc[units["table"] == "metrics", "column"], units.loc[units["table"] == "metrics", "unit"]))
    assert list(got) == list(metrics.columns)
    assert got["vrmse"] == "m/s" and got["hpe_final"] == "m" and got["vert_rms"] == "m" and got["diverged"] == ""
    e = units[units["table"] == "epochs"]
    assert dict(zip(e["column"], e["unit"]))["rms_baX"] == "m/s²"
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["seed"] == 7 and meta["options"]["runs"] == 3 and meta["options"]["sensors"] == ["dvl", "depth"]
    assert meta["units"]["metrics"]["vrmse"] == "m/s" and meta["finished"]
    assert "?" not in set(units["unit"])  # every column nespm writes is in the schema
