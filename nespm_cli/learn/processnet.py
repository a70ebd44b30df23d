"""ProcessNet (anukf.md section III-B/C, eqs 34-42) in plain numpy.

The network regresses the per-axis white-noise level of one inertial sensor from a window
of its readings. It is about 10k parameters, so numpy is enough and no deep-learning
framework is pulled in. Everything is batched over windows: inputs are ``(B, w=100, 3)``
(batch, time, axis), activations ``(B, length, channels)``.

Layers (eqs 34-41), ``W`` stored as ``(tap, in, out)`` so that the paper's
``Θ_l(j, k, h) = W[h, j, k]``:

====== ========================================== ============== =========
layer  operation                                  output         params
====== ========================================== ============== =========
l1     conv k=3 'same' zero pad, 3→30, ReLU (35)   (B, 100, 30)   W1 b1
l2     conv 30→30, ReLU (36)                      (B, 100, 30)   W2 b2
l3     average pool 2 (37)                        (B, 50, 30)
l4     conv 30→30, ReLU (38)                      (B, 50, 30)    W3 b3
l5     conv 30→30, ReLU (39)                      (B, 50, 30)    W4 b4
l6     max pool 2 (40)                            (B, 25, 30)
l7     flatten (time-major, C order)              (B, 750)
out    linear 750→3 (41)                          (B, 3)         W5 b5
====== ========================================== ============== =========

Eq 37 is printed as ``0.5·l2(2i−1) + l2(2i)``, which weights the two samples unequally
and is not a pooling at all; we read it as the average pool ``0.5·(l2(2i−1) + l2(2i))``
the text announces ("followed by max/average pooling").

A convolution is one matmul on an im2col array built by stacking the three shifted copies
of the padded input along the channel axis, ``(B, L, 3·C_in) @ (3·C_in, C_out)``; there is
no Python loop over samples or positions.

Scaling. The paper's gyro network has "scale components to the input and the output,
forcing the network to work with sufficiently large numbers". :class:`Normalizer` does
this for both sensors and is stored with the weights:

* input: optionally the ``diff_order``-th difference along time, then the window mean per
  axis is removed (this takes away gravity, the sensor bias and slow motion, none of which
  carry information on the noise level), then division by ``in_scale``; the differenced
  window is zero-padded at its start back to length ``w``;
* output: ``label / out_scale``.

With ``in_scale = σ_base·sqrt(C(2d, d))`` (the std of the d-th difference of white noise of
std σ_base) and ``out_scale = σ_base``, both networks see inputs of std 1-6 and targets in
[1, 6] whatever the sensor units. The choice of ``diff_order`` per sensor is discussed in
:mod:`nespm_cli.learn.training`.

Files: :func:`save_nets` / :func:`load_nets` write one ``.npz`` holding any number of
networks under prefixes ``<sensor>/`` (weights, normalizer, sensor name) and a JSON string
``meta`` (training configuration and metrics); no pickles.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from math import comb
from pathlib import Path

import numpy as np

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
from nespm_cli.errors import NespmError

WINDOW = 100
IN_CH = 3
CHANNELS = 30
OUT = 3
KERNEL = 3
#: windows per block of :meth:`ProcessNet.predict` (a fixed shape: the outputs do not depend on the batch)
BLOCK = 64
PARAM_NAMES = ("W1", "b1", "W2", "b2", "W3", "b3", "W4", "b4", "W5", "b5")

# Base white-noise std per 100 Hz sample of the corruption protocol (corruption.py) and the
# input difference order chosen per sensor (see training.py for the measurements).
#: validity bounds of a network std, as multiples of the nominal std (anukf.md III-D)
VALIDITY_CLIP = (0.25, 24.0)
SENSOR_BASE_STD = {"acc": NOMINAL_ACC_NOISE, "gyro": NOMINAL_GYRO_NOISE}  # m/s^2, rad/s
SENSOR_DIFF_ORDER = {"acc": 1, "gyro": 2}


# ----------------------------------------------------------------------------- layers
def conv_forward(x: np.ndarray, W: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """'same' k=3 cross-correlation with zero padding (eqs 35, 36, 38, 39 before the ReLU).

    Args:
        x: (B, L, Cin); W: (3, Cin, Cout); b: (Cout,).

    Returns:
        ``(z, cols)``: z (B, L, Cout) and the im2col array (B, L, 3·Cin) for the backward pass.
    """
    B, L, C = x.shape
    cols = np.empty((B, L, 3 * C), dtype=x.dtype)  # [x(t-1), x(t), x(t+1)], zero beyond the ends
    cols[:, 0, :C] = 0.0
    cols[:, 1:, :C] = x[:, :-1]
    cols[:, :, C:2 * C] = x
    cols[:, :-1, 2 * C:] = x[:, 1:]
    cols[:, -1, 2 * C:] = 0.0
    z = cols @ W.reshape(-1, W.shape[-1]) + b
    return z, cols


def conv_backward(dz: np.ndarray, cols: np.ndarray, W: np.ndarray, need_dx: bool = True):
    """Gradients of :func:`conv_forward`: ``(dx (B, L, Cin) or None, dW, db)``."""
    K, Cin, Cout = W.shape
    dW = (cols.transpose(0, 2, 1) @ dz).sum(axis=0).reshape(W.shape)
    db = dz.sum(axis=(0, 1))
    if not need_dx:
        return None, dW, db
    L = dz.shape[1]
    dcols = dz @ W.reshape(-1, Cout).T  # (B, L, 3 Cin)
    dxp = np.zeros((dz.shape[0], L + 2, Cin), dtype=dz.dtype)
    for h in range(K):  # three taps, not positions
        dxp[:, h:h + L] += dcols[..., h * Cin:(h + 1) * Cin]
    return dxp[:, 1:L + 1], dW, db


def avgpool_forward(x: np.ndarray) -> np.ndarray:
    """Eq 37 read as average pooling: ``out[i] = 0.5·(x[2i] + x[2i+1])`` (0-based)."""
    B, L, C = x.shape
    return x.reshape(B, L // 2, 2, C).mean(axis=2)


def avgpool_backward(dout: np.ndarray) -> np.ndarray:
    return np.repeat(0.5 * dout, 2, axis=1)


def maxpool_forward(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq 40: ``out[i] = max(x[2i], x[2i+1])``; returns the output and the winner mask
    (ties go to the first sample, so exactly one sample per pair gets the gradient)."""
    B, L, C = x.shape
    x2 = x.reshape(B, L // 2, 2, C)
    first = x2[:, :, 0] >= x2[:, :, 1]
    return np.where(first, x2[:, :, 0], x2[:, :, 1]), first


def maxpool_backward(dout: np.ndarray, first: np.ndarray) -> np.ndarray:
    B, L2, C = dout.shape
    d = np.zeros((B, L2, 2, C), dtype=dout.dtype)
    d[:, :, 0] = np.where(first, dout, 0)
    d[:, :, 1] = np.where(first, 0, dout)
    return d.reshape(B, 2 * L2, C)


def mse_loss(pred: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray]:
    """Eq 42: ``(1/n) Σ_i ||N_i − N̂_i||²`` over a batch of n rows; returns ``(loss, dloss/dpred)``."""
    n = pred.shape[0]
    r = pred - target
    return float(np.sum(r * r) / n), (2.0 / n) * r


# ----------------------------------------------------------------------------- normalizer
@dataclass(frozen=True)
class Normalizer:
    """Input/output scaling of one sensor's network (see the module docstring).

    Attributes:
        sensor: "acc" or "gyro" (any name is allowed).
        in_scale: divisor of the (differenced, mean-removed) window, sensor units.
        out_scale: divisor of the label (noise std), sensor units.
        diff_order: order d of the time difference taken before the mean removal.
    """

    sensor: str
    in_scale: float
    out_scale: float
    diff_order: int = 0

    @classmethod
    def for_sensor(cls, sensor: str, base_std: float | None = None, diff_order: int | None = None) -> "Normalizer":
        """Scales from the protocol's base noise std so that inputs and targets are O(1)."""
        if base_std is None:
            if sensor not in SENSOR_BASE_STD:
                raise NespmError(f"unknown sensor {sensor!r}: give base_std")
            base_std = SENSOR_BASE_STD[sensor]
        d = SENSOR_DIFF_ORDER.get(sensor, 0) if diff_order is None else int(diff_order)
        return cls(sensor, float(base_std) * float(np.sqrt(comb(2 * d, d))), float(base_std), d)

    def transform(self, windows: np.ndarray, dtype=np.float64) -> np.ndarray:
        """Raw windows (K, w, 3) in sensor units -> network inputs (K, w, 3) of ``dtype``.

        The difference and the mean are taken in float64 (the gyro noise is 1e-4 of the
        signal) before the cast.
        """
        x = np.asarray(windows, dtype=np.float64)
        d = self.diff_order
        if d:
            x = np.diff(x, n=d, axis=1)
        x = x - x.mean(axis=1, keepdims=True)
        x = x / self.in_scale
        if d:
            x = np.concatenate([np.zeros(x.shape[:1] + (d,) + x.shape[2:]), x], axis=1)
        return x.astype(dtype, copy=False)

    def encode(self, y: np.ndarray) -> np.ndarray:
        """Label in sensor units -> network target."""
        return np.asarray(y, dtype=np.float64) / self.out_scale

    def decode(self, out: np.ndarray) -> np.ndarray:
        """Network output -> noise std in sensor units."""
        return np.asarray(out, dtype=np.float64) * self.out_scale


# ----------------------------------------------------------------------------- network
class ProcessNet:
    """The ProcessNet regression network of eqs 34-41.

    Attributes:
        params: dict ``W1 (3,3,30), b1 (30,), W2..W4 (3,30,30), b2..b4 (30,), W5 (750,3), b5 (3,)``.
        normalizer: the :class:`Normalizer` of the sensor (None for a bare network).
        dtype: float64 (gradient checks) or float32 (training, 2x faster).

    ``forward`` works on network-space inputs (already normalized) and keeps a cache for
    ``backward``; ``predict`` is the cache-free batched version; ``predict_std`` takes raw
    windows in sensor units and returns noise stds in sensor units.
    """

    def __init__(self, normalizer: Normalizer | None = None, seed: int | None = 0, dtype=np.float64,
                 window: int = WINDOW, channels: int = CHANNELS):
        if window % 4:
            raise NespmError(f"ProcessNet window must be a multiple of 4, got {window}")
        self.normalizer = normalizer
        self.dtype = np.dtype(dtype)
        self.window = window
        self.channels = channels
        self.params: dict[str, np.ndarray] = {}
        self._cache = None
        if seed is not None:
            self.init(seed)

    @property
    def sensor(self) -> str | None:
        return self.normalizer.sensor if self.normalizer else None

    def shapes(self) -> dict[str, tuple]:
        C, w = self.channels, self.window
        return {"W1": (KERNEL, IN_CH, C), "b1": (C,), "W2": (KERNEL, C, C), "b2": (C,),
                "W3": (KERNEL, C, C), "b3": (C,), "W4": (KERNEL, C, C), "b4": (C,),
                "W5": ((w // 4) * C, OUT), "b5": (OUT,)}

    def init(self, seed: int) -> "ProcessNet":
        """He initialization (std sqrt(2 / fan_in)) of the weights, zero biases."""
        rng = np.random.default_rng(seed)
        p = {}
        for name, shape in self.shapes().items():
            if name.startswith("W"):
                fan_in = int(np.prod(shape[:-1]))
                p[name] = (rng.standard_normal(shape) * np.sqrt(2.0 / fan_in)).astype(self.dtype)
            else:
                p[name] = np.zeros(shape, dtype=self.dtype)
        self.params = p
        return self

    @property
    def n_params(self) -> int:
        return int(sum(v.size for v in self.params.values()))

    # -- forward / backward
    def _check(self, x):
        x = np.asarray(x)
        if x.ndim != 3 or x.shape[1:] != (self.window, IN_CH):
            raise NespmError(f"ProcessNet input must be (B, {self.window}, {IN_CH}), got {x.shape}")
        return x.astype(self.dtype, copy=False)

    def forward(self, x: np.ndarray) -> np.ndarray:
        """(B, w, 3) normalized windows -> (B, 3) network outputs; caches for :meth:`backward`."""
        p = self.params
        x = self._check(x)
        z1, c1 = conv_forward(x, p["W1"], p["b1"])
        a1 = np.maximum(z1, 0)
        z2, c2 = conv_forward(a1, p["W2"], p["b2"])
        a2 = np.maximum(z2, 0)
        a3 = avgpool_forward(a2)
        z4, c4 = conv_forward(a3, p["W3"], p["b3"])
        a4 = np.maximum(z4, 0)
        z5, c5 = conv_forward(a4, p["W4"], p["b4"])
        a5 = np.maximum(z5, 0)
        a6, first = maxpool_forward(a5)
        f7 = a6.reshape(len(x), -1)
        y = f7 @ p["W5"] + p["b5"]
        self._cache = dict(c1=c1, z1=z1, c2=c2, z2=z2, c4=c4, z4=z4, c5=c5, z5=z5, first=first, f7=f7,
                           shape6=a6.shape)
        return y

    def relu_pattern(self) -> np.ndarray:
        """Concatenated ReLU on/off and max-pool winner masks of the last forward (tests)."""
        c = self._cache
        return np.concatenate([(c[k] > 0).ravel() for k in ("z1", "z2", "z4", "z5")] + [c["first"].ravel()])

    def backward(self, dy: np.ndarray, input_grad: bool = False) -> dict[str, np.ndarray]:
        """Exact gradients of a loss with ``dloss/dy = dy`` (B, 3) w.r.t. every parameter
        (and the input ``"x"`` if ``input_grad``), for the last :meth:`forward`."""
        if self._cache is None:
            raise NespmError("ProcessNet.backward called before forward")
        p, c = self.params, self._cache
        dy = np.asarray(dy, dtype=self.dtype)
        g = {"W5": c["f7"].T @ dy, "b5": dy.sum(axis=0)}
        d6 = (dy @ p["W5"].T).reshape(c["shape6"])
        d5 = maxpool_backward(d6, c["first"]) * (c["z5"] > 0)
        d4, g["W4"], g["b4"] = conv_backward(d5, c["c5"], p["W4"])
        d4 = d4 * (c["z4"] > 0)
        d3, g["W3"], g["b3"] = conv_backward(d4, c["c4"], p["W3"])
        d2 = avgpool_backward(d3) * (c["z2"] > 0)
        d1, g["W2"], g["b2"] = conv_backward(d2, c["c2"], p["W2"])
        d1 = d1 * (c["z1"] > 0)
        dx, g["W1"], g["b1"] = conv_backward(d1, c["c1"], p["W1"], need_dx=input_grad)
        if input_grad:
            g["x"] = dx
        return g

    def predict(self, x: np.ndarray, batch: int = BLOCK) -> np.ndarray:
        """Batched inference without a cache: (K, w, 3) normalized windows -> (K, 3).

        The windows go through in blocks of ``batch`` (default :data:`BLOCK`), the last one filled up
        with zero windows: every block is the same shape of products, so a window's output does not
        depend on how many windows share the call or where it sits among them (the chunk size and a
        run's place in its chunk never change a number; tests/test_processnet.py), and a block's
        im2col arrays stay in the cache (64 windows: 1.46x faster on one BLAS thread than the 1024 of
        before, whose outputs moved by float32's last bits with the number of windows;
        benchmarks/README.md).
        """
        x = self._check(x)
        p = self.params
        K = len(x)
        out = np.empty((K, OUT), dtype=self.dtype)
        for s in range(0, K, batch):  # fixed-size blocks; every window is independent
            blk = x[s:s + batch]
            n = len(blk)
            if n < batch:
                blk = np.concatenate([blk, np.zeros((batch - n,) + blk.shape[1:], dtype=blk.dtype)])
            h = np.maximum(conv_forward(blk, p["W1"], p["b1"])[0], 0)
            h = avgpool_forward(np.maximum(conv_forward(h, p["W2"], p["b2"])[0], 0))
            h = np.maximum(conv_forward(h, p["W3"], p["b3"])[0], 0)
            h = maxpool_forward(np.maximum(conv_forward(h, p["W4"], p["b4"])[0], 0))[0]
            out[s:s + n] = (h.reshape(batch, -1) @ p["W5"] + p["b5"])[:n]
        return out

    def predict_std(self, windows: np.ndarray, batch: int = BLOCK) -> np.ndarray:
        """Raw windows (K, w, 3) in sensor units -> predicted noise std (K, 3) in sensor units
        (unclipped; see :func:`training.predict_noise_std` for the clipped version)."""
        if self.normalizer is None:
            raise NespmError("ProcessNet.predict_std needs a normalizer")
        x = self.normalizer.transform(windows, self.dtype)
        return self.normalizer.decode(self.predict(x, batch))

    # -- files
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        a = {f"{prefix}{k}": v for k, v in self.params.items()}
        a[f"{prefix}window"] = np.array(self.window)
        a[f"{prefix}channels"] = np.array(self.channels)
        if self.normalizer is not None:
            n = self.normalizer
            a[f"{prefix}sensor"] = np.array(n.sensor)
            a[f"{prefix}norm.in_scale"] = np.array(n.in_scale)
            a[f"{prefix}norm.out_scale"] = np.array(n.out_scale)
            a[f"{prefix}norm.diff_order"] = np.array(n.diff_order)
        return a

    @classmethod
    def from_arrays(cls, arrays, prefix: str) -> "ProcessNet":
        key = f"{prefix}sensor"
        norm = None
        if key in arrays:
            norm = Normalizer(str(arrays[key]), float(arrays[f"{prefix}norm.in_scale"]),
                              float(arrays[f"{prefix}norm.out_scale"]), int(arrays[f"{prefix}norm.diff_order"]))
        W1 = arrays[f"{prefix}W1"]
        net = cls(norm, seed=None, dtype=W1.dtype, window=int(arrays[f"{prefix}window"]),
                  channels=int(arrays[f"{prefix}channels"]))
        net.params = {k: np.array(arrays[f"{prefix}{k}"]) for k in PARAM_NAMES}
        for k, shape in net.shapes().items():
            if net.params[k].shape != shape:
                raise NespmError(f"ProcessNet file: {prefix}{k} has shape {net.params[k].shape}, expected {shape}")
        return net

    def save(self, path, meta: dict | None = None) -> Path:
        """Write this network (prefix ``<sensor>/``) and ``meta`` to ``path`` (.npz)."""
        return save_nets(path, {self.sensor or "net": self}, meta)

    @classmethod
    def load(cls, path, sensor: str | None = None) -> tuple["ProcessNet", dict]:
        """Read one network from a file written by :meth:`save` or :func:`save_nets`;
        ``sensor`` selects it when the file holds several."""
        nets, meta = load_nets(path)
        if sensor is None:
            if len(nets) != 1:
                raise NespmError(f"{path}: holds networks {sorted(nets)}; name the sensor")
            sensor = next(iter(nets))
        if sensor not in nets:
            raise NespmError(f"{path}: no {sensor!r} network (has {sorted(nets)})")
        return nets[sensor], meta


class Adam:
    """Adam (Kingma & Ba) with bias correction, updating a params dict in place."""

    def __init__(self, params: dict[str, np.ndarray], lr: float = 1e-3, betas=(0.9, 0.999), eps: float = 1e-8):
        self.params = params
        self.lr = lr
        self.b1, self.b2 = betas
        self.eps = eps
        self.t = 0
        self.m = {k: np.zeros_like(v) for k, v in params.items()}
        self.v = {k: np.zeros_like(v) for k, v in params.items()}

    def step(self, grads: dict[str, np.ndarray]) -> None:
        self.t += 1
        c1 = 1.0 - self.b1 ** self.t
        c2 = 1.0 - self.b2 ** self.t
        for k, p in self.params.items():
            g = grads[k]
            m, v = self.m[k], self.v[k]
            m *= self.b1
            m += (1 - self.b1) * g
            v *= self.b2
            v += (1 - self.b2) * (g * g)
            p -= (self.lr / c1) * m / (np.sqrt(v / c2) + self.eps)


# ----------------------------------------------------------------------------- files
def save_nets(path, nets: dict[str, ProcessNet], meta: dict | None = None) -> Path:
    """One ``.npz`` with every network under ``<name>/`` plus ``meta`` as a JSON string."""
    path = Path(path)
    arrays = {"format": np.array("nespm-processnet-1"), "nets": np.array(json.dumps(sorted(nets))),
              "meta": np.array(json.dumps(meta or {}, default=_json_default))}
    for name, net in nets.items():
        arrays.update(net.to_arrays(f"{name}/"))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)
    return path


def load_nets(path) -> tuple[dict[str, ProcessNet], dict]:
    """Inverse of :func:`save_nets`: ``({name: ProcessNet}, meta)``."""
    path = Path(path)
    if not path.is_file():
        raise NespmError(f"{path}: no such ProcessNet file")
    with np.load(path, allow_pickle=False) as z:
        if "nets" not in z or "meta" not in z:
            raise NespmError(f"{path}: not a ProcessNet file")
        names = json.loads(str(z["nets"]))
        arrays = {k: z[k] for k in z.files}
    nets = {name: ProcessNet.from_arrays(arrays, f"{name}/") for name in names}
    return nets, json.loads(str(arrays["meta"]))


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "__dataclass_fields__"):
        return asdict(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")
