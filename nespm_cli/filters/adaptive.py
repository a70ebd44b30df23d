"""Adaptive process noise from ProcessNet (anukf.md eqs 43-48); the network itself runs in
:mod:`nespm_cli.learn.noise_model`.

Once per DVL interval each run's IMU readings of that interval (exactly 100 steps: one
ProcessNet window) go through the accelerometer and gyro networks, which return the
per-axis noise std per 100 Hz sample, ``σ̂_a`` [m/s²] and ``σ̂_g`` [rad/s]. They become the
diagonal blocks of Q_net (eq 43):

* q_a = σ̂_a² · τ          (eq 44; τ = the IMU step, so σ̂² τ is the noise PSD)
* q_v = q_a · τ_a         (eq 45; τ_a = the time-update span, one DVL interval)
* q_g = σ̂_g² · τ          (eq 46)
* q_Ψ = q_g · τ_g         (eq 47; τ_g = the span)
* bias blocks: ``nominal`` (default) the fixed filters' bias random walk; ``scaled`` that
  times (σ̂/σ_nominal)²; ``paper`` q_a and q_g themselves, as eq 43 is written.

and Q = G Q_net Gᵀ (eq 48) with G = blockdiag(C_bn, C_bn, I, I): per-axis body-frame
noise rotated into NED. With σ̂ equal to the nominal std and the default τ's, Q is exactly
the fixed Q of :func:`filters.model.process_noise`, so an adaptive filter fed the nominal
std reproduces its non-adaptive twin (a test checks this to 1e-12).

The factor and the filter's nominal: a model's std is read as a factor on the reference std
(:data:`REFERENCE_ACC`, :data:`REFERENCE_GYRO`: the papers' nominal 0.03 m/s², 7.3e-6 rad/s per
sample, the level ProcessNet is trained at and the ONNX ``q_scale`` is defined on), and σ̂ =
factor × the filter's own nominal std (``cfg.acc_noise``, ``cfg.gyro_noise``: ``--filter-acc-noise``
/ ``--filter-gyro-noise`` when given, else the injected noise; times ``acc_noise_scale`` ...). A
model that predicts the reference (factor 1) is thus the non-adaptive twin whatever the nominal.

Validity (anukf.md III-D: positive, not too small, not too large), one rule for every output
(``std`` or ``q_scale``, any kind of model): a finite positive output's factor is clipped to
``[clip_lo, clip_hi]``; a non-finite or non-positive output is a *fault* (:func:`model_faults`):
it is counted per run and loses that run from the epoch closing the window (reason
``noise-model``, :func:`nespm_cli.filters.engine.run_filter`); Q gets σ_nominal in its place only
so that the batch stays finite. So Q is symmetric positive semi-definite for any network output.

Why ``nominal`` bias noise by default: with the default ``--dynamic-bias run`` the biases
are constant over a run, so a noisier window says nothing about the bias moving, and
inflating its random walk only slows the bias estimate. Measured on real track 5, 8 runs,
dynamic schedule, synthetic DVL (VRMSE / MRMSE / mean NEES): ``nominal`` 0.0754 m/s /
0.0341 rad / 9.98, ``scaled`` 0.0857 / 0.0392 / 9.93, the non-adaptive UKF 0.0727 /
0.0322 / 13.39. ``scaled`` is the matched choice with ``--dynamic-bias segment`` (the bias
scaled with the noise); eq 43's literal q_a = σ̂_a² τ (0.03² · 0.01 = 9e-6 m²/s⁴ per
interval) is 9 times the nominal accelerometer bias random walk (``paper``).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

BIAS_MODES = ("nominal", "scaled", "paper")
#: the std a model's output is a factor of [m/s², rad/s per IMU sample] (module docstring)
REFERENCE_ACC, REFERENCE_GYRO = NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
#: the reason a run lost to a fault of the noise model is recorded with
FAULT_REASON = "noise-model"


def model_faults(std_a: np.ndarray, std_g: np.ndarray) -> np.ndarray:
    """(...,) bool: where a model's output is unusable, i.e. any of the 6 axes non-finite or
    <= 0 (``std_a``, ``std_g`` (..., 3) [m/s², rad/s]; a ``q_scale`` <= 0 arrives as NaN or 0)."""
    with np.errstate(invalid="ignore"):
        ok = [np.isfinite(s) & (s > 0) for s in (np.asarray(std_a, float), np.asarray(std_g, float))]
    return ~(ok[0].all(axis=-1) & ok[1].all(axis=-1))


def valid_std(std: np.ndarray, nominal: float, clip: tuple[float, float],
              reference: float | None = None) -> np.ndarray:
    """The std Q uses (same shape as ``std``): ``nominal × clip(std / reference, lo, hi)`` where
    ``std`` is finite and > 0, NaN where it is not (a fault: :func:`model_faults`).

    ``reference`` None: ``nominal`` (then this is ``std`` clipped to ``[lo, hi] × nominal``);
    :func:`adaptive_q` passes :data:`REFERENCE_ACC` / :data:`REFERENCE_GYRO`, so the model's factor
    multiplies the filter's nominal (``--filter-acc-noise``)."""
    ref = float(nominal if reference is None else reference)
    s = np.asarray(std, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.isfinite(s) & (s > 0)
        factor = np.clip(np.where(ok, s, ref) / ref, clip[0], clip[1])
    return np.where(ok, nominal * factor, np.nan)


def q_factor(std: np.ndarray, cfg, sensor: str) -> np.ndarray:
    """The factor on the filter's nominal Q std that ``std`` (..., 3) of ``sensor`` (``acc`` or
    ``gyro``) gives, validated and clipped as :func:`adaptive_q` uses it (NaN at a fault)."""
    nominal = cfg.acc_noise if sensor == "acc" else cfg.gyro_noise
    ref = REFERENCE_ACC if sensor == "acc" else REFERENCE_GYRO
    return valid_std(std, nominal, tuple(cfg.q_clip), ref) / nominal


def adaptive_q(std_a: np.ndarray, std_g: np.ndarray, C_bn: np.ndarray, cfg, dt_imu: float,
               span: float, layout=None) -> np.ndarray:
    """Discrete process noise (B, n, n) of one time update, eqs 43-48, for ``layout`` (a
    :class:`nespm_cli.nav.state.StateLayout`; None: ``cfg.layout``); position has none.

    Args:
        std_a, std_g: (B, 3) network noise std per IMU sample [m/s², rad/s], any values (each
            read as a factor on :data:`REFERENCE_ACC` / :data:`REFERENCE_GYRO`, times the nominal).
        C_bn: (B, 3, 3) body-to-NED DCM of the navigation solution (G of eq 48).
        cfg: :class:`filters.model.FilterConfig` (nominal std, bias random walks, τ's,
            ``adaptive_bias``, ``q_clip``).
        dt_imu: IMU step [s] (default τ); span: time-update span [s] (default τ_a, τ_g).
    """
    clip = tuple(cfg.q_clip)
    sa = valid_std(std_a, cfg.acc_noise, clip, REFERENCE_ACC)
    sg = valid_std(std_g, cfg.gyro_noise, clip, REFERENCE_GYRO)
    # a fault: its run is lost (adaptive_filters); the nominal keeps the batch's Q finite meanwhile
    sa = np.where(np.isnan(sa), cfg.acc_noise, sa)
    sg = np.where(np.isnan(sg), cfg.gyro_noise, sg)
    tau = dt_imu if cfg.tau is None else cfg.tau
    tau_a = span if cfg.tau_a is None else cfg.tau_a
    tau_g = span if cfg.tau_g is None else cfg.tau_g
    q_a = sa**2 * tau  # eq 44
    q_g = sg**2 * tau  # eq 46
    q_v = q_a * tau_a  # eq 45
    q_psi = q_g * tau_g  # eq 47
    if cfg.adaptive_bias == "paper":
        q_ba, q_bg = q_a, q_g
    elif cfg.adaptive_bias == "nominal":
        q_ba = np.full_like(sa, cfg.acc_bias_rw**2 * span)
        q_bg = np.full_like(sg, cfg.gyro_bias_rw**2 * span)
    else:
        q_ba = cfg.acc_bias_rw**2 * span * (sa / cfg.acc_noise) ** 2
        q_bg = cfg.gyro_bias_rw**2 * span * (sg / cfg.gyro_noise) ** 2
    lay = cfg.layout if layout is None else layout
    B = sa.shape[:-1]
    Q = np.zeros(B + (lay.n, lay.n))
    Ct = np.swapaxes(C_bn, -1, -2)
    V, A = lay.slice("vel"), lay.slice("att")
    Q[..., V, V] = (C_bn * q_v[..., None, :]) @ Ct  # eq 48: C diag(q_v) Cᵀ
    Q[..., A, A] = (C_bn * q_psi[..., None, :]) @ Ct
    idx = np.arange(3)
    if lay.has("ba"):
        i = lay.offset("ba") + idx
        Q[..., i, i] = q_ba
    if lay.has("bg"):
        i = lay.offset("bg") + idx
        Q[..., i, i] = q_bg
    return 0.5 * (Q + np.swapaxes(Q, -1, -2))
