"""A small ONNX noise model built with the ``onnx`` helper API alone (no deep-learning framework).

It follows the contract of docs/learned.md: input ``imu`` (N, W, 6) float32 raw IMU windows
(specific force [m/s²], angular rate [rad/s]), output ``std`` (N, 6): the per-axis white-noise
std per IMU sample, estimated as ``sqrt(mean(diff(x)²) / 2)`` over the window (the first
difference of white noise of std σ has variance 2σ²; the slow motion, gravity and bias cancel).
A "learned" network exported from PyTorch or any framework has the same two tensors.

    python examples/onnx_noise_model.py diff-std.onnx
    nespm mc --filters ekf,anekf --noise-model diff-std.onnx --tracks 5 --runs 10 --out results/onnx
"""
from __future__ import annotations

import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

WINDOW = 100


def build(window: int = WINDOW) -> onnx.ModelProto:
    """The ModelProto of the difference-std noise model for ``window``-step windows."""
    i64 = lambda name, v: numpy_helper.from_array(np.array(v, dtype=np.int64), name)  # noqa: E731
    inits = [i64("one", [1]), i64("end", [window]), i64("zero", [0]), i64("last", [window - 1]), i64("time", [1]),
             numpy_helper.from_array(np.array(0.5, dtype=np.float32), "half")]
    nodes = [
        helper.make_node("Slice", ["imu", "one", "end", "time"], ["later"]),
        helper.make_node("Slice", ["imu", "zero", "last", "time"], ["earlier"]),
        helper.make_node("Sub", ["later", "earlier"], ["diff"]),            # (N, W-1, 6)
        helper.make_node("Mul", ["diff", "diff"], ["sq"]),
        helper.make_node("ReduceMean", ["sq"], ["msq"], axes=[1], keepdims=0),  # (N, 6)
        helper.make_node("Mul", ["msq", "half"], ["var"]),
        helper.make_node("Sqrt", ["var"], ["std"]),
    ]
    graph = helper.make_graph(nodes, "diff_std",
                              [helper.make_tensor_value_info("imu", TensorProto.FLOAT, ["N", window, 6])],
                              [helper.make_tensor_value_info("std", TensorProto.FLOAT, ["N", 6])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="nespm-example")
    model.ir_version = 8
    helper.set_model_props(model, {"nespm.rate_hz": "100"})
    onnx.checker.check_model(model)
    return model


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "diff-std.onnx"
    onnx.save(build(), out)
    print(out)
