"""Closed-loop INS filtering of a batch of Monte Carlo runs: the generic loop over merged sensor times.

One loop over time; every operation inside is batched over the runs (and the sigma points). The
filters are classes of the filter protocol (:mod:`nespm_cli.filters.protocol`) looked up by name
in the registry (:mod:`nespm_cli.filters.registry`); the measurements come from sensor channels
(:class:`nespm_cli.sensors.source.Channel`); this module knows neither a filter nor a sensor by
name. Built-in filters:

* ``ins`` (:mod:`.ins`): free inertial, no measurement update (no covariance).
* ``ekf`` (:mod:`.ekf`): Φ = Π (I + F dt) over the time-update span, ``P ← Φ P Φᵀ + Q``;
  linearised update (the measurement's H), Joseph form.
* ``ukf``, ``ukf-nespm`` (:mod:`.ukf`): sigma points through the same Φ (anukf.md eqs
  5-23), or each through the full strapdown (eqs 35-40); the measurement's nonlinear model.
* ``anekf``, ``anukf``, ``anukf-nespm`` (:mod:`.adaptive_filters`): the same three with Q
  from the ProcessNet noise std of each GT interval (anukf.md eqs 43-49).
* ``ckf``, ``ckf-nespm`` (:mod:`.ckf`): cubature Kalman filters (2n points, no tuning).
* ``iekf`` (:mod:`.iekf`): right-invariant EKF with bias states (docs/iekf.md; 12 or 15 states).

Time: the event times are the GT epochs (where the solution is recorded) merged with every
channel's measurement times. A measurement between two IMU samples splits that IMU step there
(both parts take the step's reading, as a recorded IMU is split at the GT epochs), so no
measurement is moved in time. Between two events the filter propagates over one span
(``time_update dvl``, the papers' "cycle") or step by step (``imu``). At an event the
measurements are applied one after another, in the order of the channels (``--sensors``), each
on the posterior of the previous one (sequential updates; for independent noises this is the
stacked update). A measurement missing in some runs (a dropout) is applied to the others only.

After every time update and every measurement the estimate is fed back into the navigation
solution and bias compensation (closed loop), so the state mean is zero between steps.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
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
from nespm_cli.filters import adaptive_ekfs  # noqa: F401
from nespm_cli.filters import adaptive_q  # noqa: F401
from nespm_cli.filters.adaptive import FAULT_REASON, model_faults
from nespm_cli.filters.model import FilterConfig, NavState
from nespm_cli.filters.protocol import ImuData
from nespm_cli.filters.registry import filter_names, filter_source, get_filter, is_builtin
from nespm_cli.filters.robust import inflated, lockout_guard, screen
from nespm_cli.filters.smoother import SmootherRecord, dead_reckoned_position
from nespm_cli.filters.timeline import Timeline, dvl_channel
from nespm_cli.sensors.guard import checked_measurement, with_lever
from nespm_cli.sensors.source import Channel, Context

#: the built-in filters' names (plugins: :func:`nespm_cli.filters.registry.filter_names`)
FILTERS = filter_names(builtin_only=True)


@dataclass
class SensorRecord:
    """What one sensor's channel did in a filter, at its K measurement times: ``t`` (K,) [s since
    the first epoch]; ``used`` (R, K) whether the update was applied; ``nu`` (R, K, m) the
    innovation and ``S`` (R, K, m, m) its covariance where the filter reports them (NaN otherwise);
    with a robust update (:mod:`.robust`), ``rejected`` (R, K) the samples the χ² gate refused (present,
    not used) and ``weight`` (R, K) the Huber factor on R (1: unchanged); None in records made without."""

    t: np.ndarray
    used: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    rejected: np.ndarray | None = None
    weight: np.ndarray | None = None

    def dof(self) -> np.ndarray:
        """(R, K) the rows each applied measurement had: m less its masked rows (a sensor's missing
        component, e.g. a lost DVL beam, enters as a row with zero innovation and a unit, uncoupled
        S: it adds 0 to the NIS); 0 where not applied."""
        m = self.nu.shape[-1]
        eye = np.eye(m, dtype=bool)
        masked = (self.nu == 0.0) & np.all(np.where(eye, self.S == 1.0, self.S == 0.0), axis=-1)
        return np.where(np.isfinite(self.nis()), m - masked.sum(axis=-1), 0)

    def nis(self) -> np.ndarray:
        """(R, K) normalised innovation squared ``νᵀ S⁻¹ ν`` (NaN where not applied)."""
        with np.errstate(all="ignore"):
            ok = np.isfinite(self.S).all(axis=(-2, -1))
            S = np.where(ok[..., None, None], self.S, np.eye(self.S.shape[-1]))
            try:
                sol = np.linalg.solve(S, np.where(ok[..., None], self.nu, 0.0)[..., None])[..., 0]
            except np.linalg.LinAlgError:  # a singular S (a diverged run's) has no NIS: NaN there
                ok = ok & (np.linalg.matrix_rank(S) == S.shape[-1])
                S = np.where(ok[..., None, None], S, np.eye(self.S.shape[-1]))
                sol = np.linalg.solve(S, np.where(ok[..., None], self.nu, 0.0)[..., None])[..., 0]
            return np.where(ok, (self.nu * sol).sum(axis=-1), np.nan)


@dataclass
class FilterOutput:
    """Per-epoch posterior of R runs at N GT epochs, error state of ``layout`` (n states).

    ``pos`` (R, N, 3), ``v_n`` (R, N, 3), ``C_bn`` (R, N, 3, 3); ``P`` (R, N, n, n) the covariance
    (NaN for ``ins``), with ``P6`` (R, N, 6, 6) its [dv, dpsi] block and ``P_diag`` (R, N, n) its
    diagonal; ``b_a``, ``b_g`` (R, N, 3) bias compensation; ``diverged`` (R,); ``dvl_used`` (R, N)
    whether a DVL update was applied in each run at each epoch (a dropped or gated sample: False in
    that run); ``sensors`` the
    :class:`SensorRecord` of each sensor by name; ``noise_std`` the adaptive filters' network std
    ``(std_a, std_g)`` (R, N-1, 3), else None; ``smoothed`` the RTS-smoothed solution (a
    FilterOutput with no sensors) when ``run_filter(..., smooth=True)``, else None; ``lost_epoch``
    (R,) the first epoch recorded after the filter flagged the run diverged (−1: never);
    ``lost_reason`` (R,) object, ``"noise-model"`` for a run lost to its noise model (a window
    whose output is non-finite or <= 0, :func:`.adaptive.model_faults`, before any numeric
    divergence), else ``""``; ``noise_faults`` (R,) int, how many windows of each run were such
    faults (filters that ``needs_noise_std``), else None.
    """

    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    P: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray
    diverged: np.ndarray
    dvl_used: np.ndarray
    layout: str = "12"
    sensors: dict = field(default_factory=dict)
    noise_std: tuple | None = None
    smoothed: "FilterOutput | None" = None
    lost_epoch: np.ndarray | None = None
    lost_reason: np.ndarray | None = None  # (R,) object
    noise_faults: np.ndarray | None = None

    @property
    def P6(self) -> np.ndarray:
        """(R, N, 6, 6) the covariance of the velocity and attitude blocks."""
        from nespm_cli.nav.state import parse_layout

        lay = parse_layout(self.layout)
        i = np.r_[lay.slice("vel"), lay.slice("att")]
        return self.P[..., i[:, None], i]

    @property
    def P_diag(self) -> np.ndarray:
        """(R, N, n) the variances of the states."""
        return np.einsum("...ii->...i", self.P)


def run_filter(
    kind: str,
    cfg: FilterConfig,
    f_meas: np.ndarray,
    w_meas: np.ndarray,
    dt: np.ndarray,
    epoch_index: np.ndarray,
    dvl: np.ndarray | None = None,
    dvl_mask: np.ndarray | None = None,
    nav0: NavState | None = None,
    noise_std: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
    channels: list[Channel] | None = None,
    smooth: bool = False,
) -> FilterOutput:
    """Run one filter over a batch of runs.

    Args:
        kind: a registered filter name (``FILTERS`` or a plugin's, :func:`registry.filter_names`).
        cfg: the tuning, with the error-state layout ``cfg.state``.
        f_meas, w_meas: (R, M, 3) corrupted IMU, step j from sample j to j+1.
        dt: (M,) step durations [s].
        epoch_index: (N,) IMU sample index of each GT epoch (starting at 0).
        dvl, dvl_mask: the papers' measurement, without ``channels``: (R, N, 3) body-frame DVL
            velocity at the epochs [m/s] and (N,) whether it is applied (epoch 0 never), with
            ``cfg.dvl_std`` and ``cfg.lever_arm``.
        nav0: initial navigation solution of the R runs.
        noise_std: for the adaptive filters, ``(std_a, std_g)`` each (R, N-1, 3): the
            network's noise std per IMU sample in each GT interval (``adaptive.predict_interval_std``).
        progress: optional ``progress(k)``, called each time the k-th GT interval is done.
        channels: the sensors' measurements (:class:`nespm_cli.sensors.source.Channel`), applied
            in this order at equal times; replaces ``dvl``/``dvl_mask``.
        smooth: also run the fixed-interval RTS smoother (:mod:`nespm_cli.filters.smoother`; a
            ``smoothable`` filter) and return its solution in ``out.smoothed``.
    """
    cls = get_filter(kind)
    if nav0 is None:
        raise NespmError("run_filter: nav0 (the initial solution) is required")
    if cls.needs_noise_std and noise_std is None:
        raise NespmError(f"filter {kind} needs the network noise std (noise_std)")
    if cfg.time_update not in ("imu", "dvl"):
        raise NespmError(f"--time-update: unknown mode {cfg.time_update!r}; choose imu or dvl")
    if channels is None:
        channels = [] if dvl is None else [dvl_channel(dvl, dvl_mask, cfg, dt, epoch_index)]
    layout = cfg.layout
    for ch in channels:
        ch.sensor.check(layout)
    R, N = nav0.v_n.shape[0], len(epoch_index)
    line = Timeline(dt, epoch_index, channels)
    f_meas, w_meas, dt = line.expand(f_meas), line.expand(w_meas), line.dt
    call = guarded(kind, R)
    if smooth and not getattr(cls, "smoothable", False):
        raise NespmError(f"--smooth: filter {kind} has no RTS smoother (filters with one: "
                         f"{', '.join(n for n in filter_names() if getattr(get_filter(n), 'smoothable', False))})")
    filt = call(cls, "__init__", cfg, nav0, ImuData(f_meas, w_meas, dt), noise_std)
    # (R, N-1) the windows whose noise-model output is unusable: each loses its run at the epoch closing it
    faults = model_faults(*noise_std) if cls.needs_noise_std else None
    cov = cls.has_covariance
    builtin = is_builtin(kind)
    n = layout.n
    out = FilterOutput(
        pos=np.empty((R, N, 3)), v_n=np.empty((R, N, 3)), C_bn=np.empty((R, N, 3, 3)),
        P=np.full((R, N, n, n), np.nan), b_a=np.empty((R, N, 3)), b_g=np.empty((R, N, 3)),
        diverged=filt.diverged, dvl_used=np.zeros((R, N), dtype=bool), layout=layout.name,
        sensors={ch.sensor.name: SensorRecord(ch.t, np.zeros(ch.ok.shape, dtype=bool),
                                              np.full(ch.z.shape, np.nan),
                                              np.full(ch.z.shape + (ch.z.shape[-1],), np.nan),
                                              np.zeros(ch.ok.shape, dtype=bool), np.ones(ch.ok.shape))
                 for ch in channels},
    )
    robust, gate_prob, gate_streak = cfg.robust_update()  # --filter-option NAME.robust (filters.robust)
    streaks = [np.zeros(R, dtype=np.int64) for _ in channels]  # consecutive gate failures per channel and run

    models = [ch.sensor for ch in channels]  # the sensors as this filter's model sees them
    for c, ch in enumerate(channels):
        lever = cfg.model_lever(ch.sensor.name, ch.sensor.opt.lever_arm)  # --filter-option NAME.lever_arm_X_S
        if lever is not None:
            models[c] = with_lever(ch.sensor, lever)

    def record(k):
        nav = call(filt.state, "state")
        call(lambda: store(out, k, nav), "state")
        if cov:
            P = call(filt.covariance, "covariance")
            if np.shape(P) != (R, n, n):
                raise NespmError(f"filter {kind} ({filter_source(kind)}): covariance() returned shape {np.shape(P)}, "
                                 f"expected ({R}, {n}, {n}) for --state {layout.name}")
            if not builtin:
                check_covariance(kind, P, np.asarray(filt.diverged, dtype=bool).reshape(R), k)
            out.P[:, k] = P

    def apply(c: int, i: int, j_last: int, epoch: int | None):
        """Measurement ``i`` of channel ``c``, at the end of IMU step ``j_last``."""
        ch = channels[c]
        ok = ch.ok[:, i]
        if not ok.any():
            return
        z = ch.z[:, i]
        if not ok.all():  # rows without it get a valid run's value: finite, and undone after the update
            z = np.where(ok[:, None], z, z[np.argmax(ok)])
        nav = call(filt.state, "state")
        ctx = Context(f_meas[:, j_last] - nav.b_a, w_meas[:, j_last] - nav.b_g, ch.track)
        meas = checked_measurement(models[c], z, nav, ctx, layout)  # a plugin's: every call checked
        if cfg.r_scale and cfg.r_factor(ch.sensor.name) != 1.0:  # this filter's R (--filter-option NAME.r_scale_S)
            meas.R = np.asarray(meas.R) * cfg.r_factor(ch.sensor.name) ** 2
        rec = out.sensors[ch.sensor.name]
        if robust != "none":  # screened on the prior covariance before the filter sees it
            failed, w = screen(robust, gate_prob, call(filt.covariance, "covariance"), meas.H(nav),
                               meas.innovation(nav), meas.R)
            rejected, streaks[c] = lockout_guard(failed, ok, streaks[c], gate_streak)
            rec.rejected[:, i], rec.weight[:, i] = rejected, np.where(ok, w, 1.0)
            if robust == "huber" and (w != 1.0).any():
                meas.R = inflated(meas.R, w)
            ok = ok & ~rejected
            if not ok.any():
                return
        if ok.all():
            res = call(filt.update, "update", meas, j_last)
        elif hasattr(filt, "update_where"):
            res = call(filt.update_where, "update", meas, j_last, ok)
        else:
            raise NespmError(f"filter {kind} ({filter_source(kind)}): a measurement of {ch.sensor.name} is missing "
                             "in some runs, and the filter has no update_where (derive it from ErrorStateFilter)")
        rec.used[:, i] = ok
        if res is not None:
            nu, S = checked_result(kind, res, R, ch.z.shape[-1], ch.sensor.name)
            rec.nu[:, i] = np.where(ok[:, None], nu, np.nan)
            rec.S[:, i] = np.where(ok[:, None, None], S, np.nan)
        if epoch is not None and ch.sensor.name == "dvl":
            out.dvl_used[:, epoch] |= ok  # the runs this sample was applied in

    imu_mode = cfg.time_update == "imu"
    rts = SmootherRecord() if smooth else None
    out.lost_epoch = np.full(R, -1, dtype=np.int64)
    out.lost_reason = np.full(R, "", dtype=object)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        record(0)
        if rts is not None:
            rts.start(filt)
        for a, b, k, epoch, todo in line.spans():
            if rts is not None:
                rts.begin_span()
            for j0, j1 in (((j, j + 1) for j in range(a, b)) if imu_mode else ((a, b),)):
                call(filt.propagate, "propagate", j0, j1, k)
                if rts is not None:
                    rts.add_transition(filt.last_transition)
            if rts is not None:
                rts.prior(filt)
            if cov:
                for c, i in todo:
                    apply(c, i, b - 1, epoch)
            call(filt.check, "check")
            if rts is not None:
                rts.posterior(filt, epoch)
            if epoch is not None:
                record(epoch)
                if faults is not None and epoch > 0:  # the filter ran it on the nominal Q: lost, not the plain filter
                    model = faults[:, epoch - 1] & (out.lost_epoch < 0)
                    out.lost_epoch[model], out.lost_reason[model] = epoch, FAULT_REASON
                out.lost_epoch[(out.lost_epoch < 0) & np.asarray(filt.diverged, dtype=bool)] = epoch
                if progress is not None:
                    progress(epoch)
    out.diverged = np.asarray(call(lambda: filt.diverged, "diverged"), dtype=bool).reshape(R)
    if faults is not None:
        out.diverged = out.diverged | (out.lost_reason == FAULT_REASON)
        out.noise_faults = faults.sum(axis=1).astype(np.int64)
    out.noise_std = filt.noise_std
    if rts is not None:
        t_epochs = np.concatenate([[0.0], np.cumsum(dt)])[epoch_index]
        out.smoothed = smoothed_output(out, rts, filt, t_epochs - t_epochs[0])
    return out


def smoothed_output(out: FilterOutput, rts: SmootherRecord, filt, t_epochs: np.ndarray) -> FilterOutput:
    """The RTS-smoothed solution of ``out`` (:meth:`SmootherRecord.smooth`): same epochs, layout and
    divergence flags; its sensor records are empty (no update applied: NaN NIS). Without a position block the smoothed position is the
    filter's moved by the integral of the smoothing's velocity change
    (:func:`nespm_cli.filters.smoother.dead_reckoned_position`; ``t_epochs`` (N,) [s])."""
    R, N = out.v_n.shape[:2]
    navs, P = rts.smooth(filt, N)
    sm = FilterOutput(pos=np.empty((R, N, 3)), v_n=np.empty((R, N, 3)), C_bn=np.empty((R, N, 3, 3)), P=P,
                      b_a=np.empty((R, N, 3)), b_g=np.empty((R, N, 3)), diverged=out.diverged.copy(),
                      lost_epoch=out.lost_epoch.copy(), lost_reason=out.lost_reason.copy(),
                      noise_faults=out.noise_faults,
                      dvl_used=out.dvl_used.copy(), layout=out.layout,
                      sensors={name: SensorRecord(r.t, np.zeros_like(r.used), np.full_like(r.nu, np.nan),
                                                  np.full_like(r.S, np.nan), np.zeros_like(r.used),
                                                  np.ones(r.used.shape)) for name, r in out.sensors.items()})
    for k, nav in enumerate(navs):
        store(sm, k, nav)
    if not filt.layout.has("pos"):
        sm.pos = dead_reckoned_position(out.pos, sm.v_n - out.v_n, t_epochs)
    return sm


def check_covariance(kind: str, P: np.ndarray, diverged: np.ndarray, k: int) -> None:
    """A plugin filter's ``covariance()`` at epoch ``k``: symmetric positive definite in every run it
    has not flagged diverged (the NEES and the report divide by it), else one line naming the filter."""
    live = np.asarray(P, dtype=float)[~diverged]
    if live.size == 0:
        return
    try:
        if not np.isfinite(live).all():
            raise np.linalg.LinAlgError
        if np.abs(live - np.swapaxes(live, -1, -2)).max() > 1e-9 * np.abs(live).max():
            raise NespmError(f"filter {kind} ({filter_source(kind)}): covariance() at epoch {k} is not symmetric; "
                             "symmetrize it (ErrorStateFilter.symmetrize)")
        np.linalg.cholesky(live)
    except np.linalg.LinAlgError:
        with np.errstate(all="ignore"):
            low = np.linalg.eigvalsh(np.where(np.isfinite(live), live, 0.0)).min(axis=-1)
        bad = int((~(low > 0) | ~np.isfinite(live).all(axis=(-2, -1))).sum())
        raise NespmError(f"filter {kind} ({filter_source(kind)}): covariance() at epoch {k} is not positive definite "
                         f"in {bad} of {len(live)} runs not flagged diverged (smallest eigenvalue "
                         f"{float(np.nanmin(low)):.3g}); flag such runs in check() or keep P positive definite") from None


def checked_result(kind: str, res, R: int, m: int, sensor: str) -> tuple[np.ndarray, np.ndarray]:
    """A filter's ``update`` result ``(nu (R, m), S (R, m, m))``, else one line naming the filter: a
    wrong shape is never broadcast into the sensor's record (its NIS)."""
    try:
        nu, S = (np.asarray(a, dtype=float) for a in res)
    except (TypeError, ValueError):
        raise NespmError(f"filter {kind} ({filter_source(kind)}): update returned {type(res).__name__}; return "
                         "None or (nu, S) (docs/plugins.md)") from None
    if nu.shape != (R, m) or S.shape != (R, m, m):
        raise NespmError(f"filter {kind} ({filter_source(kind)}): update for sensor {sensor} returned nu of shape "
                         f"{nu.shape} and S of shape {S.shape}, expected ({R}, {m}) and ({R}, {m}, {m})")
    return nu, S


def store(out: FilterOutput, k: int, nav: NavState) -> None:
    """Record the solution ``nav`` of the R runs at epoch ``k``."""
    out.pos[:, k], out.v_n[:, k], out.C_bn[:, k] = nav.pos, nav.v_n, nav.C_bn
    out.b_a[:, k], out.b_g[:, k] = nav.b_a, nav.b_g


def guarded(kind: str, R: int) -> Callable:
    """``call(fn, method, *args)``: ``fn(*args)``, with any exception of a filter's code turned into
    one line naming the filter, where it is defined and the method (``NESPM_DEBUG=1``: re-raised
    as it is, with its traceback)."""

    def call(fn, method: str, *args):
        try:
            return fn(*args)
        except NespmError:
            raise
        except (Exception, SystemExit) as exc:
            if os.environ.get("NESPM_DEBUG"):
                raise
            where = f"filter {kind} ({filter_source(kind)})"
            if isinstance(exc, SystemExit):
                raise NespmError(f"{where}: {method} called sys.exit({exc.code!r}); a filter raises "
                                 "nespm_cli.errors.NespmError to stop with a message") from None
            if isinstance(exc, NotImplementedError):
                raise NespmError(f"{where}: {method} is not implemented (a filter implements __init__, propagate, "
                                 "update, check, state, covariance and diverged: docs/plugins.md)") from None
            text = " ".join(str(exc).split())[:160]
            raise NespmError(f"{where}: {method} raised {exc.__class__.__name__}: {text} "
                             f"({R} runs; NESPM_DEBUG=1 shows the traceback)") from None
    return call
