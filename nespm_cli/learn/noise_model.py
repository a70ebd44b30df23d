"""ProcessNet at run time (anukf.md III-D): the packaged weights, one IMU window per DVL
interval, and the network's noise std for every run and interval.

What the filters do with that std (Q of eqs 43-48) is :mod:`nespm_cli.filters.adaptive`.
"""
from __future__ import annotations

import dataclasses
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from nespm_cli.errors import NespmError

from nespm_cli.learn.processnet import VALIDITY_CLIP
from nespm_cli.learn.training import load_processnet, predict_noise_std

WINDOW = 100  # IMU steps per ProcessNet window (anukf.md: w = 100)
#: how a message names the option of the model file: its two spellings, one option (--noise-model
#: and its alias --weights); :func:`nespm_cli.learn.noise_models.load_noise_model` puts the one typed
OPTION = "--noise-model/--weights"


def default_weights() -> Path:
    """The weights that ship with the package (trained on the embedded tracks 1-4)."""
    return Path(str(resources.files("nespm_cli.learn") / "processnet.npz"))


#: the reference windows of :func:`check_weights`: the IMU steps of the first DVL intervals of
#: embedded track 5 (synthesized, exact) plus white noise of 1x and 4x the nominal std
REFERENCE_TRACK = 5
REFERENCE_WINDOWS = 20
REFERENCE_SEED = 20240601
REFERENCE_LEVELS = (1.0, 4.0)  # multiples of the nominal std


@lru_cache(maxsize=4)
def load_weights(path: str | None):
    """``(acc_net, gyro_net, meta)`` from ``path`` (None: the packaged default); cached per process.

    The networks are checked before they are used (:func:`check_weights`); every failure, a
    missing, corrupt or foreign file included, is a NespmError naming the file.
    """
    p = Path(path) if path else default_weights()
    if not p.is_file():
        raise NespmError(f"{OPTION} {p}: no such file (train one with `nespm train`)")
    try:
        nets = load_processnet(p)
    except NespmError as exc:
        msg = str(exc)
        raise NespmError(f"{OPTION} {msg}" if msg.startswith(f"{p}:") else f"{OPTION} {p}: {msg}") from None
    except Exception as exc:  # a corrupt or foreign .npz
        raise NespmError(f"{OPTION} {p}: not a ProcessNet file ({type(exc).__name__}: {exc})") from None
    check_weights(nets[0], nets[1], f"{OPTION} {p}")
    return nets


def reference_windows() -> tuple[np.ndarray, np.ndarray]:
    """The deterministic windows the weights are checked on: ``(f, w)``, each
    (len(REFERENCE_LEVELS), REFERENCE_WINDOWS, WINDOW, 3) [m/s², rad/s].

    Level i is the exact synthesized IMU of the first :data:`REFERENCE_WINDOWS` DVL intervals of
    embedded track :data:`REFERENCE_TRACK` plus white noise of ``REFERENCE_LEVELS[i]`` times the
    nominal std per 100 Hz sample (one draw, seed :data:`REFERENCE_SEED`, scaled per level).
    """
    from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
    from nespm_cli.data.embedded import embedded_track
    from nespm_cli.nav.synthesis import synthesize

    tr = embedded_track(REFERENCE_TRACK)
    s = slice(0, REFERENCE_WINDOWS + 1)
    truth = synthesize(dataclasses.replace(tr, t=tr.t[s], pos=tr.pos[s], v_n=tr.v_n[s], euler=tr.euler[s],
                                           dvl=tr.dvl[s], imu=None))
    rng = np.random.default_rng(REFERENCE_SEED)
    out = []
    for clean, nominal in ((truth.f_b, NOMINAL_ACC_NOISE), (truth.w_ib_b, NOMINAL_GYRO_NOISE)):
        noise = rng.standard_normal(clean.shape)
        levels = np.stack([clean + k * nominal * noise for k in REFERENCE_LEVELS])  # (L, M, 3)
        out.append(interval_windows(levels, truth.epoch_index))
    return out[0], out[1]


def check_weights(acc_net, gyro_net, name: str) -> None:
    """Refuse networks the adaptive filters would silently misuse; ``name`` starts every message.

    Checks, per network: every parameter a finite floating-point array and the normalizer's
    scales finite and positive; then on :func:`reference_windows` (1x and 4x the nominal noise
    std) the predicted std, in multiples of the nominal std
    (:data:`nespm_cli.data.corruption.NOMINAL_ACC_NOISE`, ``NOMINAL_GYRO_NOISE``), must be finite
    and > 0 (the rule of every noise model's output, :func:`output_problem`), not all at or beyond
    the validity clip :data:`nespm_cli.learn.processnet.VALIDITY_CLIP` (the filters would replace
    every value by a bound), and larger on average at 4x than at 1x.
    Mean outputs at 1x / 4x: the packaged weights 1.05 / 4.06 (acc), 1.04 / 4.07 (gyro); weights of
    `nespm train --tracks 1 --test-tracks 5 --runs 2 --epochs 1` 3.40 / 3.82 and 3.66 / 4.20. About
    30 ms (0.1 s with the reference track built), once per process (:func:`load_weights` is cached).
    """
    from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

    lo, hi = VALIDITY_CLIP
    windows = reference_windows()
    for sensor, net, x, nominal in (("acc", acc_net, windows[0], NOMINAL_ACC_NOISE),
                                    ("gyro", gyro_net, windows[1], NOMINAL_GYRO_NOISE)):
        what = f"{name}: {sensor} network"
        for key, arr in net.params.items():
            a = np.asarray(arr)
            if not np.issubdtype(a.dtype, np.floating):
                raise NespmError(f"{what}: parameter {key} has dtype {a.dtype}, expected floating point")
            bad = int(a.size - np.count_nonzero(np.isfinite(a)))
            if bad:
                raise NespmError(f"{what}: parameter {key} holds {bad} non-finite value{'s' if bad != 1 else ''} "
                                 f"(NaN or inf) of {a.size}")
        norm = net.normalizer
        if norm is None or not all(np.isfinite(v) and v > 0 for v in (norm.in_scale, norm.out_scale)):
            raise NespmError(f"{what}: normalizer scales must be finite and positive, got "
                             f"{None if norm is None else (norm.in_scale, norm.out_scale)}")
        try:
            with np.errstate(all="ignore"):
                p = net.predict_std(x.reshape((-1,) + x.shape[-2:])).reshape(x.shape[:2] + (3,)) / nominal
        except NespmError as exc:
            raise NespmError(f"{what}: {exc}") from None
        except Exception as exc:  # a network the file describes but that cannot run
            raise NespmError(f"{what}: cannot run on {WINDOW}-sample windows ({type(exc).__name__}: {exc})") from None
        bad = output_problem(p)
        if bad:
            raise NespmError(f"{what}: on the reference windows {bad}")
        if not ((p > lo) & (p < hi)).any():
            raise NespmError(f"{what}: every output on the reference windows is at or beyond the validity clip "
                             f"{lo:g}-{hi:g} x nominal (range {p.min():.4g}-{p.max():.4g}); the adaptive filters "
                             "would use the clip bounds only")
        m1, m4 = float(p[0].mean()), float(p[-1].mean())
        if not m4 > m1:
            raise NespmError(f"{what}: does not read the noise level: mean output {m1:.4g} x nominal at "
                             f"{REFERENCE_LEVELS[0]:g}x the nominal noise, {m4:.4g} at {REFERENCE_LEVELS[-1]:g}x "
                             "(must increase)")


def output_problem(y: np.ndarray) -> str:
    """The one rule of a noise model's output (``std`` or ``q_scale``, any kind of model): every value
    finite and > 0. Returns ``""`` when ``y`` obeys it, else what breaks it ("2 of 240 outputs are
    non-finite (NaN or inf) and 1 is <= 0 (...)"). The filters apply the same rule at run time
    (:func:`nespm_cli.filters.adaptive.model_faults`: the run is lost)."""
    y = np.asarray(y, dtype=float)
    with np.errstate(invalid="ignore"):
        nonfinite = int(y.size - np.count_nonzero(np.isfinite(y)))
        nonpos = int(np.count_nonzero(np.isfinite(y) & ~(y > 0)))
    counts = [(n, what) for n, what in ((nonfinite, "non-finite (NaN or inf)"), (nonpos, "<= 0")) if n]
    if not counts:
        return ""
    parts = [f"{n}{f' of {y.size} outputs' if i == 0 else ''} {'is' if n == 1 else 'are'} {what}"
             for i, (n, what) in enumerate(counts)]
    return " and ".join(parts) + " (every output must be finite and > 0)"


def interval_windows(x: np.ndarray, epoch_index: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Cut IMU readings into one window per DVL interval: the :data:`WINDOW` steps that end at
    the interval's closing epoch.

    With the synthesized IMU every interval has exactly 100 steps, so the window is the whole
    interval. A recorded IMU on the 400/399 s GT grid has 100.25 samples per interval, plus the
    step split at the epoch (:func:`nespm_cli.nav.synthesis.recorded_grid`): 101-102 steps, of
    which the last 100 are the window (the split step's reading then appears twice; 1 % of a
    window).

    Args:
        x: (R, M, 3) readings; step j runs from sample j to j+1.
        epoch_index: (N,) IMU sample index of each epoch.

    Returns:
        (R, N-1, 100, 3): window k holds steps ``epoch_index[k+1]-100 .. epoch_index[k+1]-1``.
    """
    e = np.asarray(epoch_index)
    steps = np.diff(e)
    if len(e) < 2 or not np.all(steps >= WINDOW):
        bad = int(np.flatnonzero(steps < WINDOW)[0]) if len(e) >= 2 else 0
        raise NespmError(
            f"adaptive filters need at least {WINDOW} IMU steps per DVL interval; interval {bad} has "
            f"{int(steps[bad]) if len(steps) else 0} (use --imu synthetic)")
    rows = e[1:, None] - window + np.arange(window)  # (N-1, window)
    return x[:, rows]


def predict_interval_std(f_meas: np.ndarray, w_meas: np.ndarray, epoch_index: np.ndarray,
                         weights: str | None = None, clip: tuple[float, float] | None = None):
    """ProcessNet noise std for every run and DVL interval (any noise model:
    :func:`nespm_cli.learn.noise_models.predict_interval_std`).

    Returns ``(std_a, std_g)``, each (R, N-1, 3) [m/s², rad/s per IMU sample], unclipped
    (clipping happens in :func:`adaptive_q`, so the raw prediction can be recorded).
    """
    acc, gyro, _ = load_weights(weights)
    return predict_noise_std(acc, gyro, interval_windows(f_meas, epoch_index),
                             interval_windows(w_meas, epoch_index), clip=clip)


#: IMU rate of every experiment [Hz] (the windows the filters cut are 100 steps of 10 ms)
IMU_RATE_HZ = 100.0


class NoiseModel:
    """The noise-model protocol (:mod:`nespm_cli.learn.noise_models`, docs/learned.md).

    Attributes:
        name: short kind name ("processnet", "onnx", a plugin's).
        window: IMU steps per window (100 for every built-in).
        rate_hz: IMU rate the model expects [Hz].
        source: the file it was loaded from (None: built in memory).
    """

    name: str = "noise-model"
    window: int = WINDOW
    rate_hz: float = IMU_RATE_HZ
    source: Path | None = None

    def predict(self, windows: np.ndarray) -> np.ndarray:
        """``(..., window, 6)`` raw IMU windows (specific force [m/s²], angular rate [rad/s]) ->
        ``(..., 6)`` white-noise std per IMU sample in the same units, unclipped."""
        raise NotImplementedError
