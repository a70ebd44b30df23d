"""Closed-loop INS/DVL filtering of a batch of Monte Carlo runs: the generic loop.

One loop over time (DVL intervals, and IMU steps inside them); every operation inside is
batched over the runs (and the sigma points). The filters are classes of the filter
protocol (:mod:`nespm_cli.filters.protocol`) looked up by name in the registry
(:mod:`nespm_cli.filters.registry`); this module knows none of them by name. Built-ins:

* ``ins`` (:mod:`.ins`): free inertial, no DVL update (no covariance).
* ``ekf`` (:mod:`.ekf`): Φ = Π (I + F dt) over the time-update span, ``P ← Φ P Φᵀ + Q``;
  linearised DVL update (H of eq 33), Joseph form.
* ``ukf``, ``ukf-nespm`` (:mod:`.ukf`): sigma points through the same Φ (anukf.md eqs
  5-23), or each through the full strapdown (eqs 35-40); nonlinear DVL model (eq 33).
* ``anekf``, ``anukf``, ``anukf-nespm`` (:mod:`.adaptive_filters`): the same three with Q
  from the ProcessNet noise std of each DVL interval (anukf.md eqs 43-49).
* ``ckf``, ``ckf-nespm`` (:mod:`.ckf`): cubature Kalman filters (2n points, no tuning), the
  points through Φ or each through the full strapdown.
* ``iekf`` (:mod:`.iekf`): right-invariant EKF with bias states (docs/iekf.md).

After every time update and every DVL update the estimate is fed back into the
navigation solution and bias compensation (closed loop), so the state mean is zero
between steps and every sigma set is centred on the navigation solution.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from nespm_cli.errors import NespmError
# register the built-ins, in the order of FILTERS
from nespm_cli.filters import ins  # noqa: F401,I001
from nespm_cli.filters import ekf  # noqa: F401
from nespm_cli.filters import ukf  # noqa: F401
from nespm_cli.filters import adaptive_filters  # noqa: F401
from nespm_cli.filters import ckf  # noqa: F401
from nespm_cli.filters import iekf  # noqa: F401
from nespm_cli.filters.measurements import DvlMeasurement
from nespm_cli.filters.model import FilterConfig, NavState
from nespm_cli.filters.protocol import ImuData
from nespm_cli.filters.registry import filter_names, filter_source, get_filter
from nespm_cli.nav.earth import radii, transport_rates

#: the built-in filters' names (plugins: :func:`nespm_cli.filters.registry.filter_names`)
FILTERS = filter_names(builtin_only=True)


@dataclass
class FilterOutput:
    """Per-epoch posterior of R runs at N GT epochs.

    ``pos`` (R, N, 3), ``v_n`` (R, N, 3), ``C_bn`` (R, N, 3, 3); ``P6`` (R, N, 6, 6) the
    [dv, dpsi] block and ``P_diag`` (R, N, 12) of the covariance (NaN for ``ins``);
    ``b_a``, ``b_g`` (R, N, 3) bias compensation; ``diverged`` (R,); ``dvl_used`` (N,);
    ``noise_std`` the adaptive filters' network std ``(std_a, std_g)`` (R, N-1, 3), else None.
    """

    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    P6: np.ndarray
    P_diag: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray
    diverged: np.ndarray
    dvl_used: np.ndarray
    noise_std: tuple | None = None


def _w_nb(nav: NavState, w_ib_comp: np.ndarray) -> np.ndarray:
    """Body rate relative to NED (B, 3) from the compensated gyro output."""
    R_N, R_E = radii(nav.pos[..., 0])
    w_ie, w_en = transport_rates(nav.pos[..., 0], nav.pos[..., 2], nav.v_n, R_N, R_E)
    return w_ib_comp - (np.swapaxes(nav.C_bn, -1, -2) @ (w_ie + w_en)[..., None])[..., 0]


def run_filter(
    kind: str,
    cfg: FilterConfig,
    f_meas: np.ndarray,
    w_meas: np.ndarray,
    dt: np.ndarray,
    epoch_index: np.ndarray,
    dvl: np.ndarray | None,
    dvl_mask: np.ndarray,
    nav0: NavState,
    noise_std: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
) -> FilterOutput:
    """Run one filter over a batch of runs.

    Args:
        kind: a registered filter name (``FILTERS`` or a plugin's, :func:`registry.filter_names`).
        f_meas, w_meas: (R, M, 3) corrupted IMU, step j from sample j to j+1.
        dt: (M,) step durations [s].
        epoch_index: (N,) IMU sample index of each GT epoch (starting at 0).
        dvl: (R, N, 3) body-frame DVL velocity at the epochs [m/s].
        dvl_mask: (N,) whether the DVL update is applied at each epoch (epoch 0 never).
        nav0: initial navigation solution of the R runs.
        noise_std: for the adaptive filters, ``(std_a, std_g)`` each (R, N-1, 3): the
            network's noise std per IMU sample in each DVL interval (``adaptive.predict_interval_std``).
        progress: optional ``progress(k)``, called after each of the N-1 epoch intervals with
            the number of intervals done (for a progress bar; it must not raise).
    """
    cls = get_filter(kind)
    if cls.needs_noise_std and noise_std is None:
        raise NespmError(f"filter {kind} needs the network noise std (noise_std)")
    R, N = nav0.v_n.shape[0], len(epoch_index)
    call = guarded(kind, R)
    filt = call(cls, "__init__", cfg, nav0, ImuData(f_meas, w_meas, dt), noise_std)
    cov = cls.has_covariance
    out = FilterOutput(
        pos=np.empty((R, N, 3)), v_n=np.empty((R, N, 3)), C_bn=np.empty((R, N, 3, 3)),
        P6=np.full((R, N, 6, 6), np.nan), P_diag=np.full((R, N, 12), np.nan),
        b_a=np.empty((R, N, 3)), b_g=np.empty((R, N, 3)), diverged=filt.diverged,
        dvl_used=np.zeros(N, dtype=bool),
    )
    lever = np.asarray(cfg.lever_arm, dtype=float)

    def record(k):
        n = call(filt.state, "state")
        call(lambda: store(out, k, n), "state")
        if cov:
            P = call(filt.covariance, "covariance")
            if np.shape(P) != (R, 12, 12):
                raise NespmError(f"filter {kind} ({filter_source(kind)}): covariance() returned shape {np.shape(P)}, "
                                 f"expected ({R}, 12, 12)")
            out.P6[:, k] = P[:, :6, :6]
            out.P_diag[:, k] = np.einsum("...ii->...i", P)

    def measurement(k, j_last):
        """The DVL measurement of epoch ``k``, lever-arm rate from IMU step ``j_last``."""
        nav = call(filt.state, "state")
        w_nb = _w_nb(nav, w_meas[:, j_last] - nav.b_g)
        return DvlMeasurement(dvl[:, k], w_nb, lever, cfg.dvl_std)

    imu_mode = cfg.time_update == "imu"
    if cfg.time_update not in ("imu", "dvl"):
        raise NespmError(f"--time-update: unknown mode {cfg.time_update!r}; choose imu or dvl")
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        record(0)
        for k in range(N - 1):
            j0, j1 = int(epoch_index[k]), int(epoch_index[k + 1])
            if imu_mode:
                for j in range(j0, j1):
                    call(filt.propagate, "propagate", j, j + 1, k)
            else:
                call(filt.propagate, "propagate", j0, j1, k)
            if cov and dvl_mask[k + 1]:
                call(filt.update, "update", measurement(k + 1, j1 - 1), j1 - 1)
                out.dvl_used[k + 1] = True
            call(filt.check, "check")
            record(k + 1)
            if progress is not None:
                progress(k + 1)
    out.diverged = np.asarray(call(lambda: filt.diverged, "diverged"), dtype=bool).reshape(R)
    out.noise_std = filt.noise_std
    return out


def store(out: FilterOutput, k: int, nav: NavState) -> None:
    """Record the solution ``nav`` of the R runs at epoch ``k``."""
    out.pos[:, k], out.v_n[:, k], out.C_bn[:, k] = nav.pos, nav.v_n, nav.C_bn
    out.b_a[:, k], out.b_g[:, k] = nav.b_a, nav.b_g


def guarded(kind: str, R: int) -> Callable:
    """``call(fn, method, *args)``: ``fn(*args)``, with any exception of a filter's code turned into
    one line naming the filter, where it is defined and the method (``NESPM_DEBUG=1``: re-raised
    as it is, with its traceback)."""
    import os

    def call(fn, method: str, *args):
        try:
            return fn(*args)
        except NespmError:
            raise
        except Exception as exc:
            if os.environ.get("NESPM_DEBUG"):
                raise
            where = f"filter {kind} ({filter_source(kind)})"
            if isinstance(exc, NotImplementedError):
                raise NespmError(f"{where}: {method} is not implemented (a filter implements __init__, propagate, "
                                 "update, check, state, covariance and diverged: docs/plugins.md)") from None
            text = " ".join(str(exc).split())[:160]
            raise NespmError(f"{where}: {method} raised {exc.__class__.__name__}: {text} "
                             f"({R} runs; NESPM_DEBUG=1 shows the traceback)") from None
    return call
