"""``iae-ekf``, ``sh-ekf``, ``vb-ekf``: the EKF with each sensor's R adapted from its innovations.

The EKF's time update (the compiled IMU-rate transition, the fixed Q) is unchanged; the
measurement update estimates the noise covariance of the measuring sensor from its innovations
and uses it (:mod:`nespm_cli.filters.adaptive_r`, docs/filters.md "Adaptive R"), once per
measurement, batched over the runs:

* ``iae-ekf``: ``R̂ = Ĉ_ν − H P⁻ Hᵀ`` over the last ``window`` seconds of that sensor's
  innovations (Mohamed & Schwarz 1999), the nominal R until the first window is full; a given
  window longer than the track is an error, the default (30 s) is cut to a shorter track's span;
* ``sh-ekf``: Sage-Husa, ``R_k = (1 − d) R_{k−1} + d (ν νᵀ − H P⁻ Hᵀ)``, ``d = 1 − forgetting``,
  starting at the nominal R;
* ``vb-ekf``: variational Bayes (Särkkä & Nummenmaa 2009), a diagonal R with inverse-gamma rows,
  ``iterations`` fixed-point iterations, forgetting ``rho``, prior mean the nominal R.

``iae-ekf`` and ``sh-ekf`` keep their estimate positive definite with
:func:`~nespm_cli.filters.adaptive_r.bounded` (``r_floor R₀ ≤ R ≤ r_ceiling R₀``); the VB
estimate is positive by construction. Q is the EKF's (not adapted). A sensor is identified by its
measurement class and dimension (each sensor of ``--sensors`` has its own class); its estimate is
a (runs, m, m) array, and the runs where a measurement is missing keep theirs.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.filters.adaptive_r import bounded, iae_r, pair_mask, sage_husa_r, valid_rows, vb_update
from nespm_cli.filters.ekf import EKF
from nespm_cli.filters.model import joseph_update
from nespm_cli.filters.registry import register


#: the bounds of iae-ekf and sh-ekf's estimate, relative to the nominal R (:func:`bounded`)
BOUNDS = {"r_floor": 0.01, "r_ceiling": 1e4}


class AdaptiveREKF(EKF):
    """Base: the EKF with a per-sensor adapted R (subclasses implement :meth:`adapted_update`).

    Attributes: ``r_est`` ``{sensor key: (R, m, m)}`` the current R estimate per sensor (for inspection
    and the tests); ``t_meas`` (M+1,) the time [s] at the end of each IMU step."""

    adaptive_of = None

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.t_end = np.concatenate([[0.0], np.cumsum(self.dt)])[1:]
        self.span_s = float(self.t_end[-1]) if len(self.t_end) else 0.0
        self.r_est: dict = {}
        self.ok = np.ones(self.R, dtype=bool)
        self.check_options(self.name, self.options, {k for k, _ in cfg.options}, self.span_s)

    @classmethod
    def check_options(cls, name: str, options: dict, given: set, span_s: float) -> None:
        """One line naming ``--filter-option NAME.KEY`` for a value outside its domain; ``options`` the
        filter's values, ``given`` the keys set explicitly, ``span_s`` the (shortest) track's span [s].
        Called by the experiment's validation before anything is written, and again by the filter."""
        o = options
        if "r_floor" in o and not 0.0 < o["r_floor"] <= 1.0 <= o["r_ceiling"]:
            raise NespmError(f"--filter-option {name}.r_floor/r_ceiling: need 0 < r_floor <= 1 <= r_ceiling, "
                             f"got {o['r_floor']}, {o['r_ceiling']}")
        for key in ("forgetting", "rho"):
            if key in o and not 0.0 < float(o[key]) < 1.0:
                raise NespmError(f"--filter-option {name}.{key}={float(o[key]):g}: a forgetting factor must lie in "
                                 "(0, 1)")

    def update(self, measurement, j_last: int):
        nav = self.nav
        nu = measurement.innovation(nav)
        H = measurement.H(nav)
        m = nu.shape[-1]
        R0 = np.broadcast_to(measurement.R, (self.R, m, m)).astype(float)
        key = (type(measurement).__module__, type(measurement).__qualname__, m)
        valid = valid_rows(H, nu)
        x, self.P, S, Rm = self.adapted_update(key, H, nu, R0, valid, float(self.t_end[j_last]))
        prev = self.r_est.get(key, R0)
        self.r_est[key] = np.where(self.ok[:, None, None], Rm, prev)
        self.feedback(x)
        return nu, S

    def update_where(self, measurement, j_last: int, ok: np.ndarray):
        """The EKF's, with the adaptive state of the runs not ``ok`` left as it was."""
        self.ok = np.asarray(ok, dtype=bool)
        try:
            return super().update_where(measurement, j_last, ok)
        finally:
            self.ok = np.ones(self.R, dtype=bool)

    def masked(self, R: np.ndarray, R0: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """``R`` on the elements of valid row pairs, the nominal ``R0`` elsewhere (B, m, m)."""
        return np.where(pair_mask(valid), R, R0)

    def adapted_update(self, key, H, nu, R0, valid, t):
        """Return ``(x, P⁺, S, R used)`` and advance the sensor ``key``'s estimator."""
        raise NotImplementedError


@register("iae-ekf")
class IAEEKF(AdaptiveREKF):
    """Innovation-based adaptive estimation of R over a window of ``window`` seconds."""

    option_defaults = {"window": 30.0, **BOUNDS}
    #: searched by ``nespm tune`` beside the noise factors (log scale, seconds)
    tune_ranges = {"window": (5.0, 120.0)}

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.window = min(float(self.options["window"]), self.span_s)  # the default, cut to a short track
        self.buf: dict = {}

    @classmethod
    def check_options(cls, name: str, options: dict, given: set, span_s: float) -> None:
        super().check_options(name, options, given, span_s)
        window = float(options["window"])
        if not window > 0:
            raise NespmError(f"--filter-option {name}.window={window:g}: must be > 0 s")
        if window > span_s and "window" in given:  # a default longer than a short track is cut to it
            raise NespmError(f"--filter-option {name}.window={window:g}: longer than the track ({span_s:.1f} s)")

    def adapted_update(self, key, H, nu, R0, valid, t):
        P_prior = self.P
        hph = H @ P_prior @ np.swapaxes(H, -1, -2)
        st = self.buf.setdefault(key, {"t": [], "outer": [], "hph": [], "w": [], "first": t})
        st["t"].append(t)
        st["outer"].append(nu[..., :, None] * nu[..., None, :])
        st["hph"].append(hph)
        st["w"].append((pair_mask(valid) & self.ok[:, None, None]).astype(float))
        while st["t"] and st["t"][0] <= t - self.window + 1e-9:
            for a in ("t", "outer", "hph", "w"):
                st[a].pop(0)
        if t - st["first"] + 1e-9 < self.window - self.dt_imu:  # the first window is not full yet
            Rm = R0
        else:
            R_hat, count = iae_r(np.stack(st["outer"]), np.stack(st["hph"]), np.stack(st["w"]))
            Rm = self.masked(bounded(np.where(count >= 2, R_hat, R0), R0, self.options["r_floor"],
                                     self.options["r_ceiling"]), R0, valid)
        x, P, S = joseph_update(P_prior, H, nu, Rm)
        return x, P, S, Rm


@register("sh-ekf")
class SageHusaEKF(AdaptiveREKF):
    """Sage-Husa R with forgetting factor ``forgetting`` (memory about ``1/(1 − b)`` measurements);
    ``form`` ``residual`` (default: the update uses ``R_{k−1}``, then ``R_k`` from the post-fit
    residual) or ``innovation`` (``R_k`` from the innovation, used in the same update)."""

    option_defaults = {"forgetting": 0.97, "form": "residual", **BOUNDS}
    #: searched by ``nespm tune`` (linear): a memory of about 10 to 1,000 measurements
    tune_ranges = {"forgetting": (0.9, 0.999, "linear")}

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.b = float(self.options["forgetting"])

    @classmethod
    def check_options(cls, name: str, options: dict, given: set, span_s: float) -> None:
        super().check_options(name, options, given, span_s)
        if options["form"] not in ("residual", "innovation"):
            raise NespmError(f"--filter-option {name}.form={options['form']}: choose residual or innovation")

    def adapted_update(self, key, H, nu, R0, valid, t):
        Ht = np.swapaxes(H, -1, -2)
        prev = self.r_est.get(key, R0)
        lo, hi = self.options["r_floor"], self.options["r_ceiling"]
        if self.options["form"] == "innovation":
            R_new = bounded(sage_husa_r(prev, nu, H @ self.P @ Ht, 1.0 - self.b), R0, lo, hi)
            Rm = self.masked(np.where(self.ok[:, None, None], R_new, prev), R0, valid)
            x, P, S = joseph_update(self.P, H, nu, Rm)
            return x, P, S, Rm
        Rm = self.masked(prev, R0, valid)
        x, P, S = joseph_update(self.P, H, nu, Rm)
        eps = nu - (H @ x[..., None])[..., 0]
        R_new = bounded(sage_husa_r(prev, eps, H @ P @ Ht, 1.0 - self.b, sign=1.0), R0, lo, hi)
        return x, P, S, self.masked(R_new, R0, valid)


@register("vb-ekf")
class VBEKF(AdaptiveREKF):
    """Variational-Bayes adaptive diagonal R (Särkkä & Nummenmaa 2009), forgetting ``rho``."""

    option_defaults = {"rho": 0.97, "iterations": 3}
    #: searched by ``nespm tune`` (linear): a memory of about 10 to 1,000 measurements
    tune_ranges = {"rho": (0.9, 0.999, "linear")}

    def __init__(self, cfg, nav0, imu, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.rho = float(self.options["rho"])
        self.ig: dict = {}

    @classmethod
    def check_options(cls, name: str, options: dict, given: set, span_s: float) -> None:
        super().check_options(name, options, given, span_s)
        if int(options["iterations"]) < 1:
            raise NespmError(f"--filter-option {name}.iterations={options['iterations']}: must be >= 1")

    def adapted_update(self, key, H, nu, R0, valid, t):
        if key not in self.ig:  # prior: the steady-state shape ½ / (1 − ρ), mean the nominal R
            a0 = np.full(nu.shape, 0.5 / (1.0 - self.rho))
            self.ig[key] = (a0, a0 * np.einsum("...ii->...i", R0))
        alpha, beta = self.ig[key]
        x, P, S, Rm, a, b = vb_update(self.P, H, nu, alpha, beta, self.rho, int(self.options["iterations"]),
                                      valid, R0)
        ok = self.ok[:, None]
        self.ig[key] = (np.where(ok, a, alpha), np.where(ok, b, beta))
        return x, P, S, Rm


__all__ = ["AdaptiveREKF", "IAEEKF", "SageHusaEKF", "VBEKF"]
