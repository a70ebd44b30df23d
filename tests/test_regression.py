"""Seeded regression values: every built-in filter's per-run numbers, pinned to 1e-9.

Configuration (all of it determines the numbers):

- ``nespm mc`` in-process, seed 7, track 5 of the embedded tracks cut to its first 40 epochs
  (~39 s, written to a temporary A-KIT folder and passed as ``--data-dir``), 4 runs (0-3) in
  chunks of 2, every other option at its default (nominal scenario, constant schedule,
  recorded DVL, synthetic IMU, the packaged ProcessNet weights);
- all 7 filters of ``nespm_cli.filters.FILTERS`` in one command, with ``--jobs 2`` (worker
  processes); then one filter each, with ``--jobs 1`` (in-process), for
  ``--schedule dynamic`` (anukf-nespm), ``--scenario outage --outage-start 15
  --outage-length 10`` (ekf) and ``--dvl synthetic`` (ukf).

EXPECTED holds, per (case, filter), the per-run VRMSE [m/s], MRMSE [rad] and mean NEES of
metrics.parquet, and the mean over the 4 runs of each (ins has no covariance: NaN NEES).

These are regression values of the current implementation, computed once with it (commit
2541d01 plus the working tree of the day this file was written), NOT theoretical or published
values: they only say that the numbers have not changed. They were checked to be bit-identical
between two runs and between --jobs 1 and --jobs 2 (results do not depend on --jobs by design).
A change that moves any of them (filters, corruption draws, synthesis, metrics, track cut...)
must explain in its commit why the numbers change, and update them here in the same commit.

Cost: ~10-20 s (the seven filters over 40 epochs are one batch per chunk).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from conftest import nespm, write_short_tracks
from nespm_cli.filters import FILTERS

SEED, TRACK, EPOCHS, RUNS, CHUNK = 7, 5, 40, 4, 2
OUTAGE_START, OUTAGE_LENGTH = 15.0, 10.0
REL = 1e-9
NAN = math.nan

#: case -> (extra mc options, --jobs)
CASES = {
    "nominal": (["--filters", ",".join(FILTERS)], 2),
    "dynamic": (["--filters", "anukf-nespm", "--schedule", "dynamic"], 1),
    "outage": (["--filters", "ekf", "--scenario", "outage", "--outage-start", str(OUTAGE_START),
                "--outage-length", str(OUTAGE_LENGTH)], 1),
    "synthetic-dvl": (["--filters", "ukf", "--dvl", "synthetic"], 1),
}

# Regression values of the current implementation (see the module docstring): seed 7, the first
# 40 epochs of embedded track 5, runs 0-3. Any change of them must be explained in the commit.
EXPECTED = {
    ("nominal", "ins"): {
        "vrmse": [15.543255914788388, 16.947416581741535, 14.659779435435794, 10.068449731751615],
        "mrmse": [0.0041681690701997134, 0.0033622012464468447, 0.0014263774855436313, 0.002722669243699045],
        "nees": [NAN, NAN, NAN, NAN],
        "mean": {"vrmse": 14.304725415929333, "mrmse": 0.0029198542614723086, "nees": NAN},
    },
    ("nominal", "ekf"): {
        "vrmse": [0.03736315380346817, 0.0551442193910821, 0.08302362785695516, 0.045509044751669656],
        "mrmse": [0.002385134103758939, 0.0019763884524727844, 0.0014027126975896754, 0.0014254396478362115],
        "nees": [5.050313374043271, 2.9312667601693034, 1.2861693594264278, 1.9214867648811385],
        "mean": {"vrmse": 0.055260011450793775, "mrmse": 0.0017974187254144027, "nees": 2.797309064630035},
    },
    ("nominal", "ukf"): {
        "vrmse": [0.03735788792717467, 0.05514848987651148, 0.0830300839598843, 0.04552254591701877],
        "mrmse": [0.002385126470459454, 0.0019763818859878514, 0.0014027125303852543, 0.0014254419723280635],
        "nees": [5.049945760523863, 2.931536489375856, 1.2868644734694459, 1.922310186309803],
        "mean": {"vrmse": 0.055264751920147306, "mrmse": 0.001797415714790156, "nees": 2.797664227419742},
    },
    ("nominal", "ukf-nespm"): {
        "vrmse": [0.03736004989468965, 0.05514908885929184, 0.08302973523429763, 0.045523340811630064],
        "mrmse": [0.0023849961117763737, 0.0019762994573220517, 0.0014027142889201105, 0.0014253669295016963],
        "nees": [5.049487396459376, 2.931277608728108, 1.2868242143563915, 1.922199475584744],
        "mean": {"vrmse": 0.05526555369997729, "mrmse": 0.001797344196880058, "nees": 2.797447173782155},
    },
    ("nominal", "anekf"): {
        "vrmse": [0.03735762730051181, 0.05514095314205001, 0.08302173536602771, 0.0455037553171507],
        "mrmse": [0.002386022766584098, 0.0019769587493947524, 0.0014027304351343715, 0.0014258093859630357],
        "nees": [5.0506774664508285, 2.9317151563838046, 1.2857447657142889, 1.9213898755843641],
        "mean": {"vrmse": 0.05525601778143505, "mrmse": 0.0017978803342690644, "nees": 2.7973818160333215},
    },
    ("nominal", "anukf"): {
        "vrmse": [0.037352377710261786, 0.05514522272807194, 0.08302818415769499, 0.04551724981815197],
        "mrmse": [0.0023860151298714257, 0.001976952179042214, 0.0014027302672623137, 0.0014258117108401302],
        "nees": [5.050311108881581, 2.931984012191635, 1.2864378287664284, 1.9222116623461645],
        "mean": {"vrmse": 0.055260758603545165, "mrmse": 0.0017978773217540208, "nees": 2.7977361530464524},
    },
    ("nominal", "anukf-nespm"): {
        "vrmse": [0.03735453616324694, 0.055145820133028815, 0.08302783639294672, 0.04551804559098078],
        "mrmse": [0.0023858848283791747, 0.001976869494235266, 0.0014027324140127326, 0.0014257367043028918],
        "nees": [5.049854416448481, 2.9317254320276183, 1.2863982279622121, 1.9221008015999925],
        "mean": {"vrmse": 0.055261559570050814, "mrmse": 0.001797805860232516, "nees": 2.797519719509576},
    },
    ("dynamic", "anukf-nespm"): {
        "vrmse": [0.1219913928914149, 0.14606895059829839, 0.10463329160666536, 0.12940691546320093],
        "mrmse": [0.010107614345435428, 0.011042950504093776, 0.007380189020261164, 0.008686430682092683],
        "nees": [79.01792520373064, 84.0518175851284, 19.83536574509746, 58.73985496327391],
        "mean": {"vrmse": 0.1255251376398949, "mrmse": 0.009304296137970763, "nees": 60.41124087430761},
    },
    ("outage", "ekf"): {
        "vrmse": [0.06360035155407531, 0.07027397649871586, 0.08652758305857686, 0.06558649605098063],
        "mrmse": [0.002717443680832011, 0.0022689091718468344, 0.0014257390249012166, 0.0015932806282548662],
        "nees": [5.387269436796615, 3.2939805585663366, 1.3715808574549313, 2.0952597492372496],
        "mean": {"vrmse": 0.07149710179058716, "mrmse": 0.002001343126458732, "nees": 3.0370226505137827},
    },
    ("synthetic-dvl", "ukf"): {
        "vrmse": [0.031157712527707507, 0.05017733411253195, 0.08110633319324378, 0.039827494883164505],
        "mrmse": [0.0015797945102385533, 0.0013446932634265973, 0.001478630662635495, 0.0007573526806804281],
        "nees": [8.083254700663199, 3.8290303709250124, 3.742079752808236, 4.542029764828913],
        "mean": {"vrmse": 0.05056721867916194, "mrmse": 0.0012901177792452685, "nees": 5.04909864730634},
    },
}

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict:
    """``{case: results folder}`` of the four mc commands (computed once)."""
    root = tmp_path_factory.mktemp("regression")
    data = write_short_tracks(root / "data", (TRACK,), EPOCHS)
    out = {}
    for case, (extra, jobs) in CASES.items():
        rc, stdout, stderr = nespm("mc", "--tracks", TRACK, "--runs", RUNS, "--seed", SEED, "--chunk-size", CHUNK,
                                   "--jobs", jobs, "--no-progress", "--data-dir", data, "--out", root / case, *extra)
        assert rc == 0, stderr
        out[case] = root / case
    return out


def _rows(results: dict, case: str, filt: str) -> pd.DataFrame:
    m = pd.read_parquet(results[case] / "metrics.parquet")
    return m[m["filter"] == filt].sort_values("run").reset_index(drop=True)


def test_every_builtin_filter_is_pinned():
    """A new built-in filter needs its regression values here."""
    assert sorted(f for case, f in EXPECTED if case == "nominal") == sorted(FILTERS)
    assert sorted({case for case, _ in EXPECTED}) == sorted(CASES)


@pytest.mark.parametrize("case,filt", list(EXPECTED), ids=[f"{c}-{f}" for c, f in EXPECTED])
def test_regression_values(results, case, filt):
    m = _rows(results, case, filt)
    exp = EXPECTED[(case, filt)]
    assert m["run"].tolist() == list(range(RUNS))
    assert (m["seed"] == SEED).all() and (m["n_samples"] == EPOCHS).all() and not m["diverged"].any()
    for col in ("vrmse", "mrmse", "nees"):
        got = m[col].to_numpy(float)
        assert got.tolist() == pytest.approx(exp[col], rel=REL, abs=0, nan_ok=True), col
        assert float(np.mean(got)) == pytest.approx(exp["mean"][col], rel=REL, abs=0, nan_ok=True), f"mean {col}"


def test_the_variant_options_took_effect(results):
    """The three variants really ran what they say (else their pins would be nominal numbers)."""
    opts = {case: json.loads((d / "manifest.json").read_text())["options"] for case, d in results.items()}
    assert opts["nominal"]["corruption"]["schedule"] == "constant"
    assert opts["dynamic"]["corruption"]["schedule"] == "dynamic"
    assert opts["outage"]["scenario"] == "outage" and opts["synthetic-dvl"]["dvl"] == "synthetic"
    for case, filt in (("dynamic", "anukf-nespm"), ("outage", "ekf"), ("synthetic-dvl", "ukf")):
        assert not np.array_equal(_rows(results, case, filt)["vrmse"], _rows(results, "nominal", filt)["vrmse"]), case
    e = pd.read_parquet(results["outage"] / "epochs.parquet")
    t = e["t"].to_numpy()
    off = (t >= OUTAGE_START) & (t < OUTAGE_START + OUTAGE_LENGTH)
    assert 9 <= off.sum() <= 11 and not e["dvl_used"][off].any() and e["dvl_used"][~off][1:].all()
    assert t[-1] > OUTAGE_START + OUTAGE_LENGTH + 10  # the window lies inside the 40-epoch track
