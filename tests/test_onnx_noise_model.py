"""Noise models through ONNX (docs/learned.md): ProcessNet exported with ``onnx.helper`` gives the
numpy ProcessNet's std, Q and metrics; the input/output contract is checked at load in one line;
the optional extra's absence is one line. Never imports torch.

Cost: a few seconds of onnxruntime plus three 3-run ``mc`` calls on a 40-interval track cut.
"""
from __future__ import annotations

import copy
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nespm_cli.data.tracks import write_akit
from nespm_cli.errors import NespmError
from nespm_cli.learn.noise_model import load_weights, reference_windows
from nespm_cli.learn.noise_models import ProcessNetModel, load_noise_model, predict_interval_std
from nespm_cli.learn.processnet import save_nets

from conftest import assert_one_error_line, cli, short_track

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
ROOT = Path(__file__).resolve().parents[1]


def _need_onnx():
    pytest.importorskip("onnx", reason="the optional extra onnx (pip install 'nespm[onnx]') is not installed")
    pytest.importorskip("onnxruntime", reason="the optional extra onnx (pip install 'nespm[onnx]') is not installed")


def _float64(net):
    n = copy.copy(net)
    n.params = {k: v.astype(np.float64) for k, v in net.params.items()}
    n.dtype = np.dtype(np.float64)
    return n


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """The packaged ProcessNet (float32) and a float64 copy, each as .npz and exported .onnx."""
    _need_onnx()
    from nespm_cli.learn.noise_models import export_processnet

    d = tmp_path_factory.mktemp("onnx")
    acc, gyro, _ = load_weights(None)
    save_nets(d / "pn64.npz", {"acc": _float64(acc), "gyro": _float64(gyro)})
    out = {"npz32": None, "onnx32": export_processnet(None, d / "pn32.onnx"), "npz64": d / "pn64.npz"}
    out["onnx64"] = export_processnet(out["npz64"], d / "pn64.onnx")
    return {k: (str(v) if v else None) for k, v in out.items()}


def _onnx_model(path: Path, in_name="imu", in_type=None, in_shape=("N", 100, 6), out_name="std",
                out_shape=("N", 6), window=100):
    """A contract-shaped (or deliberately mis-shaped) model: the mean of each column."""
    import onnx
    from onnx import TensorProto, helper

    in_type = TensorProto.FLOAT if in_type is None else in_type
    nodes = [helper.make_node("ReduceMean", [in_name], ["m"], axes=[1], keepdims=0),
             helper.make_node("Abs", ["m"], [out_name])]
    g = helper.make_graph(nodes, "g", [helper.make_tensor_value_info(in_name, in_type, list(in_shape))],
                          [helper.make_tensor_value_info(out_name, in_type, list(out_shape))])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.save(m, path)
    return str(path)


def test_processnet_onnx_equals_numpy_std_and_q(models):
    """float64 network: ONNX = numpy to rounding (measured 1.1e-15 in std), Q to 1e-6 relative
    with 1e6 x margin. The packaged float32 network: the two float32 summation orders (OpenBLAS vs
    MLAS) differ by up to 4.7e-7 in std on these 40 windows and 6.9e-7 on 4000 (measured,
    benchmarks/bench_onnx_noise_model.py), i.e. 1.4e-6 in Q = std²: asserted at 4e-6 (about 30 x
    float32's 1.2e-7 epsilon, the 750-term sums' rounding)."""
    from nespm_cli.filters import FilterConfig
    from nespm_cli.filters.adaptive import adaptive_q

    cfg = FilterConfig()

    f, w = reference_windows()
    x = np.concatenate([f, w], axis=-1)  # (2, 20, 100, 6)
    for npz, onx, tol in ((models["npz64"], models["onnx64"], 1e-12), (models["npz32"], models["onnx32"], 4e-6)):
        a, b = load_noise_model(npz), load_noise_model(onx)
        assert isinstance(a, ProcessNetModel) and b.name == "onnx" and b.window == 100
        sa, sb = a.predict(x), b.predict(x)
        assert sa.shape == sb.shape == (2, 20, 6)
        qa, qb = (adaptive_q(s_[..., :3].reshape(-1, 3), s_[..., 3:].reshape(-1, 3), np.tile(np.eye(3), (40, 1, 1)),
                             cfg, 0.01, 1.0) for s_ in (sa, sb))  # Q of eqs 43-48, (40, n, n)
        nz = qa != 0
        assert nz.any() and np.array_equal(nz, qb != 0)
        assert np.max(np.abs(qb[nz] / qa[nz] - 1)) < tol
    # the filters' path: one window per run and DVL interval, batched over runs
    rng = np.random.default_rng(1)
    e = np.arange(0, 1001, 100)
    fm, wm = rng.normal(0, 0.03, (3, 1000, 3)) + [0, 0, 9.8], rng.normal(0, 7.3e-6, (3, 1000, 3))
    ref = predict_interval_std(fm, wm, e, models["npz64"], clip=(0.25, 24))
    got = predict_interval_std(fm, wm, e, models["onnx64"], clip=(0.25, 24))
    for r, g in zip(ref, got):
        assert r.shape == (3, 10, 3)
        np.testing.assert_allclose(g ** 2, r ** 2, rtol=1e-6, atol=0)  # float64 pair


@pytest.fixture(scope="module")
def short_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("short")
    write_akit(short_track(5, epochs=41), d)
    return d


def test_mc_metrics_through_onnx_equal_numpy_and_manifest_hashes_model(capsys, models, short_dir, tmp_path):
    """The same experiment with each .npz (via --weights) and its ONNX export (via --noise-model):
    every anekf metric equal to 1e-7 relative (measured: 1.6e-15 for the float64 network, 3e-8 for
    the float32 one); the manifest records the model file's SHA-256.

    anukf-nespm is left out of the equality: its UT (alpha = 1e-3) turns even the 1e-15 std
    difference of the float64 pair into 8e-7 in mrmse (measured), the filter's conditioning and
    not the model's (docs/learned.md)."""
    import hashlib
    import json

    from nespm_cli.learn.noise_model import default_weights

    files = dict(models, npz32=str(default_weights()))
    frames = {}
    for key, flag in (("npz64", "--weights"), ("onnx64", "--noise-model"), ("npz32", "--weights"),
                      ("onnx32", "--noise-model")):
        out = tmp_path / key
        rc, so, err = cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "3", "--filters",
                          "anekf", "--schedule", "dynamic", "--dvl", "synthetic", "--no-progress",
                          flag, files[key], "--out", out)
        assert rc == 0, err
        frames[key] = pd.read_parquet(out / "metrics.parquet").sort_values(["filter", "track", "run"])
        man = json.loads((out / "manifest.json").read_text())
        assert hashlib.sha256(Path(files[key]).read_bytes()).hexdigest() in json.dumps(man)
    for npz, onx in (("npz64", "onnx64"), ("npz32", "onnx32")):
        ref, got = frames[npz], frames[onx]
        num = [c for c in ref.columns if ref[c].dtype.kind == "f" and not c.endswith("seconds")]
        assert {"q_factor_acc", "mrmse"} <= set(num) and len(ref) == 3
        for c in num:
            a, b = ref[c].to_numpy(), got[c].to_numpy()
            fin = np.isfinite(a)
            assert np.array_equal(fin, np.isfinite(b)), c
            np.testing.assert_allclose(b[fin], a[fin], rtol=1e-7, atol=0, err_msg=f"{onx} {c}")


@pytest.mark.parametrize("kw, words", [
    (dict(in_name="x"), ["inputs", "'imu'", "['x']"]),
    (dict(in_shape=("N", 100, 3), out_shape=("N", 3)), ["input 'imu'", "[N, W, 6]"]),
    (dict(in_shape=(8, 100, 6)), ["input 'imu'", "N dynamic"]),
    (dict(out_name="sigma"), ["outputs", "'std'", "['sigma']"]),
    (dict(in_shape=("N", 100, 6), out_shape=("N", 5)), ["output 'std'", "[N, 6]"]),
    (dict(in_type=7), ["input 'imu'", "dtype tensor(int64)"]),
])
def test_wrong_contract_is_one_line_naming_the_tensor(capsys, tmp_path, short_dir, kw, words):
    _need_onnx()
    bad = _onnx_model(tmp_path / "bad.onnx", **kw)
    with pytest.raises(NespmError) as exc:
        load_noise_model(bad)
    assert "\n" not in str(exc.value) and all(w in str(exc.value) for w in words), str(exc.value)
    rc, so, err = cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "2", "--filters", "anekf",
                      "--noise-model", bad, "--no-progress", "--out", tmp_path / "never")
    assert_one_error_line(rc, so, err, "--noise-model", "bad.onnx")
    assert not (tmp_path / "never").exists()  # refused before any run


def test_not_onnx_and_missing_extra_are_one_line(capsys, tmp_path, short_dir, monkeypatch):
    _need_onnx()
    junk = tmp_path / "junk.onnx"
    junk.write_text("not a model\n")
    with pytest.raises(NespmError, match=r"junk.onnx: not a loadable ONNX model"):
        load_noise_model(str(junk))
    other = tmp_path / "model.tflite"
    other.write_bytes(b"x")
    with pytest.raises(NespmError, match=r"unknown model file type '.tflite'"):
        load_noise_model(str(other))
    good = _onnx_model(tmp_path / "fine.onnx")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as if the extra were not installed
    rc, so, err = cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "2", "--filters", "anekf",
                      "--noise-model", good, "--no-progress", "--out", tmp_path / "never")
    assert_one_error_line(rc, so, err, "fine.onnx", "nespm[onnx]")


def test_example_model_runs_through_the_filters(capsys, tmp_path, short_dir):
    """examples/onnx_noise_model.py (onnx helper API only): a float32 difference-std model; its
    std on white noise of the nominal level is that level (within the 100-sample spread)."""
    _need_onnx()
    spec = importlib.util.spec_from_file_location("onnx_example", ROOT / "examples" / "onnx_noise_model.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    import onnx

    path = tmp_path / "diff-std.onnx"
    onnx.save(mod.build(), path)
    m = load_noise_model(str(path))
    rng = np.random.default_rng(3)
    x = rng.standard_normal((400, 100, 6)) * 0.03 + [0, 0, 9.8, 0, 0, 0]
    s = m.predict(x)[:, :3].mean()
    assert abs(s / 0.03 - 1) < 0.02  # 1200 estimates of relative spread 1/sqrt(2*99): mean within 0.6 %
    rc, so, err = cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "2", "--filters", "anekf",
                      "--schedule", "dynamic", "--dvl", "synthetic", "--noise-model", path, "--no-progress",
                      "--out", tmp_path / "ex")
    assert rc == 0, err
    q = pd.read_parquet(tmp_path / "ex" / "metrics.parquet")["q_factor_acc"]
    assert ((q >= 0.25) & (q <= 24)).all()


def test_train_export_onnx_bad_value_is_one_line(capsys, tmp_path):
    rc, so, err = cli(capsys, "train", "--tracks", "1", "--test-tracks", "5", "--runs", "1", "--epochs", "1",
                      "--export", "tflite", "--out", tmp_path / "w.npz", "--no-progress")
    assert_one_error_line(rc, so, err, "--export", "onnx")


def test_train_export_onnx_writes_the_same_model(capsys, tmp_path, monkeypatch):
    """`nespm train --export onnx` writes <out>.onnx beside the weights; it predicts the weights'
    std (float32 network: Q to 4e-6, see above); without the extra it stops before training."""
    _need_onnx()
    out = tmp_path / "w.npz"
    rc, so, err = cli(capsys, "train", "--tracks", "1", "--test-tracks", "5", "--runs", "2", "--epochs", "1",
                      "--export", "onnx", "--out", out, "--no-progress")
    assert rc == 0, err
    x = np.concatenate(reference_windows(), axis=-1)
    a, b = load_noise_model(str(out)).predict(x), load_noise_model(str(out.with_suffix(".onnx"))).predict(x)
    assert np.max(np.abs((b / a) ** 2 - 1)) < 4e-6
    monkeypatch.setitem(sys.modules, "onnx", None)
    rc, so, err = cli(capsys, "train", "--tracks", "1", "--test-tracks", "5", "--runs", "2", "--epochs", "1",
                      "--export", "onnx", "--out", tmp_path / "never.npz", "--no-progress")
    assert_one_error_line(rc, so, err, "--export onnx", "nespm[onnx]")
    assert not (tmp_path / "never.npz").exists()


def test_q_scale_output_is_nominal_times_sqrt_factor(tmp_path):
    """Output q_scale (N, 2): factors on the nominal acc / gyro variance -> std per axis."""
    _need_onnx()
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

    four = numpy_helper.from_array(np.array([[4.0, 9.0]]), "four")
    nodes = [helper.make_node("ReduceMean", ["imu"], ["m"], axes=[1, 2], keepdims=0),  # (N,)
             helper.make_node("Unsqueeze", ["m", "ax"], ["m1"]),
             helper.make_node("Mul", ["m1", "zero"], ["z"]),
             helper.make_node("Add", ["z", "four"], ["q_scale"])]
    g = helper.make_graph(nodes, "q", [helper.make_tensor_value_info("imu", TensorProto.DOUBLE, ["N", 50, 6])],
                          [helper.make_tensor_value_info("q_scale", TensorProto.DOUBLE, ["N", 2])],
                          [four, numpy_helper.from_array(np.array([1], dtype=np.int64), "ax"),
                           numpy_helper.from_array(np.array(0.0), "zero")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.save(m, tmp_path / "q.onnx")
    model = load_noise_model(str(tmp_path / "q.onnx"))
    assert model.window == 50
    std = model.predict(np.ones((2, 3, 50, 6)))
    assert std.shape == (2, 3, 6)
    np.testing.assert_allclose(std[0, 0], [2 * NOMINAL_ACC_NOISE] * 3 + [3 * NOMINAL_GYRO_NOISE] * 3, rtol=1e-15)


def test_register_a_noise_model_kind(tmp_path):
    """A kind registered by suffix (what the nespm.noise_models entry point does for a package)
    is used by --noise-model; a loader that fails is one line naming the file."""
    from nespm_cli.learn import noise_models as nm

    class Constant(nm.NoiseModel):
        name = "constant"

        def predict(self, windows):
            return np.full(np.shape(windows)[:-2] + (6,), 2.0)

    def load(path):
        if path.read_text() != "ok":
            raise ValueError("bad header")
        return Constant()

    nm.register(".const", load)
    try:
        good, bad = tmp_path / "a.const", tmp_path / "b.const"
        good.write_text("ok")
        bad.write_text("no")
        e = np.arange(0, 301, 100)
        sa, sg = nm.predict_interval_std(np.zeros((2, 300, 3)), np.zeros((2, 300, 3)), e, str(good))
        assert sa.shape == sg.shape == (2, 3, 3) and (sa == 2).all()
        with pytest.raises(NespmError, match=r"b.const: cannot be loaded as .const \(ValueError: bad header\)"):
            nm.load_noise_model(str(bad))
    finally:
        nm.unregister(".const")
