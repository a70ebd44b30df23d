"""The recorded IMU against the IMU its ground truth implies (``nespm check``, IMU part).

The implied IMU is the inverse strapdown of the 1 Hz GT (:func:`nav.synthesis.synthesize`).
The GT resolves motion only below its Nyquist frequency (0.5 Hz), so both are brought to
the same bandwidth first: a zero-phase 4th-order Butterworth low-pass at
:data:`CUTOFF_HZ` on each signal's own grid (:func:`bandlimit`). Then, on the implied IMU's
step midpoints:

* **axis mapping**: the signed permutation A (of the 48) minimising the normalised residual
  energy ``sum ||x_imp - A x_rec||^2 / sum ||x_imp||^2`` over both sensors (gravity makes the
  accelerometer's axis signs unambiguous, the turns the gyro's), with its margin over the
  identity (:func:`axis_mapping`);
* **time offset** of the IMU stamps against the GT (stamp minus GT time), by a search of the
  mean-removed gyro residual over :data:`OFFSETS` (0.01 s grid), with a
  1-sigma from the curvature of the curve and the residual's effective sample count
  (:func:`time_offset`);
* per-axis correlation, residual mean and std; **apparent biases** (residual mean) and residual
  std in sliding windows, and the windows that disagree with the rest (:func:`windows`);
* the **attitude** the recorded gyros integrate away from the GT over the track
  (:func:`attitude_drift`).

A recorded sample ``i`` is the mean rate over ``(t[i-1], t[i]]``; it is compared at the
middle of that interval (its stamp minus half a step), so an exact IMU has zero offset.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from nespm_cli.data.corrections import axes_text
from nespm_cli.nav.earth import w_en_n, w_ie_n
from nespm_cli.nav.rotations import exp_so3, log_so3, signed_permutations
from nespm_cli.nav.synthesis import from_recorded, synthesize

CUTOFF_HZ = 0.3  # [Hz] common bandwidth: below the GT's 0.5 Hz Nyquist, where its splines are faithful
OFFSETS = np.round(np.arange(-4.0, 4.0 + 1e-9, 0.01), 2)  # [s] time-offset search grid
EDGE_S = 10.0  # [s] filter transients: this much is left out at each end
WINDOW_S = 20.0  # [s] sliding-window length for the apparent biases
WINDOW_STEP_S = 10.0  # [s] step between window starts
FLAG_SIGMAS = 6.0  # a window whose bias departs from the track's median by this many robust spreads...
GYRO_FLOOR = np.radians(200.0 / 3600.0)  # [rad/s] ...and by more than 200 deg/h
ACC_FLOOR = 0.01  # [m/s^2] ...or 1 mg-ish (0.01 m/s^2) on an accelerometer axis
RELATIVE = 0.1  # ...and by more than this fraction of the window's own signal RMS on that axis (errors in
# proportion to the motion, as the 1 Hz GT's splines make in turns, stay below it)
UNRESOLVED_RATIO = 2.0  # a flagged window whose recorded gyro RMS at 0.5-2 Hz (above the GT's Nyquist) is
# this many times the track's median window and above UNRESOLVED_FLOOR is "unresolved": the 1 Hz GT cannot
# describe its motion. (A sensor fault such as a bias step is broadband too, but far below the floor.)
UNRESOLVED_FLOOR = np.radians(0.3)  # [rad/s] 0.3 deg/s
STD_RATIO = 10.0  # ...or whose residual std is this many times the median window's (and above the floors);
# turns raise the residual std several-fold (the 1 Hz GT's splines miss part of them), so this is set well above it


def bandlimit(x: np.ndarray, dt: float, cutoff_hz: float = CUTOFF_HZ) -> np.ndarray:
    """Zero-phase low-pass of ``x`` (M, ...) sampled every ``dt`` [s] along axis 0."""
    sos = butter(4, cutoff_hz, fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def compare_grid(track) -> dict:
    """Implied and recorded IMU, band-limited, on the implied steps' midpoints.

    Returns ``t`` (K,) [s, GT file time], ``imp_f``, ``imp_w`` (K, 3) implied, ``rec_t`` (M,)
    effective times of the recorded samples, ``rec_f``, ``rec_w`` (M, 3) band-limited recorded
    readings, and ``inner`` (K,) bool: the samples :data:`EDGE_S` away from both ends.
    """
    ref = synthesize(track)
    t_mid = 0.5 * (ref.t[1:] + ref.t[:-1])
    dt_imp = float(np.median(ref.dt))
    imu = np.asarray(track.imu, dtype=float)
    dt_rec = float(np.median(np.diff(imu[:, 0])))
    inner = (t_mid > t_mid[0] + EDGE_S) & (t_mid < t_mid[-1] - EDGE_S)
    return {"t": t_mid, "imp_f": bandlimit(ref.f_b, dt_imp), "imp_w": bandlimit(ref.w_ib_b, dt_imp),
            "rec_t": imu[:, 0] - 0.5 * dt_rec, "rec_f": bandlimit(imu[:, 1:4], dt_rec),
            "rec_w": bandlimit(imu[:, 4:7], dt_rec), "inner": inner, "dt": dt_rec,
            "rec_hf": sosfiltfilt(butter(4, [0.5, 2.0], btype="band", fs=1.0 / dt_rec, output="sos"),
                                  imu[:, 4:7], axis=0)}


def resample(g: dict, offset: float = 0.0, A: np.ndarray | None = None,
             drift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Recorded (f, w) (K, 3) at the compare times ``t``: the samples stamped ``t + offset + drift t``
    (data/corrections.py), axes mapped by ``A``."""
    t = g["t"] + offset + drift * g["t"]
    f = np.stack([np.interp(t, g["rec_t"], g["rec_f"][:, i]) for i in range(3)], axis=-1)
    w = np.stack([np.interp(t, g["rec_t"], g["rec_w"][:, i]) for i in range(3)], axis=-1)
    if A is not None:
        f, w = f @ A.T, w @ A.T
    return f, w


def axis_mapping(g: dict, offset: float = 0.0) -> dict:
    """Best signed permutation (``f_b = A f_rec``) and its margin over the identity.

    ``offset``: the IMU time offset [s] at which to compare (:func:`search`). Cost of A:
    normalised residual energy summed over the two sensors (0 = perfect, 2 = no
    better than zero). Returns ``axes`` (text, as ``--imu-axes`` takes it), ``matrix``,
    ``cost``, ``identity_cost``, ``second_cost`` and ``margin`` (identity cost minus best; 0
    when the identity is best: then ``second_cost - cost`` says how clearly).
    """
    m = g["inner"]
    f, w = resample(g, offset)
    cost = np.zeros(48)
    perms = signed_permutations()
    for x_imp, x_rec in ((g["imp_f"][m], f[m]), (g["imp_w"][m], w[m])):
        norm = float((x_imp**2).sum())
        pred = np.einsum("pij,kj->pki", perms, x_rec)  # (48, K, 3)
        cost += ((x_imp[None] - pred) ** 2).sum(axis=(1, 2)) / norm
    order = np.argsort(cost)
    best = perms[order[0]]
    return {"axes": axes_text(best), "matrix": best.tolist(), "cost": float(cost[order[0]]),
            "identity_cost": float(cost[0]), "second_cost": float(cost[order[1]]),
            "margin": float(cost[0] - cost[order[0]]), "det": float(np.linalg.det(best))}


def search(g: dict) -> tuple[dict, dict]:
    """Axis mapping, time offset and clock drift together: the mapping at zero offset, the
    offset for that mapping, the mapping again at that offset (a 1 s offset can hide the
    mapping), the local offsets along the track (:func:`local_offsets`), their straight line
    (:func:`clock_drift`) and, when the drift is significant, the offset again with it applied.
    Returns ``(axis_mapping, time_offset)``; ``time_offset`` holds ``drift`` (the line fit) and
    ``local`` (the windows) besides the :func:`time_offset` keys."""
    mapping = axis_mapping(g)
    offset = time_offset(g, np.asarray(mapping["matrix"]))
    mapping = axis_mapping(g, offset["offset_s"])
    A = np.asarray(mapping["matrix"])
    local = local_offsets(g, A)
    drift = clock_drift(local)
    if drift["significant"]:
        offset = time_offset(g, A, drift=drift["drift"])
    else:
        offset = time_offset(g, A)
    return mapping, {**offset, "drift": drift, "local": local}


def residual(g: dict, offset: float, A: np.ndarray, drift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Recorded minus implied (f, w) residuals (K, 3) after ``offset``, ``drift`` and ``A``."""
    f, w = resample(g, offset, A, drift)
    return f - g["imp_f"], w - g["imp_w"]


PARABOLA_HALF = 6.0  # [grid steps] half-width of the tent weights of the parabola fit (11 points inside)
PARABOLA_ITER = 60  # fixed-point iterations at most (converged to 1e-12 steps in a few on every track seen)


def parabola_minimum(offsets: np.ndarray, cost: np.ndarray, n_eff: float) -> tuple[float, float, bool]:
    """Minimum of a cost curve on a uniform grid: ``(offset, 1-sigma, at_edge)``.

    A parabola fitted with tent weights ``max(0, 1 - |x - c| / PARABOLA_HALF)`` (x in grid steps) about a
    centre ``c``; ``c`` is moved to the fitted vertex until it stays (a fixed point, started at the grid
    minimum). The weights fall to zero at the window's edges, so the fit, and so the vertex, changes
    continuously with the costs: two near-tied grid minima give the same vertex, and a last-bit change
    of the inputs moves it by round-off only (a window re-centred on the grid minimum moved it by ~30 µs).
    The vertex is used when the curvature is positive and it lies within 1.5 grid steps of the grid
    minimum (else the grid minimum; near ties the vertex lies between the two tied points). 1-sigma ``sqrt(2 c0 / (n_eff c''))`` with ``c0`` the cost at the grid
    minimum and ``c''`` the fit's curvature [cost / s²].
    """
    offsets = np.asarray(offsets, dtype=float)
    cost = np.asarray(cost, dtype=float)
    k = int(np.argmin(cost))
    step = float(offsets[1] - offsets[0]) if len(offsets) > 1 else 1.0
    x = (offsets - offsets[k]) / step  # grid steps from the grid minimum
    c, a2, a1, ok = 0.0, 0.0, 0.0, False
    for _ in range(PARABOLA_ITER):
        w = np.clip(1.0 - np.abs(x - c) / PARABOLA_HALF, 0.0, None)
        sel = w > 0
        if sel.sum() < 3:
            break
        u = x[sel] - c
        sw = np.sqrt(w[sel])
        (a2, a1, _), *_ = np.linalg.lstsq(np.stack([u * u, u, np.ones_like(u)], axis=-1) * sw[:, None],
                                          cost[sel] * sw, rcond=None)
        if not a2 > 0:
            ok = False
            break
        vertex = float(np.clip(c - a1 / (2.0 * a2), -PARABOLA_HALF, PARABOLA_HALF))
        done = abs(vertex - c) < 1e-12
        c = vertex
        ok = abs(c) <= 1.5
        if done:
            break
    curv = 2.0 * a2 / step**2  # [cost / s^2]
    std = float(np.sqrt(2.0 * cost[k] / (n_eff * curv))) if curv > 0 else float("inf")
    best = float(offsets[k] + c * step) if ok else float(offsets[k])
    return best, std, bool(k in (0, len(offsets) - 1))


LOCAL_S = 40.0  # [s] window of a local time offset
LOCAL_STEP_S = 20.0  # [s] step between local windows
LOCAL_OFFSETS = np.round(np.arange(-2.0, 2.0 + 1e-9, 0.01), 2)  # [s] local search grid
DRIFT_SIGMAS = 3.0  # a clock drift is corrected when beyond this many sigma...
DRIFT_MIN_S = 0.05  # ...and when it moves the offset by at least this much over the track [s]


def local_offsets(g: dict, A: np.ndarray, offsets: np.ndarray = LOCAL_OFFSETS) -> list[dict]:
    """The gyro time offset in windows of :data:`LOCAL_S` every :data:`LOCAL_STEP_S` (inner samples).

    One interpolation per candidate offset for the whole track; the per-window costs come
    from cumulative sums (mean removed per window). Each: ``t`` (window centre), ``offset_s``,
    ``std_s`` (as :func:`parabola_minimum`, ``n_eff = 2 B LOCAL_S``), ``at_edge``.
    """
    m = g["inner"]
    t = g["t"]
    starts = np.arange(t[m][0], t[m][-1] - LOCAL_S + 1e-9, LOCAL_STEP_S)
    if len(starts) == 0:
        return []
    ti = t[m]
    lo, hi = np.searchsorted(ti, starts), np.searchsorted(ti, starts + LOCAL_S)  # window j: inner samples lo..hi-1
    n = np.maximum(hi - lo, 1)[:, None]

    def window_ss(x: np.ndarray) -> np.ndarray:
        """Sum over the axes of each window's squared deviations from its mean (from cumulative sums
        of the deviations from the track mean, so a constant bias does not cancel; >= 0)."""
        x = x - x.mean(axis=0)
        c1 = np.vstack([np.zeros(3), np.cumsum(x, axis=0)])
        c2 = np.vstack([np.zeros(3), np.cumsum(x * x, axis=0)])
        s1, s2 = c1[hi] - c1[lo], c2[hi] - c2[lo]
        return np.maximum(s2 - s1 * s1 / n, 0.0).sum(axis=1)

    norm = np.maximum(window_ss(g["imp_w"][m]), 1e-300)
    cost = np.empty((len(offsets), len(starts)))
    for i, o in enumerate(offsets):  # one interpolation per candidate offset, all windows at once
        _, rw = residual(g, float(o), A)
        cost[i] = window_ss(rw[m]) / norm
    out = []
    for j, s0 in enumerate(starts):
        best, std, edge = parabola_minimum(offsets, cost[:, j], 2.0 * CUTOFF_HZ * LOCAL_S)
        out.append({"t": float(s0 + LOCAL_S / 2), "offset_s": best, "std_s": std, "at_edge": edge})
    return out


def clock_drift(local: list[dict]) -> dict:
    """Straight line ``offset(t) = a + drift t`` through the local offsets (weighted by 1/sigma^2,
    windows at the search edge left out), with 1-sigma of both scaled by the fit's reduced
    chi-square (when above 1). ``significant``: beyond :data:`DRIFT_SIGMAS` sigma and moving the
    offset by at least :data:`DRIFT_MIN_S` over the track."""
    rows = [r for r in local if not r["at_edge"] and np.isfinite(r["std_s"]) and r["std_s"] > 0]
    if len(rows) < 3:
        return {"drift": 0.0, "drift_std": None, "intercept_s": None, "chi2_red": None, "significant": False,
                "windows_used": len(rows)}
    t = np.array([r["t"] for r in rows])
    y = np.array([r["offset_s"] for r in rows])
    w = 1.0 / np.array([r["std_s"] for r in rows]) ** 2
    X = np.stack([np.ones_like(t), t], axis=-1)
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    a, b = cov @ X.T @ (w * y)
    chi2 = float((w * (y - a - b * t) ** 2).sum() / max(len(rows) - 2, 1))
    cov = cov * max(chi2, 1.0)
    sb = float(np.sqrt(cov[1, 1]))
    span = float(t[-1] - t[0] + LOCAL_S)
    sig = abs(b) > DRIFT_SIGMAS * sb and abs(b) * span >= DRIFT_MIN_S
    return {"drift": float(b) if sig else 0.0, "drift_fit": float(b), "drift_std": sb, "intercept_s": float(a),
            "intercept_std_s": float(np.sqrt(cov[0, 0])), "chi2_red": chi2, "significant": bool(sig),
            "windows_used": len(rows)}


def time_offset(g: dict, A: np.ndarray, offsets: np.ndarray = OFFSETS, drift: float = 0.0) -> dict:
    """IMU stamp minus GT time [s]: the offset minimising the mean-removed residual.

    The cost is the gyro residual variance normalised by the implied rate's variance (the
    turns carry the timing; the accelerometer residual mixes in the GT's attitude errors
    through gravity). 1-sigma: ``sqrt(2 c0 / (n_eff c''))`` with ``c''`` the curvature of a
    parabola through the 11 grid points around the minimum and ``n_eff = 2 B T`` the
    effective sample count of a residual band-limited to B = :data:`CUTOFF_HZ` over T s.
    ``drift`` [s/s]: a clock drift applied first (the offset is then the one at GT time 0).
    Returns ``offset_s``, ``std_s``, ``curve`` (``{"offset_s": [...], "cost": [...]}``) and
    ``at_edge`` (the minimum is at the end of the grid: the offset is outside the search).
    """
    m = g["inner"]
    var_w = g["imp_w"][m].var(axis=0).sum()
    cost = np.empty(len(offsets))
    for i, o in enumerate(offsets):  # one interpolation per candidate offset (801), vectorized over samples
        _, rw = residual(g, float(o), A, drift)
        cost[i] = rw[m].var(axis=0).sum() / var_w
    T = float(g["t"][m][-1] - g["t"][m][0])
    best, std, edge = parabola_minimum(offsets, cost, max(2.0 * CUTOFF_HZ * T, 1.0))
    return {"offset_s": round(best, 3), "std_s": std, "cost": float(np.min(cost)),
            "curve": {"offset_s": offsets.tolist(), "cost": cost.tolist()}, "at_edge": edge}


def axis_stats(g: dict, rf: np.ndarray, rw: np.ndarray) -> dict:
    """Per-axis correlation, residual mean and std (inner samples) of both sensors."""
    m = g["inner"]
    out = {}
    for key, imp, r in (("acc", g["imp_f"], rf), ("gyro", g["imp_w"], rw)):
        rec = imp[m] + r[m]
        corr = [float(np.corrcoef(imp[m][:, i], rec[:, i])[0, 1]) if imp[m][:, i].std() > 0 else float("nan")
                for i in range(3)]
        # scale-factor error k and bias b per axis: r = b + k x_imp (least squares)
        X = np.stack([np.ones(int(m.sum())), np.zeros(int(m.sum()))], axis=-1)
        k, b = [], []
        for i in range(3):
            X[:, 1] = imp[m][:, i]
            (bi, ki), *_ = np.linalg.lstsq(X, r[m][:, i], rcond=None)
            k.append(float(ki))
            b.append(float(bi))
        out[key] = {"corr": corr, "resid_mean": r[m].mean(axis=0).tolist(), "resid_std": r[m].std(axis=0).tolist(),
                    "signal_std": imp[m].std(axis=0).tolist(), "scale_factor": k, "bias": b}
    return out


def remove_bias_scale(g: dict, rf: np.ndarray, rw: np.ndarray, stats: dict) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (K, 3) minus the track's constant bias and scale-factor term of :func:`axis_stats`."""
    out = []
    for key, imp, r in (("acc", g["imp_f"], rf), ("gyro", g["imp_w"], rw)):
        out.append(r - np.asarray(stats[key]["bias"]) - np.asarray(stats[key]["scale_factor"]) * imp)
    return out[0], out[1]


def windows(g: dict, rf: np.ndarray, rw: np.ndarray) -> list[dict]:
    """Apparent biases (residual means) and residual stds in sliding windows, with a flag.

    Windows of :data:`WINDOW_S` every :data:`WINDOW_STEP_S` over the inner samples. A window
    is ``inconsistent`` when on some axis its bias departs from the median window bias by more
    than :data:`FLAG_SIGMAS` robust spreads (1.4826 MAD over windows), by more than the
    floor (:data:`GYRO_FLOOR`, :data:`ACC_FLOOR`) and by more than :data:`RELATIVE` of the
    window's signal RMS (gyro: the rate; accelerometer: its variation about the window mean),
    or its residual std exceeds :data:`STD_RATIO` times the median window std, the floor and
    the same fraction of the signal. ``reasons`` says which. A flagged window whose recorded
    gyro RMS at 0.5-2 Hz exceeds :data:`UNRESOLVED_RATIO` times the median window's and
    :data:`UNRESOLVED_FLOOR` is
    ``unresolved`` instead (motion the 1 Hz GT cannot describe: the data may be right, the
    truth is not known well enough there to score a filter).
    """
    t, m = g["t"], g["inner"]
    t0, t1 = t[m][0], t[m][-1]
    starts = np.arange(t0, max(t1 - WINDOW_S, t0) + 1e-9, WINDOW_STEP_S)
    rows = []
    for s in starts:
        sel = m & (t >= s) & (t < s + WINDOW_S)
        hf = g["rec_hf"][(g["rec_t"] >= s) & (g["rec_t"] < s + WINDOW_S)]
        rows.append({"start": float(s), "end": float(s + WINDOW_S),
                     "gyro_hf": float(np.sqrt((hf**2).mean(axis=0)).max()) if len(hf) else 0.0,
                     "acc_bias": rf[sel].mean(axis=0), "acc_std": rf[sel].std(axis=0),
                     "gyro_bias": rw[sel].mean(axis=0), "gyro_std": rw[sel].std(axis=0),
                     "acc_rms": np.sqrt(((g["imp_f"][sel] - g["imp_f"][sel].mean(axis=0)) ** 2).mean(axis=0)),
                     "gyro_rms": np.sqrt((g["imp_w"][sel] ** 2).mean(axis=0))})
    for key, floor in (("acc", ACC_FLOOR), ("gyro", GYRO_FLOOR)):
        b = np.array([r[f"{key}_bias"] for r in rows])
        s = np.array([r[f"{key}_std"] for r in rows])
        med = np.median(b, axis=0)
        spread = 1.4826 * np.median(np.abs(b - med), axis=0)
        med_s = np.median(s, axis=0)
        for r, bi, si in zip(rows, b, s):
            dev = np.abs(bi - med)
            rel = RELATIVE * r[f"{key}_rms"]
            bad_b = (dev > FLAG_SIGMAS * spread) & (dev > floor) & (dev > rel)
            bad_s = (si > STD_RATIO * med_s) & (si > floor) & (si > rel)
            reasons = r.setdefault("reasons", [])
            for i in np.flatnonzero(bad_b):
                reasons.append(f"{key} {'xyz'[i]} bias {bi[i] - med[i]:+.3g} from the median")
            for i in np.flatnonzero(bad_s & ~bad_b):
                reasons.append(f"{key} {'xyz'[i]} residual std {si[i] / med_s[i]:.1f}x the median")
    hf_med = float(np.median([r["gyro_hf"] for r in rows]))
    for r in rows:
        r["unresolved"] = bool(r["reasons"]) and bool(r["gyro_hf"] > max(UNRESOLVED_RATIO * hf_med, UNRESOLVED_FLOOR))
        if r["unresolved"]:
            r["reasons"].append(f"gyro power above the GT's Nyquist {r['gyro_hf'] / hf_med:.1f}x the median: "
                                "the 1 Hz GT cannot describe this motion")
        for k in ("acc_bias", "acc_std", "gyro_bias", "gyro_std", "acc_rms", "gyro_rms"):
            r[k] = [float(x) for x in r[k]]
        r["inconsistent"] = bool(r["reasons"]) and not r["unresolved"]
    return rows


def own_noise(track) -> dict:
    """The recorded IMU's own white noise std per sample, per axis: ``acc`` [m/s^2], ``gyro``
    [rad/s], from the second difference of the raw readings (``std = 1.4826 MAD(d2) / sqrt(6)``:
    motion slow against the 100 Hz rate cancels in d2, white noise keeps ``sqrt(6)`` of its std;
    the MAD ignores the turns' rare large steps). Vibration above a few hertz counts as noise
    here, as it does in the filter. Also ``quantum``: the smallest step between readings of each
    sensor (the file's resolution)."""
    imu = np.asarray(track.imu, dtype=float)
    d2 = np.diff(imu[:, 1:7], n=2, axis=0)
    std = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)
    quanta = []
    for cols in (slice(1, 4), slice(4, 7)):
        steps = np.abs(np.diff(imu[:, cols], axis=0))
        steps = steps[steps > 0]
        quanta.append(float(steps.min()) if steps.size else float("nan"))
    return {"acc": std[:3].tolist(), "gyro": std[3:].tolist(), "quantum": {"acc": quanta[0], "gyro": quanta[1]}}


def attitude_drift(track) -> dict:
    """Attitude the recorded gyros integrate away from the GT: per GT interval, the recorded
    gyro increment (product of its steps, earth and transport rate removed along the GT)
    against the GT's attitude change; accumulated in the navigation frame (first order).

    Apply the track's corrections first. Returns ``t`` (N,) [s], ``drift_deg`` (N, 3) the
    accumulated roll/pitch/yaw-axis (NED) attitude difference, ``final_deg`` (3,) and
    ``rate_deg_h`` (3,) its least-squares slope [deg/h].
    """
    truth = from_recorded(track)
    e = truth.epoch_index
    n_int = len(e) - 1
    C_gt = truth.C_bn[e]
    steps = np.diff(e)
    S = int(steps.max())
    w_in = w_ie_n(truth.pos[:-1]) + w_en_n(truth.pos[:-1], truth.v_n[:-1])  # (K, 3) n-frame rate per step
    # per step: body increment exp(w_ib dt), n-frame increment exp(w_in dt)
    dC_b = exp_so3(truth.w_ib_b * truth.dt[:, None])
    dC_n = exp_so3(w_in * truth.dt[:, None])
    P = C_gt.copy()  # propagate every interval from its GT start, the intervals side by side
    for s in range(S):  # at most ~102 sub-steps, vectorized over the intervals
        j = e[:-1] + s
        live = s < steps
        jj = np.where(live, j, 0)
        upd = np.einsum("kij,kjl,klm->kim", np.swapaxes(dC_n[jj], -1, -2), P[:-1], dC_b[jj])
        P[:-1] = np.where(live[:, None, None], upd, P[:-1])
    # error of the interval: C_gt(k+1) vs propagated, as a small n-frame rotation
    err_n = log_so3(np.einsum("kij,kjl->kil", P[:-1], np.swapaxes(C_gt[1:], -1, -2)))
    drift = np.vstack([np.zeros(3), np.cumsum(err_n, axis=0)])
    t = truth.t[e]
    slope = np.polyfit(t - t[0], drift, 1)[0] if n_int >= 2 else np.zeros(3)
    return {"t": t.tolist(), "drift_deg": np.degrees(drift).tolist(), "final_deg": np.degrees(drift[-1]).tolist(),
            "rate_deg_h": (np.degrees(slope) * 3600.0).tolist()}
