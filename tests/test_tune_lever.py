"""A sensor's lever arm in one filter's model (``--filter-option NAME.lever_arm_x_dvl``) and its
calibration by ``nespm tune`` (``--tune-range '*.lever_arm_x_dvl=LOW:HIGH'``; docs/tuning.md).

The embedded tracks' DVL sits 1.6 m aft of the IMU (``data.embedded.L_DVL``) and the papers'
filters assume it at the IMU. Setting the coordinate for one filter is the same model as the
study's ``--dvl-lever-arm`` for every filter (bit for bit), and tune finds it on a training track.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from nespm_cli.data.embedded import L_DVL
from conftest import assert_one_error_line, cli
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, filter_config_of, validate
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.spec import TuneSpec
from nespm_cli.tuning.space import apply_ranges, default_space, optional_space
from nespm_cli.filters.registry import get_filter
from nespm_cli.nav.state import LAYOUT_12

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
SHORT = dict(tracks=(5,), runs=2, filters=("ekf", "ukf"), window="0:120")  # the recorded (embedded) DVL


def _v_n(spec: Spec) -> dict:
    out = simulate(spec, 5, np.arange(2), spec.filters)[0]
    return {f: out[f][0].v_n for f in spec.filters}


def test_a_filters_lever_arm_is_the_sensors_for_that_filter_alone():
    """``ekf.lever_arm_x_dvl=-1.6`` (and ukf's) gives the numbers of ``--dvl-lever-arm -1.6 0 0`` bit for
    bit; set for the ekf alone, the ukf keeps the default model bit for bit; the lever arm moves the
    velocity (the recorded DVL was made 1.6 m aft)."""
    assert tuple(L_DVL) == (-1.6, 0.0, 0.0)
    base = validate(Spec(**SHORT))
    told = validate(Spec(**SHORT, dvl_lever_arm=tuple(L_DVL)))
    both = validate(Spec(**SHORT, filter_options=(("ekf", "lever_arm_x_dvl", "-1.6"), ("ukf", "lever_arm_x_dvl", "-1.6"))))
    ekf_only = validate(Spec(**SHORT, filter_options=(("ekf", "lever_arm_x_dvl", "-1.6"),)))
    ref, t, b, e = _v_n(base), _v_n(told), _v_n(both), _v_n(ekf_only)
    for f in ("ekf", "ukf"):
        assert np.array_equal(b[f], t[f])
    assert np.array_equal(e["ekf"], t["ekf"]) and np.array_equal(e["ukf"], ref["ukf"])
    assert np.abs(t["ekf"] - ref["ekf"]).max() > 1e-2  # not a no-op: the lever arm matters here
    cfg = filter_config_of(ekf_only, "ekf")
    assert cfg.levers == (("dvl", 0, -1.6),) and filter_config_of(ekf_only, "ukf").levers == ()
    assert cfg.model_lever("dvl", (0.0, 0.2, 0.3)) == (-1.6, 0.2, 0.3)  # one coordinate over the sensor's


def test_a_heading_has_no_lever_arm_option(capsys):
    """A heading is a rotation: its model reads no lever arm, so a filter's lever-arm option for it
    would be silently ignored: refused in one line naming the sensors that have one."""
    rc, out, err = cli(capsys, "mc", "--sensors", "dvl,heading", "--tracks", "5", "--runs", "1",
                       "--filter-option", "ekf.lever_arm_x_heading=1", "--out", "/nonexistent/never")
    assert_one_error_line(rc, out, err, "--filter-option ekf.lever_arm_x_heading", "lever arm (dvl)")


def test_lever_arm_is_off_in_the_default_space_and_a_range_turns_it_on():
    """Not a noise parameter: absent from the default space; a range adds it (linear, default the
    sensor's coordinate, kind ``model``); ``=off`` on it is a no-op; ``*`` reaches every filter."""
    space = {f: default_space(f, get_filter(f), LAYOUT_12, ("dvl",), 1e-3) for f in ("ekf", "ukf")}
    assert not any(p.key.startswith("lever_arm") for ps in space.values() for p in ps)
    optional = {f: optional_space(f, get_filter(f), {"dvl": (-0.5, 0.0, 0.25)}) for f in space}
    got = apply_ranges(space, [("*", "lever_arm_x_dvl", -3.0, 3.0)], optional)
    for f in ("ekf", "ukf"):
        p = next(q for q in got[f] if q.key == "lever_arm_x_dvl")
        assert (p.low, p.high, p.log, p.default, p.kind) == (-3.0, 3.0, False, -0.5, "model")
        assert len(got[f]) == len(space[f]) + 1
    assert apply_ranges(space, [("ekf", "lever_arm_z_dvl", None, None)], optional) == space
    with pytest.raises(NespmError, match="lever_arm_x_dvl"):  # the error lists what a range may turn on
        apply_ranges(space, [("ekf", "lever_arm_q_dvl", 0.0, 1.0)], optional)


def test_tune_calibrates_the_dvl_lever_arm_on_a_training_track(tmp_path):
    """Only the lever arm searched (the noise left at its defaults), 24 trials on the first 300 s of
    track 1 (its turns make the fore-aft offset observable): the best trial lies within 0.3 m of the
    truth's -1.6 m (measured: -1.612, score 0.0310; 0.3 m off the score is x1.17-1.25, at 0 m x4.5),
    and tuned.toml writes the searched value as is (the level scales Q, R and P0 alone)."""
    spec = Spec(tracks=(1,), runs=2, filters=("ekf",), window="0:300")
    noise = [p.key for p in default_space("ekf", get_filter("ekf"), LAYOUT_12, ("dvl",), 1e-3)]
    ranges = [("ekf", k, None, None) for k in noise] + [("ekf", "lever_arm_x_dvl", -3.0, 3.0)]
    best = run_tune(TuneSpec(spec, trials=24, profile=False, level_runs=2, ranges=tuple(ranges), refine_trials=0), tmp_path / "t")
    b = best["best"]["ekf"]
    assert abs(b["shape"]["lever_arm_x_dvl"] - L_DVL[0]) < 0.3, b["shape"]
    assert b["values"]["lever_arm_x_dvl"] == b["shape"]["lever_arm_x_dvl"]
    trials = pd.read_parquet(tmp_path / "t" / "trials.parquet")
    default = trials.loc[trials["trial"] == 0, "score"].item()
    assert b["score"] < 0.5 * default  # the default model (DVL at the IMU) is far off
    record = json.loads((tmp_path / "t" / "tune.json").read_text())
    assert [p["key"] for p in record["space"]["ekf"]] == ["lever_arm_x_dvl"]
    assert f"lever_arm_x_dvl = {b['values']['lever_arm_x_dvl']!r}" in (tmp_path / "t" / "tuned.toml").read_text()
