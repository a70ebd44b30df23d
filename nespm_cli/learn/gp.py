"""Gaussian-process regression for the GP-UKF (gp-ukf.md section 4, eqs 4-10).

:class:`GPModel` is one independent GP per output dimension, each with

    k(x, x') = σ_f² exp(−½ Σ_d (x_d − x'_d)² / ℓ_d²) + σ_n² δ(x, x')     (eq 7, ARD form; eq 4 noise)

on standardized inputs and standardized outputs. Hyperparameters (σ_f², ℓ_1..ℓ_D, σ_n²) are
found by maximising the log marginal likelihood (eqs 8-9) with its analytic gradient
(eq 10) by L-BFGS-B, started from a default point plus ``n_restarts`` seeded random points
drawn log-uniformly inside the bounds. This is the model and procedure of scikit-learn's
``GaussianProcessRegressor(ConstantKernel * RBF(ARD) + WhiteKernel, normalize_y=True,
n_restarts_optimizer=n_restarts)``, with the same θ = log hyperparameters and jitter
(tests/test_gp.py checks the likelihood and its gradient against scikit-learn's). It is
written out here because scikit-learn's gradient builds an (N, N, D) array and costs
~1.7 s per evaluation at N = 1000, D = 15 against ~0.15 s here (single-threaded), and a
12-output REMUS model needs thousands of evaluations. The output standardization (``normalize_y``) is done
here too, so that its mean and scale are saved with the model.

Prediction (eqs 5-6) is our own numpy code from the fitted hyperparameters, so that a model
loaded from disk predicts like the one that was fitted (identically at the same BLAS thread
count, to ~1e-9 otherwise: K can be ill-conditioned), and so that it is batched over any
leading axes with one kernel evaluation per output:

    mean(x*) = y_mean + y_scale · k*ᵀ α,             α = (K + σ_n² I)⁻¹ y          (eq 5)
    var(x*)  = y_scale² · (σ_f² − k*ᵀ (K + σ_n² I)⁻¹ k* [+ σ_n²])                  (eq 6)

with ``noise=True`` (the default) adding σ_n²: the variance of a new noisy observation,
which is what the filter uses as its process / observation noise (docs/gp-ukf.md).

Subset of data: GP training is O(N³) in time and O(N²) in memory per output and per
likelihood evaluation, so at most ``max_points`` (default 1000) training pairs are kept, a
seeded uniform random subsample of the rows given to :meth:`GPModel.fit`. With 1000 points
one likelihood evaluation (a 1000×1000 Cholesky and inverse) takes ~0.15 s and the fitted
model holds one such factor per output (8 MB each).

Files: :meth:`GPModel.save` / :meth:`GPModel.load` use one ``.npz`` (no pickles): the kept
training inputs and targets, the standardization and the hyperparameters; the Cholesky
factors are recomputed on load (cheap next to fitting).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.linalg import LinAlgError, cho_solve, cholesky, lapack, solve_triangular
from scipy.optimize import minimize
from scipy.spatial.distance import cdist

from nespm_cli.errors import NespmError

#: Default number of training points kept per model (subset of data).
MAX_POINTS = 1000
#: Default number of extra optimizer starts (besides the default start), per output.
N_RESTARTS = 1
#: Diagonal jitter added to K besides σ_n² (scikit-learn's default ``alpha``).
JITTER = 1e-10
#: Hyperparameter bounds, in standardized units (inputs and outputs have unit std).
BOUNDS = {"constant": (1e-3, 1e5), "length": (1e-2, 1e4), "noise": (1e-9, 1e1)}

_FORMAT = "nespm-gp-v1"


def _rbf(A: np.ndarray, B: np.ndarray, const: float, length: np.ndarray) -> np.ndarray:
    """σ_f² exp(−½ |(a − b)/ℓ|²) between rows of ``A`` (N, D) and ``B`` (M, D) -> (N, M) (eq 7).

    Squared distances come from ``cdist`` (each pair on its own, no |a|²+|b|²−2ab
    cancellation), so a point's kernel row does not depend on the batch it is in.
    """
    return const * np.exp(-0.5 * cdist(A / length, B / length, "sqeuclidean"))


# --- marginal likelihood (eqs 8-10) ----------------------------------------------------------
# θ = log [σ_f², ℓ_1, ..., ℓ_D, σ_n²], the parametrization and order of scikit-learn's
# ConstantKernel * RBF(ARD) + WhiteKernel, whose log_marginal_likelihood this reproduces
# (tests/test_gp.py); the gradient below avoids its (N, N, D) kernel-gradient array, which
# makes it ~10x faster at N = 1000, D = 15.

def theta_default(d_in: int) -> np.ndarray:
    """Default start: σ_f² = 1, ℓ = 1 (one input std), σ_n² = 1e-2 (10 % noise std)."""
    return np.log(np.r_[1.0, np.ones(d_in), 1e-2])


def log_bounds(d_in: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of θ (log units), from :data:`BOUNDS`."""
    b = [BOUNDS["constant"]] + [BOUNDS["length"]] * d_in + [BOUNDS["noise"]]
    lo, hi = np.log(np.array(b)).T
    return lo, hi


def _unpack(theta: np.ndarray) -> tuple[float, np.ndarray, float]:
    e = np.exp(theta)
    return float(e[0]), e[1:-1].copy(), float(e[-1])


def log_marginal_likelihood(theta: np.ndarray, X: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Log marginal likelihood L(θ) (eq 9) and its gradient dL/dθ (eq 10).

    ``X`` (N, D) and ``y`` (N,) in standardized units; θ as in :func:`theta_default`.
    Returns ``(-inf, 0)`` if K is not positive definite.
    """
    const, length, noise = _unpack(theta)
    n = X.shape[0]
    Z = X / length
    Kf = _rbf(X, X, const, length)  # σ_f² E = dK/d log σ_f²
    K = Kf.copy()
    K[np.diag_indices(n)] += noise + JITTER
    try:
        L = cholesky(K, lower=True, check_finite=False)
    except LinAlgError:
        return -np.inf, np.zeros_like(theta)
    alpha = cho_solve((L, True), y, check_finite=False)
    lml = -0.5 * y @ alpha - np.log(np.diag(L)).sum() - 0.5 * n * np.log(2 * np.pi)  # eq 9
    Kinv, info = lapack.dpotri(L, lower=1)
    if info != 0:
        return -np.inf, np.zeros_like(theta)
    Kinv = np.tril(Kinv) + np.tril(Kinv, -1).T
    W = np.outer(alpha, alpha) - Kinv  # eq 10: dL/dθ = ½ tr(W dK/dθ)
    M = W * Kf
    r = M.sum(axis=1)
    grad = np.empty_like(theta)
    grad[0] = 0.5 * M.sum()
    # dK/d log ℓ_d = Kf ∘ (z_d,i − z_d,j)²: Σ_ij M_ij (z_i − z_j)² = 2 (z² · r − z · M z)
    grad[1:-1] = (Z**2).T @ r - np.einsum("id,id->d", Z, M @ Z)
    grad[-1] = 0.5 * noise * np.trace(W)
    return float(lml), grad


def _neg_lml(theta, X, y):
    v, g = log_marginal_likelihood(theta, X, y)
    if not np.isfinite(v):
        return 1e25, np.zeros_like(theta)
    return -v, -g


class GPModel:
    """Independent GPs, one per output, with ARD squared-exponential kernel + white noise.

    Parameters
    ----------
    max_points:
        Cap on the training set (subset of data, seeded random subsample).
    n_restarts:
        Extra L-BFGS-B starts of the marginal-likelihood optimization per output.
    seed:
        Seeds both the subsample and the restart points.
    """

    def __init__(self, max_points: int = MAX_POINTS, n_restarts: int = N_RESTARTS, seed: int = 0):
        if max_points < 2:
            raise NespmError(f"GPModel: max_points must be at least 2, got {max_points}")
        self.max_points = int(max_points)
        self.n_restarts = int(n_restarts)
        self.seed = int(seed)
        self._fitted = False
        self.fit_warnings: list[str] = []

    # --- fitting ---------------------------------------------------------------------------
    def fit(self, X: np.ndarray, Y: np.ndarray) -> "GPModel":
        """Fit to inputs ``X`` (N, d_in) and targets ``Y`` (N, d_out) or (N,); returns self.

        Rows with any non-finite value are dropped; then at most ``max_points`` rows are kept
        (seeded random subsample). Units are whatever the caller's are; the model
        standardizes both sides internally.
        """
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
        if Y.ndim == 1:
            Y = Y[:, None]
        if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0]:
            raise NespmError(f"GPModel.fit: need X (N, d_in) and Y (N, d_out), got {X.shape} and {Y.shape}")
        ok = np.isfinite(X).all(axis=1) & np.isfinite(Y).all(axis=1)
        X, Y = X[ok], Y[ok]
        if X.shape[0] < 2:
            raise NespmError("GPModel.fit: fewer than 2 finite training rows")
        rng = np.random.default_rng(self.seed)
        if X.shape[0] > self.max_points:
            keep = np.sort(rng.choice(X.shape[0], self.max_points, replace=False))
            X, Y = X[keep], Y[keep]
        self.X_train, self.Y_train = X, Y
        self.x_mean, self.x_scale = X.mean(axis=0), _scale(X.std(axis=0))
        self.y_mean, self.y_scale = Y.mean(axis=0), _scale(Y.std(axis=0))
        Xs = (X - self.x_mean) / self.x_scale
        Ys = (Y - self.y_mean) / self.y_scale
        d_in, d_out = X.shape[1], Y.shape[1]
        self.const = np.empty(d_out)
        self.length = np.empty((d_out, d_in))
        self.noise = np.empty(d_out)
        self.log_marginal_likelihood = np.empty(d_out)
        self.fit_warnings = []
        lo, hi = log_bounds(d_in)
        for j in range(d_out):  # one independent GP per output
            starts = [theta_default(d_in)] + [rng.uniform(lo, hi) for _ in range(self.n_restarts)]
            best = None
            for t0 in starts:
                r = minimize(lambda t: _neg_lml(t, Xs, Ys[:, j]), t0, jac=True, method="L-BFGS-B",
                             bounds=list(zip(lo, hi)))
                if np.isfinite(r.fun) and (best is None or r.fun < best.fun):
                    best = r
            if best is None:
                raise NespmError(f"GPModel.fit: no finite marginal likelihood for output {j}")
            theta = best.x
            at = np.isclose(theta, lo) | np.isclose(theta, hi)
            if at[0]:
                self.fit_warnings.append(f"output {j}: signal variance at its bound {np.exp(theta[0]):.3g}")
            for i in np.flatnonzero(at[1:-1]):
                self.fit_warnings.append(f"output {j}: length scale of input {i} at its bound "
                                         f"{np.exp(theta[1 + i]):.3g} (standardized units)")
            if at[-1]:
                self.fit_warnings.append(f"output {j}: noise variance at its bound {np.exp(theta[-1]):.3g}")
            self.const[j], self.length[j], self.noise[j] = _unpack(theta)
            self.log_marginal_likelihood[j] = -best.fun
        self._factor()
        return self

    def _factor(self) -> None:
        """Cholesky factors L_j of K_j + (σ_n,j² + jitter) I and α_j = K⁻¹ y_j (eqs 5-6)."""
        Xs = (self.X_train - self.x_mean) / self.x_scale
        Ys = (self.Y_train - self.y_mean) / self.y_scale
        n, d_out = Ys.shape
        self._Xs = Xs
        self._L = np.empty((d_out, n, n))
        self._alpha = np.empty((d_out, n))
        for j in range(d_out):
            K = _rbf(Xs, Xs, self.const[j], self.length[j])
            K[np.diag_indices(n)] += self.noise[j] + JITTER
            self._L[j] = cholesky(K, lower=True)
            self._alpha[j] = cho_solve((self._L[j], True), Ys[:, j])
        self._fitted = True

    # --- prediction --------------------------------------------------------------------------
    @property
    def d_in(self) -> int:
        return self.X_train.shape[1]

    @property
    def d_out(self) -> int:
        return self.Y_train.shape[1]

    @property
    def n_train(self) -> int:
        return self.X_train.shape[0]

    def predict(self, X: np.ndarray, return_var: bool = True, noise: bool = True):
        """Predictive mean and variance at ``X`` (..., d_in), batched over leading axes.

        Returns ``mean`` (..., d_out) in the units of the training targets and, if
        ``return_var``, ``var`` (..., d_out) in their units squared: the latent variance
        (eq 6) plus, if ``noise``, the learnt noise variance σ_n². The mean alone costs
        O(N) per point and output, the variance O(N²).
        """
        if not self._fitted:
            raise NespmError("GPModel.predict: the model is not fitted")
        X = np.asarray(X, dtype=float)
        if X.shape[-1] != self.d_in:
            raise NespmError(f"GPModel.predict: inputs have {X.shape[-1]} columns, the model {self.d_in}")
        lead = X.shape[:-1]
        Xs = ((X.reshape(-1, self.d_in) - self.x_mean) / self.x_scale)
        B = Xs.shape[0]
        mean = np.empty((B, self.d_out))
        var = np.empty((B, self.d_out)) if return_var else None
        for j in range(self.d_out):
            Ks = _rbf(Xs, self._Xs, self.const[j], self.length[j])  # (B, N) = k(x*, X)
            mean[:, j] = Ks @ self._alpha[j]  # eq 5
            if return_var:
                v = solve_triangular(self._L[j], Ks.T, lower=True, check_finite=False)  # (N, B)
                var[:, j] = self.const[j] - np.einsum("nb,nb->b", v, v)  # eq 6
        mean = self.y_mean + self.y_scale * mean
        if not return_var:
            return mean.reshape(lead + (self.d_out,))
        var = np.maximum(var, 0.0)  # round-off can make a latent variance a hair negative
        if noise:
            var = var + self.noise
        var = var * self.y_scale**2
        return mean.reshape(lead + (self.d_out,)), var.reshape(lead + (self.d_out,))

    def predict_offsets(self, X0: np.ndarray, dX: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean at ``X0`` (..., d_in) and its change at ``X0 + dX``, ``dX`` (..., S, d_in).

        Returns ``mean0`` (..., d_out) and ``dmean`` (..., S, d_out) = mean(X0 + dX) − mean(X0),
        the latter formed without subtracting two means: per training point,
        ``k(x0 + d, x_i) − k(x0, x_i) = k(x0, x_i) · expm1(−d·(x0 − x_i)/ℓ² − |d/ℓ|²/2)``.
        This matters for the unscented transform with α = 1e-3, whose sigma points are
        ~1e-3 σ apart and whose weights (~1/α²) would amplify the O(1e-9) rounding of a
        mean computed as k*ᵀα with an ill-conditioned K (α entries of 1e2-1e3 cancelling).
        """
        if not self._fitted:
            raise NespmError("GPModel.predict_offsets: the model is not fitted")
        X0 = np.asarray(X0, dtype=float)
        dX = np.asarray(dX, dtype=float)
        lead, S = X0.shape[:-1], dX.shape[-2]
        if X0.shape[-1] != self.d_in or dX.shape != lead + (S, self.d_in):
            raise NespmError(f"GPModel.predict_offsets: X0 {X0.shape} and dX {dX.shape} do not match "
                             f"(..., {self.d_in}) and (..., S, {self.d_in})")
        Z0 = (X0.reshape(-1, self.d_in) - self.x_mean) / self.x_scale  # (B, D)
        dZ = dX.reshape(-1, S, self.d_in) / self.x_scale  # (B, S, D)
        B_ = Z0.shape[0]
        mean0 = np.empty((B_, self.d_out))
        dmean = np.empty((B_, S, self.d_out))
        for j in range(self.d_out):
            k0 = _rbf(Z0, self._Xs, self.const[j], self.length[j])  # (B, N), as in predict
            A = dZ / self.length[j] ** 2  # (B, S, D)
            # exponent change −d·(z0 − z_i)/ℓ² − |d/ℓ|²/2; its first-order part is exactly odd in d
            cross = (A.reshape(-1, self.d_in) @ self._Xs.T).reshape(B_, S, -1)  # d·z_i/ℓ² (B, S, N)
            lin = np.einsum("bsd,bd->bs", A, Z0)  # d·z0/ℓ²
            cross -= (lin + 0.5 * np.einsum("bsd,bsd->bs", A, dZ))[..., None]  # the exponent change
            np.expm1(cross, out=cross)  # k(x0 + d, x_i)/k(x0, x_i) − 1
            mean0[:, j] = k0 @ self._alpha[j]  # eq 5, summed as in predict
            dmean[:, :, j] = (cross @ (k0 * self._alpha[j])[:, :, None])[..., 0]
        mean0 = self.y_mean + self.y_scale * mean0
        dmean = self.y_scale * dmean
        return mean0.reshape(lead + (self.d_out,)), dmean.reshape(lead + (S, self.d_out))

    def noise_var(self) -> np.ndarray:
        """Learnt noise variance σ_n² per output (d_out,), in target units squared."""
        return self.noise * self.y_scale**2

    # --- files -----------------------------------------------------------------------------
    def arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """Everything needed to rebuild the model, as arrays keyed ``prefix + name``."""
        meta = {"format": _FORMAT, "max_points": self.max_points, "n_restarts": self.n_restarts,
                "seed": self.seed, "fit_warnings": self.fit_warnings}
        out = {"X_train": self.X_train, "Y_train": self.Y_train, "x_mean": self.x_mean,
               "x_scale": self.x_scale, "y_mean": self.y_mean, "y_scale": self.y_scale,
               "const": self.const, "length": self.length, "noise": self.noise,
               "log_marginal_likelihood": self.log_marginal_likelihood,
               "meta": np.array(json.dumps(meta))}
        return {prefix + k: v for k, v in out.items()}

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "") -> "GPModel":
        """Inverse of :meth:`arrays` (``arrays`` may be an open ``np.load`` file)."""
        try:
            meta = json.loads(str(arrays[prefix + "meta"]))
        except KeyError as e:
            raise NespmError(f"GP model file: missing {prefix}meta") from e
        if meta.get("format") != _FORMAT:
            raise NespmError(f"GP model file: format {meta.get('format')!r}, expected {_FORMAT!r}")
        m = cls(meta["max_points"], meta["n_restarts"], meta["seed"])
        m.fit_warnings = list(meta.get("fit_warnings", []))
        for k in ("X_train", "Y_train", "x_mean", "x_scale", "y_mean", "y_scale", "const", "length",
                  "noise", "log_marginal_likelihood"):
            setattr(m, k, np.asarray(arrays[prefix + k], dtype=float))
        m._factor()
        return m

    def save(self, path: str | Path) -> None:
        """Write the model to one ``.npz`` (no pickles)."""
        np.savez(path, **self.arrays())

    @classmethod
    def load(cls, path: str | Path) -> "GPModel":
        """Read a model written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as f:
            return cls.from_arrays(f)


def _scale(s: np.ndarray) -> np.ndarray:
    """Standard deviations with zeros (constant columns) replaced by 1, as scikit-learn does."""
    return np.where(s > 0, s, 1.0)
