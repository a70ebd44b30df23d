"""The GP-UKF experiment's true model (gp-ukf.md section 6): the ideal UKF's process and observation models
(the simulator's REMUS 100 by RK4, the measured states), GP-h on the measured states, and the 5 Hz simulated
runs of a :class:`~nespm_cli.experiments.gp_ukf.spec.GPSpec` with yaw unwrapped (docs/gp-ukf.md, "The
experiment"; the runner is :mod:`nespm_cli.experiments.gp_ukf.run`).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.experiments.gp_ukf.spec import OUTPUT_HZ, GPSpec
from nespm_cli.filters.gp_ukf import DeviationModel
from nespm_cli.learn.gp import GPModel
from nespm_cli.vehicles import Remus100, SensorSuite, simulate_runs
from nespm_cli.vehicles.remus100 import IPSI, saturate
from nespm_cli.vehicles.sensors import I_PSI_MEAS, MEASURED_STATES

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


#: the state column each of the 10 measurements reads (paper order)
MEAS_COLUMNS = np.asarray(MEASURED_STATES)


def _observe(x: np.ndarray) -> np.ndarray:
    """The ideal h: the measured components of x (..., 12) -> (..., 10), yaw unwrapped."""
    return np.asarray(x)[..., MEAS_COLUMNS]


TRUE_H = DeviationModel(_observe, lambda x0, D: (x0[..., MEAS_COLUMNS], D[..., MEAS_COLUMNS]))


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


def simulate_prepared(spec: GPSpec, runs) -> tuple:
    """``(SimResult, x, u, z)`` of ``runs`` at the experiment's 5 Hz (:func:`prepare`: yaw unwrapped)."""
    sim = simulate_runs(len(runs), duration_s=spec.duration_s, seed=spec.seed, runs=list(runs),
                        output_hz=OUTPUT_HZ, keep_fine=False)
    return sim, *prepare(sim)


def ideal_Q(x: np.ndarray, u: np.ndarray, f: TrueModel) -> np.ndarray:
    """Fixed Q (12, 12) of the ideal UKF: diag of the mean square one-step error of ``f`` on one
    run's truth ``x`` (T, 12), commands ``u`` (T, 3)."""
    e = x[1:] - f(x[:-1], u[:-1])
    return np.diag(np.mean(e**2, axis=0))
