"""Training data, training loop and evaluation of the two ProcessNets (anukf.md III-C).

Data. Windows are cut from corrupted IMU streams: the clean synthesized IMU of a track
(:func:`synthesis.synthesize`) plus the additive errors of the ``dynamic`` corruption
schedule (:func:`corruption.imu_errors`), for ``runs`` realizations per track. The label of
a window is the per-axis std of the white noise injected in it (base std x segment
factor; the RMS of the per-sample stds for a window straddling a segment boundary).

What makes the problem learnable: input preprocessing (``Normalizer.diff_order``).
The network must find a white noise far below the motion signal. After removing the
window mean, the residual motion of a 1 s window (aligned with a GT interval) on the real
tracks is, in units of the base noise std (median / 99th percentile over windows, worst
axis): accelerometer 0.3-0.6 / 6-16 for the raw window, < 0.15 at the 99th percentile for
the first difference; gyro 180-440 / 3000-8600 raw (turns of up to 0.3 rad/s against
7.3e-6 rad/s of noise), 3-8 / 84-270 for the first difference, < 0.35 for the second.
Within one GT interval the synthesized IMU is a smooth spline, so differencing removes the
motion and leaves (coloured) noise of known std, sqrt(C(2d, d))·σ. Measured (train on real
tracks 1-4, 16 runs, 8 epochs; Spearman on held-out real tracks 5-6, 8 runs, 6384 windows):

============= ======= ======= ======= =======
diff order    0       1       2       3
============= ======= ======= ======= =======
accelerometer 0.987   0.991   0.990
gyro          −0.016  0.935   0.988   0.986
============= ======= ======= ======= =======

So the accelerometer network takes the first difference and the gyro network the second
(``processnet.SENSOR_DIFF_ORDER``); without differencing the gyro network learns nothing.

Result with the defaults (``train_processnet((1, 2, 3, 4), (5, 6), real data)``: 24 runs,
12 epochs, batch 32, Adam lr 3e-3 decaying to 1.5e-4, 32,558 training + 5,746 validation
windows per sensor, float32): Spearman on tracks 5-6 (8 runs, 6384 windows) **0.993
(acc), 0.992 (gyro)**, relative RMS error 4.6 % and 4.9 %; 96 s wall in all on the 2
shared cores (2 s data, 45 s + 48 s training), 0.73 GB peak memory. For reference the
classical estimator (sample std of the differenced window pooled over the three axes)
reaches 0.990 / 0.989, and per axis 0.977 / 0.969: the network pools the axes, which
share one factor in the protocol. Windows straddling a segment boundary (5 %) are
predicted almost as well (mean |relative error| 4.6 % vs 3.6 % inside a segment, acc).
Windows must be the IMU steps of one GT/DVL interval, as in training: shifted by 25 or 50
samples (a spline knot inside the window) the gyro network drops to 0.983 / 0.974 (acc
unchanged at 0.993).

Speed: the numpy network trains at about 9,000 windows/s in float32 on one core (the
stacked 3-D matmuls do not use BLAS threads, which were 3-9x slower when the cores are
shared); inference runs at about 14,000 windows/s.
"""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from nespm_cli.data.corruption import CorruptionConfig, draw, imu_errors, segment_index
from nespm_cli.errors import NespmError
from nespm_cli.learn.processnet import BLOCK, VALIDITY_CLIP, Adam, Normalizer, ProcessNet, load_nets, mse_loss, save_nets
from nespm_cli.data.corrections import apply_corrections
from nespm_cli.data.tracks import load_track
from nespm_cli.nav.synthesis import from_recorded, synthesize

SENSORS = ("acc", "gyro")
DEFAULT_RUNS = 24
DEFAULT_EPOCHS = 12
DEFAULT_TEST_RUNS = 8
# predict_noise_std clips the outputs to [lo, hi] x the base std (anukf.md III-D: "positive,
# not too small, not too large"); the protocol's factors are 1-6.
DEFAULT_CLIP = VALIDITY_CLIP


# ----------------------------------------------------------------------------- data
def clean_imu(number: int, data_dir=None, imu: str = "synthetic", corrections: dict | None = None,
              accept_residual: bool | None = None):
    """The clean IMU of a track (:class:`~nespm_cli.nav.synthesis.ImuTruth`): synthesized from the GT,
    or the recorded one with the track's corrections (``corrections``: ``{track: Corrections}``).
    ``accept_residual``: :func:`~nespm_cli.data.tracks.load_track`'s (None: the track spec's key decides)."""
    track = load_track(int(number), data_dir, accept_residual=accept_residual)
    c = (corrections or {}).get(int(number))
    if c is not None:
        track = apply_corrections(track, c)
    return synthesize(track) if imu == "synthetic" else from_recorded(track)


def make_windows(track_numbers, data_dir=None, runs: int = DEFAULT_RUNS, seed: int = 0, schedule: str = "dynamic",
                 window: int = 100, stride: int = 100, config: CorruptionConfig | None = None,
                 imu: str = "synthetic", corrections: dict | None = None, accept_residual: bool | None = None) -> dict:
    """Windows of corrupted IMU readings and their injected noise levels.

    For every track, ``runs`` realizations are drawn exactly as the Monte Carlo runner
    draws them (``corruption.draw(seed, track, range(runs), duration, config)`` and
    ``corruption.imu_errors``), added to the clean synthesized IMU and cut into windows of
    ``window`` samples every ``stride`` samples, starting at the first IMU step. With the
    defaults (100, 100) window k is exactly the IMU steps of GT/DVL interval k, the window
    the filters hand to the network once per DVL update. With ``imu="recorded"`` (the
    track's recorded IMU, ``corrections`` applied: :func:`clean_imu`) the windows are the
    last ``window`` steps before every GT epoch, as the filters cut them
    (:func:`nespm_cli.learn.noise_model.interval_windows`); ``stride`` does not apply.

    The regression target is the noise **std**, not the variance (the paper's "diagonal
    entries of Q"): the factors span 1-6 in std but 1-36 in variance, so std targets are
    far better conditioned for an MSE loss (a variance loss is dominated by the noisiest
    windows) and the ReLU network, positively homogeneous in its input, naturally
    produces an output proportional to the input's scale. The filters square it.

    Args:
        track_numbers: tracks to use; ``data_dir`` None means the embedded tracks.
        runs: realizations per track (run indices 0..runs-1).
        config: corruption std values (default: the protocol's, with ``schedule``).
        accept_residual: :func:`clean_imu`'s (``--accept-residual``: True; None: the track spec's key).

    Returns:
        dict with ``X_acc``, ``X_gyro`` (K, window, 3) [m/s^2], [rad/s]; ``y_acc``,
        ``y_gyro`` (K, 3) injected noise std in the same units; ``track``, ``run`` (K,) int;
        ``t0`` (K,) start of the window [s since the track's first sample]; ``base_std``
        ``{"acc", "gyro"}``; ``config`` (dict). Rows are ordered track, run, window.
    """
    if runs < 1:
        raise NespmError(f"runs must be at least 1, got {runs}")
    if window < 1 or stride < 1:
        raise NespmError("window and stride must be positive")
    cfg = config if config is not None else CorruptionConfig(schedule=schedule)
    parts = {k: [] for k in ("X_acc", "X_gyro", "y_acc", "y_gyro", "track", "run", "t0")}
    for n in track_numbers:
        truth = clean_imu(int(n), data_dir, imu, corrections, accept_residual)
        t_rel = truth.t - truth.t[0]
        M = truth.steps
        if M < window:
            raise NespmError(f"track {n}: {M} IMU steps, fewer than one window of {window}")
        real = draw(seed, int(n), np.arange(runs), float(t_rel[-1]), cfg)
        e_f, e_w = imu_errors(real, truth.t)
        seg = segment_index(t_rel[1:], cfg.segment_s, real.acc_factors.shape[1])  # segment of every step
        if imu == "synthetic":
            starts = np.arange(0, M - window + 1, stride)
        else:
            e = truth.epoch_index
            starts = e[1:] - window
            starts = starts[starts >= 0]
        idx = starts[:, None] + np.arange(window)  # (K, w)
        K = len(starts)
        for key, clean, err, base, fac in (("acc", truth.f_b, e_f, cfg.acc_noise, real.acc_factors),
                                           ("gyro", truth.w_ib_b, e_w, cfg.gyro_noise, real.gyro_factors)):
            meas = clean[None] + err  # (R, M, 3)
            parts[f"X_{key}"].append(meas[:, idx].reshape(runs * K, window, 3))
            std = base * fac[:, seg]  # (R, M) per-sample injected std
            y = np.sqrt(np.mean(std[:, idx] ** 2, axis=-1)).reshape(-1)  # RMS over the window
            parts[f"y_{key}"].append(np.repeat(y[:, None], 3, axis=1))
        parts["track"].append(np.full(runs * K, int(n)))
        parts["run"].append(np.repeat(np.arange(runs), K))
        parts["t0"].append(np.tile(t_rel[starts], runs))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["base_std"] = {"acc": cfg.acc_noise, "gyro": cfg.gyro_noise}
    out["config"] = asdict(cfg)
    return out


# ----------------------------------------------------------------------------- training
def train(X: np.ndarray, y: np.ndarray, sensor: str, epochs: int = DEFAULT_EPOCHS, batch: int = 32, lr: float = 3e-3,
          val_frac: float = 0.15, patience: int = 4, seed: int = 0, progress: Callable[[dict], None] | None = None,
          base_std: float | None = None, diff_order: int | None = None, dtype=np.float32,
          lr_final: float = 0.05) -> tuple[ProcessNet, dict]:
    """Train one ProcessNet on raw windows ``X`` (K, 100, 3) and noise stds ``y`` (K, 3).

    The windows are normalized once (:class:`processnet.Normalizer` of ``sensor``), split
    at random into training and validation (``val_frac``), and trained with Adam on the
    MSE of eq 42 in normalized units. The learning rate decays geometrically from ``lr``
    to ``lr·lr_final`` over ``epochs``. Early stopping: training ends after ``patience``
    epochs without a lower validation loss, and the weights of the best epoch are restored.

    Args:
        progress: called after every epoch with ``{"sensor", "epoch", "epochs",
            "train_loss", "val_loss", "best", "seconds"}``.
        dtype: float32 trains twice as fast as float64 and is ample for a 1e-2 loss.

    Returns:
        ``(net, history)``; history holds per-epoch ``train_loss``, ``val_loss`` (normalized
        MSE), ``lr``, ``seconds`` (cumulative), plus ``best_epoch`` (0-based), ``epochs_run``,
        ``n_train``, ``n_val`` and ``val_index`` (the validation rows of ``X``).
    """
    X = np.asarray(X)
    y = np.asarray(y, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or y.shape != (len(X), 3):
        raise NespmError(f"train: X must be (K, w, 3) and y (K, 3), got {X.shape} and {y.shape}")
    if not 0 < val_frac < 1:
        raise NespmError("val_frac must be in (0, 1)")
    norm = Normalizer.for_sensor(sensor, base_std, diff_order)
    F = norm.transform(X, dtype)
    T = norm.encode(y).astype(dtype)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(F))
    n_val = max(1, int(round(val_frac * len(F))))
    if len(F) - n_val < 1:
        raise NespmError("train: not enough windows for a validation split")
    vi, ti = perm[:n_val], perm[n_val:]
    Fv, Tv = F[vi], T[vi]
    net = ProcessNet(norm, seed=seed, dtype=dtype, window=X.shape[1])
    net.params["b5"][:] = T[ti].mean(axis=0)  # start at the mean level
    opt = Adam(net.params, lr=lr)
    hist = {"train_loss": [], "val_loss": [], "lr": [], "seconds": []}
    best, best_params, best_epoch, bad = np.inf, None, -1, 0
    t_start = time.perf_counter()
    for ep in range(epochs):
        opt.lr = lr * lr_final ** (ep / max(1, epochs - 1))
        order = ti[rng.permutation(len(ti))]
        tot = 0.0
        for s in range(0, len(order), batch):
            b = order[s:s + batch]
            loss, dy = mse_loss(net.forward(F[b]), T[b])
            opt.step(net.backward(dy))
            tot += loss * len(b)
        val = mse_loss(net.predict(Fv).astype(np.float64), Tv.astype(np.float64))[0]
        hist["train_loss"].append(tot / len(order))
        hist["val_loss"].append(val)
        hist["lr"].append(opt.lr)
        hist["seconds"].append(time.perf_counter() - t_start)
        if val < best:
            best, best_epoch, bad = val, ep, 0
            best_params = {k: v.copy() for k, v in net.params.items()}
        else:
            bad += 1
        if progress is not None:
            progress({"sensor": sensor, "epoch": ep + 1, "epochs": epochs, "train_loss": hist["train_loss"][-1],
                      "val_loss": val, "best": best, "seconds": hist["seconds"][-1]})
        if bad >= patience:
            break
    for k, v in best_params.items():
        net.params[k][...] = v
    net._cache = None
    hist.update(best_epoch=best_epoch, epochs_run=len(hist["val_loss"]), n_train=len(ti), n_val=n_val,
                val_index=vi)
    return net, hist


def evaluate(net: ProcessNet, X: np.ndarray, y: np.ndarray) -> dict:
    """Agreement of predicted and injected noise std on raw windows ``X`` (K, w, 3), ``y`` (K, 3).

    Returns floats: ``spearman`` (all axes pooled), ``spearman_x/y/z``, ``rmse`` and
    ``rmse_x/y/z`` in sensor units, ``rel_rmse`` (RMS of predicted/true − 1) and ``n``.
    """
    from scipy.stats import spearmanr  # here: importing scipy.stats costs ~0.4 s (CLI start-up)

    y = np.asarray(y, dtype=np.float64)
    p = net.predict_std(X)
    out = {"n": int(len(y)), "spearman": float(spearmanr(p.ravel(), y.ravel()).statistic),
           "rmse": float(np.sqrt(np.mean((p - y) ** 2))), "rel_rmse": float(np.sqrt(np.mean((p / y - 1) ** 2)))}
    for i, c in enumerate("xyz"):
        out[f"spearman_{c}"] = float(spearmanr(p[:, i], y[:, i]).statistic)
        out[f"rmse_{c}"] = float(np.sqrt(np.mean((p[:, i] - y[:, i]) ** 2)))
    return out


# ----------------------------------------------------------------------------- end to end
def train_processnet(train_tracks=(1, 2, 3, 4), test_tracks=(5, 6), data_dir=None, out_path="processnet.npz",
                     runs: int = DEFAULT_RUNS, epochs: int = DEFAULT_EPOCHS, seed: int = 0,
                     progress: Callable[[dict], None] | None = None, test_runs: int = DEFAULT_TEST_RUNS,
                     batch: int = 32, lr: float = 3e-3, val_frac: float = 0.15, patience: int = 4,
                     imu: str = "synthetic", corrections: dict | None = None,
                     accept_residual: bool | None = None) -> dict:
    """Train the accelerometer and gyro ProcessNets and write them with their evaluation.

    Trains on ``runs`` dynamic-schedule realizations of ``train_tracks``, evaluates the
    Spearman correlation between predicted and injected noise std on ``test_runs``
    realizations of the held-out ``test_tracks`` (tracks read as :func:`make_windows` with
    ``accept_residual``), and writes

    * ``out_path`` (.npz): both networks (``acc/...``, ``gyro/...``) with their
      normalizers, and ``meta`` (JSON: configuration, histories, test metrics);
    (the loss curves are drawn by :func:`nespm_cli.reports.training.plot_history` from ``history``).

    Returns a summary: ``spearman`` ``{"acc", "gyro"}`` on the test tracks, ``test``
    (full :func:`evaluate` dicts), ``epochs_run``, ``history`` (per sensor), ``seconds`` (total
    and per phase), ``path``.
    """
    t_all = time.perf_counter()
    out_path = Path(out_path)
    overlap = set(train_tracks) & set(test_tracks)
    if overlap:
        raise NespmError(f"training and test tracks overlap: {sorted(overlap)}")
    t0 = time.perf_counter()
    tr = make_windows(train_tracks, data_dir, runs, seed, imu=imu, corrections=corrections,
                      accept_residual=accept_residual)
    te = make_windows(test_tracks, data_dir, test_runs, seed, imu=imu, corrections=corrections,
                      accept_residual=accept_residual)
    t_data = time.perf_counter() - t0
    nets, hists, tests, secs = {}, {}, {}, {}
    for s in SENSORS:
        t0 = time.perf_counter()
        nets[s], hists[s] = train(tr[f"X_{s}"], tr[f"y_{s}"], s, epochs=epochs, batch=batch, lr=lr,
                                  val_frac=val_frac, patience=patience, seed=seed, progress=progress,
                                  base_std=tr["base_std"][s])
        secs[s] = time.perf_counter() - t0
        tests[s] = evaluate(nets[s], te[f"X_{s}"], te[f"y_{s}"])
        del tr[f"X_{s}"]
    seconds = time.perf_counter() - t_all
    meta = {
        "kind": "nespm-processnet",
        "config": {"train_tracks": list(train_tracks), "test_tracks": list(test_tracks),
                   "data_dir": str(data_dir) if data_dir is not None else None, "runs": runs, "test_runs": test_runs,
                   "epochs": epochs, "batch": batch, "lr": lr, "val_frac": val_frac, "patience": patience,
                   "seed": seed, "schedule": "dynamic", "window": 100, "stride": 100, "corruption": tr["config"],
                   "imu": imu, "corrections": {str(k): asdict(v) for k, v in (corrections or {}).items()},
                   "normalizer": {s: asdict(nets[s].normalizer) for s in SENSORS}},
        "history": {s: {k: v for k, v in h.items() if k != "val_index"} for s, h in hists.items()},
        "test": tests,
        "seconds": {"total": seconds, "data": t_data, **secs},
    }
    save_nets(out_path, nets, meta)
    return {"spearman": {s: tests[s]["spearman"] for s in SENSORS}, "test": tests,
            "epochs_run": {s: hists[s]["epochs_run"] for s in SENSORS}, "history": hists,
            "seconds": time.perf_counter() - t_all, "seconds_detail": meta["seconds"],
            "path": str(out_path)}


def load_processnet(path) -> tuple[ProcessNet, ProcessNet, dict]:
    """Read a file written by :func:`train_processnet`: ``(acc_net, gyro_net, meta)``."""
    nets, meta = load_nets(path)
    missing = [s for s in SENSORS if s not in nets]
    if missing:
        raise NespmError(f"{path}: no {' or '.join(missing)} network")
    return nets["acc"], nets["gyro"], meta


def predict_noise_std(acc_net: ProcessNet, gyro_net: ProcessNet, f_windows: np.ndarray, w_windows: np.ndarray,
                      clip: tuple[float, float] | None = DEFAULT_CLIP, batch: int = BLOCK) -> tuple[np.ndarray, np.ndarray]:
    """Noise std of accelerometers and gyros from windows of their readings.

    Args:
        f_windows, w_windows: (..., 100, 3) specific force [m/s^2] and angular rate [rad/s]
            (any leading batch shape, e.g. (runs, 100, 3): one window per run, the IMU
            steps of the last DVL interval).
        clip: outputs are clipped to ``[lo, hi] x`` the network's base std (positive, not
            too small, not too large: anukf.md III-D); None disables.

    Returns:
        ``(std_acc, std_gyro)``, each (..., 3) in m/s^2 and rad/s per 100 Hz sample.
    """
    res = []
    for net, x in ((acc_net, f_windows), (gyro_net, w_windows)):
        x = np.asarray(x, dtype=np.float64)
        lead = x.shape[:-2]
        p = net.predict_std(x.reshape((-1,) + x.shape[-2:]), batch)
        if clip is not None:
            base = net.normalizer.out_scale
            p = np.clip(p, clip[0] * base, clip[1] * base)
        res.append(p.reshape(lead + (3,)))
    return res[0], res[1]
