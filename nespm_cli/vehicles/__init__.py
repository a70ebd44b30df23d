"""Vehicle simulation: a batched 6-DOF REMUS 100 (gp-ukf.md eqs 1-2, section 6).

Modules:

* :mod:`.remus100` -- the vehicle model ``M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau`` with
  Prestero's (2001) coefficients and a fixed-step RK4 integrator;
* :mod:`.sensors`  -- virtual DVL, gyroscope, accelerometer (tilt), compass and depth sensor with
  additive Gaussian noise and 12-bit quantisation;
* :mod:`.guidance` -- helix path, line-of-sight guidance and the speed / heading / depth PIDs;
* :mod:`.simulate` -- closed-loop batched runs (:func:`simulate_runs`) and A-KIT track export
  (:func:`to_track`, :func:`write_tracks`, which never overwrites tracks it did not write:
  :func:`check_simulate_folder`).

See ``docs/remus100.md`` for the model, its sources and every choice the paper leaves open.
"""
from __future__ import annotations

from nespm_cli.vehicles.remus100 import COMMAND_NAMES, STATE_NAMES, Remus100, Remus100Params
from nespm_cli.vehicles.sensors import MEASUREMENT_NAMES, SensorSuite
from nespm_cli.vehicles.guidance import GuidanceGains, Helix
from nespm_cli.vehicles.simulate import (SimResult, check_simulate_folder, simulate_record, simulate_runs, to_track,
                                        write_tracks)

__all__ = [
    "COMMAND_NAMES",
    "MEASUREMENT_NAMES",
    "STATE_NAMES",
    "GuidanceGains",
    "Helix",
    "Remus100",
    "Remus100Params",
    "SensorSuite",
    "SimResult",
    "check_simulate_folder",
    "simulate_record",
    "simulate_runs",
    "to_track",
    "write_tracks",
]
