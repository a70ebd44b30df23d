"""Learned noise models that cannot fail quietly (docs/learned.md, "When a model fails at run
time"; issue 39 item 3).

Checked, with ONNX models built here with the ``onnx`` helper API alone:

* a model that is finite on the load check's reference windows but NaN on some run-time windows
  (those whose accelerometer noise exceeds 5x nominal, i.e. the dynamic schedule's loudest
  segments) loses exactly the runs with such a window, at the epoch that closes the first one;
  the others keep their numbers; no lost run reads as the plain EKF;
* one rule for every output: NaN, a negative ``std`` and a ``q_scale`` <= 0 on the same windows
  give the same faults; at load a negative ``std`` is refused like a ``q_scale`` <= 0;
* the faults at the filter: any axis non-finite or <= 0 loses its run at that window (reason
  ``noise-model``, counted per run), and leaves the other runs of the batch bit-identical;
* ``--filter-acc-noise`` / ``--filter-gyro-noise`` set the nominal a model's factor multiplies:
  factor 1 is the EKF at any nominal, factors (2, 3) at nominal (a, g) are the EKF at (2a, 3g),
  for ``q_scale`` and ``std`` outputs alike;
* messages name the option typed; the manifest records onnx and onnxruntime.

Cost: about 20 s (five 3-6-run ``mc`` calls on the first 60 s of embedded track 5).
"""
from __future__ import annotations

import json
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE, CorruptionConfig
from nespm_cli.errors import NespmError
from nespm_cli.filters import FilterConfig, run_filter
from nespm_cli.filters.adaptive import FAULT_REASON, model_faults

from conftest import assert_one_error_line, cli
from test_filters import make_inputs, short_truth

pytest.importorskip("onnx", reason="the optional extra onnx (pip install 'nespm[onnx]') is not installed")
pytest.importorskip("onnxruntime", reason="the optional extra onnx (pip install 'nespm[onnx]') is not installed")

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

#: windows whose accelerometer x difference-std exceeds this many x nominal are the "bad" ones:
#: the reference windows reach 4.50 (4x level), the dynamic schedule's factors U[1, 6]
THRESHOLD = 5.0
#: the runs of the experiments: embedded track 5, its first 60 s, dynamic schedule, synthetic DVL
COMMON = ("--tracks", "5", "--window", "0:60", "--dvl", "synthetic", "--no-progress", "--jobs", "1")


# ----------------------------------------------------------------------------- models (onnx.helper)
def _save(path: Path, nodes: list, inits: list, out_name: str, width: int) -> str:
    import onnx
    from onnx import TensorProto, helper

    g = helper.make_graph(nodes, "m", [helper.make_tensor_value_info("imu", TensorProto.DOUBLE, ["N", 100, 6])],
                          [helper.make_tensor_value_info(out_name, TensorProto.DOUBLE, ["N", width])], inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, path)
    return str(path)


def _const(name: str, value) -> object:
    from onnx import numpy_helper

    return numpy_helper.from_array(np.asarray(value), name)


def _diff_std_nodes() -> tuple[list, list]:
    """Nodes computing ``s`` (N, 6) = sqrt(mean(diff(x)²) / 2) over each window's 100 steps (the
    white-noise std per sample), and ``bad`` (N, 1): acc x's s above THRESHOLD x nominal."""
    from onnx import helper

    i64 = lambda v: np.array(v, dtype=np.int64)  # noqa: E731
    inits = [_const("one", i64([1])), _const("big", i64([1000])), _const("zero", i64([0])),
             _const("m1", i64([-1])), _const("ax1", i64([1])), _const("half", 0.5),
             _const("c0", i64([0])), _const("c1", i64([1])), _const("ax", i64([1])),
             _const("thr", THRESHOLD * NOMINAL_ACC_NOISE)]
    nodes = [helper.make_node("Slice", ["imu", "one", "big", "ax1"], ["hi"]),
             helper.make_node("Slice", ["imu", "zero", "m1", "ax1"], ["lo"]),
             helper.make_node("Sub", ["hi", "lo"], ["d"]),
             helper.make_node("Mul", ["d", "d"], ["d2"]),
             helper.make_node("ReduceMean", ["d2"], ["ms"], axes=[1], keepdims=0),
             helper.make_node("Mul", ["ms", "half"], ["var"]),
             helper.make_node("Sqrt", ["var"], ["s"]),
             helper.make_node("Slice", ["s", "c0", "c1", "ax"], ["sx"]),
             helper.make_node("Greater", ["sx", "thr"], ["bad"])]
    return nodes, inits


def faulty_model(path: Path, kind: str) -> str:
    """The difference-std model, broken on the loud windows (``bad``) in one of three ways:
    ``nan`` std NaN, ``negative`` std negated, ``q_scale`` a factor of -1 (elsewhere (s / nominal)²)."""
    from onnx import helper

    nodes, inits = _diff_std_nodes()
    if kind == "q_scale":
        inits += [_const("c3", np.array([3], dtype=np.int64)), _const("c4", np.array([4], dtype=np.int64)),
                  _const("nominal", np.array([[NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE]])), _const("minus", -1.0)]
        nodes += [helper.make_node("Slice", ["s", "c3", "c4", "ax"], ["sg"]),
                  helper.make_node("Concat", ["sx", "sg"], ["s2"], axis=1),
                  helper.make_node("Div", ["s2", "nominal"], ["f"]),
                  helper.make_node("Mul", ["f", "f"], ["q"]),
                  helper.make_node("Where", ["bad", "minus", "q"], ["q_scale"])]
        return _save(path, nodes, inits, "q_scale", 2)
    if kind == "nan":
        inits.append(_const("nan", np.nan))
        nodes.append(helper.make_node("Where", ["bad", "nan", "s"], ["std"]))
    else:
        nodes += [helper.make_node("Neg", ["s"], ["neg"]), helper.make_node("Where", ["bad", "neg", "s"], ["std"])]
    return _save(path, nodes, inits, "std", 6)


def constant_model(path: Path, output: str, values) -> str:
    """A model whose output is ``values`` for every window (``q_scale`` (2,) or ``std`` (6,))."""
    from onnx import helper

    inits = [_const("ax", np.array([1], dtype=np.int64)), _const("zero", 0.0),
             _const("value", np.asarray(values, dtype=np.float64)[None, :])]
    nodes = [helper.make_node("ReduceMean", ["imu"], ["m"], axes=[1, 2], keepdims=0),
             helper.make_node("Unsqueeze", ["m", "ax"], ["m1"]),
             helper.make_node("Mul", ["m1", "zero"], ["z"]),
             helper.make_node("Add", ["z", "value"], [output])]
    return _save(path, nodes, inits, output, len(values))


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("learned")
    return {k: faulty_model(d / f"{k}.onnx", k) for k in ("nan", "negative", "q_scale")}


def _metrics(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "metrics.parquet").sort_values(["filter", "run"]).reset_index(drop=True)


# ----------------------------------------------------------------------------- the must-hold
def test_nan_on_some_windows_loses_those_runs_never_reads_as_the_ekf(capsys, tmp_path, models):
    """6 runs, dynamic schedule: the runs with a loud window are lost at the epoch that closes
    the first one (lost_at = that window's end), their error sums NaN; the other runs are kept
    with finite numbers that are not the EKF's; the command says how many were lost."""
    from nespm_cli.experiments.mc import realization_inputs
    from nespm_cli.experiments.spec import Spec, validate
    from nespm_cli.learn.noise_models import predict_interval_std

    out = tmp_path / "mc"
    rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "6", "--schedule", "dynamic", "--filters", "ekf,anekf",
                      "--noise-model", models["nan"], "--out", out)
    assert rc == 0, err
    m = _metrics(out)
    ekf, an = m[m["filter"] == "ekf"].set_index("run"), m[m["filter"] == "anekf"].set_index("run")

    # what the model says on these very windows (the same realization, through the library)
    spec = validate(Spec(tracks=(5,), runs=6, window="0:60", dvl="synthetic", filters=("anekf",),
                         weights=models["nan"], corruption=CorruptionConfig(schedule="dynamic")))
    _, truth, _, f, w, _, _ = realization_inputs(spec, 5, np.arange(6))
    faults = model_faults(*predict_interval_std(f, w, truth.epoch_index, spec.weights))  # (6, N-1)
    hit = faults.any(axis=1)
    assert 0 < hit.sum() < 6, faults.sum(axis=1)  # some runs, not all (measured: 4 of 6)
    assert not faults.all(axis=1).any()  # finite elsewhere
    e = truth.epoch_index
    t_rel = truth.t[e] - truth.t[e[0]]
    first = np.argmax(faults, axis=1)

    np.testing.assert_array_equal(an["diverged"].to_numpy(), hit)
    np.testing.assert_allclose(an.loc[hit, "lost_at"].to_numpy(), t_rel[first[hit] + 1], rtol=0, atol=1e-9)
    assert an.loc[hit, "vrmse"].isna().all() and an.loc[hit, "mrmse"].isna().all()
    assert not ekf["diverged"].any()
    kept = ~hit
    assert np.isfinite(an.loc[kept, "vrmse"]).all() and an.loc[kept, "lost_at"].isna().all()
    # a kept run is the learned filter, not the EKF: its Q follows the windows (factors 1-5)
    assert (np.abs(an.loc[kept, "vrmse"] / ekf.loc[kept, "vrmse"] - 1) > 1e-3).all()
    assert f"{int(hit.sum())} diverged" in so + err


def test_one_rule_nan_negative_std_and_q_scale_give_the_same_faults(models):
    """The three breakages of the same windows are the same faults, on 4 runs x 59 windows."""
    from nespm_cli.learn.noise_models import predict_interval_std

    truth = short_truth()
    inp = make_inputs(truth, np.arange(4), CorruptionConfig(schedule="dynamic"))
    got = {k: model_faults(*predict_interval_std(inp["f"], inp["w"], truth.epoch_index, p)) for k, p in models.items()}
    assert got["nan"].any() and not got["nan"].all()
    np.testing.assert_array_equal(got["negative"], got["nan"])
    np.testing.assert_array_equal(got["q_scale"], got["nan"])


@pytest.mark.parametrize("output, values, words", [
    ("std", [-0.03, 0.03, 0.03, 7.3e-6, 7.3e-6, 7.3e-6], "40 of 240 outputs are <= 0"),
    ("q_scale", [1.0, 0.0], "40 of 80 outputs are <= 0"),
    ("std", [0.03, 0.03, 0.03, np.inf, 7.3e-6, 7.3e-6], "40 of 240 outputs are non-finite"),
])
def test_load_check_refuses_std_and_q_scale_alike(capsys, tmp_path, output, values, words):
    """A negative std on the reference windows was accepted (and clipped) before; now it is
    refused in one line exactly like a q_scale of 0, before anything is written."""
    bad = constant_model(tmp_path / "bad.onnx", output, values)
    rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "2", "--filters", "anekf", "--noise-model", bad,
                      "--out", tmp_path / "never")
    assert_one_error_line(rc, so, err, "--noise-model", "bad.onnx", f"output '{output}'", words, "finite and > 0")
    assert not (tmp_path / "never").exists()


# ----------------------------------------------------------------------------- at the filter
@pytest.fixture(scope="module")
def batch():
    truth = short_truth(epochs=31)
    return truth, make_inputs(truth, np.arange(6), CorruptionConfig(schedule="dynamic"))


@pytest.mark.parametrize("kind", ["anekf", "anukf"])
def test_a_fault_loses_its_run_at_its_window_and_nothing_else(batch, kind):
    """Runs 1-4 get one bad axis each (NaN, +inf, -1e-3, 0) in windows 7, 12, 12 and 20 (run 4
    twice, 20 and 25); runs 0 and 5 are clean. Lost: runs 1-4 at epochs 8, 13, 13, 21 with the
    reason noise-model and 1, 1, 1, 2 faults; runs 0 and 5 bit-identical to a batch without any fault."""
    truth, inp = batch
    e = truth.epoch_index
    R, K = 6, len(e) - 1
    sa, sg = np.full((R, K, 3), 1.5 * NOMINAL_ACC_NOISE), np.full((R, K, 3), 2.0 * NOMINAL_GYRO_NOISE)
    ref = run_filter(kind, FilterConfig(), inp["f"], inp["w"], truth.dt, e, inp["dvl"], inp["mask"], inp["nav0"],
                     (sa, sg))
    ba, bg = sa.copy(), sg.copy()
    ba[1, 7, 0] = np.nan
    bg[2, 12, 2] = np.inf
    ba[3, 12, 1] = -1e-3
    bg[4, 20, 0] = 0.0
    ba[4, 25, 2] = np.nan
    out = run_filter(kind, FilterConfig(), inp["f"], inp["w"], truth.dt, e, inp["dvl"], inp["mask"], inp["nav0"],
                     (ba, bg))
    np.testing.assert_array_equal(out.diverged, [False, True, True, True, True, False])
    np.testing.assert_array_equal(out.lost_epoch, [-1, 8, 13, 13, 21, -1])
    assert list(out.lost_reason) == ["", FAULT_REASON, FAULT_REASON, FAULT_REASON, FAULT_REASON, ""]
    np.testing.assert_array_equal(out.noise_faults, [0, 1, 1, 1, 2, 0])
    assert not ref.diverged.any() and (ref.noise_faults == 0).all()
    for r in (0, 5):
        assert np.array_equal(out.v_n[r], ref.v_n[r]) and np.array_equal(out.P[r], ref.P[r])
    for r in (1, 2, 3, 4):  # before its fault the run is the same filter
        k = out.lost_epoch[r]
        assert np.array_equal(out.v_n[r, :k], ref.v_n[r, :k])


def test_a_run_already_diverged_keeps_its_own_reason(batch):
    """A fault after a numeric divergence does not rename it: run 0's IMU jumps by 1e6 m/s² in
    interval 3 (speed past 50 m/s: lost at epoch 4, reason empty = numeric) and its model is NaN
    from window 10 on (21 faults counted); run 1, NaN from window 10 only, is lost at epoch 11."""
    truth, inp = batch
    e = truth.epoch_index
    K = len(e) - 1
    f = np.array(inp["f"], copy=True)
    f[0, e[3] + 50, 0] = 1e6
    sa, sg = np.full((6, K, 3), NOMINAL_ACC_NOISE), np.full((6, K, 3), NOMINAL_GYRO_NOISE)
    sa[:2, 10:] = np.nan
    out = run_filter("anekf", FilterConfig(), f, inp["w"], truth.dt, e, inp["dvl"], inp["mask"], inp["nav0"],
                     (sa, sg))
    np.testing.assert_array_equal(out.lost_epoch[:3], [4, 11, -1])
    assert list(out.lost_reason[:3]) == ["", FAULT_REASON, ""]
    np.testing.assert_array_equal(out.noise_faults[:3], [K - 10, K - 10, 0])


# ----------------------------------------------------------------------------- the nominal
@pytest.mark.parametrize("output, values", [
    ("q_scale", [4.0, 9.0]),
    ("std", [2 * NOMINAL_ACC_NOISE] * 3 + [3 * NOMINAL_GYRO_NOISE] * 3),
])
def test_filter_noise_options_set_the_nominal_the_factor_multiplies(capsys, tmp_path, output, values):
    """Factors (2, 3) on the std (q_scale 4, 9, or std 2x and 3x the reference) with
    --filter-acc-noise 0.05 --filter-gyro-noise 2e-5: anekf equals the EKF told 0.1 and 6e-5
    (measured to 4e-15 relative; asserted 1e-9). Before, the options were ignored (anekf used
    0.06 and 2.19e-5 whatever they said): 4 % in vrmse and mrmse, 14 % in nees from these."""
    model = constant_model(tmp_path / "c.onnx", output, values)
    a = tmp_path / "a"
    rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "3", "--filters", "anekf", "--noise-model", model,
                      "--filter-acc-noise", "0.05", "--filter-gyro-noise", "2e-5", "--out", a)
    assert rc == 0, err
    b = tmp_path / "b"
    rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "3", "--filters", "ekf", "--filter-acc-noise", "0.1",
                      "--filter-gyro-noise", "6e-5", "--out", b)
    assert rc == 0, err
    ma, mb = _metrics(a), _metrics(b)
    assert not ma["diverged"].any()
    for c in ("vrmse", "mrmse", "nees", "hpe_final"):
        np.testing.assert_allclose(ma[c].to_numpy(), mb[c].to_numpy(), rtol=1e-9, err_msg=c)


def test_factor_one_is_the_ekf_at_any_nominal(capsys, tmp_path):
    """q_scale 1: anekf = ekf in the same folder, at the default nominal and at
    --filter-acc-noise 0.08 --filter-gyro-noise 1e-4 (the recorded-IMU use of README)."""
    model = constant_model(tmp_path / "one.onnx", "q_scale", [1.0, 1.0])
    nees = []
    for i, extra in enumerate(((), ("--filter-acc-noise", "0.08", "--filter-gyro-noise", "1e-4"))):
        out = tmp_path / f"f{i}"
        rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "3", "--filters", "ekf,anekf", "--noise-model", model,
                          *extra, "--out", out)
        assert rc == 0, err
        m = _metrics(out)
        ekf, an = m[m["filter"] == "ekf"], m[m["filter"] == "anekf"]
        for c in ("vrmse", "mrmse", "nees"):
            np.testing.assert_allclose(an[c].to_numpy(), ekf[c].to_numpy(), rtol=1e-9, err_msg=f"{extra} {c}")
        nees.append(an["nees"].to_numpy())
    assert (np.abs(nees[1] / nees[0] - 1) > 1e-3).all()  # and the told nominal matters: 0.08 is not 0.03


# ----------------------------------------------------------------------------- messages, manifest
def test_messages_name_the_option_typed(capsys, tmp_path):
    from nespm_cli.learn.noise_models import load_noise_model, typed_option

    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.zeros(3))
    assert typed_option(("noise_model", "tracks")) == "--noise-model"
    assert typed_option(("weights",)) == "--weights"
    for option in ("--noise-model", "--weights"):
        with pytest.raises(NespmError) as exc:
            load_noise_model(str(bad), option)
        assert str(exc.value).startswith(f"{option} {bad}: not a ProcessNet file"), str(exc.value)
    rc, so, err = cli(capsys, "mc", *COMMON, "--runs", "2", "--filters", "anekf", "--noise-model", bad,
                      "--out", tmp_path / "never")
    assert_one_error_line(rc, so, err, "--noise-model", str(bad), "not a ProcessNet file")


def test_manifest_records_onnx_versions():
    from nespm_cli.experiments.store import versions

    v = versions()
    assert v["onnx"] == version("onnx") and v["onnxruntime"] == version("onnxruntime")
    assert json.loads(json.dumps(v)) == v
