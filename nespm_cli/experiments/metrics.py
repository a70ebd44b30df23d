"""Error metrics at the GT epochs: VRMSE and MRMSE (anukf.md eqs 50-53), NEES.

* velocity error: ``v_nav − v_GT``, norm in m/s;
* misalignment: the Euler angles of ``C_b^n (C_b^n,GT)ᵀ`` (eq 53), norm in rad;
* NEES: ``eᵀ P6⁻¹ e`` of the 6 states [δv, δψ] with ``e = truth ⊖ nav`` and ``P6`` the
  filter's posterior covariance block; 6 on average for a consistent filter;
* horizontal position error (HPE): ``hypot(north, east)`` of ``nav − truth`` in m, also as a
  percentage of the horizontal distance the truth travelled (the field's usual "% of distance
  travelled" figure); vertical error ``down`` [m] (nav − truth, positive down);
* per-block NEES (:func:`block_nees`): the NEES of any block of the filter's layout (position,
  velocity, attitude, biases), ``dof`` 3 each;
* per-sensor NIS (:func:`sensor_nis`): ``νᵀ S⁻¹ ν`` of every applied measurement, mean per run;
  the innovation likelihood (:func:`innovation_terms`, :func:`truth_free_metrics`): all a run without
  ground truth (``ImuTruth.known`` False) is measured by, its errors not produced.

The t = 0 rule (docs/filters.md, "Epochs in the metrics"): the papers' columns (``sse_vel``,
``sse_att``, ``sse_hpe``, ``n_samples``, ``vrmse``, ``mrmse``) sum over every GT epoch including the
first, t = 0, where the error is the initial error no filter can change (eq 50 sums over "the
samples in the trajectory"); the posterior columns (``*_post``, :data:`POSTERIOR_COLUMNS`) sum over
the epochs after the first, where every filter has had its first update; so do ``nees_post`` and
``vert_rms_post``, the twins of the per-run mean NEES and vertical RMS (:data:`POSTERIOR_SUMMARIES`). The
reports' summaries use the posterior ones, so an improvement is not diluted by the common initial error.
Robust updates (``--filter-option NAME.robust``): :func:`sensor_rejections` counts each sensor's
rejected and applied samples per run.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nespm_cli.nav.earth import ned_offset
from nespm_cli.nav.rotations import attitude_minus, dcm_to_euler


@dataclass
class EpochErrors:
    """Per-run, per-epoch errors (R, N) plus horizontal position errors (R, N, 2) [m].

    ``hpe`` (R, N) [m] is the horizontal error norm ``hypot(ne[..., 0], ne[..., 1])`` (computed
    from ``ne`` when not given); ``dist`` (N,) [m] the truth's cumulative horizontal distance
    travelled since the first epoch (0 at the first epoch; NaN when the truth was not given).
    """

    vel: np.ndarray
    att: np.ndarray
    nees: np.ndarray
    ne: np.ndarray
    hpe: np.ndarray | None = None
    dist: np.ndarray | None = None
    down: np.ndarray | None = None  # (R, N) vertical error nav − truth [m, positive down]

    def __post_init__(self) -> None:
        if self.hpe is None:
            self.hpe = np.hypot(self.ne[..., 0], self.ne[..., 1])
        if self.dist is None:
            self.dist = np.full(self.vel.shape[-1], np.nan)


def distance_travelled(pos_true: np.ndarray) -> np.ndarray:
    """Cumulative horizontal distance [m] (N,) along ``pos_true`` (N, 3): the sum of the
    horizontal norms of the :func:`earth.ned_offset` increments between consecutive epochs."""
    pos_true = np.asarray(pos_true, dtype=float)
    step = ned_offset(pos_true[1:], pos_true[:-1])[..., :2]
    return np.concatenate([[0.0], np.cumsum(np.hypot(step[..., 0], step[..., 1]))])


def epoch_errors(out, v_true: np.ndarray, C_true: np.ndarray, pos_true: np.ndarray) -> EpochErrors:
    """Errors of a :class:`filters.FilterOutput` against truth at the N epochs.

    Args:
        v_true: (N, 3) NED velocity; C_true: (N, 3, 3); pos_true: (N, 3).
    """
    dv = out.v_n - v_true
    vel = np.linalg.norm(dv, axis=-1)
    C_mis = out.C_bn @ np.swapaxes(C_true, -1, -2)  # eq 53
    att = np.linalg.norm(dcm_to_euler(C_mis), axis=-1)
    e = np.concatenate([-dv, attitude_minus(C_true, out.C_bn)], axis=-1)  # truth ⊖ nav
    if np.isnan(out.P6).all():
        nees = np.full(vel.shape, np.nan)
    else:
        with np.errstate(all="ignore"):
            try:
                sol = np.linalg.solve(out.P6, e[..., None])[..., 0]
            except np.linalg.LinAlgError:
                sol = (np.linalg.pinv(out.P6) @ e[..., None])[..., 0]
        nees = (e * sol).sum(axis=-1)
    ned = ned_offset(out.pos, pos_true)
    return EpochErrors(vel, att, nees, ned[..., :2], dist=distance_travelled(pos_true),
                       down=ned[..., 2])  # hpe derived from ne


#: the blocks whose NEES and coverage are reported (those of the filter's layout with a known truth)
STAT_BLOCKS = ("vel", "att", "pos", "ba", "bg")


def block_error(out, block: str, v_true: np.ndarray, C_true: np.ndarray, pos_true: np.ndarray,
                bias_true: tuple | None = None):
    """``(e, P_b)``: the error ``truth ⊖ nav`` of one block (R, N, 3) and its covariance block
    (R, N, 3, 3), or None where the layout lacks the block, there is no covariance, or (biases) the
    truth is unknown. Blocks ``pos``, ``vel``, ``att`` and, with ``bias_true = (b_a, b_g)`` each
    (R, N, 3) (the corruption's biases, :func:`nespm_cli.data.corruption.true_biases`), ``ba`` and
    ``bg``: the residual bias ``b_true − b̂`` the state estimates."""
    from nespm_cli.nav.state import parse_layout

    lay = parse_layout(out.layout)
    if not lay.has(block) or np.isnan(out.P).all() or (block in ("ba", "bg") and bias_true is None):
        return None
    e = {"pos": lambda: ned_offset(pos_true, out.pos), "vel": lambda: v_true - out.v_n,
         "att": lambda: attitude_minus(C_true, out.C_bn), "ba": lambda: bias_true[0] - out.b_a,
         "bg": lambda: bias_true[1] - out.b_g}[block]()
    i = lay.slice(block)
    return e, out.P[..., i, i]


def block_nees(out, block: str, v_true: np.ndarray, C_true: np.ndarray, pos_true: np.ndarray,
               bias_true: tuple | None = None) -> np.ndarray:
    """(R, N) NEES of one block of the filter's layout: ``eᵀ P_b⁻¹ e`` with ``e = truth ⊖ nav`` of that
    block and ``P_b`` its covariance block (3 on average for a consistent filter); NaN without a
    covariance, where the layout lacks the block or its truth is unknown (:func:`block_error`)."""
    got = block_error(out, block, v_true, C_true, pos_true, bias_true)
    if got is None:
        return np.full(out.v_n.shape[:2], np.nan)
    e, Pb = got
    with np.errstate(all="ignore"):
        sol = np.linalg.solve(Pb, e[..., None])[..., 0]
    return (e * sol).sum(axis=-1)


def block_statistics(out, v_true: np.ndarray, C_true: np.ndarray, pos_true: np.ndarray,
                     bias_true: tuple | None = None, axes: bool = False) -> dict[str, np.ndarray]:
    """Per block of :data:`STAT_BLOCKS`, each error and covariance block formed once: ``nees_<block>``
    (R, N) as :func:`block_nees`, and ``cover<k>_<block>`` (R, N) the fraction of the block's 3
    components inside ``±k σ`` of the filter's own variances for k = 1, 2, 3 (0, 1/3, 2/3 or 1; a
    consistent filter covers 68.3 / 95.4 / 99.7 %). NaN without the block, a covariance or a truth.

    ``axes``: also, per component (labels of :data:`nespm_cli.nav.state.BLOCKS`, e.g. ``dvN``),
    ``e_<label>`` the error (truth ⊖ nav, SI units) and ``s_<label>`` the filter's std, each (R, N),
    for the blocks the filter has (``--save-series axes``)."""
    from nespm_cli.nav.state import BLOCKS

    res = {}
    nan = np.full(out.v_n.shape[:2], np.nan)
    for block in STAT_BLOCKS:
        got = block_error(out, block, v_true, C_true, pos_true, bias_true)
        if got is None:
            res[f"nees_{block}"] = nan
            res.update({f"cover{k}_{block}": nan for k in (1, 2, 3)})
            continue
        e, Pb = got
        with np.errstate(all="ignore"):
            res[f"nees_{block}"] = (e * np.linalg.solve(Pb, e[..., None])[..., 0]).sum(axis=-1)
            sigma = np.sqrt(np.einsum("...ii->...i", Pb))
            for k in (1, 2, 3):
                res[f"cover{k}_{block}"] = (np.abs(e) <= k * sigma).mean(axis=-1)
        if axes:
            for c, label in enumerate(BLOCKS[block][2]):
                res[f"e_{label}"], res[f"s_{label}"] = e[..., c], sigma[..., c]
    return res


def _nis_and_dof(rec) -> tuple[np.ndarray, np.ndarray, int]:
    """``(nis, dof, m)``: each measurement's NIS and rows (R, K) (0 NIS where not applied), its size m."""
    nis = rec.nis()
    return np.where(np.isfinite(nis), nis, 0.0), rec.dof().astype(float), rec.nu.shape[-1]


def epoch_nis(out, t_epochs: np.ndarray) -> dict[str, np.ndarray]:
    """``{nis_<sensor>: (R, N)}``: per run, the NIS of the sensor's measurements applied in the GT
    interval ending at each epoch ``(t_{k-1}, t_k]`` (NaN where none was applied), scaled to the
    sensor's full size m: ``m Σ NIS / Σ dof`` over them, dof the rows each had (a lost DVL beam is
    one row fewer: :meth:`nespm_cli.filters.engine.SensorRecord.dof`), so its expectation is m.
    For a sensor at the GT epochs (the DVL, depth by default) that is its NIS at the epoch."""
    res = {}
    t_epochs = np.asarray(t_epochs, dtype=float)
    for name, rec in getattr(out, "sensors", {}).items():
        nis, dof, m = _nis_and_dof(rec)  # (R, K)
        R, N = nis.shape[0], len(t_epochs)
        k = np.clip(np.searchsorted(t_epochs, np.asarray(rec.t, dtype=float) - 1e-9, side="left"), 0, N - 1)
        cols = np.broadcast_to(k, nis.shape)
        rows = np.broadcast_to(np.arange(R)[:, None], nis.shape)
        total, count = np.zeros((R, N)), np.zeros((R, N))
        np.add.at(total, (rows, cols), nis)  # scatter-add over runs and measurements at once
        np.add.at(count, (rows, cols), dof)
        with np.errstate(invalid="ignore", divide="ignore"):
            res[f"nis_{name}"] = np.where(count > 0, m * total / count, np.nan)
    return res


def sensor_nis(out) -> dict[str, np.ndarray]:
    """``{nis_<sensor>: (R,)}``: per run, the NIS of the measurements applied, ``m Σ NIS / Σ dof`` (the
    mean NIS when every measurement had its m rows; see :func:`epoch_nis`); NaN where none was
    applied or the filter reports no innovation. Its χ² expectation is the sensor's dimension m."""
    res = {}
    for name, rec in getattr(out, "sensors", {}).items():
        nis, dof, m = _nis_and_dof(rec)
        total, count = nis.sum(axis=1), dof.sum(axis=1)
        with np.errstate(all="ignore"):
            res[f"nis_{name}"] = np.where(count > 0, m * total / np.maximum(count, 1), np.nan)
    return res


def sensor_rejections(out, robust: bool = True) -> dict[str, np.ndarray]:
    """``{rejected_<sensor>, applied_<sensor>, downweighted_<sensor>: (R,) int}`` per sensor of a
    :class:`nespm_cli.filters.engine.FilterOutput`: the samples the χ² gate refused (present in the run, not
    applied), those applied (a dropped or rejected sample is not), and those a Huber update applied with an
    inflated R (weight > 1), over the run. ``robust`` False (the filter has no robust update): 0 rejected
    and downweighted, the applied counted all the same. A record without ``rejected`` / ``weight`` counts 0."""
    res = {}
    for name, rec in getattr(out, "sensors", {}).items():
        used = np.asarray(rec.used, dtype=bool)
        zero = np.zeros(used.shape[0], dtype=np.int64)
        rej = zero if not robust or rec.rejected is None else np.asarray(rec.rejected, bool).sum(axis=1)
        down = zero if not robust or rec.weight is None else (used & (np.asarray(rec.weight) > 1.0)).sum(axis=1)
        res[f"rejected_{name}"] = np.asarray(rej, dtype=np.int64)
        res[f"applied_{name}"] = used.sum(axis=1).astype(np.int64)
        res[f"downweighted_{name}"] = np.asarray(down, dtype=np.int64)
    return res


def innovation_terms(rec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(nis, logdet, rows, ok)`` (R, K) of one sensor's record (:class:`nespm_cli.filters.engine.SensorRecord`):
    each measurement's NIS, ``log det S``, rows (a masked row, e.g. a lost beam, enters with ν = 0 and a unit
    uncoupled S row: no row, nothing added) and whether it counts: applied with a finite, positive-definite S
    and at least one row. The one rule of the innovation likelihood ``½ Σ (νᵀ S⁻¹ ν + log det S)`` per row
    (``nespm tune --objective innovation``, :func:`truth_free_metrics`); NIS and log det are 0 where not ok."""
    nis = rec.nis()  # (R, K), NaN where not applied or S singular
    rows = rec.dof().astype(float)
    eye = np.eye(rec.S.shape[-1])
    with np.errstate(all="ignore"):
        finite = np.isfinite(rec.S).all(axis=(-2, -1)) & np.isfinite(nis)
        sign, logdet = np.linalg.slogdet(np.where(finite[..., None, None], rec.S, eye))
    ok = finite & (sign > 0) & (rows > 0)
    return np.where(ok, nis, 0.0), np.where(ok, logdet, 0.0), rows, ok


def truth_free_metrics(out) -> dict[str, np.ndarray]:
    """A run's numbers without ground truth, (R,) each: ``diverged`` (the engine's numeric flag alone: the
    attitude rule needs the truth), ``diverged_reason`` (``numeric`` or ``""``), ``inconsistent`` (False: the
    NEES test needs the truth), per sensor ``nis_<sensor>`` (:func:`sensor_nis`) and ``nll_<sensor>`` the
    negative log-likelihood per row of its innovations ``½ (Σ NIS + Σ log det S) / Σ rows`` (without
    ½ log 2π; NaN without a row), and ``innovation_nll`` their mean over the sensors. No error column:
    there is nothing to measure an error against."""
    bad = np.asarray(out.diverged, dtype=bool)
    res = {"diverged": bad, "diverged_reason": np.where(bad, "numeric", "").astype(object),
           "inconsistent": np.zeros(len(bad), dtype=bool), **sensor_nis(out)}
    nll = []
    for name, rec in getattr(out, "sensors", {}).items():
        nis, logdet, rows, ok = innovation_terms(rec)
        n = np.where(ok, rows, 0.0).sum(axis=1)
        with np.errstate(all="ignore"):
            res[f"nll_{name}"] = np.where(n > 0, 0.5 * (nis.sum(axis=1) + logdet.sum(axis=1)) / n, np.nan)
        nll.append(res[f"nll_{name}"])
    with np.errstate(all="ignore"):
        res["innovation_nll"] = np.mean(nll, axis=0) if nll else np.full(len(bad), np.nan)
    return res


#: the epochs table's columns that hold errors against the truth (dropped without one)
ERROR_PREFIXES = ("vel_err", "att_err", "nees", "north_", "east_", "hpe", "cover", "rms_", "sig_", "nci_", "pcrb_")


def truth_free_epochs(epochs):
    """The epochs table (``epochs.parquet``) of a study without ground truth: the columns of errors
    (:data:`ERROR_PREFIXES`, NaN there) left out; the NIS per sensor, ``dvl_used`` and ``n_runs`` kept."""
    return epochs[[c for c in epochs.columns if not c.startswith(ERROR_PREFIXES)]]


@dataclass(frozen=True)
class DivergenceRule:
    """When a run counts as *lost*, or as *inconsistent* (docs/filters.md, "Lost and inconsistent runs").

    Lost (its estimate says nothing any more; its error sums are NaN, and the report compares the
    filters on the runs no filter lost, with each filter's loss count beside): a non-finite state
    or covariance or a speed above 50 m/s (the engine's numeric test), or

    * ``att_deg`` [deg]: an attitude error above this at any epoch after ``after_s``.

    Inconsistent (its covariance is overconfident, its estimate may still be good; it keeps its
    errors in every average and is counted in ``inconsistent``):

    * ``nees``: its NEES averaged over any ``window_s`` [s] window after ``after_s`` exceeds this
      (the 6-dof chi-square 99.9 % point is 22.5: 40x beyond it for half a minute).
    """

    att_deg: float = 45.0
    nees: float = 1000.0
    window_s: float = 30.0
    after_s: float = 60.0


def divergence(err: EpochErrors, numeric: np.ndarray, t_rel: np.ndarray,
               rule: DivergenceRule = DivergenceRule()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lost (R,) bool, reason (R,) str, inconsistent (R,) bool)``: ``reason`` is ``numeric``,
    ``attitude`` or ``""`` (the run is not lost); ``inconsistent`` the NEES test of ``rule``.

    ``numeric`` (R,) is the engine's flag; ``t_rel`` (N,) [s] the epoch times from the first.
    """
    numeric = np.asarray(numeric, dtype=bool)
    t_rel = np.asarray(t_rel, dtype=float)
    late = t_rel >= rule.after_s
    with np.errstate(invalid="ignore"):
        att = np.where(late, err.att, 0.0)
        bad_att = np.nanmax(att, axis=1) > np.radians(rule.att_deg) if late.any() else np.zeros(len(numeric), bool)
        dt = float(np.median(np.diff(t_rel))) if len(t_rel) > 1 else 1.0
        w = max(int(round(rule.window_s / dt)), 1)
        # a filter without a covariance (ins) has NaN NEES: no test; an overflow counts as large
        nees = np.nan_to_num(np.asarray(err.nees, dtype=float), nan=0.0, posinf=1e300)[:, late]
        if nees.shape[1] >= w:
            c = np.concatenate([np.zeros((nees.shape[0], 1)), np.cumsum(nees, axis=1)], axis=1)
            bad_nees = ((c[:, w:] - c[:, :-w]) / w).max(axis=1) > rule.nees
        else:
            bad_nees = np.zeros(len(numeric), dtype=bool)
    reason = np.where(numeric, "numeric", np.where(bad_att, "attitude", ""))
    return reason != "", reason.astype(object), bad_nees & ~numeric


def lost_epoch(err: EpochErrors, reason: np.ndarray, numeric_epoch: np.ndarray | None, t_rel: np.ndarray,
               rule: DivergenceRule = DivergenceRule()) -> np.ndarray:
    """(R,) int: the first epoch at which each lost run was lost (−1: not lost), for ``reason`` of
    :func:`divergence`: ``numeric`` the engine's (``FilterOutput.lost_epoch``; where it is unknown,
    the first epoch with a non-finite error), ``attitude`` the first epoch after ``rule.after_s``
    with the attitude error beyond ``rule.att_deg``."""
    R, N = err.vel.shape
    t_rel = np.asarray(t_rel, dtype=float)
    with np.errstate(invalid="ignore"):
        over = (t_rel >= rule.after_s) & (err.att > np.radians(rule.att_deg))
        nonfinite = ~(np.isfinite(err.vel) & np.isfinite(err.att))
    first = lambda m: np.where(m.any(axis=1), np.argmax(m, axis=1), N)  # noqa: E731
    numeric = np.asarray(numeric_epoch if numeric_epoch is not None else np.full(R, -1), dtype=np.int64)
    numeric = np.where(numeric >= 0, numeric, first(nonfinite))
    reason = np.asarray(reason, dtype=object)
    k = np.where(reason == "numeric", numeric, np.where(reason == "attitude", first(over), -1))
    return np.where((k >= N) & (reason != ""), N - 1, k).astype(np.int64)


def alive_metrics(err: EpochErrors, lost_k: np.ndarray, t_rel: np.ndarray) -> dict[str, np.ndarray]:
    """Every run's errors up to the point it was lost (all epochs for a run not lost), (R,) each:
    ``lost_at`` [s] the time of the first lost epoch (NaN: not lost), ``vrmse_alive`` [m/s],
    ``mrmse_alive`` [rad], ``hpe_rms_alive`` [m] the RMS over the epochs before it (NaN for a run
    lost at its first epoch)."""
    N = err.vel.shape[1]
    k = np.asarray(lost_k, dtype=np.int64)
    end = np.where(k >= 0, k, N)
    alive = np.arange(N)[None, :] < end[:, None]
    with np.errstate(all="ignore"):
        rms = lambda x: np.sqrt(np.where(alive, np.asarray(x, float) ** 2, 0.0).sum(axis=1) / end)  # noqa: E731
        out = {"vrmse_alive": rms(err.vel), "mrmse_alive": rms(err.att), "hpe_rms_alive": rms(err.hpe)}
    out = {c: np.where(end > 0, v, np.nan) for c, v in out.items()}
    out["lost_at"] = np.where(k >= 0, np.asarray(t_rel, dtype=float)[np.clip(k, 0, N - 1)], np.nan)
    return out


#: papers' column -> its posterior twin (the sum over the epochs after the first; ``n_samples`` -> ``n_post``)
POSTERIOR_COLUMNS: dict[str, str] = {"sse_vel": "sse_vel_post", "sse_att": "sse_att_post",
                                     "sse_hpe": "sse_hpe_post", "n_samples": "n_post"}
#: per-run summaries over every epoch -> their twins over the epochs after the first (the t = 0 rule); a
#: folder written before them has the every-epoch column only (``nespm_cli.reports.stats.posterior_view``)
POSTERIOR_SUMMARIES: dict[str, str] = {"nees": "nees_post", "vert_rms": "vert_rms_post"}


def posterior_sums(err: EpochErrors, diverged: np.ndarray) -> dict[str, np.ndarray]:
    """(R,) each: ``sse_vel_post`` [(m/s)²], ``sse_att_post`` [rad²], ``sse_hpe_post`` [m²], the sums of
    the squared errors over the epochs after the first (t > 0; NaN for a lost run), ``n_post``
    (int, the epochs summed: N − 1), and the twins of :data:`POSTERIOR_SUMMARIES` over the same epochs:
    ``nees_post`` the mean 6-DOF NEES, ``vert_rms_post`` [m] the RMS vertical error. The t = 0 error is the
    initial error, the same for every filter
    of a run, so these are the sums a filter can change (module docstring, "the t = 0 rule")."""
    bad = np.asarray(diverged, dtype=bool)
    n = err.vel.shape[1]
    with np.errstate(all="ignore"):
        sums = {"sse_vel_post": (np.asarray(err.vel, float)[:, 1:] ** 2).sum(axis=1),
                "sse_att_post": (np.asarray(err.att, float)[:, 1:] ** 2).sum(axis=1),
                "sse_hpe_post": (np.asarray(err.hpe, float)[:, 1:] ** 2).sum(axis=1)}
    out = {k: np.where(bad, np.nan, v) for k, v in sums.items()}
    out["n_post"] = np.full(len(bad), max(n - 1, 0), dtype=np.int64)
    down = np.asarray(err.down if err.down is not None else np.full(err.vel.shape, np.nan), dtype=float)[:, 1:]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # one epoch: nothing after t = 0 (NaN)
        out["nees_post"] = np.where(bad, np.nan, np.asarray(err.nees, float)[:, 1:].mean(axis=1))
        out["vert_rms_post"] = np.where(bad, np.nan, np.sqrt((down ** 2).mean(axis=1)))
    return out


def run_metrics(err: EpochErrors, diverged: np.ndarray) -> dict[str, np.ndarray]:
    """Per-run summary (R,) arrays; every error sum of a diverged run is NaN.

    Horizontal position (``docs/results-schema.md``): ``sse_hpe`` [m²] the sum over epochs of the
    squared HPE, ``hpe_final`` [m] at the last epoch, ``hpe_rms`` [m] = sqrt(sse_hpe / n_samples),
    ``hpe_max`` [m], ``north_final`` / ``east_final`` [m] the final error's components (nav − truth,
    for the scatter of final positions), ``distance`` [m] the truth's horizontal distance travelled over the track
    (a property of the truth: finite for diverged runs too) and ``hpe_final_pct`` =
    100 · hpe_final / distance (NaN when the truth did not move).

    Posterior sums (:func:`posterior_sums`): ``sse_vel_post``, ``sse_att_post``, ``sse_hpe_post``,
    ``n_post``, the same sums without the first epoch (t = 0), and ``nees_post``, ``vert_rms_post``.
    """
    n = err.vel.shape[1]
    bad = np.asarray(diverged, dtype=bool)
    nan_if_bad = lambda x: np.where(bad, np.nan, x)  # noqa: E731
    sse_vel = nan_if_bad((err.vel**2).sum(axis=1))
    sse_att = nan_if_bad((err.att**2).sum(axis=1))
    with np.errstate(all="ignore"):  # a diverged run's position may be non-finite
        hpe = np.asarray(err.hpe, dtype=float)
        sse_hpe = nan_if_bad((hpe**2).sum(axis=1))
        hpe_final = nan_if_bad(hpe[:, -1])
        ne_final = np.where(bad[:, None], np.nan, np.asarray(err.ne, dtype=float)[:, -1])
        distance = np.full(len(bad), float(np.asarray(err.dist, dtype=float)[-1]))
        hpe_final_pct = np.where(distance > 0, 100.0 * hpe_final / np.where(distance > 0, distance, 1.0), np.nan)
        hpe_cols = {
            "sse_hpe": sse_hpe,
            "hpe_final": hpe_final,
            "north_final": ne_final[:, 0],
            "east_final": ne_final[:, 1],
            "hpe_rms": np.sqrt(sse_hpe / n),
            "hpe_max": nan_if_bad(hpe.max(axis=1)),
            "distance": distance,
            "hpe_final_pct": hpe_final_pct,
        }
    down = np.asarray(err.down if err.down is not None else np.full(err.vel.shape, np.nan), dtype=float)
    with np.errstate(all="ignore"):
        hpe_cols["vert_rms"] = nan_if_bad(np.sqrt((down**2).mean(axis=1)))
    return {
        "vrmse": np.sqrt(sse_vel / n),
        "mrmse": np.sqrt(sse_att / n),
        "sse_vel": sse_vel,
        "sse_att": sse_att,
        "n_samples": np.full(len(bad), n, dtype=np.int64),
        "max_vel_err": nan_if_bad(err.vel.max(axis=1)),
        "max_att_err": nan_if_bad(err.att.max(axis=1)),
        "nees": nan_if_bad(err.nees.mean(axis=1)),
        "diverged": bad,
        **hpe_cols,
        **posterior_sums(err, bad),
    }


def cep(radial: np.ndarray, p: float = 0.5) -> float:
    """Circular error probable: the radius holding the fraction ``p`` of the horizontal errors
    ``radial`` (R,) [m] (the sample quantile, linear interpolation; NaN entries left out). CEP50
    is ``p = 0.5`` (for a circular Gaussian of std σ per axis: σ sqrt(2 ln 2) = 1.1774 σ), R95
    ``p = 0.95``; NaN without a finite error."""
    r = np.asarray(radial, dtype=float)
    r = r[np.isfinite(r)]
    return float(np.quantile(r, p)) if r.size else float("nan")


def rmse(sse: np.ndarray, n: np.ndarray) -> float:
    """Eq 50 over a set of runs: sqrt(Σ sse / Σ n), NaN entries (diverged) left out."""
    ok = np.isfinite(sse)
    return float(np.sqrt(sse[ok].sum() / n[ok].sum())) if ok.any() else float("nan")


@lru_cache(maxsize=4096)
def nees_band(dof: int, runs: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` band of the mean NEES over ``runs`` runs for ``dof`` states (chi² / runs).
    Cached: a report asks for the same few (dof, runs) pairs at every epoch (the main job's report made
    12,079 calls, about 0.1 ms each: 1.3 of its 8.3 CPU-s, before the cache). The χ² quantile is
    ``2 gammaincinv(k/2, q)``, what ``scipy.stats.chi2.ppf`` evaluates (the same bits, tested), without
    importing ``scipy.stats`` (about 1 CPU-s, which ``nespm tune`` paid for this alone)."""
    from scipy.special import gammaincinv

    a = (1.0 - p) / 2.0
    k = dof * runs
    return float(2 * gammaincinv(k / 2, a) / runs), float(2 * gammaincinv(k / 2, 1.0 - a) / runs)
