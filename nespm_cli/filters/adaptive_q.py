"""``aq-ekf``: the EKF with its accelerometer (and optionally gyro) white noise (Q) adapted per run.

Estimator (``method = ml``, the default): the Q factor θ = φ² on a block's nominal white noise by
maximum likelihood on the innovations (Mehra 1972, "Approaches to adaptive filtering", IEEE TAC 17(5)
693-698: the innovation ν_j ~ N(0, S_j(θ)) of a Kalman filter; one Fisher-scoring step on a faded
window). ``S(θ) = H P⁻(θ) Hᵀ + R``; its sensitivity ``D_j = ∂S_j/∂θ = H M_j⁻ Hᵀ`` where
``M = ∂P/∂θ`` is carried beside P (:func:`sensitivity_prior`, :func:`sensitivity_post`):

    M⁻ ← Φ M⁺ Φᵀ + Q0_blk,        M⁺ = (I − K H) M⁻ (I − K H)ᵀ

(the derivative of the Riccati recursion at the optimal gain: the gain's own derivative drops out).
Each update gives the score and information of θ (:func:`score_terms`)

    g_j = ½ (νᵀ S⁻¹ D S⁻¹ ν − tr S⁻¹ D),   a_j = ½ tr(S⁻¹ D S⁻¹ D)

and the data's estimate is the faded scoring step from the θ_j each update ran with,

    θ̂ = Σ_j b^{k−j} w_j (g_j + a_j θ_j) / Σ_j b^{k−j} w_j a_j        (:func:`scoring_factor`)

with ``w_j = max(θ̂_{j−1}, 1)²``: the information on log θ above the nominal, so that after a step up
the new updates (whose θ information a_j is smaller, θ being a larger share of S) are not outweighed by
the old ones (with Fisher weights w = 1 the median factor was 2.6 of 4 100 s after a x4 step). The factor
used is that estimate shrunk in log towards the nominal by a normal prior of std ``prior_std`` on log θ
(:func:`shrunk_factor`): at the nominal 0.03 m/s² the accelerometer noise is 2-7 % of the DVL
innovation covariance, the data's information on θ over a 50-update memory is about 1 (σ_θ ≈ 1: no
estimator puts φ within 1.5x of 1 in most runs from the data alone), while after a x4 step it is
30 %, the information on log θ about 10 and the prior weighs about a tenth.

— unbiased to first order whatever the share of θ in S (with velocity-only DVL updates most of
``P⁻ − P⁺`` in the velocity block comes from the attitude and bias states, which biased and slowed
the state-correction estimator below), and it follows a step within about one memory
``1/(1 − b)`` updates instead of through the filter's slow feedback loop.

``method = corrections``: covariance matching on the state corrections (Mohamed & Schwarz 1999,
"Adaptive Kalman filtering for INS/GPS", J. Geodesy 73, 193-203):
``q̂_j = Q_j + Δx_j Δx_jᵀ − (P_j⁻ − P_j⁺)`` (:func:`matched_q`, equal to the paper's
``Δx Δxᵀ + P⁺ − Φ P⁺_prev Φᵀ``), the block traces faded, ``φ² = Σ b^{k−j} tr q̂_j / Σ b^{k−j} tr Q0_j``
(:func:`faded_ratio`). Kept for comparison: measured biased low and slow (docs/filters.md).

Both: φ held at 1 for the first ``warmup`` seconds (the P0 transient; M is carried from t = 0),
bounded to ``[q_floor, q_ceiling]`` (on the std); ``adapt = acc`` adapts the velocity block (accelerometer),
``both`` the attitude block (gyro) too; the bias random walks and R stay nominal. Batched over runs;
the time update is the EKF's compiled one. The factor of each GT interval is exposed as ``noise_std``
(``φ × reference std``), so ``mc`` records ``q_factor_acc`` / ``q_factor_gyro``.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.filters.adaptive import REFERENCE_ACC, REFERENCE_GYRO
from nespm_cli.filters.ekf import EKF
from nespm_cli.filters.model import joseph_update, process_noise
from nespm_cli.filters.registry import register

ADAPT = ("acc", "both")
METHODS = ("ml", "corrections")


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


def sensitivity_prior(M: np.ndarray, Phi: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """(B, c, n, n) ``Φ M Φᵀ + diag(q0)``: the time update of the sensitivities ``M = ∂P/∂θ_c`` (B, c, n, n),
    ``Φ`` (B, n, n), ``q0`` (c, n) the nominal Q diagonal of each adapted block (zero elsewhere) [SI²]."""
    Pm = Phi[:, None] @ M @ np.swapaxes(Phi, -1, -2)[:, None]
    i = np.arange(M.shape[-1])
    Pm[..., i, i] += q0
    return Pm


def sensitivity_post(M: np.ndarray, P_prior: np.ndarray, H: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(B, c, n, n) ``(I − K H) M (I − K H)ᵀ`` with ``K = P⁻ Hᵀ S⁻¹``: the measurement update of ``M``."""
    K = np.swapaxes(np.linalg.solve(S, H @ P_prior), -1, -2)
    A = (np.eye(P_prior.shape[-1]) - K @ H)[:, None]
    out = A @ M @ np.swapaxes(A, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def score_terms(M: np.ndarray, H: np.ndarray, S: np.ndarray, nu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(g, a)`` each (B, c): the score ``½ (νᵀ S⁻¹ D S⁻¹ ν − tr S⁻¹ D)`` and the Fisher information
    ``½ tr(S⁻¹ D S⁻¹ D)`` of θ_c for one innovation ``nu`` (B, m) with covariance ``S`` (B, m, m),
    ``D = H M Hᵀ`` (``M`` (B, c, n, n) the prior sensitivities, ``H`` (B, m, n))."""
    D = H[:, None] @ M @ np.swapaxes(H, -1, -2)[:, None]  # (B, c, m, m)
    SiD = np.linalg.solve(S[:, None], D)  # S⁻¹ D
    w = np.linalg.solve(S, nu[..., None])[..., 0]  # S⁻¹ ν
    quad = np.einsum("bi,bcij,bj->bc", w, D, w)
    g = 0.5 * (quad - np.einsum("bcii->bc", SiD))
    a = 0.5 * np.einsum("bcij,bcji->bc", SiD, SiD)
    return g, a


def shrunk_factor(theta: np.ndarray, info: np.ndarray, prior_std: float) -> np.ndarray:
    """(B, c) the std factor ``exp(½ λ log θ)``, ``λ = I / (I + 1/prior_std²)``: the data's variance factor ``theta``
    (B, c) with its information ``I = info θ²`` on ``log θ`` (``info`` (B, c) on θ) shrunk in log towards the
    nominal (θ = 1) by a normal prior of std ``prior_std`` on ``log θ``."""
    i_log = info * theta**2
    lam = i_log / (i_log + prior_std**-2)
    return np.exp(0.5 * lam * np.log(theta))


def scoring_factor(num: np.ndarray, den: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(B, c) the std factor ``√θ̂``, ``θ̂ = num / den`` the faded scoring step (``num = Σ b^{k−j}(g_j + a_j θ_j)``,
    ``den = Σ b^{k−j} a_j``), clipped to ``[lo, hi]``; 1 where ``den`` is 0."""
    return factor(num, den, lo, hi)


@register("aq-ekf")
class AdaptiveQEKF(EKF):
    """The EKF with Q's accelerometer (and gyro) white-noise blocks adapted per run (module docstring).
    Attributes: ``fac`` (R, 2) the current std factors (acc, gyro)."""

    option_defaults = {"forgetting": 0.98, "warmup": 20.0, "q_floor": 0.25, "q_ceiling": 24.0, "adapt": "acc",
                       "method": "ml", "prior_std": 1.0}
    #: searched by ``nespm tune`` (linear): a memory of about 10 to 1,000 updates
    tune_ranges = {"forgetting": (0.9, 0.999, "linear")}
    per_run = ("P", "fac", "raw", "num", "den", "q_used", "q_nom", "M")

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        span = float(np.sum(self.dt))
        self.check_options(self.name, self.options, {k for k, _ in cfg.options}, span)
        lay = self.layout
        self.blocks = (lay.slice("vel"), lay.slice("att"))
        z = np.zeros((self.R, 2))
        self.fac, self.num, self.den, self.q_used, self.q_nom = np.ones((self.R, 2)), z, z.copy(), z.copy(), z.copy()
        self.raw = np.ones((self.R, 2))  # the data's variance factor θ̂ before the prior's shrinkage
        self.b = float(self.options["forgetting"])
        self.gyro = self.options["adapt"] == "both"
        self.ml = self.options["method"] == "ml"
        self.M = np.zeros((self.R, 2 if self.gyro else 1, lay.n, lay.n))  # ∂P/∂θ per adapted block
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
        if not 0.0 < float(o["prior_std"]) < np.inf:
            raise NespmError(f"--filter-option {name}.prior_std={float(o['prior_std']):g}: must be > 0 and finite "
                             "(a large value: no prior)")
        if o["method"] not in METHODS:
            raise NespmError(f"--filter-option {name}.method={o['method']}: choose {' or '.join(METHODS)}")

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
        self.q0 = np.zeros((self.M.shape[1], self.layout.n))
        for i in range(self.M.shape[1]):
            self.q0[i, self.blocks[i]] = np.diag(Q0)[self.blocks[i]]
        self.t += span
        self.history[k] = self.fac.copy()
        return Q

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        super().propagate(j0, j1, k)
        if self.ml:
            self.M = sensitivity_prior(self.M, self.last_transition, self.q0)

    def update(self, measurement, j_last: int):
        nav = self.nav
        nu = measurement.innovation(nav)
        H = measurement.H(nav)
        P_prior = self.P
        x, self.P, S = joseph_update(P_prior, H, nu, measurement.R)
        lo, hi = float(self.options["q_floor"]), float(self.options["q_ceiling"])
        c = self.M.shape[1]
        if self.ml:
            if self.t >= float(self.options["warmup"]):
                g, a = score_terms(self.M, H, S, nu)
                theta = self.fac[:, :c] ** 2
                w = np.maximum(self.raw[:, :c], 1.0) ** 2  # log-θ information above the nominal (module docstring)
                self.num[:, :c] = self.b * self.num[:, :c] + w * (g + a * theta)
                self.den[:, :c] = self.b * self.den[:, :c] + w * a
                self.raw[:, :c] = scoring_factor(self.num[:, :c], self.den[:, :c], lo, hi) ** 2
                self.fac[:, :c] = shrunk_factor(self.raw[:, :c], self.den[:, :c], float(self.options["prior_std"]))
            self.M = sensitivity_post(self.M, P_prior, H, S)
        elif self.t >= float(self.options["warmup"]):
            q_hat = matched_q(self.q_used, x, P_prior, self.P, self.blocks)
            self.num, self.den = faded_ratio(self.num, self.den, q_hat, self.q_nom, self.b)
            fac = factor(self.num, self.den, lo, hi)
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


__all__ = ["ADAPT", "METHODS", "AdaptiveQEKF", "block_traces", "factor", "faded_ratio", "matched_q", "score_terms",
           "scoring_factor", "sensitivity_post", "sensitivity_prior", "shrunk_factor"]
