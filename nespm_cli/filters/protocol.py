"""The filter protocol: what :func:`nespm_cli.filters.engine.run_filter` asks of a filter.

Shapes carry the batch axis first: R Monte Carlo runs, M IMU steps, N GT epochs, n error
states in the blocks of ``cfg.layout`` (:class:`nespm_cli.nav.state.StateLayout`; the papers'
12: ``x = [dv (0:3) m/s, dpsi (3:6) rad, b_a (6:9) m/s², b_g (9:12) rad/s]``, the 15-state
layout puts ``dp`` [m, NED] first). ``nav ⊕ x = truth`` (:mod:`nespm_cli.filters.model`);
closed loop, so x = 0 between calls.

Who calls what, when (one filter object per ``run_filter`` call, i.e. per filter and chunk of runs)::

    filt = cls(cfg, nav0, imu, noise_std)         # once; nav0 copied, P = cfg.p0() per run
    record(filt.state(), filt.covariance())       # epoch 0
    for each span [j0, j1) between event times    # GT epochs and every sensor's times, merged
        filt.propagate(j0, j1, k)                 # k: the GT interval holding the span
        # (time_update == "imu": filt.propagate(j, j + 1, k) for j in range(j0, j1))
        for each measurement at j1 (in --sensors order):
            nu_S = filt.update(measurement, j1 - 1)   # optional (nu, S) for the NIS
        filt.check()
        at a GT epoch: record(filt.state(), filt.covariance())
    diverged = filt.diverged

A filter is a subclass of :class:`Filter` (the bare interface) — usually of
:class:`ErrorStateFilter`, which holds the shared closed-loop machinery (navigation solution,
covariance, divergence mask, strapdown + transition matrix over a span, fixed or adaptive Q,
feedback, divergence check) — registered under a name with
:func:`nespm_cli.filters.registry.register`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.filters import kernels
from nespm_cli.filters.adaptive import adaptive_q
from nespm_cli.filters.model import (FilterConfig, NavState, feedback, invariant_system_matrix, process_noise,
                                     system_matrix)
from nespm_cli.filters.options import option_values
from nespm_cli.filters.unscented import UTWeights, safe_cholesky
from nespm_cli.nav.products import mat_mul
from nespm_cli.nav.rotations import exp_so3
from nespm_cli.nav.state import StateLayout, error, parse_layout, position_plus
from nespm_cli.nav.strapdown import na_cycle
from nespm_cli.sensors.measurement import Measurement


@dataclass
class ImuData:
    """The corrupted IMU of R runs: ``f`` (R, M, 3) specific force [m/s²], ``w`` (R, M, 3)
    angular rate [rad/s], ``dt`` (M,) step durations [s]; step j goes from sample j to j+1."""

    f: np.ndarray
    w: np.ndarray
    dt: np.ndarray


class Filter:
    """The batched filter interface (all methods act on every run of the batch at once).

    Class attributes:
        name: the registered name (set by :func:`~nespm_cli.filters.registry.register`).
        has_covariance: False for a filter with no covariance and no measurement update
            (``ins``): ``run_filter`` then records NaN covariance and never calls ``update``.
        needs_noise_std: True if the filter needs the ProcessNet noise std (``noise_std``).
        adaptive_of: name of the non-adaptive twin of an adaptive filter, else None.
        layouts: the error-state layouts it serves (names, ``StateLayout.name``), None: any.
    """

    name: str = ""
    #: the filter's own options and their defaults (``--filter-option NAME.KEY=VALUE``; read them with
    #: :func:`nespm_cli.filters.options.option_values` or :attr:`ErrorStateFilter.options`)
    option_defaults: dict = {}
    #: FilterConfig tuning fields it takes per filter (the sigma-point filters: alpha, beta, kappa)
    tunable: tuple = ()
    has_covariance: bool = True
    needs_noise_std: bool = False
    adaptive_of: str | None = None
    layouts: tuple | None = None

    @classmethod
    def supports(cls, layout: StateLayout | str) -> bool:
        """Whether the filter serves the error-state ``layout``."""
        return cls.layouts is None or parse_layout(layout).name in cls.layouts

    def __init__(self, cfg: FilterConfig, nav0: NavState, imu: ImuData,
                 noise_std: tuple[np.ndarray, np.ndarray] | None = None):
        """``cfg`` the tuning; ``nav0`` the initial solution of the R runs (not modified);
        ``imu`` the inputs; ``noise_std`` ``(std_a, std_g)`` each (R, N-1, 3) per-sample std
        [m/s², rad/s] of each GT interval (adaptive filters), else None."""
        raise NotImplementedError

    def propagate(self, j0: int, j1: int, k: int) -> None:
        """Time update over IMU steps ``[j0, j1)`` (one span, all inside GT interval ``k``)."""
        raise NotImplementedError

    def update(self, measurement: Measurement, j_last: int):
        """Measurement update with ``measurement`` (:class:`nespm_cli.sensors.measurement.Measurement`);
        ``j_last`` the IMU step ending at its time. May return ``(nu, S)``: the innovation (R, m)
        and its covariance (R, m, m), which the engine records for the NIS (None: not recorded)."""
        raise NotImplementedError

    def check(self) -> None:
        """Flag diverged runs in :attr:`diverged` and sanitize them so the batch goes on."""
        raise NotImplementedError

    def state(self) -> NavState:
        """The current navigation solution (R,) — the filter's own object: read, do not modify."""
        raise NotImplementedError

    def covariance(self) -> np.ndarray | None:
        """The error-state covariance (R, n, n) [SI units squared], or None without one."""
        raise NotImplementedError

    @property
    def diverged(self) -> np.ndarray:
        """(R,) bool: runs flagged diverged so far (the same array object throughout)."""
        raise NotImplementedError

    @property
    def noise_std(self):
        """The noise std the filter used (``(std_a, std_g)``) or None; copied into the output."""
        return None


class ErrorStateFilter(Filter):
    """Closed-loop error-state filter base: subclasses implement ``propagate`` and ``update``.

    Attributes available to subclasses: ``cfg``; ``layout`` (``cfg.layout``, n states);
    ``nav`` (:class:`NavState`, R runs); ``P`` (R, n, n); ``bad`` (R,) divergence mask; ``f``,
    ``w`` (R, M, 3), ``dt`` (M,) the IMU; ``R`` the number of runs; ``ut`` the scaled-UT weights
    of ``cfg``; ``dt_imu`` the median IMU step [s]; ``eye`` Iₙ; ``compiled`` whether the IMU-rate
    loops run compiled (:mod:`nespm_cli.filters.kernels`; ``strapdown`` and ``transition`` use
    them by themselves).
    """

    #: the error whose dynamics ``transition`` accumulates: False the common x of model.py
    #: (system_matrix), True the right-invariant ξ of iekf.py (model.invariant_system_matrix)
    invariant_error: bool = False
    #: the attributes holding per-run state besides the solution (``update_where`` restores them)
    per_run: tuple = ("P",)
    #: whether the RTS smoother can run on this filter (:mod:`nespm_cli.filters.smoother`): its
    #: covariance propagates as ``Φ P Φᵀ + Q`` and ``propagate`` leaves that Φ in ``last_transition``
    smoothable: bool = False
    #: (R, n, n) the Φ of the last ``propagate`` (smoothable filters)
    last_transition: np.ndarray | None = None

    def __init__(self, cfg: FilterConfig, nav0: NavState, imu: ImuData, noise_std=None):
        if self.needs_noise_std and noise_std is None:
            raise NespmError(f"filter {self.name} needs the network noise std (noise_std)")
        self._noise_std = noise_std if self.needs_noise_std else None
        self.cfg = cfg
        self.options = option_values(type(self), cfg)  # the filter's own options, defaults filled in
        self.layout = cfg.layout
        if not self.supports(self.layout):
            raise NespmError(f"filter {self.name} serves --state {' or '.join(self.layouts)}, not {self.layout.name}")
        n = self.layout.n
        self.f, self.w, self.dt = imu.f, imu.w, imu.dt
        self.nav = nav0.copy()
        R = nav0.v_n.shape[0]
        self.R = R
        self.P = np.broadcast_to(cfg.p0(), (R, n, n)).copy()
        self.bad = np.zeros(R, dtype=bool)
        self.ut = UTWeights(n, cfg.alpha, cfg.beta, cfg.kappa)
        self.dt_imu = float(np.median(imu.dt))
        self.eye = np.eye(n)
        self.compiled = kernels.compiled_enabled()

    # --- interface -------------------------------------------------------------------------
    def state(self) -> NavState:
        return self.nav

    def covariance(self) -> np.ndarray | None:
        return self.P if self.has_covariance else None

    @property
    def diverged(self) -> np.ndarray:
        return self.bad

    @property
    def noise_std(self):
        return self._noise_std

    # --- helpers for subclasses --------------------------------------------------------------
    def imu(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Bias-compensated IMU of step j: ``(f, w)`` each (R, 3)."""
        nav = self.nav
        return self.f[:, j] - nav.b_a, self.w[:, j] - nav.b_g

    def span(self, j0: int, j1: int) -> float:
        """Duration of steps ``[j0, j1)`` [s]."""
        return float(self.dt[j0:j1].sum())

    def process_noise(self, span: float, k: int) -> np.ndarray:
        """Discrete Q (n, n) or (R, n, n) of a time update of ``span`` s in GT interval ``k``.

        Fixed (``cfg``); adaptive filters (``needs_noise_std``) use the network std of interval
        ``k`` through :func:`nespm_cli.filters.adaptive.adaptive_q` (anukf.md eqs 43-48),
        evaluated at the current attitude (call it before moving the solution).
        """
        if self._noise_std is None:  # a function of the span alone: formed once per span length (a copy each call)
            held = self.__dict__.get("_q_of_span")
            if held is None or held[0] is not self.cfg or held[1] != self.dt_imu or len(held[2]) > 64:
                held = self._q_of_span = (self.cfg, self.dt_imu, {})
            Q = held[2].get(span)
            if Q is None:
                Q = held[2][span] = process_noise(self.cfg, self.dt_imu, span)
            return Q.copy()
        std_a, std_g = self._noise_std
        return adaptive_q(std_a[:, k], std_g[:, k], self.nav.C_bn, self.cfg, self.dt_imu, span, self.layout)

    def strapdown(self, j0: int, j1: int) -> None:
        """Move the navigation solution through steps ``[j0, j1)`` (free inertial)."""
        if self.compiled:
            n = self.contiguous_nav()
            kernels.strapdown(n.pos, n.v_n, n.C_bn, n.b_a, n.b_g, self.f, self.w, self.dt, j0, j1)
            return
        for j in range(j0, j1):
            f, w = self.imu(j)
            n = self.nav
            n.pos, n.v_n, n.C_bn = na_cycle(n.pos, n.v_n, n.C_bn, f, w, self.dt[j])

    def transition(self, j0: int, j1: int) -> np.ndarray:
        """Move the solution through steps ``[j0, j1)`` and return Φ = Π (I + F dt) (R, n, n),
        F evaluated on the solution before each step: :func:`nespm_cli.filters.model.system_matrix`,
        or :func:`~nespm_cli.filters.model.invariant_system_matrix` where ``invariant_error``."""
        if self.compiled:
            n = self.contiguous_nav()
            return kernels.transition(n.pos, n.v_n, n.C_bn, n.b_a, n.b_g, self.f, self.w, self.dt, j0, j1,
                                      invariant=self.invariant_error, layout=self.layout)
        Phi = np.broadcast_to(self.eye, self.P.shape).copy()
        for j in range(j0, j1):
            f, w = self.imu(j)
            n = self.nav
            F = (invariant_system_matrix(n.pos, n.v_n, n.C_bn) if self.invariant_error
                 else system_matrix(n.pos, n.v_n, n.C_bn, f, self.layout))
            Phi = (self.eye + F * self.dt[j]) @ Phi
            n.pos, n.v_n, n.C_bn = na_cycle(n.pos, n.v_n, n.C_bn, f, w, self.dt[j])
        return Phi

    def points_through_cycle(self, X: np.ndarray, j0: int, j1: int):
        """The solution (point 0) and the solution ⊕ each error-state offset ``X`` (R, S-1, n)
        (sigma or cubature points) through steps ``[j0, j1)``, each point compensating the IMU
        with its own biases (ukf-nespm.md eqs 35-38). Returns ``(pos, v, C, dp)``: (R, S, 3)
        ``[lat, lon, h]``, (R, S, 3) [m/s], (R, S, 3, 3) and each point's position offset from
        point 0, NED [m] (R, S, 3): its initial ``dp`` (none without a position block, eq 35) plus
        the trapezoid integral of its velocity offset (eqs 28-30 in deviation form, so the
        position spread is not lost to differencing latitudes); the solution is not modified.
        Compiled where :attr:`compiled` (:func:`nespm_cli.filters.kernels.points_through_cycle`,
        same bits)."""
        lay = self.layout
        if self.compiled:
            n = self.contiguous_nav()
            return kernels.points_through_cycle(n.pos, n.v_n, n.C_bn, n.b_a, n.b_g, X, self.f, self.w, self.dt,
                                                j0, j1, lay)
        nav = self.nav
        S = X.shape[1] + 1
        Xa = np.concatenate([np.zeros((self.R, 1, lay.n)), X], axis=1)  # point 0 is the solution
        pos = np.repeat(nav.pos[:, None], S, axis=1)
        dp = np.zeros((self.R, S, 3))
        if lay.has("pos"):  # eq 35, with position in the state: pos ⊕ dp
            dp = Xa[..., lay.slice("pos")] + 0.0
            pos[:, 1:] = position_plus(pos[:, 1:], dp[:, 1:])
        v = nav.v_n[:, None] + Xa[..., lay.slice("vel")]  # eq 36
        C = mat_mul(exp_so3(Xa[..., lay.slice("att")]), nav.C_bn[:, None])  # eq 37: ⊕
        b_a = nav.b_a[:, None] + (Xa[..., lay.slice("ba")] if lay.has("ba") else 0.0)
        b_g = nav.b_g[:, None] + (Xa[..., lay.slice("bg")] if lay.has("bg") else 0.0)
        for j in range(j0, j1):  # eq 38 over the span, every point compensating its own biases
            e = v - v[:, :1]
            pos, v, C = na_cycle(pos, v, C, self.f[:, j, None] - b_a, self.w[:, j, None] - b_g, self.dt[j])
            dp = dp + (e + (v - v[:, :1])) * (0.5 * self.dt[j])
        return pos, v, C, dp

    def contiguous_nav(self) -> NavState:
        """The solution with C-contiguous float64 arrays (what the compiled loops update in place)."""
        n = self.nav
        n.pos, n.v_n, n.C_bn = (np.ascontiguousarray(a, dtype=np.float64) for a in (n.pos, n.v_n, n.C_bn))
        n.b_a, n.b_g = (np.ascontiguousarray(a, dtype=np.float64) for a in (n.b_a, n.b_g))
        return n

    def cholesky(self, P: np.ndarray | None = None) -> np.ndarray:
        """Batched Cholesky factor (R, n, n) of ``P`` (default ``self.P``); failing runs are flagged."""
        return safe_cholesky(self.P if P is None else P, self.bad)

    def feedback(self, x: np.ndarray) -> None:
        """Close the loop: ``nav ⊕ x`` (x (R, n)) per block, biases into the compensation."""
        feedback(self.nav, x, self.layout)

    # --- the RTS smoother's view of the filter (nespm_cli.filters.smoother) -------------------
    def smoother_covariance(self) -> np.ndarray:
        """(R, n, n) the covariance in the error coordinates ``propagate``'s Φ acts on."""
        return self.P

    def smoother_error(self, nav_to: NavState, nav_from: NavState) -> np.ndarray:
        """(R, n) ``nav_to ⊖ nav_from`` in those coordinates (:func:`nespm_cli.nav.state.error`)."""
        return error(self.layout, nav_to.pos, nav_to.v_n, nav_to.C_bn, nav_to.b_a, nav_to.b_g, nav_from)

    def smoother_retract(self, nav: NavState, x: np.ndarray) -> None:
        """``nav ⊕ x`` in place, ``x`` (R, n) in those coordinates."""
        feedback(nav, x, self.layout)

    def smoother_to_common(self, P: np.ndarray, nav: NavState) -> np.ndarray:
        """(R, n, n) a covariance of those coordinates in the common error of :mod:`.model`, at ``nav``."""
        return P

    def symmetrize(self) -> None:
        """``P ← (P + Pᵀ) / 2``."""
        self.P = 0.5 * (self.P + np.swapaxes(self.P, -1, -2))

    def update_where(self, measurement: Measurement, j_last: int, ok: np.ndarray):
        """:meth:`update` applied to the runs where ``ok`` (R,) only: the others keep their solution
        and the attributes of :attr:`per_run` (a measurement missing in some runs, e.g. a dropout)."""
        keep = ~np.asarray(ok, dtype=bool)
        nav0 = self.nav.copy()
        saved = {a: np.array(getattr(self, a), copy=True) for a in self.per_run}
        res = self.update(measurement, j_last)
        nav = self.nav
        for a in ("pos", "v_n", "C_bn", "b_a", "b_g"):
            arr = np.array(getattr(nav, a), copy=True)
            arr[keep] = getattr(nav0, a)[keep]
            setattr(nav, a, arr)
        for a, v in saved.items():
            arr = np.array(getattr(self, a), copy=True)
            arr[keep] = v[keep]
            setattr(self, a, arr)
        return res

    def check(self) -> None:
        """Flag runs whose solution or covariance is non-finite or implausible; sanitize them."""
        nav = self.nav
        speed = np.linalg.norm(nav.v_n, axis=-1)
        bad_now = ~np.isfinite(speed) | ~np.isfinite(nav.C_bn).all(axis=(-2, -1))
        if self.has_covariance:  # free inertial is allowed to drift: only a non-finite solution fails it
            bad_now |= speed > self.cfg.vel_limit
            bad_now |= ~np.isfinite(self.P).all(axis=(-2, -1))
            bad_now |= (np.einsum("...ii->...i", self.P) < 0).any(axis=-1)
        new = bad_now & ~self.bad
        self.bad |= bad_now
        if self.bad.any():
            b = self.bad
            nav.v_n[b] = 0.0
            nav.C_bn[b] = np.eye(3)
            nav.pos[b] = np.where(np.isfinite(nav.pos[b]), nav.pos[b], 0.0)
            nav.b_a[b] = 0.0
            nav.b_g[b] = 0.0
            if new.any() and self.has_covariance:
                self.P[new] = self.cfg.p0()


__all__ = ["ErrorStateFilter", "Filter", "ImuData", "Measurement"]
