"""The GP-UKF experiment's spec (gp-ukf.md section 6): its name, filters and state units, what
determines its numbers (:class:`GPSpec`) and its checks. Light (NumPy only), so that the ``nespm``
command's option defaults (``default(GPSpec, ...)``) and the report cost no import of the models
(:mod:`nespm_cli.experiments.gp_ukf.model`) or the runner (:mod:`nespm_cli.experiments.gp_ukf.run`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError

EXPERIMENT = "gp-ukf"  # the manifest's "experiment"
FILTERS = ("ukf-ideal", "gp-ukf")
#: unit of each state's error, in the order of ``nespm_cli.vehicles.STATE_NAMES`` (u v w p q r X Y Z θ ψ φ)
STATE_UNITS = ("m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s", "m", "m", "m", "rad", "rad", "rad")
#: GP-h inputs: "own" = each measurement's GP takes the one state it measures; "state" = every
#: measurement's GP takes the whole state (the paper's GP-h(x); its fits degenerate, docs/gp-ukf.md)
H_INPUTS = ("own", "state")
OUTPUT_HZ = 5.0  # the paper's capture and filter rate
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
