"""ProcessNet at run time (anukf.md III-D): the packaged weights, one IMU window per DVL
interval, and the network's noise std for every run and interval.

What the filters do with that std (Q of eqs 43-48) is :mod:`nespm_cli.filters.adaptive`.
"""
from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from nespm_cli.errors import NespmError

from nespm_cli.learn.training import load_processnet, predict_noise_std

WINDOW = 100  # IMU steps per ProcessNet window (anukf.md: w = 100)


def default_weights() -> Path:
    """The weights that ship with the package (trained on the embedded tracks 1-4)."""
    return Path(str(resources.files("nespm_cli.learn") / "processnet.npz"))


@lru_cache(maxsize=4)
def load_weights(path: str | None):
    """``(acc_net, gyro_net, meta)`` from ``path`` (None: the packaged default); cached per process."""
    p = Path(path) if path else default_weights()
    if not p.is_file():
        raise NespmError(f"--weights {p}: no such file (train one with `nespm train`)")
    try:
        return load_processnet(p)
    except NespmError:
        raise
    except Exception as exc:  # a corrupt or foreign .npz
        raise NespmError(f"--weights {p}: not a ProcessNet file ({type(exc).__name__}: {exc})") from None


def interval_windows(x: np.ndarray, epoch_index: np.ndarray) -> np.ndarray:
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
    rows = e[1:, None] - WINDOW + np.arange(WINDOW)  # (N-1, WINDOW)
    return x[:, rows]


def predict_interval_std(f_meas: np.ndarray, w_meas: np.ndarray, epoch_index: np.ndarray,
                         weights: str | None = None, clip: tuple[float, float] | None = None):
    """Network noise std for every run and DVL interval.

    Returns ``(std_a, std_g)``, each (R, N-1, 3) [m/s², rad/s per IMU sample], unclipped
    (clipping happens in :func:`adaptive_q`, so the raw prediction can be recorded).
    """
    acc, gyro, _ = load_weights(weights)
    return predict_noise_std(acc, gyro, interval_windows(f_meas, epoch_index),
                             interval_windows(w_meas, epoch_index), clip=clip)
