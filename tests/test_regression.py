"""Seeded regression values: every built-in filter's per-run numbers, pinned per filter family.

Configuration (all of it determines the numbers):

- ``nespm mc`` in-process, seed 7, track 5 of the embedded tracks cut to its first 40 epochs
  (~39 s, written to a temporary A-KIT folder and passed as ``--data-dir``), 4 runs (0-3) in
  chunks of 2, every other option at its default (nominal scenario, constant schedule,
  recorded DVL, synthetic IMU, the packaged ProcessNet weights);
- all 13 filters of ``nespm_cli.filters.FILTERS`` in one command, with ``--jobs 2`` (worker
  processes); then one or two filters each, with ``--jobs 1`` (in-process), for
  ``--schedule dynamic`` (anukf-nespm), ``--scenario outage --outage-start 15
  --outage-length 10`` (ekf), ``--dvl synthetic`` (ukf) and ``--alpha 0.5`` (ukf-nespm and
  anukf-nespm: the sigma points through the navigation cycle with well-conditioned weights).

EXPECTED holds, per (case, filter), the per-run VRMSE [m/s], MRMSE [rad] and mean NEES of
metrics.parquet, and the mean over the 4 runs of each (ins has no covariance: NaN NEES).

These are regression values of the current implementation, NOT theoretical or published
values: they only say that the numbers have not changed. First computed at commit 2541d01;
re-pinned with issue 15 (the compiled time loop) on a machine whose OpenBLAS ran its SkylakeX
kernels; ``alpha-0.5`` added with issue 21; ``iae-ekf``, ``sh-ekf``, ``vb-ekf`` with issue 32.

Tolerances: how far the CPU and the BLAS build move these numbers, measured. The last bits of
BLAS/LAPACK (Cholesky, batched products, solves) differ between OpenBLAS's kernels; the filters
carry them over the track, and a filter's conditioning decides how far they grow.
``benchmarks/blas_spread.py`` runs these four commands (and the real-data job of
tests/test_real_regression.py) in fresh processes under ``OPENBLAS_CORETYPE`` = Haswell, Zen,
Sandybridge, Nehalem and Prescott, and with NumPy's runtime SIMD dispatch cut to its baseline
(``NPY_DISABLE_CPU_FEATURES``), and compares every per-run number with the default kernel's
(2026-12-02, a 2-vCPU AMD EPYC, NumPy 2.4.6 with OpenBLAS 0.3.31; SkylakeX cannot run there, and
the pins, made under SkylakeX, sit 1.2e-8 from the Haswell numbers for ukf-nespm). Largest
relative difference over every variant and column:

============================  ===========  ===========================================
family                        measured     why, and the tolerance (about 30x, rounded up)
============================  ===========  ===========================================
ins, ekf, ukf, ckf,           2.9e-12      weights of order one: round-off stays round-off
ckf-nespm, iekf, outage,                   -> REL_LINEAR = 1e-9
synthetic DVL, alpha 0.5
anekf, anukf, anukf-nespm     1.7e-9       Q from ProcessNet (batched products) feeds P, the
at alpha 0.5                               gain and back -> REL_ADAPTIVE = 1e-7
ukf-nespm, anukf-nespm at     4.8e-6       the scaled UT at alpha = 1e-3: the outer weights
alpha = 1e-3 (nominal,                     are 1 / (2 alpha² n) = 4.2e4 and the centre
dynamic)                                   weight -1e6, so every last-bit change of the sigma
                                           points' images reaches the mean 4e4 times larger
                                           -> REL_NESPM = 2e-4
============================  ===========  ===========================================

So the tight pin on the NESPM code (points through the cycle, eqs 35-40) is the ``alpha-0.5``
case; at the papers' alpha = 1e-3 its numbers are pinned only as closely as the arithmetic
determines them. Bit-identity stays where it is a property of the code (tests/test_mc.py: jobs;
tests/test_kernels.py: compiled vs NumPy loop in one process), never of the machine. Nothing in
the tests sets OPENBLAS_CORETYPE or similar: the measurement above is a one-off, re-run with the
script when a filter changes.

A change that moves any of them beyond its tolerance (filters, corruption draws, synthesis,
metrics, track cut...) must explain in its commit why the numbers change, and update them here
in the same commit.

Cost: ~10-20 s (the ten filters over 40 epochs are one batch per chunk).
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
REL_LINEAR, REL_ADAPTIVE, REL_NESPM = 1e-9, 1e-7, 2e-4  # measured spread x ~30 (module docstring)
NAN = math.nan


def tolerance(case: str, filt: str) -> float:
    """The relative tolerance of a (case, filter) pin: its family's (module docstring)."""
    if filt in ("ukf-nespm", "anukf-nespm") and case != "alpha-0.5":
        return REL_NESPM
    if filt in ("anekf", "anukf", "anukf-nespm", "aq-ekf"):  # aq-ekf: a factor fed back from the data
        return REL_ADAPTIVE
    return REL_LINEAR

#: case -> (extra mc options, --jobs)
CASES = {
    "nominal": (["--filters", ",".join(FILTERS)], 2),
    "dynamic": (["--filters", "anukf-nespm", "--schedule", "dynamic"], 1),
    "outage": (["--filters", "ekf", "--scenario", "outage", "--outage-start", str(OUTAGE_START),
                "--outage-length", str(OUTAGE_LENGTH)], 1),
    "synthetic-dvl": (["--filters", "ukf", "--dvl", "synthetic"], 1),
    "alpha-0.5": (["--filters", "ukf-nespm,anukf-nespm", "--alpha", "0.5"], 1),
}

# Regression values of the current implementation (see the module docstring): seed 7, the first
# 40 epochs of embedded track 5, runs 0-3. Any change of them must be explained in the commit.
EXPECTED = {
    ("nominal", "ins"): {
        "vrmse": [15.543255914792397, 16.947416581749167, 14.65977943543567, 10.068449731758742],
        "mrmse": [0.004168169070199463, 0.0033622012464464496, 0.0014263774855418888, 0.0027226692436992887],
        "nees": [NAN, NAN, NAN, NAN],
        "mean": {"vrmse": 14.304725415933992, "mrmse": 0.0029198542614717726, "nees": NAN},
    },
    ("nominal", "aq-ekf"): {
        "vrmse": [0.03736315382893748, 0.055144219399468626, 0.08302362785896891, 0.04550904478267708],
        "mrmse": [0.002385134102187414, 0.00197638845140907, 0.0014027126976645413, 0.001425439646734851],
        "nees": [5.050313374402659, 2.931266759662282, 1.286169361431699, 1.9214867656211019],
        "mean": {"vrmse": 0.055260011467513026, "mrmse": 0.0017974187244989691, "nees": 2.797309065279436},
    },
    ("nominal", "ekf"): {
        "vrmse": [0.037363153803400384, 0.05514421939113832, 0.08302362785695659, 0.04550904475189502],
        "mrmse": [0.0023851341037587747, 0.00197638845247284, 0.0014027126975933168, 0.001425439647836365],
        "nees": [5.0503133740346415, 2.9312667601705575, 1.2861693594288748, 1.921486764895204],
        "mean": {"vrmse": 0.05526001145084757, "mrmse": 0.001797418725415324, "nees": 2.7973090646323198},
    },
    ("nominal", "ukf"): {
        "vrmse": [0.037357887927110006, 0.05514848987656715, 0.08303008395988559, 0.04552254591724177],
        "mrmse": [0.00238512647045966, 0.0019763818859871753, 0.0014027125303860558, 0.001425441972328174],
        "nees": [5.049945760516183, 2.931536489376692, 1.2868644734708217, 1.9223101863237368],
        "mean": {"vrmse": 0.05526475192020113, "mrmse": 0.0017974157147902664, "nees": 2.797664227421858},
    },
    ("nominal", "ukf-nespm"): {
        "vrmse": [0.03736005055686667, 0.05514908904642973, 0.08302973508234379, 0.04552334443385307],
        "mrmse": [0.0023849955694839036, 0.0019762996270399594, 0.0014027146290860322, 0.0014253668633170515],
        "nees": [5.04948709987193, 2.9312782730675577, 1.2868242987504623, 1.9221989676603457],
        "mean": {"vrmse": 0.05526555477987331, "mrmse": 0.0017973441722317367, "nees": 2.7974471598375743},
    },
    ("nominal", "anekf"): {
        "vrmse": [0.037357627295598925, 0.05514095314427712, 0.08302173536549691, 0.0455037553149682],
        "mrmse": [0.0023860227683056073, 0.0019769587488361016, 0.0014027304351758765, 0.0014258093853677868],
        "nees": [5.050677468082389, 2.9317151556867906, 1.2857447658090924, 1.921389874912449],
        "mean": {"vrmse": 0.05525601778008529, "mrmse": 0.001797880334421343, "nees": 2.79738181612268},
    },
    ("nominal", "anukf"): {
        "vrmse": [0.03735237770535416, 0.055145222730306656, 0.08302818415715765, 0.045517249815984706],
        "mrmse": [0.002386015131592902, 0.00197695217848318, 0.0014027302673063995, 0.0014258117102449377],
        "nees": [5.050311110512619, 2.9319840114959512, 1.2864378288624863, 1.9222116616753593],
        "mean": {"vrmse": 0.055260758602200796, "mrmse": 0.0017978773219068547, "nees": 2.797736153136604},
    },
    ("nominal", "anukf-nespm"): {
        "vrmse": [0.03735453713288156, 0.05514582067693246, 0.08302783626191587, 0.045518044660483294],
        "mrmse": [0.002385883967047129, 0.0019768702808799733, 0.0014027326281085466, 0.0014257366872199712],
        "nees": [5.049853051421753, 2.931726417084376, 1.2863987716330332, 1.922100778927516],
        "mean": {"vrmse": 0.055261559683053296, "mrmse": 0.001797805890813905, "nees": 2.7975197547666695},
    },
    ("nominal", "ckf"): {
        "vrmse": [0.03735786748593504, 0.055148482170757226, 0.08303008463667341, 0.04552252530576056],
        "mrmse": [0.0023851273126359084, 0.001976382486663214, 0.0014027125927307885, 0.0014254424012495272],
        "nees": [5.049947096506232, 2.931537384482863, 1.2868639133651096, 1.922308665438349],
        "mean": {"vrmse": 0.05526473989978156, "mrmse": 0.0017974161983198597, "nees": 2.7976642649481382},
    },
    ("nominal", "ckf-nespm"): {
        "vrmse": [0.037360034965655396, 0.0551490821396838, 0.08302973652029039, 0.045523328616481354],
        "mrmse": [0.0023849946485181373, 0.0019762991355630837, 0.0014027150207240246, 0.0014253662865295464],
        "nees": [5.049492426849627, 2.931279846514838, 1.2868242642371481, 1.9221985965436297],
        "mean": {"vrmse": 0.055265545560527735, "mrmse": 0.001797343772833698, "nees": 2.797448783536311},
    },
    ("nominal", "iekf"): {
        "vrmse": [0.0373570833349502, 0.05514443196675528, 0.0830237193632933, 0.045521670937229024],
        "mrmse": [0.002385403515105659, 0.001976337385456522, 0.0014027656312922568, 0.0014264681752803282],
        "nees": [5.050160098981666, 2.9319865911023273, 1.2866316729212397, 1.9240270308595744],
        "mean": {"vrmse": 0.055261726400556946, "mrmse": 0.0017977436767836917, "nees": 2.7982013484662023},
    },
    ("nominal", "iae-ekf"): {
        "vrmse": [0.03573635622438623, 0.05484446037502654, 0.08322676645661319, 0.04283374762830222],
        "mrmse": [0.0022852868262724048, 0.0019482219415315402, 0.001436195484837945, 0.0013679094858779265],
        "nees": [6.098815726814765, 4.394558935732155, 2.4752694359419705, 3.2387052115452306],
        "mean": {"vrmse": 0.05416033267108204, "mrmse": 0.001759403434629954, "nees": 4.05183732750853},
    },
    ("nominal", "sh-ekf"): {
        "vrmse": [0.034645008509432855, 0.05379591075169348, 0.08284383034696707, 0.043174620679408554],
        "mrmse": [0.00229631230311855, 0.0019099717604919087, 0.001405963997165407, 0.0013653837798466176],
        "nees": [5.007673468465654, 2.8860192058052903, 1.31994512291231, 1.9034849993967768],
        "mean": {"vrmse": 0.053614842571875494, "mrmse": 0.0017444079601556207, "nees": 2.779280699145008},
    },
    ("nominal", "vb-ekf"): {
        "vrmse": [0.034561908550165395, 0.053766498424596465, 0.08282833165280393, 0.04303566969093383],
        "mrmse": [0.002289240371313872, 0.0019035102361853761, 0.001405847563041518, 0.0013606268879107401],
        "nees": [5.001195751615157, 2.8787619535863285, 1.321437358725622, 1.9035533374859255],
        "mean": {"vrmse": 0.053548102079624904, "mrmse": 0.0017398062646128765, "nees": 2.7762371003532587},
    },
    ("dynamic", "anukf-nespm"): {
        "vrmse": [0.1219913923667863, 0.1460689501265907, 0.1046332918590896, 0.12940691784893293],
        "mrmse": [0.010107614430508824, 0.011042950390111949, 0.007380190279661092, 0.008686430789023489],
        "nees": [79.01792430035651, 84.05181817661227, 19.835370342955752, 58.73985557249996],
        "mean": {"vrmse": 0.12552513805034987, "mrmse": 0.009304296472326338, "nees": 60.411242098106115},
    },
    ("outage", "ekf"): {
        "vrmse": [0.06360035155379473, 0.07027397649865585, 0.08652758305858019, 0.06558649605160505],
        "mrmse": [0.0027174436808318206, 0.0022689091718473037, 0.0014257390249039895, 0.0015932806282550169],
        "nees": [5.387269436787551, 3.293980558564397, 1.3715808574572887, 2.0952597492574077],
        "mean": {"vrmse": 0.07149710179065896, "mrmse": 0.0020013431264595326, "nees": 3.0370226505166613},
    },
    ("synthetic-dvl", "ukf"): {
        "vrmse": [0.031157712527653078, 0.05017733411253465, 0.081106333193246, 0.03982749488315945],
        "mrmse": [0.001579794510238317, 0.0013446932634262826, 0.0014786306626365486, 0.0007573526806805953],
        "nees": [8.083254700626046, 3.8290303709231175, 3.742079752812548, 4.54202976482762],
        "mean": {"vrmse": 0.0505672186791483, "mrmse": 0.0012901177792454359, "nees": 5.049098647297333},
    },
    ("alpha-0.5", "ukf-nespm"): {
        "vrmse": [0.037360046936767824, 0.05514908739125348, 0.08302973579334244, 0.04552333890192978],
        "mrmse": [0.0023849953830132067, 0.0019762997177470223, 0.0014027149613455951, 0.0014253667575027356],
        "nees": [5.049488414115253, 2.9312787494926282, 1.2868244102794184, 1.9221989355557052],
        "mean": {"vrmse": 0.05526555225582338, "mrmse": 0.0017973442049021402, "nees": 2.7974476273607514},
    },
    ("alpha-0.5", "anukf-nespm"): {
        "vrmse": [0.03735453280951566, 0.05514581924941126, 0.08302783711641538, 0.04551804286728759],
        "mrmse": [0.0023858841506471627, 0.0019768700242118425, 0.0014027327023875748, 0.0014257365304508904],
        "nees": [5.049854807713025, 2.9317267285495117, 1.2863980000643902, 1.922100525110827],
        "mean": {"vrmse": 0.05526155801065747, "mrmse": 0.0017978058519243676, "nees": 2.797520015359438},
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


def test_tolerance_families():
    """The wide tolerance is for the badly conditioned NESPM mean only; everything else is tight."""
    assert tolerance("nominal", "ukf-nespm") == REL_NESPM == tolerance("dynamic", "anukf-nespm")
    assert tolerance("alpha-0.5", "ukf-nespm") == REL_LINEAR and tolerance("nominal", "ckf-nespm") == REL_LINEAR
    assert tolerance("nominal", "anekf") == REL_ADAPTIVE == tolerance("alpha-0.5", "anukf-nespm")
    assert {tolerance(c, f) for c, f in EXPECTED if f in ("ins", "ekf", "ukf", "ckf", "iekf")} == {REL_LINEAR}


def test_every_builtin_filter_is_pinned():
    """A new built-in filter needs its regression values here."""
    assert sorted(f for case, f in EXPECTED if case == "nominal") == sorted(FILTERS)
    assert sorted({case for case, _ in EXPECTED}) == sorted(CASES)


@pytest.mark.parametrize("case,filt", list(EXPECTED), ids=[f"{c}-{f}" for c, f in EXPECTED])
def test_regression_values(results, case, filt):
    m = _rows(results, case, filt)
    exp = EXPECTED[(case, filt)]
    rel = tolerance(case, filt)
    assert m["run"].tolist() == list(range(RUNS))
    assert (m["seed"] == SEED).all() and (m["n_samples"] == EPOCHS).all() and not m["diverged"].any()
    for col in ("vrmse", "mrmse", "nees"):
        got = m[col].to_numpy(float)
        assert got.tolist() == pytest.approx(exp[col], rel=rel, abs=0, nan_ok=True), col
        assert float(np.mean(got)) == pytest.approx(exp["mean"][col], rel=rel, abs=0, nan_ok=True), f"mean {col}"


def test_the_variant_options_took_effect(results):
    """The three variants really ran what they say (else their pins would be nominal numbers)."""
    opts = {case: json.loads((d / "manifest.json").read_text())["options"] for case, d in results.items()}
    assert opts["nominal"]["corruption"]["schedule"] == "constant"
    assert opts["dynamic"]["corruption"]["schedule"] == "dynamic"
    assert opts["outage"]["scenario"] == "outage" and opts["synthetic-dvl"]["dvl"] == "synthetic"
    assert opts["alpha-0.5"]["filter_config"]["alpha"] == 0.5
    for case, filt in (("dynamic", "anukf-nespm"), ("outage", "ekf"), ("synthetic-dvl", "ukf"),
                       ("alpha-0.5", "ukf-nespm")):
        assert not np.array_equal(_rows(results, case, filt)["vrmse"], _rows(results, "nominal", filt)["vrmse"]), case
    e = pd.read_parquet(results["outage"] / "epochs.parquet")
    t = e["t"].to_numpy()
    off = (t >= OUTAGE_START) & (t < OUTAGE_START + OUTAGE_LENGTH)
    assert 9 <= off.sum() <= 11 and not e["dvl_used"][off].any() and e["dvl_used"][~off][1:].all()
    assert t[-1] > OUTAGE_START + OUTAGE_LENGTH + 10  # the window lies inside the 40-epoch track
