"""A sensor or filter plugin's mistakes are one line naming the plugin and its file, exit 2 (docs/sensors.md
and docs/plugins.md, "Errors"): an exception in any method (``__init__`` too), ``sys.exit``, a wrong
shape, NaN in R, H or an own option, an asymmetric R, a draw from numpy's global generator, a
singular covariance or a mis-shaped innovation of a filter — never a traceback, a filter blamed for
a sensor's bug, or a silent broadcast."""
from __future__ import annotations

import pandas as pd
import pytest

from conftest import assert_one_error_line, nespm

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

TWIN = """'''A test sensor plugin: two independent depth gauges, z = [D, D] [m], with a bug chosen by its option.'''
import sys
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.sensors import Measurement, Sensor, SensorOptions, register


@dataclass(frozen=True)
class TwinOptions(SensorOptions):
    std: float = 0.1
    interval: float | None = 2.0
    bug: str = ""
    gain: float = 1.0


class TwinMeasurement(Measurement):
    def __init__(self, z, opt, layout):
        self.z, self.layout, self.opt = z, layout, opt
        R = np.eye(2) * opt.std**2
        if opt.bug == "nan_R":
            R[1, 1] = np.nan
        if opt.bug == "asym_R":
            R[0, 1] = 0.5 * opt.std**2
        if opt.bug == "tiny_asym_R":
            R[0, 1] = 1e-14 * opt.std**2
        self.R = R

    def predict(self, nav):
        if self.opt.bug == "raise_predict":
            raise ZeroDivisionError("float division by zero")
        p = np.repeat(-nav.pos[:, 2:3], 2, axis=1) * self.opt.gain
        return p[:, 0] if self.opt.bug == "predict_shape" else p  # (R,): z - p would broadcast to (R, 2)

    def h(self, X, nav):
        return np.repeat(self.block(X, "pos")[..., 2:3], 2, axis=-1) * self.opt.gain

    def H(self, nav):
        if self.opt.bug == "raise_H":
            raise ValueError("could not broadcast input array from shape (4,1,15) into shape (4,2,15)")
        H = self.zeros_H(nav)
        H[..., :, self.layout.slice("pos").start + 2] = self.opt.gain
        if self.opt.bug == "nan_H":
            H[0, 0, 0] = np.nan
        if self.opt.bug == "H_shape":
            return H[:, :1]
        return H


@register("twin")
class Twin(Sensor):
    dim = 2
    labels = ("d1", "d2")
    observes = ("pos",)
    Options = TwinOptions

    def __init__(self, options=None):
        super().__init__(options)
        if self.opt.bug == "init":
            raise ValueError("invalid literal for int() with base 10: 'x'")
        if self.opt.bug == "init_nespm":
            raise NespmError("beacon file beacons.csv: no such file")
        if self.opt.bug == "dim0":
            self.dim = 0

    def true_values(self, truth):
        if self.opt.bug == "true_values":
            raise KeyError("lat")
        v = np.repeat(-truth.pos[:, 2:3], 2, axis=1) * self.opt.gain
        return v[:, :1] if self.opt.bug == "tv_shape" else v

    def synthesize(self, truth, seed, track, runs):
        if self.opt.bug == "global_rng":
            clean = self.true_values(truth)
            return clean + self.opt.std * np.random.standard_normal((len(runs),) + clean.shape)
        return super().synthesize(truth, seed, track, runs)

    def measurement(self, z, nav, ctx, layout):
        if self.opt.bug == "measurement":
            raise IndexError("index 3 is out of bounds for axis 0 with size 2")
        if self.opt.bug == "exit":
            sys.exit(0)
        return TwinMeasurement(z, self.opt, layout)
"""

BAD_FILTER = """import numpy as np
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register

@register("bad-ekf")
class BadEKF(ErrorStateFilter):
    option_defaults = {"bug": ""}

    def propagate(self, j0, j1, k=0):
        Q = self.process_noise(self.span(j0, j1), k)
        Phi = self.transition(j0, j1)
        self.P = Phi @ self.P @ np.swapaxes(Phi, -1, -2) + Q
        self.symmetrize()

    def update(self, meas, j_last):
        if self.options["bug"] == "exit":
            import sys
            sys.exit(0)
        H, nu = meas.H(self.nav), meas.innovation(self.nav)
        S = H @ self.P @ np.swapaxes(H, -1, -2) + meas.R
        K = np.swapaxes(np.linalg.solve(S, H @ self.P), -1, -2)
        self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.symmetrize()
        self.feedback((K @ nu[..., None])[..., 0])
        if self.options["bug"] == "nu_shape":
            return nu[:, :1], S
        return nu, S

    def covariance(self):
        if self.options["bug"] == "singular":
            P = self.P.copy(); P[:, 0, :] = 0; P[:, :, 0] = 0
            return P
        return self.P
"""

RUN = ["--dvl", "synthetic", "--tracks", "5", "--runs", "2", "--chunk-size", "2", "--window", "0:30", "--no-progress"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("plugins")
    (d / "twin.py").write_text(TWIN)
    (d / "bad_filter.py").write_text(BAD_FILTER)
    return d


def twin(files, tmp_path, *options):
    args = ["mc", "--sensor-plugin", files / "twin.py", "--state", "15", "--sensors", "dvl,twin", "--filters", "ekf"]
    for o in options:
        args += ["--sensor-option", o]
    return nespm(*args, *RUN, "--out", tmp_path / "out")


@pytest.mark.parametrize("bug, needles", [
    ("init", ["__init__ raised ValueError: invalid literal"]),
    ("init_nespm", ["beacon file beacons.csv: no such file"]),
    ("dim0", ["dim = 0"]),
    ("true_values", ["true_values raised KeyError"]),
    ("tv_shape", ["true_values returned shape (14, 1), expected (14, 2)"]),
    ("global_rng", ["synthesize drew from numpy's global random generator", "--jobs"]),
    ("measurement", ["measurement raised IndexError"]),
    ("exit", ["measurement called sys.exit(0)"]),
    ("nan_R", ["R holds NaN"]),
    ("asym_R", ["R is not symmetric"]),
    ("raise_H", ["H raised ValueError: could not broadcast"]),
    ("nan_H", ["H returned NaN or inf where the solution is finite"]),
    ("H_shape", ["H returned shape (2, 1, 15), expected (2, 2, 15)"]),
    ("raise_predict", ["predict raised ZeroDivisionError: float division by zero"]),  # not blamed on innovation
    ("predict_shape", ["predict returned shape (2,), expected (2, 2)"]),  # the shape it returned, not z - p's
])
def test_a_sensor_plugins_mistake_names_the_sensor_and_its_file(files, tmp_path, bug, needles):
    rc, out, err = twin(files, tmp_path, f"twin.bug={bug}")
    line = assert_one_error_line(rc, out, err, f"sensor twin ({(files / 'twin.py').resolve()})", *needles)
    assert "ekf" not in line  # the filter that called the sensor is not blamed


def test_a_nan_own_option_is_named(files, tmp_path):
    assert_one_error_line(*twin(files, tmp_path, "twin.gain=nan"), "--sensor-option twin.gain=nan", "NaN")


def test_an_r_asymmetric_by_round_off_is_symmetrized(files, tmp_path):
    """A 1e-14 relative asymmetry (below SYM_TOL = 1e-9) is used as (R + Rᵀ)/2: the numbers of the
    symmetric R to round-off."""
    rc, _, err = twin(files, tmp_path / "a")
    assert rc == 0, err
    rc, _, err = twin(files, tmp_path / "b", "twin.bug=tiny_asym_R")
    assert rc == 0, err
    a = pd.read_parquet(tmp_path / "a" / "out" / "metrics.parquet")["nis_twin"].to_numpy()
    b = pd.read_parquet(tmp_path / "b" / "out" / "metrics.parquet")["nis_twin"].to_numpy()
    assert abs(b - a).max() < 1e-9 * abs(a).max(), (a, b)


@pytest.mark.parametrize("bug, needles", [
    ("nu_shape", ["update for sensor dvl returned nu of shape (2, 1)", "expected (2, 3)"]),
    ("singular", ["covariance() at epoch 0 is not positive definite"]),
    ("exit", ["update called sys.exit(0)"]),
])
def test_a_filter_plugins_mistake_names_the_filter_and_its_file(files, tmp_path, bug, needles):
    rc, out, err = nespm("mc", "--filter-plugin", files / "bad_filter.py", "--filters", "bad-ekf",
                         "--filter-option", f"bad-ekf.bug={bug}", *RUN, "--out", tmp_path / "out")
    assert_one_error_line(rc, out, err, f"filter bad-ekf ({(files / 'bad_filter.py').resolve()})", *needles)


def test_sys_exit_while_a_plugin_is_imported_is_one_line(tmp_path):
    p = tmp_path / "quits.py"
    p.write_text("import sys\nsys.exit(0)\n")
    rc, out, err = nespm("mc", "--sensor-plugin", p, "--sensors", "dvl", *RUN, "--out", tmp_path / "out")
    assert_one_error_line(rc, out, err, "quits.py", "sys.exit(0)")


def test_a_class_with_dim_zero_or_an_unknown_block_names_the_sensor(tmp_path):
    for name, body, needle in (("zero", "dim = 0\n    observes = ('pos',)", "dim = 0"),
                               ("badblock", "dim = 1\n    observes = ('position',)", "observes 'position'")):
        p = tmp_path / f"{name}.py"
        p.write_text("from nespm_cli.sensors import Sensor, register\n\n\n"
                     f"@register('{name}')\nclass S(Sensor):\n    {body}\n")
        rc, out, err = nespm("mc", "--sensor-plugin", p, "--sensors", f"dvl,{name}", *RUN, "--out", tmp_path / name)
        assert_one_error_line(rc, out, err, f"sensor {name} ({p.resolve()})", needle)
