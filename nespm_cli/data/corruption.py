"""The papers' corruption protocol: one reproducible realization per (track, run).

Every random draw of run ``r`` on track ``N`` comes from
``SeedSequence(seed, spawn_key=(N, r, stream))`` with a fixed stream number per kind of
draw (below), so a realization never depends on chunking, job count or filter, and each
filter sees the identical realization.

Protocol (ukf-nespm.md section IV-A, anukf.md section IV-A), all std values options:

* initial velocity error N(0, 0.25²) north and east, N(0, 0.05²) down [m/s];
* initial misalignment N(0, (0.01 deg)²) per axis (nav frame, ⊕ of eq 37);
* white noise 0.03 m/s² (accelerometers), 7.3e-6 rad/s (gyros): std per 100 Hz sample;
* biases N(0, 0.3²) m/s² and N(0, (7.3e-5)²) rad/s per axis, constant over the track;
* initial position error N(0, pos_h_std²) north and east, N(0, pos_v_std²) down [m]: 0 in the
  papers (position is not in their state); drawn from its own stream (``STREAM_POS``), so
  setting it never changes another draw.

Schedules:

* ``constant`` (UKF-NESPM paper): the biases and noise std above, unchanged.
* ``dynamic`` (ANUKF paper, "changed dynamically, multiplied by factors of 1-6"): the
  track is cut into segments of ``segment_s`` seconds (default 20 s); in each segment
  the accelerometer noise std and bias are multiplied by a factor drawn uniformly from
  [1, 6], and independently so are the gyro noise std and bias. A 20 s segment gives the
  400 s tracks 20 regimes (enough for the adaptive filters to see several) while each
  regime spans 20 DVL updates (long enough to be estimated).

  How the *biases* vary is left open by the paper ("noise and bias values were changed
  dynamically"); ``dynamic_bias`` chooses:

  - ``run`` (default): each bias is multiplied by its run's first-segment factor and held
    for the whole track: bias magnitudes span 1-6x across runs, while the noise level
    changes every segment. Reason: a bias step of 0.3 x (6 - 1) = 1.5 m/s² (0.15 g)
    every 20 s is not a physical IMU, and with it every filter's velocity error is of
    order 1 m/s (measured on tracks 5 and 6, 8 runs: UKF 3.06, ANUKF 1.32 m/s VRMSE),
    ten times the published 0.09-0.12 m/s;
  - ``segment``: the bias is multiplied by the segment's factor too (steps at every
    segment boundary), the literal reading.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nespm_cli.errors import NespmError

STREAM_INIT, STREAM_ACC, STREAM_GYRO, STREAM_DVL, STREAM_SCHEDULE, STREAM_POS = range(6)
SCHEDULES = ("constant", "dynamic")
DYNAMIC_BIAS = ("run", "segment")


#: The papers' white IMU noise std per 100 Hz sample: the corruption's default, the filters'
#: nominal Q and ProcessNet's base std all come from here.
NOMINAL_ACC_NOISE = 0.03  # [m/s^2]
NOMINAL_GYRO_NOISE = 7.3e-6  # [rad/s]


@dataclass(frozen=True)
class CorruptionConfig:
    """Standard deviations of the protocol; defaults are the papers' values."""

    vel_h_std: float = 0.25  # m/s, north and east
    vel_v_std: float = 0.05  # m/s, down
    misalignment_deg: float = 0.01  # deg per axis
    heading_deg: float | None = None  # if set, overrides the yaw-axis (down) misalignment std
    acc_noise: float = NOMINAL_ACC_NOISE  # m/s^2 per sample
    gyro_noise: float = NOMINAL_GYRO_NOISE  # rad/s per sample
    acc_bias: float = 0.3  # m/s^2
    gyro_bias: float = 7.3e-5  # rad/s
    schedule: str = "constant"
    segment_s: float = 20.0  # dynamic schedule segment length
    factor_min: float = 1.0
    factor_max: float = 6.0
    dynamic_bias: str = "run"  # dynamic schedule: bias factor held per run ("run") or per segment
    dvl_noise: float = 0.02  # m/s, synthetic DVL
    pos_h_std: float = 0.0  # m, initial position error north and east
    pos_v_std: float = 0.0  # m, initial position error down

    def __post_init__(self):
        if self.schedule not in SCHEDULES:
            raise NespmError(f"--schedule: unknown schedule {self.schedule!r}; choose from {', '.join(SCHEDULES)}")
        if self.dynamic_bias not in DYNAMIC_BIAS:
            raise NespmError(f"--dynamic-bias: choose {' or '.join(DYNAMIC_BIAS)}, got {self.dynamic_bias!r}")
        if not (self.segment_s > 0 and np.isfinite(self.segment_s)):
            raise NespmError("--segment-length must be a positive number of seconds")
        for name in ("vel_h_std", "vel_v_std", "misalignment_deg", "acc_noise", "gyro_noise", "acc_bias",
                     "gyro_bias", "dvl_noise", "heading_deg", "pos_h_std", "pos_v_std"):
            v = getattr(self, name)
            if v is None:
                continue
            if not (np.isfinite(v) and v >= 0):
                raise NespmError(f"--{name.replace('_', '-')}: must be a finite std >= 0, got {v}")
        for name in ("misalignment_deg", "heading_deg"):
            v = getattr(self, name)
            if v is not None and v > MAX_ANGLE_STD_DEG:
                raise NespmError(f"--{name.replace('_', '-')}: a std above {MAX_ANGLE_STD_DEG:g} deg is not an "
                                 f"attitude error (angles wrap at 180), got {v:g}")
        if not (1 <= self.factor_min <= self.factor_max):
            raise NespmError("dynamic schedule factors need 1 <= min <= max")


MAX_SEED = 2**63 - 1  # SeedSequence takes any non-negative integer; a 64-bit one is what the manifest holds


def check_seed(seed: int) -> int:
    """``seed`` if it is an integer from 0 to :data:`MAX_SEED`, else a one-line NespmError."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not (0 <= seed <= MAX_SEED):
        raise NespmError(f"--seed must be an integer from 0 to 2**63-1, got {seed}")
    return int(seed)


MAX_ANGLE_STD_DEG = 180.0  # [deg] an initial-misalignment std beyond half a turn means nothing


def stream(seed: int, track: int, run: int, kind: int) -> np.random.Generator:
    """The generator of one kind of draw for run ``run`` of track ``track``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(track, run, kind))))


@dataclass
class Realization:
    """The draws of R runs of one track (leading axis = run).

    Attributes:
        runs: (R,) run indices.
        dv0: (R, 3) initial velocity error [m/s] (estimate = truth + dv0).
        dpsi0: (R, 3) initial misalignment [rad] (C_est = exp([dpsi0 x]) C_true).
        b_a, b_g: (R, 3) base biases [m/s^2], [rad/s].
        acc_factors, gyro_factors: (R, S) per-segment factors (ones for ``constant``).
        dp0: (R, 3) initial position error, NED [m] (estimate = truth ⊕ dp0; zeros by default).
    """

    seed: int
    track: int
    runs: np.ndarray
    config: CorruptionConfig
    dv0: np.ndarray
    dpsi0: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray
    acc_factors: np.ndarray
    gyro_factors: np.ndarray
    dp0: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False)


def n_segments(duration: float, segment_s: float) -> int:
    return max(1, int(np.ceil(duration / segment_s - 1e-9)))


def draw(seed: int, track: int, runs, duration: float, config: CorruptionConfig) -> Realization:
    """Draw the initial errors, biases and schedule factors of ``runs`` on ``track``.

    One small generator per run is unavoidable (each run's stream must not depend on the
    other runs in its chunk); the draws themselves are a few numbers per run.
    """
    runs = np.asarray(runs, dtype=np.int64)
    S = n_segments(duration, config.segment_s)
    std_v = np.array([config.vel_h_std, config.vel_h_std, config.vel_v_std])
    mis = np.deg2rad(config.misalignment_deg)
    std_psi = np.array([mis, mis, np.deg2rad(config.heading_deg) if config.heading_deg is not None else mis])
    z = np.empty((len(runs), 12))
    fac = np.ones((len(runs), 2, S))
    for i, r in enumerate(runs):  # one generator per run (see docstring)
        z[i] = stream(seed, track, int(r), STREAM_INIT).standard_normal(12)
        if config.schedule == "dynamic":
            fac[i] = stream(seed, track, int(r), STREAM_SCHEDULE).uniform(config.factor_min, config.factor_max, (2, S))
    return Realization(
        seed=seed,
        track=track,
        runs=runs,
        config=config,
        dv0=z[:, 0:3] * std_v,
        dpsi0=z[:, 3:6] * std_psi,
        b_a=z[:, 6:9] * config.acc_bias,
        b_g=z[:, 9:12] * config.gyro_bias,
        acc_factors=fac[:, 0],
        gyro_factors=fac[:, 1],
        dp0=initial_position_error(seed, track, runs, config),
    )


def initial_position_error(seed: int, track: int, runs: np.ndarray, config: CorruptionConfig) -> np.ndarray:
    """(R, 3) initial position error NED [m], N(0, diag(h², h², v²)) from ``STREAM_POS`` (zeros,
    and no draw, when both std are 0)."""
    std = np.array([config.pos_h_std, config.pos_h_std, config.pos_v_std])
    out = np.zeros((len(runs), 3))
    if not std.any():
        return out
    for i, r in enumerate(runs):
        out[i] = stream(seed, track, int(r), STREAM_POS).standard_normal(3) * std
    return out


def segment_index(t_rel: np.ndarray, segment_s: float, S: int) -> np.ndarray:
    """Segment of each time since the start [s] (..., ) -> int index in [0, S)."""
    return np.minimum((np.asarray(t_rel) / segment_s + 1e-9).astype(np.int64), S - 1)


def empty_small_pages(shape: tuple, count: int) -> list[np.ndarray]:
    """``count`` uninitialised float arrays of ``shape`` allocated without NumPy's ``madvise(MADV_HUGEPAGE)``
    (NumPy asks for transparent huge pages for arrays of 4 MB and more; with the kernel's THP ``madvise``
    and ``defrag=madvise`` a fresh process's first touch of such arrays cost more system time: measured on a
    shared 2-vCPU VM, about 4 ms per run of ``mc`` for the IMU arrays, and the filter that reads them ran no
    slower without; benchmarks/README.md). Only where they live changes, never a value; NumPy's setting is
    restored after."""
    toggle = getattr(getattr(np, "_core", None), "multiarray", None)
    toggle = getattr(toggle, "_set_madvise_hugepage", None)  # NumPy's own switch (NUMPY_MADVISE_HUGEPAGE)
    if toggle is None:
        return [np.empty(shape) for _ in range(count)]
    before = toggle(False)
    try:
        return [np.empty(shape) for _ in range(count)]
    finally:
        toggle(before)


def imu_errors(real: Realization, t: np.ndarray, clean: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Additive IMU errors of every run on the IMU steps ending at ``t[1:]``, or with ``clean`` the
    corrupted IMU itself.

    Args:
        t: (M+1,) IMU sample times [s]; step j covers (t[j], t[j+1]].
        clean: ``(f_b, w_ib_b)``, each (M, 3): the clean specific force [m/s^2] and angular rate
            [rad/s]; when given, they are added into each run's error rows as the rows are formed
            (no second pair of (R, M, 3) arrays: half the memory touched per run).

    Returns:
        ``(e_f, e_w)``, each (R, M, 3): bias x factor + noise std x factor x N(0, 1) (the
        bias factor per ``dynamic_bias``), to be
        added to the clean specific force [m/s^2] and angular rate [rad/s]. They are cached on
        ``real`` per ``len(t)`` (the caller must not write into them).
        With ``clean``: ``(f_b + e_f, w_ib_b + e_w)`` bit for bit (one IEEE addition per element,
        the same operands), new arrays never cached; the cached errors, if any, are read, not
        written.
    """
    key = ("imu", len(t))
    if key in real._cache:
        e_f, e_w = real._cache[key]
        return (e_f, e_w) if clean is None else (clean[0] + e_f, clean[1] + e_w)
    if clean is not None:
        f_b, w_b = (np.asarray(c, dtype=float) for c in clean)
        if f_b.shape != (len(t) - 1, 3) or w_b.shape != (len(t) - 1, 3):
            raise ValueError(f"imu_errors: clean arrays must be ({len(t) - 1}, 3), got {f_b.shape} and {w_b.shape}")
    M = len(t) - 1
    R = len(real.runs)
    seg = segment_index(t[1:] - t[0], real.config.segment_s, real.acc_factors.shape[1])
    if real.config.dynamic_bias == "segment":
        bias_seg = seg
    else:  # the bias keeps the run's first-segment factor
        bias_seg = np.zeros(1, dtype=np.int64)
    e_f, e_w = empty_small_pages((R, M, 3), 2)
    cfg = real.config
    # per-run noise streams (see draw); each run is formed in place in its own rows (a cache-sized
    # working set): bias x factor + factor x (std x N(0, 1)), the same operations as the
    # whole-array expression, so the same bits (a run whose factors are all 1 skips the product by
    # them: x * 1.0 is x); with ``clean`` the clean row is added last, in the
    # same rows: fl(e + c) == fl(c + e), the one addition of ``clean + errors``
    for i, r in enumerate(real.runs):
        for out, kind, std, factors, bias, c in (
                (e_f, STREAM_ACC, cfg.acc_noise, real.acc_factors, real.b_a, None if clean is None else f_b),
                (e_w, STREAM_GYRO, cfg.gyro_noise, real.gyro_factors, real.b_g, None if clean is None else w_b)):
            n = out[i]
            stream(real.seed, real.track, int(r), kind).standard_normal((M, 3), out=n)
            n *= std
            if (factors[i] != 1.0).any():  # x * 1.0 == x exactly: the constant schedule skips the pass
                n *= factors[i, seg][:, None]
            n += factors[i, bias_seg][:, None] * bias[i]
            if c is not None:
                n += c
    if clean is None:  # the corrupted IMU is the caller's, never cached
        real._cache[key] = (e_f, e_w)
    return e_f, e_w


def true_biases(real: Realization, t_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The biases in the corrupted IMU at times ``t_rel`` (N,) [s since the first sample]: ``(b_a, b_g)``
    each (R, N, 3) [m/s², rad/s], the base bias times its schedule factor (as :func:`imu_errors`
    adds it to the step ending at that time; the white noise is not a bias)."""
    S = real.acc_factors.shape[1]
    if real.config.dynamic_bias == "segment":
        seg = segment_index(np.asarray(t_rel, dtype=float), real.config.segment_s, S)
    else:
        seg = np.zeros(len(t_rel), dtype=np.int64)
    return (real.acc_factors[:, seg, None] * real.b_a[:, None], real.gyro_factors[:, seg, None] * real.b_g[:, None])


def dvl_noise(real: Realization, n_epochs: int) -> np.ndarray:
    """Synthetic DVL noise (R, N, 3) [m/s], N(0, dvl_noise²) per axis and epoch."""
    out = np.empty((len(real.runs), n_epochs, 3))
    for i, r in enumerate(real.runs):
        out[i] = stream(real.seed, real.track, int(r), STREAM_DVL).standard_normal((n_epochs, 3))
    return real.config.dvl_noise * out


def to_rows(real: Realization) -> list[dict]:
    """One dict per run holding every draw of the realization (for realizations.parquet)."""
    rows = []
    for i, r in enumerate(real.runs):
        row = {"track": real.track, "run": int(r), "seed": real.seed, "schedule": real.config.schedule,
               "segment_s": real.config.segment_s, "dynamic_bias": real.config.dynamic_bias}
        for name, arr, comps in (("dv0", real.dv0, "ned"), ("dpsi0", real.dpsi0, "xyz"),
                                 ("ba", real.b_a, "xyz"), ("bg", real.b_g, "xyz"),
                                 ("dp0", real.dp0 if real.dp0 is not None else np.zeros((len(real.runs), 3)), "ned")):
            for j, c in enumerate(comps):
                row[f"{name}_{c}"] = float(arr[i, j])
        row["acc_factors"] = real.acc_factors[i].tolist()
        row["gyro_factors"] = real.gyro_factors[i].tolist()
        rows.append(row)
    return rows
