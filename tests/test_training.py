"""Tests of nespm_cli.learn.training: training windows and labels from the dynamic corruption
schedule, the training loop (early stopping, best weights restored), evaluation, the
end-to-end train_processnet on embedded tracks and the inference helpers.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from nespm_cli.data.corruption import CorruptionConfig, draw, imu_errors, segment_index
from nespm_cli.errors import NespmError
from nespm_cli.learn.processnet import ProcessNet, load_nets, mse_loss
from nespm_cli.nav.synthesis import synthesize
from nespm_cli.data.tracks import load_track
from nespm_cli.learn.training import (
    evaluate,
    load_processnet,
    make_windows,
    predict_noise_std,
    train,
    train_processnet,
)


@pytest.fixture(scope="module")
def win():
    return make_windows((1, 2), None, runs=3, seed=5)


# ----------------------------------------------------------------------------- windows
def test_make_windows_shapes(win):
    K = 2 * 3 * 399  # tracks x runs x (39,900 steps / 100)
    for s in ("acc", "gyro"):
        assert win[f"X_{s}"].shape == (K, 100, 3)
        assert win[f"y_{s}"].shape == (K, 3)
        assert np.all(np.isfinite(win[f"X_{s}"]))
    for k in ("track", "run", "t0"):
        assert win[k].shape == (K,)
    assert set(win["track"]) == {1, 2} and set(win["run"]) == {0, 1, 2}
    assert win["base_std"] == {"acc": 0.03, "gyro": 7.3e-6}
    assert win["config"]["schedule"] == "dynamic"


def test_windows_are_clean_imu_plus_protocol_errors(win):
    """Rows reproduce synthesize + corruption.imu_errors exactly, in track, run, window order."""
    truth = synthesize(load_track(2, None))
    cfg = CorruptionConfig(schedule="dynamic")
    real = draw(5, 2, np.arange(3), float(truth.t[-1] - truth.t[0]), cfg)
    e_f, e_w = imu_errors(real, truth.t)
    row = 3 * 399 + 1 * 399 + 17  # track 2, run 1, window 17
    assert win["track"][row] == 2 and win["run"][row] == 1
    sl = slice(1700, 1800)
    np.testing.assert_array_equal(win["X_acc"][row], truth.f_b[sl] + e_f[1, sl])
    np.testing.assert_array_equal(win["X_gyro"][row], truth.w_ib_b[sl] + e_w[1, sl])
    assert win["t0"][row] == pytest.approx(truth.t[1700] - truth.t[0])


def test_labels_are_base_std_times_segment_factor(win):
    """Inside one segment the label is base std x that segment's factor; a window straddling
    a boundary gets the RMS of its per-sample stds."""
    truth = synthesize(load_track(1, None))
    t_rel = truth.t - truth.t[0]
    cfg = CorruptionConfig(schedule="dynamic")
    real = draw(5, 1, np.arange(3), float(t_rel[-1]), cfg)
    S = real.acc_factors.shape[1]
    seg = segment_index(t_rel[1:], cfg.segment_s, S)
    starts = np.arange(0, truth.steps - 99, 100)
    first, last = seg[starts], seg[starts + 99]
    inside = first == last
    assert 0.9 < inside.mean() < 1.0  # 20 s segments, 1 s windows: a few straddle
    for r in range(3):
        rows = slice(r * 399, (r + 1) * 399)
        ya, yg = win["y_acc"][rows], win["y_gyro"][rows]
        np.testing.assert_allclose(ya[inside], 0.03 * real.acc_factors[r, first[inside], None] * np.ones(3), rtol=1e-12)
        np.testing.assert_allclose(yg[inside], 7.3e-6 * real.gyro_factors[r, first[inside], None] * np.ones(3),
                                   rtol=1e-12)
        k = np.flatnonzero(~inside)[0]
        n_first = int(np.sum(seg[starts[k]:starts[k] + 100] == first[k]))
        f = real.acc_factors[r]
        expect = 0.03 * np.sqrt((n_first * f[first[k]] ** 2 + (100 - n_first) * f[last[k]] ** 2) / 100)
        assert ya[k, 0] == pytest.approx(expect, rel=1e-12)
    assert np.all((win["y_acc"] >= 0.03 - 1e-15) & (win["y_acc"] <= 0.18 + 1e-15))


def test_make_windows_deterministic_and_seeded(win):
    again = make_windows((1, 2), None, runs=3, seed=5)
    for k in ("X_acc", "X_gyro", "y_acc", "y_gyro", "t0", "track", "run"):
        np.testing.assert_array_equal(again[k], win[k])
    other = make_windows((1,), None, runs=1, seed=6)
    assert not np.array_equal(other["y_acc"], win["y_acc"][:399])


def test_make_windows_stride_and_errors():
    w = make_windows((3,), None, runs=1, seed=0, stride=50)
    assert w["X_acc"].shape == ((39900 - 100) // 50 + 1, 100, 3)
    np.testing.assert_allclose(np.diff(w["t0"][:3]), 50 * 400 / 399 / 100, rtol=1e-9)
    with pytest.raises(NespmError):
        make_windows((3,), None, runs=0)


# ----------------------------------------------------------------------------- train / evaluate
def _noise(k, rng, sigma=0.03):
    s = rng.uniform(1, 6, k) * sigma
    return 9.8 + s[:, None, None] * rng.standard_normal((k, 100, 3)), np.repeat(s[:, None], 3, axis=1)


def test_train_history_and_best_weights_restored():
    rng = np.random.default_rng(0)
    X, y = _noise(1200, rng)
    seen = []
    net, h = train(X, y, "acc", epochs=4, batch=32, lr=3e-3, val_frac=0.25, patience=10, seed=1, progress=seen.append)
    assert len(h["train_loss"]) == len(h["val_loss"]) == h["epochs_run"] == 4 == len(seen)
    assert h["n_train"] + h["n_val"] == 1200 and h["n_val"] == 300
    assert seen[-1]["sensor"] == "acc" and seen[-1]["epoch"] == 4
    vi = h["val_index"]
    F = net.normalizer.transform(X[vi], net.dtype)
    val = mse_loss(net.predict(F).astype(float), net.normalizer.encode(y[vi]))[0]
    assert val == pytest.approx(min(h["val_loss"]), rel=1e-5)  # the best epoch's weights
    assert h["val_loss"][h["best_epoch"]] == min(h["val_loss"])
    assert h["val_loss"][-1] < h["val_loss"][0]


def test_train_early_stopping():
    """With lr = 0 the validation loss never improves after epoch 1: stop after 1 + patience."""
    rng = np.random.default_rng(1)
    X, y = _noise(200, rng)
    net, h = train(X, y, "acc", epochs=20, lr=0.0, patience=2, seed=0)
    assert h["epochs_run"] == 3 and h["best_epoch"] == 0


def test_train_input_errors():
    with pytest.raises(NespmError):
        train(np.zeros((10, 100, 3)), np.zeros((9, 3)), "acc", epochs=1)
    with pytest.raises(NespmError):
        train(np.zeros((10, 100, 3)), np.zeros((10, 3)), "acc", epochs=1, val_frac=1.5)


class _Fixed:
    """A stand-in network returning fixed predictions."""

    def __init__(self, p):
        self.p = p

    def predict_std(self, X):
        return self.p


def test_evaluate_metrics():
    y = np.repeat(np.linspace(1, 6, 50)[:, None], 3, axis=1) * 0.03
    perfect = evaluate(_Fixed(y * 1.1), np.zeros((50, 100, 3)), y)  # monotone: Spearman 1
    assert perfect["spearman"] == pytest.approx(1.0) and perfect["spearman_z"] == pytest.approx(1.0)
    assert perfect["rel_rmse"] == pytest.approx(0.1)
    assert perfect["rmse_x"] == pytest.approx(np.sqrt(np.mean((0.1 * y[:, 0]) ** 2)))
    rev = evaluate(_Fixed(y[::-1].copy()), np.zeros((50, 100, 3)), y)
    assert rev["spearman"] == pytest.approx(-1.0)
    assert rev["n"] == 50


# ----------------------------------------------------------------------------- end to end
def test_train_processnet_end_to_end(tmp_path):
    """Two embedded training tracks, held-out embedded tracks 5 and 6, a small budget."""
    out = tmp_path / "pn" / "processnet.npz"
    calls = []
    res = train_processnet((1, 2), (5, 6), None, out, runs=6, epochs=3, seed=0, progress=calls.append,
                           test_runs=2, batch=32, lr=3e-3)
    assert out.is_file()
    from nespm_cli.reports.training import plot_history

    png = plot_history(res["history"], out.with_suffix(".png"), res["test"])
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert set(res["spearman"]) == {"acc", "gyro"}
    assert len(calls) == res["epochs_run"]["acc"] + res["epochs_run"]["gyro"]
    assert res["seconds"] < 60
    # even this tiny budget (~600 Adam steps) learns the noise level on unseen tracks
    assert res["spearman"]["acc"] > 0.8 and res["spearman"]["gyro"] > 0.8, res["spearman"]

    acc, gyro, meta = load_processnet(out)
    assert acc.sensor == "acc" and gyro.sensor == "gyro"
    assert acc.normalizer.diff_order == 1 and gyro.normalizer.diff_order == 2
    assert meta["config"]["train_tracks"] == [1, 2] and meta["config"]["test_tracks"] == [5, 6]
    assert meta["test"]["gyro"]["spearman"] == pytest.approx(res["spearman"]["gyro"])
    assert len(meta["history"]["acc"]["val_loss"]) == res["epochs_run"]["acc"]
    json.dumps(meta)

    w = make_windows((4,), None, runs=2, seed=9)
    f = w["X_acc"].reshape(2, 399, 100, 3)[:, :5]  # leading batch shape (2, 5)
    g = w["X_gyro"].reshape(2, 399, 100, 3)[:, :5]
    sa, sg = predict_noise_std(acc, gyro, f, g)
    assert sa.shape == sg.shape == (2, 5, 3)
    assert np.all(np.isfinite(sa)) and np.all(sa > 0) and np.all(np.isfinite(sg)) and np.all(sg > 0)
    np.testing.assert_allclose(sa.reshape(-1, 3), np.clip(acc.predict_std(f.reshape(-1, 100, 3)), 0.0075, 0.72))
    # right order of magnitude: within a factor 2 of the injected std on average
    ratio = sg.reshape(-1, 3) / w["y_gyro"].reshape(2, 399, 3)[:, :5].reshape(-1, 3)
    assert 0.5 < np.exp(np.mean(np.log(ratio))) < 2.0
    # constant windows (no noise at all) are clipped to a positive floor
    za, zg = predict_noise_std(acc, gyro, np.full((3, 100, 3), 9.8), np.zeros((3, 100, 3)))
    assert np.all(za >= 0.25 * 0.03 - 1e-15) and np.all(zg >= 0.25 * 7.3e-6 - 1e-20)
    nets, _ = load_nets(out)
    assert set(nets) == {"acc", "gyro"}


def test_train_processnet_rejects_overlap(tmp_path):
    with pytest.raises(NespmError):
        train_processnet((1, 5), (5, 6), None, tmp_path / "x.npz", runs=1, epochs=1)


def test_load_processnet_needs_both(tmp_path):
    path = ProcessNet(None, seed=0).save(tmp_path / "one.npz")
    with pytest.raises(NespmError):
        load_processnet(path)
