"""Batched additive-noise UKF: the ideal UKF (gp-ukf.md Table 1) and the GP-UKF (Table 2).

State-space model (eq 3), one step of the filter per sample k:

    x_k = f(x_{k-1}, u_{k-1}) + ε_k,   ε_k ~ N(0, Q_k)
    z_k = h(x_k) + δ_k,                δ_k ~ N(0, R_k)

Everything is batched over a leading axis of R independent runs (Monte Carlo): ``x`` (R, n),
``P`` (R, n, n), ``u`` (R, m), ``z`` (R, p). The models act on sigma points batched on
leading axes: ``f(x (..., n), u (..., m)) -> (..., n)`` and ``h(x (..., n)) -> (..., p)``;
one call per step evaluates all 2n + 1 sigma points of all runs.

The unscented transform is the scaled one of :mod:`nespm_cli.filters.unscented` (α = 1e-3,
β = 2, κ = 0 by default), with means and covariances formed from deviations of the outer
points' images from the centre image (the centre weight is ≈ −1e6 at n = 12). Sigma points
are redrawn from (x̂_{k|k-1}, P_{k|k-1}) for the correction, as Table 1 line 3 prescribes.

Tables 1 and 2 as printed have two typos that we read as the standard UKF: line 4 of
Table 1 is ``S_k ← S_k + R`` (Table 2 line 4), and line 6 of both is
``P_{k|k} ← P_{k|k-1} − C_k S_k⁻¹ C_kᵀ`` (minus: the update removes uncertainty).

Noise: ``Q`` / ``R`` are arrays — (n, n) shared, (R, n, n) per run, or (R, T, n, n) per run
and step in :func:`run_ukf` — or callables evaluated at the centre sigma point, i.e. the
current mean: ``Q(x̂_{k-1|k-1} (R, n), u_{k-1} (R, m)) -> (R, n, n)`` and
``R(x̂_{k|k-1} (R, n)) -> (R, p, p)``. The GP-UKF uses the callables (Table 2 lines 1 and 3:
"the process noise covariance is obtained from the predictive GP uncertainty at the
previous mean sigma point").

Divergence: a run whose x or P becomes non-finite, or whose P or innovation covariance S
is not positive definite (Cholesky fails), is flagged in the boolean mask ``bad`` (R,);
from then on its outputs are NaN and its internal state is replaced by (0, I) so that the
batch's linear algebra never fails; the other runs go on unchanged (runs never mix).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence, Union

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.learn.gp import MAX_POINTS, N_RESTARTS, GPModel
from nespm_cli.filters.unscented import UTWeights, moments, safe_cholesky, sigma_offsets

ProcessModel = Callable[[np.ndarray, np.ndarray], np.ndarray]  # f(x (..., n), u (..., m)) -> (..., n)
ObservationModel = Callable[[np.ndarray], np.ndarray]  # h(x (..., n)) -> (..., p)
NoiseSpec = Union[np.ndarray, Callable[..., np.ndarray], None]

ALPHA, BETA, KAPPA = 1e-3, 2.0, 0.0


def _sym(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def _offsets(P: np.ndarray, weights: UTWeights, bad: np.ndarray) -> np.ndarray:
    """Outer sigma-point offsets (R, 2n, n) from P (R, n, n); non-PD P flags its run."""
    return sigma_offsets(safe_cholesky(P, bad), weights)


def _images(model, x: np.ndarray, D: np.ndarray, *args: np.ndarray):
    """Image of the centre ``x`` (R, n) and deviations of the outer images (R, 2n, k).

    A model with a ``deviations(x, D, *args)`` method gives them directly (formed without
    cancellation, see :class:`DeviationModel`); otherwise the model is called once on all
    2n+1 sigma points (R, 2n+1, n), with ``args`` (R, a) broadcast to (R, 2n+1, a).
    """
    dev = getattr(model, "deviations", None)
    if dev is not None:
        y0, dy = dev(x, D, *args)
        return np.asarray(y0, dtype=float), np.asarray(dy, dtype=float)
    pts = x[:, None, :] + np.concatenate([np.zeros_like(D[:, :1]), D], axis=1)
    S = pts.shape[1]
    Y = np.asarray(model(pts, *(np.broadcast_to(a[:, None, :], (a.shape[0], S, a.shape[-1])) for a in args)),
                   dtype=float)
    return Y[:, 0], Y[:, 1:] - Y[:, :1]


@dataclass(frozen=True)
class DeviationModel:
    """A model that also gives its sigma-point deviations without cancellation.

    ``call(x (..., n), *args) -> (..., k)`` is the model; ``deviations(x0 (R, n), D (R, S, n),
    *args (R, a)) -> (y0 (R, k), dy (R, S, k))`` with ``dy = model(x0 + D) − model(x0)``.
    With α = 1e-3 the UT weights (≈ 1/(2α²n)) multiply whatever rounding noise the model
    has at the 1e-3 σ scale of the sigma points; forming ``dy`` directly keeps it out.
    """

    call: Callable[..., np.ndarray]
    deviations: Callable[..., tuple[np.ndarray, np.ndarray]]

    def __call__(self, *a):
        return self.call(*a)


def _noise(spec: NoiseSpec, R: int, k: int, dim: int, *args) -> np.ndarray:
    """Noise covariance (R, dim, dim) from an array (dim, dim) / (R, dim, dim) / (R, T, dim, dim),
    a callable of the centre point(s) ``args``, or None (zero)."""
    if spec is None:
        return np.zeros((R, dim, dim))
    if callable(spec):
        out = np.asarray(spec(*args), dtype=float)
    else:
        out = np.asarray(spec, dtype=float)
        if out.ndim == 4:
            out = out[:, k]
    if out.shape[-2:] != (dim, dim) or out.ndim not in (2, 3):
        raise NespmError(f"UKF: noise covariance of shape {out.shape}, expected ({dim}, {dim}) or "
                         f"({R}, {dim}, {dim})")
    return np.broadcast_to(out, (R, dim, dim))


def ukf_predict(x: np.ndarray, P: np.ndarray, u: np.ndarray, f: ProcessModel, Q: NoiseSpec,
                weights: UTWeights, bad: np.ndarray, k: int = 0):
    """Prediction (Table 1/2 lines 1-2): ``(x̂_{k|k-1} (R, n), P_{k|k-1} (R, n, n))``.

    ``x``, ``P``: posterior at k−1; ``u`` (R, m): command u_{k-1}. ``bad`` (R,) is updated
    in place (non-PD P).
    """
    R_, n = x.shape
    D = _offsets(P, weights, bad)  # line 1: UT of f
    y0, dy = _images(f, x, D, u)
    m, Pyy = moments(dy, weights)  # mean and covariance from deviations
    x_pred = y0 + m
    P_pred = _sym(Pyy + _noise(Q, R_, k, n, x, u))  # line 2: P ← P + Q_k
    return x_pred, P_pred


def ukf_correct(x: np.ndarray, P: np.ndarray, z: np.ndarray, h: ObservationModel, R: NoiseSpec,
                weights: UTWeights, bad: np.ndarray, k: int = 0):
    """Correction (Table 1/2 lines 3-6): ``(x̂_{k|k} (R, n), P_{k|k} (R, n, n))``.

    ``x``, ``P``: prior x̂_{k|k-1}, P_{k|k-1}; ``z`` (R, p): measurement z_k. ``bad``
    is updated in place (non-PD P or S).
    """
    R_, n = x.shape
    D = _offsets(P, weights, bad)  # line 3: sigma points redrawn from the prior
    z0, dz = _images(h, x, D)
    p = z0.shape[-1]
    _, _, mz, Pzz, Pxz = moments(D, weights, dz)  # C_k = Pxz
    z_pred = z0 + mz
    S = _sym(Pzz + _noise(R, R_, k, p, x))  # line 4: S ← S + R_k
    safe_cholesky(S, bad)  # flags runs whose S is not positive definite
    S = np.where(bad[:, None, None], np.eye(p), S)
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)  # C_k S_k⁻¹ (R, n, p)
    x_post = x + (K @ (z - z_pred)[..., None])[..., 0]  # line 5
    P_post = _sym(P - K @ S @ np.swapaxes(K, -1, -2))  # line 6 (minus: see module doc)
    return x_post, P_post


def _flag(bad: np.ndarray, *arrays: np.ndarray) -> None:
    for a in arrays:
        bad |= ~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)


def ukf_step(x: np.ndarray, P: np.ndarray, u: np.ndarray, z: np.ndarray, f: ProcessModel,
             h: ObservationModel, Q: NoiseSpec, R: NoiseSpec, weights: UTWeights | None = None,
             bad: np.ndarray | None = None, k: int = 0):
    """One UKF step for R runs: predict with u_{k-1}, correct with z_k (Tables 1 and 2).

    Parameters
    ----------
    x, P : (R, n), (R, n, n)
        Posterior x̂_{k-1|k-1}, P_{k-1|k-1}.
    u : (R, m)
        Command u_{k-1}.
    z : (R, p)
        Measurement z_k.
    f, h : callables
        Process and observation models, batched on leading axes.
    Q, R : arrays or callables
        Additive noise covariances, see the module docstring.
    weights : UTWeights, optional
        Default α = 1e-3, β = 2, κ = 0.
    bad : (R,) bool, optional
        Divergence mask, updated in place (a new one is made if None).

    Returns
    -------
    (x_pred, P_pred, x_post, P_post, bad)
        Prior x̂_{k|k-1}, P_{k|k-1} and posterior x̂_{k|k}, P_{k|k}; NaN for diverged runs.
    """
    x, P, u, z = (np.asarray(a, dtype=float) for a in (x, P, u, z))
    Rn, n = x.shape
    weights = weights or UTWeights(n, ALPHA, BETA, KAPPA)
    bad = np.zeros(Rn, dtype=bool) if bad is None else bad
    _flag(bad, x, P)
    x, P = _sanitize(x, P, bad)
    x_pred, P_pred = ukf_predict(x, P, u, f, Q, weights, bad, k)
    _flag(bad, x_pred, P_pred)
    xs, Ps = _sanitize(x_pred, P_pred, bad)
    x_post, P_post = ukf_correct(xs, Ps, z, h, R, weights, bad, k)
    _flag(bad, x_post, P_post)
    return (*_nan_bad(x_pred, P_pred, bad), *_nan_bad(x_post, P_post, bad), bad)


def _sanitize(x, P, bad):
    if not bad.any():
        return x, P
    return (np.where(bad[:, None], 0.0, x),
            np.where(bad[:, None, None], np.eye(x.shape[-1]), P))


def _nan_bad(x, P, bad):
    if not bad.any():
        return x, P
    return np.where(bad[:, None], np.nan, x), np.where(bad[:, None, None], np.nan, P)


# --- running a whole sequence -------------------------------------------------------------------

@dataclass
class UKFResult:
    """Filter output over T samples for R runs.

    ``x_pred[:, k]`` is the prior x̂_{k|k-1} (for k = 0 the initial estimate x̂_0) and
    ``x_post[:, k]`` the posterior x̂_{k|k}, both (R, T, n) in state units. ``var_*`` are the
    diagonals of the covariances (R, T, n); the full ``P_*`` (R, T, n, n) are kept only with
    ``keep_cov=True``. ``diverged`` (R,) is the divergence mask and ``diverged_at`` (R,) the
    first sample whose output is NaN (−1 if never); diverged runs are NaN from there on.
    """

    x_pred: np.ndarray
    x_post: np.ndarray
    var_pred: np.ndarray
    var_post: np.ndarray
    diverged: np.ndarray
    diverged_at: np.ndarray
    P_pred: np.ndarray | None = None
    P_post: np.ndarray | None = None


def run_ukf(x0: np.ndarray, P0: np.ndarray, u: np.ndarray, z: np.ndarray, f: ProcessModel,
            h: ObservationModel, Q: NoiseSpec, R: NoiseSpec, alpha: float = ALPHA, beta: float = BETA,
            kappa: float = KAPPA, keep_cov: bool = True) -> UKFResult:
    """Run the UKF over a sequence for R runs.

    ``x0`` (R, n) or (n,), ``P0`` (R, n, n) or (n, n): estimate of x_0 before z_0;
    ``u`` (R, T, m) commands, ``z`` (R, T, p) measurements (u_{T-1} is unused). Sample 0
    is a correction with z_0 only; sample k ≥ 1 predicts with u_{k-1} and corrects with z_k.
    """
    u = np.asarray(u, dtype=float)
    z = np.asarray(z, dtype=float)
    if u.ndim != 3 or z.ndim != 3 or u.shape[:2] != z.shape[:2]:
        raise NespmError(f"UKF: need u (R, T, m) and z (R, T, p) with the same R, T; got {u.shape}, {z.shape}")
    Rn, T = z.shape[:2]
    x0 = np.asarray(x0, dtype=float)
    n = x0.shape[-1]
    x = np.broadcast_to(x0, (Rn, n)).astype(float)
    P = np.broadcast_to(np.asarray(P0, dtype=float), (Rn, n, n)).astype(float)
    w = UTWeights(n, alpha, beta, kappa)
    bad = np.zeros(Rn, dtype=bool)
    x_pred = np.empty((Rn, T, n))
    x_post = np.empty((Rn, T, n))
    var_pred = np.empty((Rn, T, n))
    var_post = np.empty((Rn, T, n))
    P_pred = np.empty((Rn, T, n, n)) if keep_cov else None
    P_post = np.empty((Rn, T, n, n)) if keep_cov else None
    at = np.full(Rn, -1)

    for k in range(T):
        if k == 0:
            _flag(bad, x, P)
            xp, Pp = _nan_bad(x, P, bad)
            xs, Ps = _sanitize(x, P, bad)
            xc, Pc = ukf_correct(xs, Ps, z[:, 0], h, R, w, bad, 0)
            _flag(bad, xc, Pc)
            xc, Pc = _nan_bad(xc, Pc, bad)
        else:
            xp, Pp, xc, Pc, bad = ukf_step(x, P, u[:, k - 1], z[:, k], f, h, Q, R, w, bad, k)
        x_pred[:, k], x_post[:, k] = xp, xc
        var_pred[:, k] = np.einsum("rii->ri", Pp)
        var_post[:, k] = np.einsum("rii->ri", Pc)
        if keep_cov:
            P_pred[:, k], P_post[:, k] = Pp, Pc
        at[(at < 0) & bad] = k
        x, P = xc, Pc
    # a final P that is not positive definite marks its run too
    check = bad.copy()
    safe_cholesky(np.where(bad[:, None, None], np.eye(n), P), check)
    at[(at < 0) & check] = T - 1
    return UKFResult(x_pred, x_post, var_pred, var_post, check, at, P_pred, P_post)


def ideal_ukf(x0: np.ndarray, P0: np.ndarray, u: np.ndarray, z: np.ndarray, f: ProcessModel,
              h: ObservationModel, Q: np.ndarray, R: np.ndarray, **kw) -> UKFResult:
    """The ideal UKF of Table 1: the true models f, h and fixed noise covariances Q, R.

    Shapes as in :func:`run_ukf`; ``Q`` (n, n) or (R, n, n), ``R`` (p, p) or (R, p, p).
    """
    return run_ukf(x0, P0, u, z, f, h, Q, R, **kw)


# --- GP models (Table 2) ------------------------------------------------------------------------

@dataclass
class GPUKFModels:
    """The learnt process and observation models of the GP-UKF.

    * ``f``: GP with NARX inputs ``[x_k[f_states], u_k]`` predicting the state *change*
      ``x_{k+1} − x_k`` (n outputs); the process model is ``x + mean`` and the process noise
      ``Q_k = diag(var)`` at the current mean (latent variance + learnt noise, eq 6 + σ_n²).
    * ``h``: GP with inputs ``x_k[h_states]`` predicting ``z_k`` (p outputs); ``R_k =
      diag(var)`` at the predicted mean.

    ``f_states`` / ``h_states`` select the state components that are GP inputs (None: all,
    as the paper's ``Xd = [η, u]``).
    """

    f: GPModel
    h: GPModel
    f_states: np.ndarray | None = None
    h_states: np.ndarray | None = None

    @staticmethod
    def _sel(x: np.ndarray, idx: np.ndarray | None) -> np.ndarray:
        return x if idx is None else x[..., idx]

    def _fx(self, x, u):
        """NARX input [x[f_states], u] (..., n_f + m)."""
        xs = self._sel(x, self.f_states)
        return np.concatenate([xs, np.broadcast_to(u, x.shape[:-1] + u.shape[-1:])], axis=-1)

    def process(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """GP-f(·): x (..., n), u (..., m) -> next-state mean (..., n)."""
        return x + self.f.predict(self._fx(x, u), return_var=False)

    def process_noise(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Q_k (R, n, n): diagonal of the GP-f predictive variance at x (R, n), u (R, m)."""
        _, var = self.f.predict(self._fx(x, u))
        return var[..., :, None] * np.eye(var.shape[-1])

    def process_deviations(self, x: np.ndarray, D: np.ndarray, u: np.ndarray):
        """x (R, n), D (R, S, n), u (R, m) -> (GP-f(x, u) (R, n), GP-f(x + D, u) − GP-f(x, u) (R, S, n))."""
        Xf = self._fx(x, u)
        dX = np.zeros(D.shape[:-1] + Xf.shape[-1:])
        Ds = self._sel(D, self.f_states)
        dX[..., :Ds.shape[-1]] = Ds  # the command is the same at every sigma point
        m0, dm = self.f.predict_offsets(Xf, dX)
        return x + m0, D + dm

    def observe_deviations(self, x: np.ndarray, D: np.ndarray):
        """x (R, n), D (R, S, n) -> (GP-h(x) (R, p), GP-h(x + D) − GP-h(x) (R, S, p))."""
        return self.h.predict_offsets(self._sel(x, self.h_states), self._sel(D, self.h_states))

    def observe(self, x: np.ndarray) -> np.ndarray:
        """GP-h(·): x (..., n) -> measurement mean (..., p)."""
        return self.h.predict(self._sel(x, self.h_states), return_var=False)

    def observation_noise(self, x: np.ndarray) -> np.ndarray:
        """R_k (R, p, p): diagonal of the GP-h predictive variance at x (R, n)."""
        _, var = self.h.predict(self._sel(x, self.h_states))
        return var[..., :, None] * np.eye(var.shape[-1])

    # files: one .npz, the two GPs under prefixes f/ and h/
    def save(self, path: str | Path) -> None:
        arrays = {**self.f.arrays("f/"), **self.h.arrays("h/")}
        for name, idx in (("f_states", self.f_states), ("h_states", self.h_states)):
            arrays[name] = np.array([], dtype=int) if idx is None else np.asarray(idx)
            arrays[name + "_all"] = np.array(idx is None)
        np.savez(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "GPUKFModels":
        with np.load(path, allow_pickle=False) as a:
            idx = {k: None if bool(a[k + "_all"]) else np.asarray(a[k]) for k in ("f_states", "h_states")}
            return cls(GPModel.from_arrays(a, "f/"), GPModel.from_arrays(a, "h/"), **idx)


def narx_training_data(x: np.ndarray, u: np.ndarray, z: np.ndarray, fraction: float = 0.4,
                       seed: int = 0, f_states: Sequence[int] | None = None,
                       h_states: Sequence[int] | None = None):
    """Training pairs from one run (gp-ukf.md section 6), randomly subsampled.

    ``x`` (T, n) states, ``u`` (T, m) commands, ``z`` (T, p) measurements, at the filter's
    sample rate. Returns ``(Xf, Yf, Xh, Yh)``: process inputs ``[x_k[f_states], u_k]`` and
    targets ``x_{k+1} − x_k`` for a random ``fraction`` of k < T−1, and observation inputs
    ``x_k[h_states]`` and targets ``z_k`` for a random ``fraction`` of k (paper: 40 %).
    """
    x, u, z = (np.asarray(a, dtype=float) for a in (x, u, z))
    if not (x.ndim == u.ndim == z.ndim == 2 and x.shape[0] == u.shape[0] == z.shape[0]):
        raise NespmError(f"GP training data: need x (T, n), u (T, m), z (T, p); got {x.shape}, {u.shape}, {z.shape}")
    if not 0 < fraction <= 1:
        raise NespmError(f"GP training data: fraction must be in (0, 1], got {fraction}")
    rng = np.random.default_rng(seed)
    T = x.shape[0]
    xf = x if f_states is None else x[:, list(f_states)]
    xh = x if h_states is None else x[:, list(h_states)]
    kf = np.sort(rng.choice(T - 1, max(2, round(fraction * (T - 1))), replace=False))
    kh = np.sort(rng.choice(T, max(2, round(fraction * T)), replace=False))
    Xf = np.concatenate([xf[kf], u[kf]], axis=1)
    Yf = x[kf + 1] - x[kf]
    return Xf, Yf, xh[kh], z[kh]


def fit_gp_ukf_models(x: np.ndarray, u: np.ndarray, z: np.ndarray, fraction: float = 0.4,
                      seed: int = 0, max_points: int = MAX_POINTS, n_restarts: int = N_RESTARTS,
                      f_states: Sequence[int] | None = None,
                      h_states: Sequence[int] | None = None) -> GPUKFModels:
    """Fit GP-f and GP-h on one run (see :func:`narx_training_data`; shapes there)."""
    Xf, Yf, Xh, Yh = narx_training_data(x, u, z, fraction, seed, f_states, h_states)
    gf = GPModel(max_points, n_restarts, seed).fit(Xf, Yf)
    gh = GPModel(max_points, n_restarts, seed + 1).fit(Xh, Yh)
    idx = lambda s: None if s is None else np.asarray(s, dtype=int)  # noqa: E731
    return GPUKFModels(gf, gh, idx(f_states), idx(h_states))


def gp_ukf(x0: np.ndarray, P0: np.ndarray, u: np.ndarray, z: np.ndarray, models: GPUKFModels,
           **kw) -> UKFResult:
    """The GP-UKF of Table 2: process and observation models and Q_k, R_k from the GPs.

    Shapes as in :func:`run_ukf`. Q_k is the GP-f variance at (x̂_{k-1|k-1}, u_{k-1}) and
    R_k the GP-h variance at x̂_{k|k-1}, both diagonal.
    """
    f = DeviationModel(models.process, models.process_deviations)
    h = DeviationModel(models.observe, models.observe_deviations)
    return run_ukf(x0, P0, u, z, f, h, models.process_noise, models.observation_noise, **kw)
