"""The PCRB row of an mc report follows a sensor's ``noise_schedule`` (issue 40): ``track_bound``
(experiments/pcrb_table.py) passes each sensor's R(t) factor to ``pcrb(r_factors=)``.

Embedded track 5, ``window 0:60``, a few runs (the bound has no noise draws: the numbers are exact).
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.experiments import pcrb_table
from nespm_cli.experiments.pcrb_table import track_bound
from nespm_cli.experiments.spec import Spec, track_inputs, validate
from nespm_cli.filters.pcrb import pcrb

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


def spec_of(schedule: str = "", runs: int = 2):
    """Track 5, 0-60 s, synthetic DVL, its ``noise_schedule`` ``schedule`` ("" none)."""
    opts = (("dvl", "noise_schedule", schedule),) if schedule else ()
    return validate(Spec(tracks=(5,), runs=runs, filters=("ekf",), dvl="synthetic", window="0:60",
                         sensor_options=opts))


def test_bound_of_a_dvl_step_is_pcrb_told_the_step(monkeypatch):
    """A x4 DVL-std step at 30 s: before it the bound is the constant-noise bound to 1e-12, after it the
    velocity bound is larger (measured: 6.0-7.1x the constant bound's variance for t > 40 s; root 0.0446 m/s
    against 0.0177 at 60 s), and it equals
    ``pcrb(r_factors=)`` called directly with the step's factors on the constant study's inputs."""
    calls = []

    def spy(*args, **kw):
        calls.append((args, dict(kw)))
        return pcrb(*args, **kw)

    monkeypatch.setattr(pcrb_table, "pcrb", spy)
    flat, labels = track_bound(spec_of(), 5, np.arange(2))
    args, kw = calls[-1]
    assert kw["r_factors"] is None  # no schedule: the bound as before, bit for bit
    step, _ = track_bound(spec_of("step:0=1,30=4"), 5, np.arange(2))
    chs = args[6]
    assert [ch.sensor.name for ch in chs] == ["dvl"]
    fac = np.where(chs[0].t >= 30.0, 4.0, 1.0)[None].repeat(chs[0].ok.shape[0], 0)
    direct = pcrb(*args, **{**kw, "r_factors": [fac]}).diag
    np.testing.assert_allclose(step[:1], direct, rtol=1e-12, atol=0)
    truth = track_inputs(spec_of(), 5)[1]
    e = truth.epoch_index
    t = truth.t[e] - truth.t[e[0]]
    vel = [labels.index(c) for c in ("dvN", "dvE", "dvD")]
    before, after = t < 29.5, t > 40.0
    np.testing.assert_allclose(step[:, before], flat[:, before], rtol=1e-12, atol=0)
    ratio = step[:, after][..., vel].sum(-1) / flat[:, after][..., vel].sum(-1)
    assert (ratio > 5.0).all()  # a x16 R: the velocity variance several times larger (no draws: exact)
    assert ratio.max() < 16.0  # but less than R's factor (the IMU between samples still informs)


def test_dynamic_schedule_gives_a_bound_per_run():
    """``dynamic:10:1:6``: each run draws its own factors, so each run has its own bound; run 3 alone
    gives the bound it has among runs 0-3 (its factors come from its own stream), and every run's
    velocity bound at the end lies between the constant bounds of x1 and x6."""
    spec = spec_of("dynamic:10:1:6", runs=4)
    many, labels = track_bound(spec, 5, np.arange(4))
    one, _ = track_bound(spec, 5, np.array([3]))
    np.testing.assert_allclose(one[0], many[3], rtol=1e-12, atol=0)
    vel = [labels.index(c) for c in ("dvN", "dvE", "dvD")]
    end = many[:, -1, vel].sum(-1)
    assert len(set(end.round(15))) == 4
    lo = track_bound(spec_of("step:0=1"), 5, [0])[0][0, -1, vel].sum()
    hi = track_bound(spec_of("step:0=6"), 5, [0])[0][0, -1, vel].sum()
    assert (end > lo).all() and (end < hi).all()
