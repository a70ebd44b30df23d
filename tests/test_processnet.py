"""Tests of nespm_cli.learn.processnet: exact gradients (finite differences), shapes and parameter
count, the two pooling layers by hand, Adam, save/load, the normalizer, and learning a
noise level from pure white noise.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import spearmanr

from nespm_cli.errors import NespmError
from nespm_cli.learn.processnet import (
    Adam,
    Normalizer,
    ProcessNet,
    avgpool_backward,
    avgpool_forward,
    conv_forward,
    load_nets,
    maxpool_backward,
    maxpool_forward,
    mse_loss,
    save_nets,
)


# ----------------------------------------------------------------------------- gradients
def _loss(net, x, t):
    return mse_loss(net.forward(x), t)[0]


def test_gradient_check_every_parameter_and_input():
    """Central differences (eps 1e-6, float64) vs backward on ~20 entries of every tensor.

    The network is piecewise linear and the loss quadratic, so central differences are
    exact up to round-off unless a perturbation moves a ReLU or max-pool decision; such
    entries are detected by comparing the activation patterns of the ±eps evaluations
    with the base pattern and skipped (there must be few). The relative error uses
    max(|analytic|, |numeric|, 1e-3·max|grad of the tensor|) as denominator, so entries
    whose gradient is pure round-off (~1e-10) do not count.
    """
    rng = np.random.default_rng(7)
    net = ProcessNet(seed=3, dtype=np.float64)
    for k, v in net.params.items():  # non-zero biases so every bias gradient is exercised
        if k.startswith("b"):
            v[...] = 0.1 * rng.standard_normal(v.shape)
    x = rng.standard_normal((3, 100, 3))
    t = rng.standard_normal((3, 3))
    loss, dy = mse_loss(net.forward(x), t)
    base = net.relu_pattern().copy()
    grads = net.backward(dy, input_grad=True)
    eps = 1e-6
    worst, checked, skipped = 0.0, 0, 0
    for name in list(net.params) + ["x"]:
        arr = x if name == "x" else net.params[name]
        g = grads[name]
        assert g.shape == arr.shape, name
        floor = 1e-3 * np.abs(g).max()
        for i in rng.choice(arr.size, min(20, arr.size), replace=False):
            ii = np.unravel_index(i, arr.shape)
            v = arr[ii]
            arr[ii] = v + eps
            lp = _loss(net, x, t)
            same = np.array_equal(net.relu_pattern(), base)
            arr[ii] = v - eps
            lm = _loss(net, x, t)
            same &= np.array_equal(net.relu_pattern(), base)
            arr[ii] = v
            if not same:
                skipped += 1
                continue
            num = (lp - lm) / (2 * eps)
            rel = abs(num - g[ii]) / max(abs(num), abs(g[ii]), floor)
            worst = max(worst, rel)
            checked += 1
    assert skipped <= 5
    assert checked >= 190
    assert worst < 1e-5, worst


def test_gradients_of_batch_are_sum_of_singles():
    """The batch gradient of a summed loss equals the sum of per-window gradients."""
    rng = np.random.default_rng(1)
    net = ProcessNet(seed=0)
    x = rng.standard_normal((4, 100, 3))
    dy = rng.standard_normal((4, 3))
    net.forward(x)
    g = net.backward(dy, input_grad=True)
    acc = {k: 0 for k in g}
    for i in range(4):
        net.forward(x[i:i + 1])
        gi = net.backward(dy[i:i + 1], input_grad=True)
        for k in g:
            acc[k] = acc[k] + (gi[k] if k != "x" else 0)
        np.testing.assert_allclose(g["x"][i], gi["x"][0], rtol=1e-12, atol=1e-14)
    for k in net.params:
        np.testing.assert_allclose(g[k], acc[k], rtol=1e-10, atol=1e-13)


# ----------------------------------------------------------------------------- structure
def test_shapes_and_parameter_count():
    net = ProcessNet(seed=0)
    k, cin, c, w, out = 3, 3, 30, 100, 3
    expected = (k * cin * c + c) + 3 * (k * c * c + c) + ((w // 4) * c * out + out)
    assert expected == 10743
    assert net.n_params == expected
    assert net.forward(np.zeros((5, 100, 3))).shape == (5, 3)
    assert net.predict(np.ones((7, 100, 3)), batch=3).shape == (7, 3)
    with pytest.raises(NespmError):
        net.forward(np.zeros((5, 50, 3)))


def test_predict_matches_forward_and_batch_independent():
    rng = np.random.default_rng(2)
    net = ProcessNet(seed=5)
    x = rng.standard_normal((50, 100, 3))
    y = net.forward(x)
    np.testing.assert_allclose(net.predict(x, batch=7), y, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(net.predict(x[10:11]), y[10:11], rtol=1e-12, atol=1e-12)


def test_predict_sees_one_block_shape_whatever_the_count(monkeypatch):
    """Every block of windows reaches the network as the same shape (``BLOCK`` windows, the last block
    filled with zero windows), so a window's output cannot depend on how many windows share the call:
    the chunk size and a run's place in its chunk never change the adaptive filters' Q. Before, the
    last partial block was multiplied as a smaller product, whose float32 rounding moved the mc
    metrics of anekf/anukf by 1.3e-6 between --chunk-size 1 and 4 (benchmarks/README.md)."""
    from nespm_cli.learn import processnet as pn

    seen = []
    conv = pn.conv_forward

    def spy(x, W, b):
        seen.append(x.shape[0])
        return conv(x, W, b)

    monkeypatch.setattr(pn, "conv_forward", spy)
    net = ProcessNet(seed=5)
    x = np.random.default_rng(4).standard_normal((pn.BLOCK * 2 + 5, 100, 3))
    for k in (1, 5, pn.BLOCK, pn.BLOCK + 1, len(x)):
        seen.clear()
        y = net.predict(x[:k])
        assert y.shape == (k, 3) and np.isfinite(y).all()
        assert set(seen) == {pn.BLOCK} and len(seen) == 4 * -(-k // pn.BLOCK)  # four convolutions a block
    np.testing.assert_allclose(net.predict(x[3:4]), net.forward(x[3:4]), rtol=1e-12, atol=1e-12)


def test_he_init_statistics():
    net = ProcessNet(seed=0)
    for name, fan_in in (("W1", 9), ("W2", 90), ("W5", 750)):
        assert net.params[name].std() == pytest.approx(np.sqrt(2 / fan_in), rel=0.15)
    assert not np.any(net.params["b1"])
    np.testing.assert_array_equal(ProcessNet(seed=4).params["W3"], ProcessNet(seed=4).params["W3"])
    assert not np.array_equal(ProcessNet(seed=4).params["W3"], ProcessNet(seed=5).params["W3"])


def test_conv_is_same_padded_cross_correlation():
    """out[i, k] = sum_j sum_h xpad[i + h, j] W[h, j, k] + b[k] (eq 35) checked by loops."""
    rng = np.random.default_rng(3)
    x = rng.standard_normal((2, 6, 3))
    W = rng.standard_normal((3, 3, 4))
    b = rng.standard_normal(4)
    z, _ = conv_forward(x, W, b)
    xp = np.pad(x, ((0, 0), (1, 1), (0, 0)))
    ref = np.zeros((2, 6, 4))
    for n in range(2):
        for i in range(6):
            for k in range(4):
                ref[n, i, k] = sum(xp[n, i + h, j] * W[h, j, k] for h in range(3) for j in range(3)) + b[k]
    np.testing.assert_allclose(z, ref, rtol=1e-12)


def test_average_pool_by_hand():
    x = np.array([1.0, 3.0, -2.0, 6.0, 5.0, 5.0]).reshape(1, 6, 1)
    np.testing.assert_array_equal(avgpool_forward(x).ravel(), [2.0, 2.0, 5.0])
    np.testing.assert_array_equal(avgpool_backward(np.array([2.0, -4.0, 1.0]).reshape(1, 3, 1)).ravel(),
                                  [1.0, 1.0, -2.0, -2.0, 0.5, 0.5])


def test_max_pool_by_hand():
    x = np.array([[1.0, 10.0], [3.0, -1.0], [-2.0, 0.0], [6.0, -3.0]]).reshape(1, 4, 2)
    y, first = maxpool_forward(x)
    np.testing.assert_array_equal(y[0], [[3.0, 10.0], [6.0, 0.0]])
    d = maxpool_backward(np.array([[1.0, 2.0], [3.0, 4.0]]).reshape(1, 2, 2), first)
    np.testing.assert_array_equal(d[0], [[0.0, 2.0], [1.0, 0.0], [0.0, 4.0], [3.0, 0.0]])


def test_mse_loss_is_eq42():
    pred = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    tgt = np.array([[1.0, 0.0, 3.0], [1.0, 1.0, 1.0]])
    loss, d = mse_loss(pred, tgt)
    assert loss == pytest.approx((4.0 + 3.0) / 2)
    np.testing.assert_allclose(d, (pred - tgt))  # 2/n with n = 2


# ----------------------------------------------------------------------------- Adam
def test_adam_converges_on_quadratic():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 5))
    H = A @ A.T + np.eye(5)  # SPD, condition ~ tens
    target = rng.standard_normal(5)
    p = {"w": np.zeros(5)}
    opt = Adam(p, lr=0.05)
    for i in range(3000):
        opt.lr = 0.05 * 0.998 ** i
        opt.step({"w": H @ (p["w"] - target)})
    assert np.abs(p["w"] - target).max() < 1e-3


def test_adam_first_step_is_lr_times_sign():
    p = {"w": np.array([1.0, -2.0, 3.0])}
    Adam(p, lr=0.1).step({"w": np.array([5.0, -1e-3, 0.2])})
    np.testing.assert_allclose(p["w"], [0.9, -1.9, 2.9], atol=1e-6)


# ----------------------------------------------------------------------------- normalizer
def test_normalizer_removes_mean_bias_and_scales():
    rng = np.random.default_rng(0)
    n = Normalizer.for_sensor("gyro")
    assert n.diff_order == 2 and n.out_scale == 7.3e-6
    assert n.in_scale == pytest.approx(7.3e-6 * np.sqrt(6))
    noise = 3.0 * 7.3e-6 * rng.standard_normal((400, 100, 3))
    ramp = 0.2 + 1e-3 * np.arange(100)[None, :, None]  # bias + linear motion: gone after d=2
    f = n.transform(noise + ramp)
    assert f.shape == (400, 100, 3)
    np.testing.assert_array_equal(f[:, :2], 0.0)  # zero pad where the difference is undefined
    assert f[:, 2:].std() == pytest.approx(3.0, rel=0.02)  # O(1): the noise factor
    np.testing.assert_allclose(f[:, 2:].mean(axis=1), 0.0, atol=1e-9)
    n0 = Normalizer("acc", 0.03, 0.03, 0)
    g = n0.transform(9.81 + 0.03 * rng.standard_normal((10, 100, 3)))
    np.testing.assert_allclose(g.mean(axis=1), 0.0, atol=1e-12)  # gravity removed
    assert n0.decode(n0.encode(np.array([0.06]))) == pytest.approx(0.06)


# ----------------------------------------------------------------------------- files
def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    acc = ProcessNet(Normalizer.for_sensor("acc"), seed=1, dtype=np.float32)
    gyro = ProcessNet(Normalizer.for_sensor("gyro"), seed=2)
    meta = {"config": {"runs": 3, "tracks": [1, 2]}, "spearman": 0.91, "name": "ü"}
    path = save_nets(tmp_path / "m.npz", {"acc": acc, "gyro": gyro}, meta)
    nets, meta2 = load_nets(path)
    assert meta2 == meta
    x = rng.standard_normal((20, 100, 3))
    for name, net in (("acc", acc), ("gyro", gyro)):
        back = nets[name]
        assert back.normalizer == net.normalizer and back.dtype == net.dtype
        np.testing.assert_array_equal(back.predict(x), net.predict(x))  # bit for bit
        np.testing.assert_array_equal(back.predict_std(x * 1e-4), net.predict_std(x * 1e-4))
    one = acc.save(tmp_path / "one.npz", {"a": 1})
    net1, m1 = ProcessNet.load(one)
    assert m1 == {"a": 1} and net1.sensor == "acc"
    np.testing.assert_array_equal(net1.predict(x), acc.predict(x))
    with pytest.raises(NespmError):
        ProcessNet.load(path)  # two networks: must name one
    assert ProcessNet.load(path, "gyro")[0].sensor == "gyro"
    with np.load(path, allow_pickle=False) as z:  # plain arrays, no pickles
        assert json.loads(str(z["meta"]))["spearman"] == 0.91


def test_load_errors(tmp_path):
    with pytest.raises(NespmError):
        load_nets(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(NespmError):
        load_nets(tmp_path / "other.npz")


# ----------------------------------------------------------------------------- learning
def test_learns_white_noise_level():
    """Pure white noise (no motion) with a random per-window std in [1, 6]·σ: a few seconds
    of training give Spearman > 0.95 between predicted and true std on fresh windows."""
    rng = np.random.default_rng(0)
    sigma = 7.3e-6
    norm = Normalizer.for_sensor("gyro", sigma, diff_order=0)

    def windows(k):
        s = rng.uniform(1, 6, k) * sigma
        return s[:, None, None] * rng.standard_normal((k, 100, 3)), np.repeat(s[:, None], 3, axis=1)

    X, y = windows(3000)
    Xt, yt = windows(1000)
    net = ProcessNet(norm, seed=0, dtype=np.float32)
    F, T = norm.transform(X, np.float32), norm.encode(y).astype(np.float32)
    net.params["b5"][:] = T.mean()
    opt = Adam(net.params, lr=3e-3)
    for ep in range(4):  # how long this takes: benchmarks/bench_claims.py (processnet-training)
        perm = rng.permutation(len(F))
        for s in range(0, len(F), 32):
            b = perm[s:s + 32]
            opt.step(net.backward(mse_loss(net.forward(F[b]), T[b])[1]))
    p = net.predict_std(Xt)
    rho = spearmanr(p.ravel(), yt.ravel()).statistic
    assert rho > 0.95, rho
    assert np.sqrt(np.mean((p / yt - 1) ** 2)) < 0.2
