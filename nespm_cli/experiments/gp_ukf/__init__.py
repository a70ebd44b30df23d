"""The GP-UKF experiment of gp-ukf.md section 6 (docs/gp-ukf.md, "The experiment"), one concept a module:

* :mod:`~nespm_cli.experiments.gp_ukf.spec`: its name, filters, state units and :class:`GPSpec` with its checks
  (light: NumPy only);
* :mod:`~nespm_cli.experiments.gp_ukf.model`: the true model, GP-h on the measured states, the simulated runs;
* :mod:`~nespm_cli.experiments.gp_ukf.training`: the GP models fitted on the training run, ``OUT/models.npz``;
* :mod:`~nespm_cli.experiments.gp_ukf.run`: the chunks, the assembly and :func:`run_gp_experiment`.

The package re-exports the spec's names at once and :func:`run_gp_experiment` on first use (PEP 562
``__getattr__``), so that importing the spec for the ``nespm`` command's option defaults imports neither
the models nor pandas (tests/test_startup.py).
"""
from __future__ import annotations

from nespm_cli.experiments.gp_ukf.spec import EXPERIMENT, FILTERS, STATE_UNITS, GPSpec, validate

__all__ = ["EXPERIMENT", "FILTERS", "STATE_UNITS", "GPSpec", "validate", "run_gp_experiment"]


def __getattr__(name: str):
    """``run_gp_experiment`` from :mod:`~nespm_cli.experiments.gp_ukf.run`, imported on first use."""
    if name == "run_gp_experiment":
        from nespm_cli.experiments.gp_ukf.run import run_gp_experiment

        return run_gp_experiment
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
