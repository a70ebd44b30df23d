"""``nespm check`` never crashes on a figure the data do not determine: a non-finite number is written as
``null`` in check.json with a finding naming it, and an undetermined time offset is not "significant".

The tracks are built in memory (``check_track`` takes a Track): a gyro scaled by 57.3 (load_track refuses
that file since issue 30; the check itself must still hold) and a GT whose attitude never changes.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from conftest import exact_imu_table, short_track
from nespm_cli.checks.verdict import check_track, json_safe, non_finite, significant
from nespm_cli.reports.check import write_check_report


def test_a_non_finite_figure_is_null_with_a_finding(tmp_path):
    tr = short_track(5, 150)
    imu = exact_imu_table(tr)
    imu[:, 4:7] *= math.degrees(1.0)  # deg/s read as rad/s: local offset curves without curvature
    r = check_track(dataclasses.replace(tr, imu=imu))
    assert 55 < min(r["imu"]["stats"]["gyro"]["scale_factor"]) < 57.3
    bad = non_finite(r, skip=("imu.series", "imu.attitude_drift.t", "imu.attitude_drift.drift_deg"))
    assert bad and all(p.startswith("imu.time_offset.local.") for p in bad)
    assert any("not finite" in f and bad[0] in f and "null" in f for f in r["findings"])
    res = {"data_dir": None, "tracks": [r], "corrections": "{}\n", "summary": {r["verdict"]: 1}}
    write_check_report(res, tmp_path, figures=False)
    back = json.loads((tmp_path / "check.json").read_text())
    local = back["tracks"][0]["imu"]["time_offset"]["local"]
    assert any(w["std_s"] is None for w in local)


def test_an_undetermined_offset_is_not_significant_and_the_check_runs(tmp_path):
    assert not significant(0.5, None) and not significant(0.5, float("inf")) and not significant(float("nan"), 0.1)
    assert significant(0.5, 0.1) and not significant(0.01, 0.001)
    tr = short_track(5, 120)
    tr = dataclasses.replace(tr, euler=np.broadcast_to(tr.euler[0], tr.euler.shape).copy())  # it never turns
    tr = dataclasses.replace(tr, imu=exact_imu_table(tr))
    r = check_track(tr)
    assert r["dvl"]["time_offset_std_s"] is None  # the DVL offset is undetermined without turns
    assert r["corrections"]["dvl_time_offset"] == 0.0
    write_check_report({"data_dir": None, "tracks": [r], "corrections": "{}\n", "summary": {r["verdict"]: 1}},
                       tmp_path, figures=False)
    assert json.loads((tmp_path / "check.json").read_text())["tracks"][0]["track"] == 5


def test_json_safe():
    x = {"a": [1.0, float("inf"), np.float64("nan")], "b": (2, {"c": -np.inf}), "d": "s"}
    assert json_safe(x) == {"a": [1.0, None, None], "b": [2, {"c": None}], "d": "s"}
    assert non_finite(x) == ["a.1", "a.2", "b.1.c"]
