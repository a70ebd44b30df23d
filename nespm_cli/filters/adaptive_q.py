"""``aq-ekf``: the EKF with its accelerometer and gyro noise (Q) adapted by covariance matching.

Covariance matching on the state corrections (Mohamed & Schwarz 1999, "Adaptive Kalman filtering
for INS/GPS", J. Geodesy 73, 193-203, the adaptive estimate of Q): over the corrections
``Δx_j = K_j ν_j`` of the measurement updates,

    Q̂_k = (1/N) Σ_j Δx_j Δx_jᵀ + P_k⁺ − Φ_k P_{k−1}⁺ Φ_kᵀ.

With the EKF's time update ``P_k⁻ = Φ_k P_{k−1}⁺ Φ_kᵀ + Q_k`` (``Q_k`` the Q the filter used) the
last two terms are ``Q_k − (P_k⁻ − P_k⁺)``, so one update contributes

    q̂_j = Q_j + Δx_j Δx_jᵀ − (P_j⁻ − P_j⁺)      (:func:`matched_q`)

(no Φ needed: the same expression whichever ``--time-update``); the expected ``Δx Δxᵀ`` of a filter
whose Q is right is ``P⁻ − P⁺``, so a larger spread of the corrections raises Q. Only the traces
of the velocity block (accelerometer white noise) and of the attitude block (gyro white noise) are
matched (the bias random walks stay nominal): a variance factor per block and run,

    φ² = Σ_j b^{k−j} tr q̂_j / Σ_j b^{k−j} tr Q0_j       (:func:`faded_ratio`)

with ``Q0`` the filter's nominal Q of the same spans and ``b`` the option ``forgetting`` (a fading
memory of about ``1/(1 − b)`` updates, the ratio needs no bias correction), held at 1 for the first
``warmup`` seconds (the P0 transient) and bounded to ``[q_floor, q_ceiling]`` (a factor on the
nominal std). The time update scales the velocity block of the nominal Q by ``φ_a²`` and the
attitude block by ``φ_g²`` (``adapt = acc``: the gyro factor stays 1). Batched over the runs; the
measurement update is the EKF's (fixed R). The factor of each GT interval is exposed as
``noise_std`` (``φ × reference std``, as the learned filters), so ``mc`` records it in
``q_factor_acc`` / ``q_factor_gyro`` (docs/filters.md "Adaptive process noise by covariance matching").
"""
from __future__ import annotations

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.filters.adaptive import REFERENCE_ACC, REFERENCE_GYRO
from nespm_cli.filters.ekf import EKF
from nespm_cli.filters.model import joseph_update, process_noise
from nespm_cli.filters.registry import register

ADAPT = ("acc", "both")


def block_traces(M: np.ndarray, blocks: tuple) -> np.ndarray:
    """(B, 2) the traces of the diagonal blocks ``blocks`` (two slices) of ``M`` (B, n, n) or (n, n)."""
    d = np.einsum("...ii->...i", M)
    return np.stack([d[..., s].sum(axis=-1) for s in blocks], axis=-1)


def matched_q(q_used: np.ndarray, x: np.ndarray, P_prior: np.ndarray, P_post: np.ndarray, blocks: tuple) -> np.ndarray:
    """Mohamed & Schwarz (1999)'s ``Q̂ = Δx Δxᵀ + P⁺ − Φ P⁺_prev Φᵀ`` of one update, as block traces:
    ``tr q̂ = tr Q_used + tr(Δx Δxᵀ) − tr(P⁻ − P⁺)`` (B, 2) [SI²] per block of ``blocks``.

    Args:
        q_used: (B, 2) the block traces of the Q the filter used since the previous update.
        x: (B, n) the correction ``Δx = K ν``; P_prior, P_post: (B, n, n) the covariance before and after.
    """
    dx2 = np.stack([(x[..., s] ** 2).sum(axis=-1) for s in blocks], axis=-1)
    return q_used + dx2 - block_traces(P_prior - P_post, blocks)


def faded_ratio(num: np.ndarray, den: np.ndarray, q_hat: np.ndarray, q_nom: np.ndarray, b: float):
    """The faded sums after one more update: ``(b num + q̂, b den + q0)`` (each (B, 2)); their ratio
    is the variance factor φ² (:func:`factor`)."""
    return b * num + q_hat, b * den + q_nom


def factor(num: np.ndarray, den: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(B, 2) the std factor ``√(num / den)`` clipped to ``[lo, hi]`` (1 where ``den`` is 0)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)
    return np.sqrt(np.clip(np.nan_to_num(r, nan=1.0), lo**2, hi**2))


@register("aq-ekf")
class AdaptiveQEKF(EKF):
    """The EKF with Q's accelerometer and gyro white-noise blocks from covariance matching on the state
    corrections (module docstring). Attributes: ``fac`` (R, 2) the current std factors (acc, gyro)."""

    option_defaults = {"forgetting": 0.98, "warmup": 20.0, "q_floor": 0.25, "q_ceiling": 24.0, "adapt": "acc"}
    #: searched by ``nespm tune`` (linear): a memory of about 10 to 1,000 updates
    tune_ranges = {"forgetting": (0.9, 0.999, "linear")}
    per_run = ("P", "fac", "num", "den", "q_used", "q_nom")

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        span = float(np.sum(self.dt))
        self.check_options(self.name, self.options, {k for k, _ in cfg.options}, span)
        lay = self.layout
        self.blocks = (lay.slice("vel"), lay.slice("att"))
        z = np.zeros((self.R, 2))
        self.fac, self.num, self.den, self.q_used, self.q_nom = np.ones((self.R, 2)), z, z.copy(), z.copy(), z.copy()
        self.b = float(self.options["forgetting"])
        self.gyro = self.options["adapt"] == "both"
        self.t = 0.0  # time [s] since the start, at the end of the last time update
        self.history: dict = {}  # GT interval k -> (R, 2) the factors its last time update used

    @classmethod
    def check_options(cls, name: str, options: dict, given: set, span_s: float) -> None:
        """One line naming ``--filter-option NAME.KEY`` for a value outside its domain (``given``, ``span_s``
        as :meth:`nespm_cli.filters.adaptive_ekfs.AdaptiveREKF.check_options`)."""
        o = options
        if not 0.0 < float(o["forgetting"]) < 1.0:
            raise NespmError(f"--filter-option {name}.forgetting={float(o['forgetting']):g}: a forgetting factor "
                             "must lie in (0, 1)")
        if not 0.0 < float(o["q_floor"]) <= 1.0 <= float(o["q_ceiling"]) < np.inf:
            raise NespmError(f"--filter-option {name}.q_floor/q_ceiling: need 0 < q_floor <= 1 <= q_ceiling "
                             f"(finite), got {o['q_floor']:g}, {o['q_ceiling']:g}")
        if not float(o["warmup"]) >= 0.0:
            raise NespmError(f"--filter-option {name}.warmup={float(o['warmup']):g}: must be >= 0 s")
        if float(o["warmup"]) >= span_s and "warmup" in given:
            raise NespmError(f"--filter-option {name}.warmup={float(o['warmup']):g}: not shorter than the track "
                             f"({span_s:.1f} s)")
        if o["adapt"] not in ADAPT:
            raise NespmError(f"--filter-option {name}.adapt={o['adapt']}: choose {' or '.join(ADAPT)}")

    def process_noise(self, span: float, k: int) -> np.ndarray:
        """(R, n, n) the nominal Q with its velocity block x φ_a² and its attitude block x φ_g²; the
        block traces of the Q used and of the nominal are added to this update cycle's."""
        Q0 = process_noise(self.cfg, self.dt_imu, span)
        scale = np.ones((self.R, self.layout.n))
        for i, s in enumerate(self.blocks):
            scale[:, s] = self.fac[:, i, None] ** 2
        Q = Q0 * np.sqrt(scale[:, :, None] * scale[:, None, :])  # diagonal Q0: the blocks scaled
        self.q_used = self.q_used + block_traces(Q, self.blocks)
        self.q_nom = self.q_nom + block_traces(Q0, self.blocks)[None, :]
        self.t += span
        self.history[k] = self.fac.copy()
        return Q

    def update(self, measurement, j_last: int):
        nav = self.nav
        nu = measurement.innovation(nav)
        P_prior = self.P
        x, self.P, S = joseph_update(P_prior, measurement.H(nav), nu, measurement.R)
        if self.t >= float(self.options["warmup"]):
            q_hat = matched_q(self.q_used, x, P_prior, self.P, self.blocks)
            self.num, self.den = faded_ratio(self.num, self.den, q_hat, self.q_nom, self.b)
            fac = factor(self.num, self.den, float(self.options["q_floor"]), float(self.options["q_ceiling"]))
            self.fac = fac if self.gyro else np.stack([fac[:, 0], np.ones(self.R)], axis=-1)
        self.q_used, self.q_nom = np.zeros((self.R, 2)), np.zeros((self.R, 2))
        self.feedback(x)
        return nu, S

    @property
    def noise_std(self):
        """``(std_a, std_g)`` each (R, K, 3): the factor each GT interval's (last) time update used, times the
        reference std (:data:`~nespm_cli.filters.adaptive.REFERENCE_ACC`), so ``q_factor`` reads the factor."""
        if not self.history:
            return None
        K = max(self.history) + 1
        f = np.ones((self.R, K, 2))
        last = np.ones((self.R, 2))
        for k in range(K):  # intervals without a time update keep the previous factor
            last = self.history.get(k, last)
            f[:, k] = last
        std_a = np.repeat(f[:, :, :1] * REFERENCE_ACC, 3, axis=-1)
        std_g = np.repeat(f[:, :, 1:] * REFERENCE_GYRO, 3, axis=-1)
        return std_a, std_g


__all__ = ["ADAPT", "AdaptiveQEKF", "block_traces", "factor", "faded_ratio", "matched_q"]
