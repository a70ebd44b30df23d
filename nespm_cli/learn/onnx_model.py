"""Learned noise models from any framework, through ONNX (docs/learned.md).

:class:`OnnxNoiseModel` runs a ``.onnx`` file with onnxruntime (CPU, one thread, batched over
runs and DVL intervals) after checking its input and output contract;
:func:`processnet_onnx` (and :func:`nespm_cli.learn.noise_models.export_processnet`) write the numpy ProcessNet (eqs 34-41 and
its :class:`~nespm_cli.learn.processnet.Normalizer`) as an ONNX graph built with ``onnx.helper``
alone. Both need the optional extra ``pip install 'nespm[onnx]'`` (onnx, onnxruntime); its
absence is one NespmError naming it.

The contract (checked at load, before any run; every breach is one line naming the tensor):

* one input ``imu``: ``(N, W, 6)`` with N dynamic (any name or -1) and W a fixed window of IMU
  steps, float32 or float64: specific force x, y, z [m/s²] then angular rate x, y, z [rad/s],
  raw readings of the W IMU steps that end at each DVL epoch (bias, gravity and all);
* one output, either ``std`` ``(N, 6)``: the per-axis white-noise std per IMU sample in the
  same units, or ``q_scale`` ``(N, 2)``: factors on the nominal accelerometer and gyro noise
  variance (std = nominal · sqrt(factor)); float32 or float64;
* optional metadata ``nespm.rate_hz`` (default 100): the IMU rate the model was made for.

A run on the 40 reference windows of :func:`nespm_cli.learn.noise_model.reference_windows` must give
values of the declared shape, every one finite and > 0 (the rule of every output, ``std`` or
``q_scale``: :func:`~nespm_cli.learn.noise_model.output_problem`); at run time a window that breaks
it loses its run (:mod:`nespm_cli.filters.adaptive_filters`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.learn.noise_model import IMU_RATE_HZ, OPTION, NoiseModel, output_problem

INPUT = "imu"
OUTPUTS = {"std": 6, "q_scale": 2}
FLOAT_TYPES = {"tensor(float)": np.float32, "tensor(double)": np.float64}
EXTRA = "pip install 'nespm[onnx]'"
OPSET = 17
#: windows per onnxruntime call (memory bound only; every window is independent)
BATCH = 4096


def require_extra(module: str, what: str):
    """``module`` (onnx or onnxruntime) imported, or one NespmError naming the extra."""
    return _import(module, what)


def _import(module: str, what: str):
    try:
        return __import__(module)
    except ImportError:
        raise NespmError(f"{what} needs the optional extra onnx ({module} is not installed): {EXTRA}") from None


def _dynamic(d) -> bool:
    return not isinstance(d, int) or d < 0


class OnnxNoiseModel(NoiseModel):
    """An ONNX noise model (module docstring's contract), run by onnxruntime on the CPU."""

    name = "onnx"

    def __init__(self, path, threads: int = 1, reference: np.ndarray | None = None):
        p = Path(path).expanduser()
        what = f"{OPTION} {p}"
        ort = _import("onnxruntime", what)
        if not p.is_file():
            raise NespmError(f"{what}: no such file")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = int(threads)
        opts.log_severity_level = 3
        try:
            sess = ort.InferenceSession(str(p), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise NespmError(f"{what}: not a loadable ONNX model ({first[:200]})") from None
        self.source, self.session = p, sess
        ins, outs = sess.get_inputs(), sess.get_outputs()
        if [i.name for i in ins] != [INPUT]:
            raise NespmError(f"{what}: inputs must be exactly one tensor named {INPUT!r}, got "
                             f"{[i.name for i in ins]} (docs/learned.md)")
        x = ins[0]
        if x.type not in FLOAT_TYPES:
            raise NespmError(f"{what}: input {INPUT!r} has dtype {x.type}, expected tensor(float) or tensor(double)")
        shp = list(x.shape)
        if len(shp) != 3 or not _dynamic(shp[0]) or _dynamic(shp[1]) or shp[2] != 6:
            raise NespmError(f"{what}: input {INPUT!r} has shape {shp}, expected [N, W, 6] with N dynamic and W "
                             "a fixed window length")
        if len(outs) != 1 or outs[0].name not in OUTPUTS:
            raise NespmError(f"{what}: outputs must be exactly one tensor named 'std' (N, 6) or 'q_scale' (N, 2), "
                             f"got {[o.name for o in outs]} (docs/learned.md)")
        y = outs[0]
        if y.type not in FLOAT_TYPES:
            raise NespmError(f"{what}: output {y.name!r} has dtype {y.type}, expected tensor(float) or tensor(double)")
        oshp, width = list(y.shape), OUTPUTS[y.name]
        if len(oshp) != 2 or not (_dynamic(oshp[0]) or oshp[0] == shp[0]) or oshp[1] != width:
            raise NespmError(f"{what}: output {y.name!r} has shape {oshp}, expected [N, {width}]")
        self.window, self.output, self.in_dtype = int(shp[1]), y.name, FLOAT_TYPES[x.type]
        meta = sess.get_modelmeta().custom_metadata_map or {}
        try:
            self.rate_hz = float(meta.get("nespm.rate_hz", IMU_RATE_HZ))
        except ValueError:
            raise NespmError(f"{what}: metadata nespm.rate_hz is {meta['nespm.rate_hz']!r}, not a number") from None
        self._check_run(what, reference)

    def _check_run(self, what: str, reference: np.ndarray | None) -> None:
        """Run once on ``reference`` (L, K, >= W, 6) windows (their last W steps; None or too
        short: zeros (2, 2, W, 6)); the output must have the declared shape and be finite and > 0."""
        ok = reference is not None and reference.shape[-2] >= self.window
        x = reference[..., -self.window:, :] if ok else np.zeros((2, 2, self.window, 6))
        try:
            raw = self._run(x.reshape((-1,) + x.shape[-2:]))
        except Exception as exc:
            raise NespmError(f"{what}: cannot run on ({x.shape[0] * x.shape[1]}, {self.window}, 6) windows "
                             f"({type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''})") from None
        width = OUTPUTS[self.output]
        if raw.shape != (x.shape[0] * x.shape[1], width):
            raise NespmError(f"{what}: output {self.output!r} has shape {list(raw.shape)} on "
                             f"{x.shape[0] * x.shape[1]} windows, expected [{x.shape[0] * x.shape[1]}, {width}]")
        bad = output_problem(raw)  # one rule for std and q_scale: finite and > 0
        if bad:
            raise NespmError(f"{what}: output {self.output!r} on the reference windows: {bad}")

    def _run(self, x: np.ndarray) -> np.ndarray:
        """(K, W, 6) -> (K, width) raw model output, float64, in chunks of :data:`BATCH`."""
        x = np.ascontiguousarray(x, dtype=self.in_dtype)
        out = [self.session.run(None, {INPUT: x[s:s + BATCH]})[0] for s in range(0, len(x), BATCH)]
        return np.concatenate(out, axis=0).astype(np.float64, copy=False) if out else np.zeros((0, OUTPUTS[self.output]))

    def predict(self, windows: np.ndarray) -> np.ndarray:
        """``(..., W, 6)`` raw windows -> ``(..., 6)`` std [m/s², rad/s per IMU sample]."""
        from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

        x = np.asarray(windows)
        lead = x.shape[:-2]
        y = self._run(x.reshape((-1,) + x.shape[-2:]))
        if self.output == "q_scale":  # a factor <= 0 gives NaN or 0: a fault for the filters, as a std <= 0
            nominal = np.array([NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE])
            with np.errstate(invalid="ignore"):
                y = np.repeat(nominal * np.sqrt(y), 3, axis=-1)
        return y.reshape(lead + (6,))


# ----------------------------------------------------------------------------- ProcessNet as ONNX
def _net_nodes(helper, numpy_helper, net, p: str, x: str, start: int, nodes: list, inits: list) -> str:
    """Nodes of one sensor's normalizer + network reading ``x`` (N, W, 3) float64 from column
    ``start``; returns the name of its (N, 3) float64 std."""
    from onnx import TensorProto

    def const(name, arr):
        inits.append(numpy_helper.from_array(np.asarray(arr), p + name))
        return p + name

    def node(op, ins, name, **attrs):
        nodes.append(helper.make_node(op, ins, [p + name], name=p + name, **attrs))
        return p + name

    norm, prm, d = net.normalizer, net.params, net.normalizer.diff_order
    i64 = lambda v: np.array(v, dtype=np.int64)  # noqa: E731
    h = node("Slice", [x, const("c0", i64([start])), const("c1", i64([start + 3])), const("ax2", i64([2]))], "cols")
    big = i64([np.iinfo(np.int64).max])
    for k in range(d):  # d-th difference along time (Normalizer.transform, float64)
        hi = node("Slice", [h, const(f"one{k}", i64([1])), const(f"end{k}", big), const(f"t{k}", i64([1]))], f"hi{k}")
        lo = node("Slice", [h, const(f"zero{k}", i64([0])), const(f"m1{k}", i64([-1])), const(f"u{k}", i64([1]))], f"lo{k}")
        h = node("Sub", [hi, lo], f"diff{k}")
    mean = node("ReduceMean", [h], "mean", axes=[1], keepdims=1)
    h = node("Div", [node("Sub", [h, mean], "centred"), const("in_scale", np.array(norm.in_scale))], "scaled")
    if d:
        h = node("Pad", [h, const("pads", i64([0, d, 0, 0, 0, 0]))], "padded")
    h = node("Cast", [h], "x32", to=TensorProto.FLOAT if net.dtype == np.float32 else TensorProto.DOUBLE)
    # channels-last (N, L, C) throughout, as processnet.py
    dt, L = net.dtype, int(net.window)
    for i, pool in ((1, None), (2, "avg"), (3, None), (4, "max")):
        # 'same' k=3 conv as processnet.conv_forward: im2col of the zero-padded input, one MatMul
        xp = node("Pad", [h, const(f"pad{i}", i64([0, 1, 0, 0, 1, 0]))], f"xp{i}")
        taps = [node("Slice", [xp, const(f"s{i}{t}", i64([t])), const(f"e{i}{t}", i64([t + L])),
                               const(f"a{i}{t}", i64([1]))], f"tap{i}{t}") for t in range(3)]
        cols = node("Concat", taps, f"cols{i}", axis=2)
        W = prm[f"W{i}"].reshape(-1, prm[f"W{i}"].shape[-1]).astype(dt)  # (3 Cin, Cout)
        h = node("Add", [node("MatMul", [cols, const(f"W{i}", W)], f"mm{i}"), const(f"b{i}", prm[f"b{i}"].astype(dt))],
                 f"conv{i}")
        h = node("Relu", [h], f"relu{i}")
        if pool:  # eqs 37 (average) and 40 (max) over pairs of time steps
            C = prm[f"W{i}"].shape[-1]
            pairs = node("Reshape", [h, const(f"pshape{i}", i64([-1, L // 2, 2, C]))], f"pairs{i}")
            h = node("ReduceMean" if pool == "avg" else "ReduceMax", [pairs], f"pool{i}", axes=[2], keepdims=0)
            L //= 2
    h = node("Reshape", [h, const("flat", i64([-1, prm["W5"].shape[0]]))], "flat7")  # time-major, as l7
    h = node("Gemm", [h, const("W5", prm["W5"].astype(dt)), const("b5", prm["b5"].astype(dt))], "out")
    h = node("Cast", [h], "out64", to=TensorProto.DOUBLE)
    return node("Mul", [h, const("out_scale", np.array(norm.out_scale))], "std")


def processnet_onnx(acc_net, gyro_net, meta: dict | None = None):
    """The ``onnx.ModelProto`` of the two ProcessNets with their normalizers: input ``imu``
    (N, W, 6) float64, output ``std`` (N, 6) float64 (the contract of this module)."""
    onnx = _import("onnx", "exporting ProcessNet as ONNX")
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], []
    a = _net_nodes(helper, numpy_helper, acc_net, "acc/", INPUT, 0, nodes, inits)
    g = _net_nodes(helper, numpy_helper, gyro_net, "gyro/", INPUT, 3, nodes, inits)
    nodes.append(helper.make_node("Concat", [a, g], ["std"], name="std", axis=1))
    graph = helper.make_graph(nodes, "processnet", [helper.make_tensor_value_info(INPUT, TensorProto.DOUBLE,
                                                                                   ["N", acc_net.window, 6])],
                              [helper.make_tensor_value_info("std", TensorProto.DOUBLE, ["N", 6])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="nespm")
    model.ir_version = 8  # readable by onnxruntime >= 1.14
    helper.set_model_props(model, {"nespm.rate_hz": f"{IMU_RATE_HZ:g}", "nespm.kind": "processnet",
                                   **{f"nespm.{k}": str(v) for k, v in (meta or {}).items()}})
    onnx.checker.check_model(model)
    return model
