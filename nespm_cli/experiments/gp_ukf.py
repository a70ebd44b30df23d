"""The GP-UKF experiment of gp-ukf.md section 6: ideal UKF against GP-UKF on REMUS 100 helix runs.

Stages (docs/gp-ukf.md, "The experiment"):

1. **Training.** Run ``train_run`` (0: "the first set of data") is simulated at 5 Hz; the
   GP-f / GP-h training pairs are a seeded random 40 % of its samples
   (:func:`~nespm_cli.filters.gp_ukf.narx_training_data`), capped at ``max_points`` per model.
   The 22 GP outputs (12 state changes, 10 measurements) are fitted as 22 independent tasks
   in parallel (``parallel_map``) and merged into the two models (GP-h: by default one
   single-input GP per measurement on the state it measures, ``h_inputs="own"``; an output
   the optimizer left at its default start is refitted); the ideal UKF's fixed Q is
   the mean square one-step error of the true model on the same run. Everything is written
   once to ``OUT/models.npz`` and reused on resume.
2. **Evaluation.** Runs ``0 .. runs-1`` (the paper's Table 3 is "for 20 runs"; run 0 is
   evaluated too and flagged ``training_run``) in chunks of ``chunk_size`` runs. A chunk
   simulates its runs (a run depends only on ``(seed, run)``), draws each run's initial
   estimate from ``SeedSequence(seed, spawn_key=(run, 1))`` and runs ``ukf-ideal`` and
   ``gp-ukf`` batched over its runs. Each finished chunk writes
   ``chunks/series-<filter>-<first>.parquet`` then ``chunks/metrics-<filter>-<first>.parquet``
   atomically (the metrics file marks it complete); a re-run computes only what is missing.
3. **Assembly.** ``metrics.parquet`` (filter x run x state), ``epochs.parquet`` (filter x
   run x epoch at 1 Hz) and ``manifest.json`` (``"experiment": "gp-ukf"``).

Yaw is handled unwrapped: the true ψ and the compass reading are unwrapped along time per
run (the compass noise, 0.5°, is far below π), so the filters' state and their h are
continuous; the yaw error is wrapped to (−π, π] before any metric.
"""
from __future__ import annotations

import dataclasses
import io
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.chunks import write_chunk
from nespm_cli.experiments.store import ResultsFolder, Task, write_atomic, write_parquet_atomic
from nespm_cli.filters.gp_ukf import DeviationModel, GPUKFModels, gp_ukf, ideal_ukf, narx_training_data
from nespm_cli.learn.gp import GPModel, theta_default
from nespm_cli.vehicles import STATE_NAMES, Remus100, SensorSuite, simulate_runs
from nespm_cli.vehicles.remus100 import IPSI, saturate
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.vehicles.sensors import I_PSI_MEAS, MEASURED_STATES

EXPERIMENT = "gp-ukf"
#: GP-h inputs: "own" = each measurement's GP takes the one state it measures; "state" = every
#: measurement's GP takes the whole state (the paper's GP-h(x); its fits degenerate, docs/gp-ukf.md)
H_INPUTS = ("own", "state")
FILTERS = ("ukf-ideal", "gp-ukf")
STATE_UNITS = ("m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s", "m", "m", "m", "rad", "rad", "rad")
OUTPUT_HZ = 5.0  # the paper's capture and filter rate
EPOCH_STRIDE = 5  # epochs.parquet keeps every 5th sample (1 Hz)
INIT_STREAM = 1  # spawn_key stream of the initial-estimate error (stream 0: the simulator's sensors)
#: std of the initial estimate error per state (the filter's P0 = diag(std²)); paper order. The
#: launch position is known to 0.1 m (the simulator's controller dead-reckons from it too)
P0_STD = (0.05, 0.05, 0.05, 0.01, 0.01, 0.01, 0.1, 0.1, 0.1,
          float(np.radians(1.0)), float(np.radians(1.0)), float(np.radians(1.0)))


@dataclass(frozen=True)
class GPSpec:
    """Everything that determines the experiment's numbers (``jobs``, backend do not)."""

    runs: int = 20
    seed: int = 0
    duration_s: float = 800.0
    max_points: int = 500
    n_restarts: int = 0
    fraction: float = 0.4
    train_run: int = 0
    chunk_size: int = 10
    rk4_substeps: int = 4
    h_inputs: str = "own"
    p0_std: tuple = P0_STD

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["p0_std"] = [float(v) for v in self.p0_std]
        return d


def validate(spec: GPSpec) -> GPSpec:
    """Check the options; one-line :class:`NespmError` naming the option otherwise."""
    if spec.runs < 1:
        raise NespmError(f"--runs must be at least 1, got {spec.runs}")
    if spec.chunk_size < 1:
        raise NespmError(f"--chunk-size must be at least 1, got {spec.chunk_size}")
    steps = spec.duration_s * OUTPUT_HZ
    if not (np.isfinite(spec.duration_s) and spec.duration_s >= 10.0 and abs(steps - round(steps)) < 1e-9):
        raise NespmError(f"--duration must be at least 10 s and a multiple of {1 / OUTPUT_HZ:g} s, "
                         f"got {spec.duration_s:g}")
    if spec.max_points < 10:
        raise NespmError(f"--max-points must be at least 10, got {spec.max_points}")
    if spec.n_restarts < 0:
        raise NespmError(f"--restarts must be >= 0, got {spec.n_restarts}")
    if not 0 < spec.fraction <= 1:
        raise NespmError(f"--fraction must be in (0, 1], got {spec.fraction:g}")
    if spec.train_run < 0:
        raise NespmError(f"--train-run must be >= 0, got {spec.train_run}")
    if spec.h_inputs not in H_INPUTS:
        raise NespmError(f"--h-inputs: choose {' or '.join(H_INPUTS)}, got {spec.h_inputs!r}")
    if spec.rk4_substeps < 1:
        raise NespmError(f"--rk4-substeps must be at least 1, got {spec.rk4_substeps}")
    p0 = np.asarray(spec.p0_std, dtype=float)
    if p0.shape != (12,) or not np.all(np.isfinite(p0) & (p0 > 0)):
        raise NespmError("p0_std: need 12 positive initial-error stds (paper state order)")
    return dataclasses.replace(spec, p0_std=tuple(float(v) for v in p0))


# --- models -----------------------------------------------------------------------------------

class TrueModel:
    """The ideal UKF's process model: the simulator's REMUS 100, RK4 over one 0.2 s filter step.

    ``substeps`` classical RK4 steps of ``dt / substeps`` with the command held (the 5 Hz sample;
    the simulator changes it at 10 Hz, which is the model error the ideal UKF's Q covers). The
    ``deviations`` method propagates the sigma-point offsets as offsets, so that the UT's
    ~1/α² weights never meet the rounding of states like X ≈ 60 m (docs/gp-ukf.md, Numerics).
    """

    def __init__(self, params=None, dt: float = 1.0 / OUTPUT_HZ, substeps: int = 4):
        self.model = Remus100() if params is None else Remus100(params)
        self.h = dt / substeps
        self.substeps = substeps

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """x (..., 12), u (..., 3) -> x after one filter step (..., 12)."""
        x = np.asarray(x, dtype=float)
        lead = x.shape[:-1]
        xf = x.reshape(-1, 12)
        c = saturate(self.model.params, np.broadcast_to(u, lead + (3,)).reshape(-1, 3))
        d, h = self.model.derivative, self.h
        for _ in range(self.substeps):
            k1 = d(xf, c)
            k2 = d(xf + (0.5 * h) * k1, c)
            k3 = d(xf + (0.5 * h) * k2, c)
            k4 = d(xf + h * k3, c)
            xf = xf + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        return xf.reshape(lead + (12,))

    def deviations(self, x0: np.ndarray, D: np.ndarray, u: np.ndarray):
        """x0 (R, 12), D (R, S, 12), u (R, 3) -> (f(x0) (R, 12), f(x0 + D) − f(x0) (R, S, 12))."""
        R, S, n = D.shape
        c = saturate(self.model.params, np.asarray(u, dtype=float))
        call = np.concatenate([c[:, None], np.broadcast_to(c[:, None], (R, S, 3))], axis=1).reshape(-1, 3)
        h = self.h

        def rhs(a, b):  # derivative at the centre a (R, n) and its change at a + b (R, S, n)
            pts = np.concatenate([a[:, None], a[:, None] + b], axis=1).reshape(-1, n)
            k = self.model.derivative(pts, call).reshape(R, S + 1, n)
            return k[:, 0], k[:, 1:] - k[:, :1]

        a, b = np.asarray(x0, dtype=float), np.asarray(D, dtype=float)
        for _ in range(self.substeps):
            k1, d1 = rhs(a, b)
            k2, d2 = rhs(a + (0.5 * h) * k1, b + (0.5 * h) * d1)
            k3, d3 = rhs(a + (0.5 * h) * k2, b + (0.5 * h) * d2)
            k4, d4 = rhs(a + h * k3, b + h * d3)
            a = a + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
            b = b + (h / 6.0) * (d1 + 2.0 * (d2 + d3) + d4)
        return a, b


_MEAS = np.asarray(MEASURED_STATES)


def _observe(x: np.ndarray) -> np.ndarray:
    """The ideal h: the measured components of x (..., 12) -> (..., 10), yaw unwrapped."""
    return np.asarray(x)[..., _MEAS]


TRUE_H = DeviationModel(_observe, lambda x0, D: (x0[..., _MEAS], D[..., _MEAS]))


class MeasuredStateGP:
    """GP-h as one single-input GP per measurement, each on the state it measures.

    Duck-types the part of :class:`~nespm_cli.learn.gp.GPModel` that
    :class:`~nespm_cli.filters.gp_ukf.GPUKFModels` uses for its observation model
    (``predict``, ``predict_offsets``, ``noise_var``); inputs are whole states (..., 12) and
    output j reads column ``cols[j]``.
    """

    def __init__(self, gps: list[GPModel], cols):
        self.gps = list(gps)
        self.cols = np.asarray(cols, dtype=int)

    @property
    def n_train(self) -> int:
        return self.gps[0].n_train

    @property
    def fit_warnings(self) -> list[str]:
        return [w.replace("output 0", f"output {j}", 1) for j, g in enumerate(self.gps) for w in g.fit_warnings]

    def predict(self, X, return_var: bool = True, noise: bool = True):
        X = np.asarray(X, dtype=float)
        outs = [g.predict(X[..., [c]], return_var, noise) for g, c in zip(self.gps, self.cols)]
        if not return_var:
            return np.concatenate(outs, axis=-1)
        return np.concatenate([o[0] for o in outs], axis=-1), np.concatenate([o[1] for o in outs], axis=-1)

    def predict_offsets(self, X0, dX):
        outs = [g.predict_offsets(np.asarray(X0)[..., [c]], np.asarray(dX)[..., [c]])
                for g, c in zip(self.gps, self.cols)]
        return np.concatenate([o[0] for o in outs], axis=-1), np.concatenate([o[1] for o in outs], axis=-1)

    def noise_var(self) -> np.ndarray:
        return np.concatenate([g.noise_var() for g in self.gps])

    def arrays(self, prefix: str = "h") -> dict:
        out = {f"{prefix}{j}/{k}": v for j, g in enumerate(self.gps) for k, v in g.arrays().items()}
        out[f"{prefix}_cols"] = self.cols
        return out

    @classmethod
    def from_arrays(cls, a, prefix: str = "h") -> "MeasuredStateGP":
        cols = np.asarray(a[f"{prefix}_cols"], dtype=int)
        return cls([GPModel.from_arrays(a, f"{prefix}{j}/") for j in range(len(cols))], cols)


def ideal_R(suite: SensorSuite | None = None) -> np.ndarray:
    """The ideal UKF's R (10, 10): diag(σ² + LSB²/12), the sensor noise plus 12-bit rounding."""
    s = SensorSuite() if suite is None else suite
    return np.diag(s.sigma**2 + s.lsb**2 / 12.0)


def prepare(sim) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, u, z) of a :class:`SimResult` with yaw unwrapped along time (truth and compass)."""
    x = sim.x.copy()
    z = sim.z.copy()
    x[..., IPSI] = np.unwrap(x[..., IPSI], axis=1)
    z[..., I_PSI_MEAS] = np.unwrap(z[..., I_PSI_MEAS], axis=1)
    # same branch as the truth at t = 0 (the compass error is a fraction of a degree)
    z[..., I_PSI_MEAS] -= 2 * np.pi * np.round((z[:, :1, I_PSI_MEAS] - x[:, :1, IPSI]) / (2 * np.pi))
    return x, sim.u.astype(float), z


def _simulate(spec: GPSpec, runs) -> tuple:
    sim = simulate_runs(len(runs), duration_s=spec.duration_s, seed=spec.seed, runs=list(runs),
                        output_hz=OUTPUT_HZ, keep_fine=False)
    return sim, *prepare(sim)


FIT_RETRIES = 2  # refits of an output left at the default start, each with one random restart
RETRY_SEED_STEP = 1000


def subsample(n: int, max_points: int, seed: int) -> np.ndarray:
    """Rows kept of ``n``: all, or the seeded random ``max_points`` that ``GPModel.fit`` would keep."""
    if n <= max_points:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_points, replace=False))


def _fit_output(kind: str, j: int, X: np.ndarray, y: np.ndarray, n_restarts: int,
                seed: int) -> tuple[str, int, dict, float, int]:
    """Fit one GP output on its (already subsampled) rows, a worker task.

    gp.py's L-BFGS-B sometimes stops at the default start (its first step makes K singular,
    the objective returns a constant with zero gradient and the line search gives up). Such an
    output is refitted up to :data:`FIT_RETRIES` times with one random restart, seeds
    ``seed + 1000 k``; the fit keeps the best likelihood of its starts. Returns
    ``(kind, j, GPModel.arrays(), seconds, retries used)``.
    """
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    with threadpool_limits(1):  # multi-threaded BLAS is many times slower on a shared CPU
        gp = GPModel(len(X), n_restarts, seed).fit(X, y[:, None])
        k = 0
        while at_default_start(gp)[0] and k < FIT_RETRIES:
            k += 1
            gp = GPModel(len(X), max(1, n_restarts), seed + RETRY_SEED_STEP * k).fit(X, y[:, None])
    return kind, j, gp.arrays(), time.perf_counter() - t0, k


def at_default_start(gp: GPModel) -> np.ndarray:
    """(d_out,) True where the optimizer returned the default start unchanged (a failed first
    line search: gp.py's L-BFGS-B stops there when its first step makes K singular)."""
    t0 = np.exp(theta_default(gp.d_in))
    return (gp.const == t0[0]) & (gp.noise == t0[-1]) & np.all(gp.length == t0[1:-1], axis=1)


def merge_outputs(parts: list[dict]) -> GPModel:
    """One :class:`GPModel` from single-output models fitted on the same rows (same seed, X).

    Output j's arrays are concatenated in order; the result predicts exactly as the parts do.
    """
    first = parts[0]
    for p in parts[1:]:
        if not np.array_equal(p["X_train"], first["X_train"]):
            raise NespmError("merge_outputs: the single-output GPs were fitted on different rows")
    metas = [json.loads(str(p["meta"])) for p in parts]
    warnings = [w.replace("output 0", f"output {j}", 1) for j, m in enumerate(metas) for w in m["fit_warnings"]]
    meta = dict(metas[0], fit_warnings=warnings)
    arrays = {"X_train": first["X_train"], "x_mean": first["x_mean"], "x_scale": first["x_scale"],
              "meta": np.array(json.dumps(meta))}
    for k in ("Y_train", "y_mean", "y_scale", "const", "length", "noise", "log_marginal_likelihood"):
        arrays[k] = np.concatenate([np.asarray(p[k]) for p in parts], axis=-1 if k == "Y_train" else 0)
    return GPModel.from_arrays(arrays)


def ideal_Q(x: np.ndarray, u: np.ndarray, f: TrueModel) -> np.ndarray:
    """Fixed Q (12, 12) of the ideal UKF: diag of the mean square one-step error of ``f`` on one
    run's truth ``x`` (T, 12), commands ``u`` (T, 3)."""
    e = x[1:] - f(x[:-1], u[:-1])
    return np.diag(np.mean(e**2, axis=0))


def _save_npz_atomic(path: Path, arrays: dict) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, lambda tmp: tmp.write_bytes(buf.getvalue()))


def train_models(spec: GPSpec, out: Path, jobs: int, backend: str, scheduler: str | None,
                 progress=None) -> dict:
    """Fit (or load) ``OUT/models.npz``; return its summary (fit seconds, training sizes, learnt
    noise std per output, the ideal Q's std, refits, fit warnings), stored in the manifest.

    ``progress``: optional callable(total, done) for a progress bar.
    """
    from nespm_cli.experiments.backend import parallel_map

    path = out / "models.npz"
    if path.exists():
        with np.load(path, allow_pickle=False) as a:
            info = json.loads(str(a["experiment_info"]))
        return info
    t0 = time.perf_counter()
    _, x, u, z = _simulate(spec, [spec.train_run])
    x, u, z = x[0], u[0], z[0]
    Xf, Yf, Xh, Yh = narx_training_data(x, u, z, spec.fraction, spec.seed)
    # the seeds of fit_gp_ukf_models (GP-f seed, GP-h seed + 1) and GPModel's subsample
    kf, kh = subsample(len(Xf), spec.max_points, spec.seed), subsample(len(Xh), spec.max_points, spec.seed + 1)
    Xf, Yf, Xh, Yh = Xf[kf], Yf[kf], Xh[kh], Yh[kh]
    tasks = [("f", j, Xf, Yf[:, j], spec.n_restarts, spec.seed) for j in range(Yf.shape[1])]
    own = spec.h_inputs == "own"
    tasks += [("h", j, Xh[:, [_MEAS[j]]] if own else Xh, Yh[:, j], spec.n_restarts, spec.seed + 1)
              for j in range(Yh.shape[1])]
    retries = {}
    parts: dict = {"f": {}, "h": {}}
    cpu = 0.0
    if progress:
        progress(len(tasks), 0)
    for done, (kind, j, arrays, secs, k) in enumerate(parallel_map(_fit_output, tasks, jobs, backend, scheduler), 1):
        parts[kind][j] = arrays
        cpu += secs
        if k:
            retries[f"{kind}{j}"] = k
        if progress:
            progress(len(tasks), done)
    gf = merge_outputs([parts["f"][j] for j in range(Yf.shape[1])])
    hp = [parts["h"][j] for j in range(Yh.shape[1])]
    gh = MeasuredStateGP([GPModel.from_arrays(p) for p in hp], _MEAS) if own else merge_outputs(hp)
    f = TrueModel(substeps=spec.rk4_substeps)
    # ARD pushes the length scale of an irrelevant input to its upper bound: expected, not listed
    notable = lambda w: [m for m in w if "length scale" not in m or "1e+04" not in m]  # noqa: E731
    info = {"fit_seconds": round(time.perf_counter() - t0, 3), "fit_cpu_seconds": round(cpu, 3),
            "n_train_f": int(gf.n_train), "n_train_h": int(gh.n_train),
            "noise_std_f": [float(v) for v in np.sqrt(gf.noise_var())],
            "noise_std_h": [float(v) for v in np.sqrt(gh.noise_var())],
            "q_ideal_std": [float(v) for v in np.sqrt(np.diag(ideal_Q(x, u, f)))],
            "fit_warnings": {"f": notable(gf.fit_warnings), "h": notable(gh.fit_warnings)},
            "refits": dict(sorted(retries.items())),
            "at_default_start": [f"f{j}" for j in np.flatnonzero(at_default_start(gf))]
            + [f"h{j}" for j, p in enumerate(hp) if at_default_start(GPModel.from_arrays(p))[0]]}
    arrays = {**gf.arrays("f/"), **gh.arrays("h" if own else "h/")}
    arrays["h_inputs"] = np.array(spec.h_inputs)
    for name in ("f_states", "h_states"):  # the layout of GPUKFModels.save: all states are inputs
        arrays[name] = np.array([], dtype=int)
        arrays[name + "_all"] = np.array(True)
    arrays["ideal_Q"] = np.diag(np.asarray(info["q_ideal_std"]) ** 2)
    arrays["ideal_R"] = ideal_R()
    arrays["experiment_info"] = np.array(json.dumps(info))
    _save_npz_atomic(path, arrays)
    return info


def load_models(out: Path) -> tuple[GPUKFModels, np.ndarray, np.ndarray]:
    """``(GP-UKF models, ideal Q (12, 12), ideal R (10, 10))`` from ``OUT/models.npz``."""
    path = Path(out) / "models.npz"
    try:
        with np.load(path, allow_pickle=False) as a:
            if str(a["h_inputs"]) == "own":
                models = GPUKFModels(GPModel.from_arrays(a, "f/"), MeasuredStateGP.from_arrays(a, "h"))
            else:
                models = GPUKFModels.load(path)
            return models, np.asarray(a["ideal_Q"]), np.asarray(a["ideal_R"])
    except (OSError, KeyError, ValueError) as exc:
        raise NespmError(f"{path}: unreadable model file ({exc.__class__.__name__}); delete it to refit") from None


# --- chunks -----------------------------------------------------------------------------------

def _chunk_name(kind: str, filt: str, first: int) -> str:
    return f"{kind}-{filt}-{first:06d}.parquet"


def initial_estimate(spec: GPSpec, runs, x0_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x̂_0 (R, 12) = truth + N(0, P0) drawn per run from SeedSequence(seed, spawn_key=(run, 1)); P0 (12, 12)."""
    std = np.asarray(spec.p0_std, dtype=float)
    xi = np.stack([np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(int(r), INIT_STREAM)))
                   .standard_normal(12) for r in runs])
    return x0_true + std * xi, np.diag(std**2)


def state_errors(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """est − truth (R, T, 12) with the yaw error wrapped to (−π, π]."""
    e = est - truth
    e[..., IPSI] = wrap_angle(e[..., IPSI])
    return e


def run_chunk(spec: GPSpec, first: int, out_dir: str, experiment: str = "", filters: tuple = FILTERS) -> tuple[str, dict]:
    """Compute one chunk of ``filters`` and write its files (carrying the folder's ``experiment``
    digest, :mod:`nespm_cli.experiments.chunks`); return ``(chunk key, timings)``."""
    from threadpoolctl import threadpool_limits

    chunks = Path(out_dir) / "chunks"
    runs = np.arange(first, min(first + spec.chunk_size, spec.runs))
    todo = list(filters)
    timings: dict = {}
    key = f"{first:06d}"
    if not todo:
        return key, timings
    with threadpool_limits(1):
        sim, x, u, z = _simulate(spec, runs)
        x0, P0 = initial_estimate(spec, runs, x[:, 0])
        models, Q, R = load_models(Path(out_dir))
        f = TrueModel(sim.params, substeps=spec.rk4_substeps)
        T = x.shape[1]
        for name in todo:
            t0 = time.perf_counter()
            if name == "ukf-ideal":
                res = ideal_ukf(x0, P0, u, z, f, TRUE_H, Q, R, keep_cov=False)
            else:
                res = gp_ukf(x0, P0, u, z, models, keep_cov=False)
            secs = time.perf_counter() - t0
            e_post = state_errors(res.x_post, x)
            e_pred = state_errors(res.x_pred, x)
            with np.errstate(invalid="ignore"):
                rmse_c = np.sqrt(np.mean(e_post[:, 1:] ** 2, axis=1))  # k >= 1 (R, 12)
                rmse_p = np.sqrt(np.mean(e_pred[:, 1:] ** 2, axis=1))
                sd_c = np.sqrt(np.mean(res.var_post[:, 1:], axis=1))
            Rn, S = len(runs), len(STATE_NAMES)  # rows: run-major, state-minor
            metrics = pd.DataFrame({
                "filter": name, "run": np.repeat(runs, S), "state": np.tile(STATE_NAMES, Rn),
                "unit": np.tile(STATE_UNITS, Rn), "training_run": np.repeat(runs == spec.train_run, S),
                "rmse_correction": rmse_c.ravel(), "rmse_prediction": rmse_p.ravel(), "sd_correction": sd_c.ravel(),
                "diverged": np.repeat(res.diverged.astype(bool), S),
                "diverged_at": np.repeat(res.diverged_at.astype(np.int64), S), "seconds": secs / Rn,
            })
            metrics["seed"] = spec.seed
            metrics["n_samples"] = T - 1
            k = np.arange(0, T, EPOCH_STRIDE)
            K = len(k)
            series = {"filter": name, "run": np.repeat(runs, K), "epoch": np.tile(k, Rn),
                      "t": np.tile(sim.t[k], Rn)}
            for s, sname in enumerate(STATE_NAMES):
                series[f"err_{sname}"] = e_post[:, k, s].ravel()
            series["pred_err_X"] = e_pred[:, k, 6].ravel()
            series["pred_err_Y"] = e_pred[:, k, 7].ravel()
            series["sd_X"] = np.sqrt(res.var_post[:, k, 6]).ravel()
            series["sd_Y"] = np.sqrt(res.var_post[:, k, 7]).ravel()
            for s, sname in ((6, "X"), (7, "Y"), (8, "Z")):
                series[f"{sname}_true"] = x[:, k, s].ravel()
            series["cross_track"] = sim.cross_track[:, k].ravel()
            series["diverged"] = np.repeat(res.diverged, K)
            # series first: a metrics file marks the chunk complete
            write_chunk(pd.DataFrame(series), chunks / _chunk_name("series", name, first), experiment)
            write_chunk(metrics, chunks / _chunk_name("metrics", name, first), experiment)
            timings[f"{name}-{first}"] = round(secs, 3)
    return key, timings


# --- the runner -------------------------------------------------------------------------------

def assemble(folder: ResultsFolder, firsts: list[int]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``metrics.parquet`` and ``epochs.parquet`` (sorted) from exactly the expected chunk files,
    each verified (:meth:`ResultsFolder.verified`)."""
    out = folder.out
    order = {f: i for i, f in enumerate(FILTERS)}
    sidx = {s: i for i, s in enumerate(STATE_NAMES)}
    metrics = pd.concat([pd.read_parquet(p) for p in folder.verified(
        [_chunk_name("metrics", f, f0) for f in FILTERS for f0 in firsts])], ignore_index=True)
    metrics = metrics.sort_values(["filter", "run", "state"], key=lambda c: c.map(order) if c.name == "filter"
                                  else (c.map(sidx) if c.name == "state" else c), kind="stable").reset_index(drop=True)
    epochs = pd.concat([pd.read_parquet(p) for p in folder.verified(
        [_chunk_name("series", f, f0) for f in FILTERS for f0 in firsts])], ignore_index=True)
    epochs = epochs.sort_values(["filter", "run", "epoch"], key=lambda c: c.map(order) if c.name == "filter" else c,
                                kind="stable").reset_index(drop=True)
    write_parquet_atomic(metrics, out / "metrics.parquet")
    write_parquet_atomic(epochs, out / "epochs.parquet")
    return metrics, epochs


def run_gp_experiment(out_dir: str | Path, runs: int = 20, seed: int = 0, duration_s: float = 800.0,
                      max_points: int = GPSpec.max_points, n_restarts: int = GPSpec.n_restarts,
                      chunk_size: int = GPSpec.chunk_size, execution: Execution | None = None, *,
                      jobs: int | None = None, progress: bool | None = None, argv=None, backend: str | None = None,
                      scheduler: str | None = None, **options) -> pd.DataFrame:
    """Run (or resume) the GP-UKF experiment into ``out_dir``; return the metrics table.

    ``options``: the other :class:`GPSpec` fields (``fraction``, ``train_run``,
    ``rk4_substeps``, ``p0_std``). ``execution`` (or its fields as keyword arguments: ``jobs``,
    ``backend``, ``scheduler``, ``progress``, ``argv``) does not change the results. Schema of
    the outputs: docs/gp-ukf.md.
    """
    ex = Execution.of(execution, jobs=jobs, progress=progress, argv=argv, backend=backend, scheduler=scheduler)
    unknown = set(options) - {f.name for f in dataclasses.fields(GPSpec)}
    if unknown:
        raise NespmError(f"run_gp_experiment: unknown option(s) {', '.join(sorted(unknown))}")
    spec = validate(GPSpec(runs=runs, seed=seed, duration_s=float(duration_s), max_points=max_points,
                           n_restarts=n_restarts, chunk_size=chunk_size, **options))
    ex.check()
    jobs, backend, argv = ex.jobs, ex.backend, (list(ex.argv) if ex.argv is not None else None)
    out = Path(out_dir)
    opts = {"experiment": EXPERIMENT, **spec.as_dict()}
    if (out / "models.npz").exists() and not (out / "manifest.json").exists():
        raise NespmError(f"{out}: has models.npz but no manifest.json; use a new --out folder")
    folder = ResultsFolder(out, opts, argv).open(experiment=EXPERIMENT, seed=spec.seed, jobs=jobs, backend=backend)
    folder.manifest.setdefault("training", None)

    firsts = list(range(0, spec.runs, spec.chunk_size))
    folder.ignore_strays({_chunk_name(k, f, f0) for k in ("metrics", "series") for f in FILTERS for f0 in firsts})

    def missing(f0: int) -> tuple:
        return tuple(f for f in FILTERS if not (folder.done(_chunk_name("metrics", f, f0))
                                                and folder.done(_chunk_name("series", f, f0))))

    todo = [Task(f"{f0:06d}", (spec, f0, str(out.resolve()), folder.experiment, fs), 1)
            for f0 in firsts for fs in [missing(f0)] if fs]
    bar = None
    if progress and not (out / "models.npz").exists():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(TextColumn("[bold]gp-ukf[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), transient=False)
        bar.start()
    try:
        fit_task = None

        def fit_progress(total, done):
            nonlocal fit_task
            if bar is None:
                return
            if fit_task is None:
                fit_task = bar.add_task(f"fit {total} GP outputs on run {spec.train_run}", total=total)
            bar.update(fit_task, completed=done)

        fitted_now = not (out / "models.npz").exists()
        info = train_models(spec, out, jobs, backend, scheduler, fit_progress if fitted_now else None)
    finally:
        if bar is not None:
            bar.stop()
    folder.manifest["training"] = info
    folder.save()
    folder.run(run_chunk, todo, ex, "gp-ukf", unit="chunks")
    metrics, _ = assemble(folder, firsts)
    folder.finish(chunks=len(firsts))
    return metrics


