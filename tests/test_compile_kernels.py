"""What a cold `mc` compiles (issue 41: its CPU at most 3x a warm one; benchmarks/README.md, the compile
section): the papers' 12-state Φ kernel unrolled (filters/compiled/unrolled_12.py) gives the generic
loop's bits; the default filters compile only their two kernels (the 12-state Φ and the points), each
function once (one signature: nothing compiled twice for another array layout or integer type), never
the generic Φ loop; the helpers are inlined by LLVM, not copied by numba at every call site. No timing
is asserted: these are the properties the compile time rests on."""
from __future__ import annotations

import collections
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import console_script, env_without_data_dir
from nespm_cli.experiments.progress import kernels_for
from nespm_cli.filters import kernels
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, StateLayout

PACKAGE = Path(kernels.__file__).resolve().parents[1]

needs_numba = pytest.mark.skipif(not kernels.compiled_enabled(), reason="the compiled kernels are not in use here")


def _inputs(seed: int, R: int = 10, M: int = 120):
    rng = np.random.default_rng(seed)
    pos = np.column_stack([rng.uniform(-1.3, 1.3, R), rng.uniform(-3, 3, R), rng.uniform(-500, 10, R)])
    v = 3.0 * rng.standard_normal((R, 3))
    v[0] = 0.0  # zero velocity: F's entries from it are exact zeros
    C = np.stack([np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in range(R)])
    b_a, b_g = 0.05 * rng.standard_normal((R, 3)), 1e-3 * rng.standard_normal((R, 3))
    f = np.tile([0.0, 0.0, -9.8], (R, M, 1)) + 0.5 * rng.standard_normal((R, M, 3))
    w = 0.05 * rng.standard_normal((R, M, 3))
    w[1, 4] = 4.0  # a rotation above 0.01 rad per step: the Rodrigues branch
    pos[2, 0] = np.pi / 2  # the pole: tan(lat) huge, F's J21 and the transport rate blow up
    f[3, 7, 1] = np.nan  # a NaN sample and an infinite one: the structural zeros' 0 · NaN must stay NaN
    f[4, 9, 0] = np.inf
    return pos, v, C, b_a, b_g, f, w, rng.uniform(0.005, 0.02, M)


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit, zeros' signs included; NaN where NaN (its sign and payload aside: which of two NaN
    operands an operation passes on follows the compiler's operand order, and a NaN made by an invalid
    operation, such as the latitude sine's range check on an infinite latitude, carries the default sign)."""
    nan = np.isnan(a)
    return (np.array_equal(a, b, equal_nan=True) and np.array_equal(nan, np.isnan(b))
            and np.array_equal(np.signbit(a[~nan]), np.signbit(b[~nan])))


@needs_numba
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("span", [(0, 1), (0, 2), (5, 5), (3, 120)])
@pytest.mark.parametrize("kernel,R", [("12", 10), ("lanes", 10), ("lanes", 37)])
def test_12_state_kernel_is_the_generic_loop_to_the_bit(seed, span, kernel, R):
    """transition_span_12 (run by run) and transition_lanes_12 (the runs in SIMD lanes: one block with
    spare lanes, and two blocks, the second partly filled) against transition_span_common with the 12-state
    offsets: Φ and the propagated solution, on spans of 1 and 2 steps (where Φ still holds exact zeros, whose
    sign is compared), an empty span, and long spans through a pole, a fast rotation, a NaN and an infinite
    IMU sample."""
    from nespm_cli.filters.compiled import spans as tk
    from nespm_cli.filters.compiled.unrolled_12 import transition_span_12
    from nespm_cli.filters.compiled.lanes_12 import transition_lanes_12

    pos, v, C, b_a, b_g, f, w, dt = _inputs(seed, R)
    j0, j1 = span
    out = []
    for name in ("generic", kernel):
        state = [pos.copy(), v.copy(), C.copy()]
        Phi = np.full((pos.shape[0], 12, 12), 7.0)
        if name == "generic":
            tk.transition_span_common(*state, b_a, b_g, f, w, dt, j0, j1, Phi, LAYOUT_12.offsets())
        else:
            (transition_span_12 if name == "12" else transition_lanes_12)(*state, b_a, b_g, f, w, dt, j0, j1, Phi)
        out.append((Phi, *state))
    for a, b in zip(*out):
        assert _same_bits(a, b)
    Phi = out[0][0]
    if j1 - j0 <= 2:
        assert np.any(Phi == 0.0)  # exact zeros were compared
    if j1 - j0 > 2:
        assert np.isnan(Phi).any() and np.isfinite(Phi[0]).all()  # the NaN run compared, the clean run finite



@needs_numba
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("R,span", [(12, (3, 120)), (37, (0, 1)), (37, (0, 2)), (9, (5, 5))])
def test_15_state_lanes_are_the_run_by_run_kernel_to_the_bit(seed, R, span):
    """transition_lanes_15 (the runs in SIMD lanes: one block with spare lanes, two blocks) against
    transition_span_position (F's zeros skipped; itself the generic loop's numbers, tests/test_transition_position.py):
    Φ and the propagated solution to the bit, zeros' signs included, on spans of one and two steps (where Φ
    still holds exact zeros), an empty span and a long one through a pole, a fast rotation, a NaN and an
    infinite IMU sample; kernels.transition picks it from LANES_MIN_15 runs."""
    from nespm_cli.filters.compiled import spans as tk
    from nespm_cli.filters.compiled.lanes_15 import transition_lanes_15

    pos, v, C, b_a, b_g, f, w, dt = _inputs(seed, R)
    out = []
    for kernel in (tk.transition_span_position, transition_lanes_15):
        state = [pos.copy(), v.copy(), C.copy()]
        Phi = np.full((R, 15, 15), 7.0)
        kernel(*state, b_a, b_g, f, w, dt, *span, Phi)
        out.append((Phi, *state))
    for a, b in zip(*out):
        assert _same_bits(a, b)
    if span[1] - span[0] in (1, 2):
        assert np.any(out[0][0] == 0.0)  # exact zeros were compared
    assert kernels.lanes_from(LAYOUT_15) == kernels.LANES_MIN_15
    assert kernels.transition_kernel(False, LAYOUT_15, R) == (
        "transition-position-lanes" if R >= kernels.LANES_MIN_15 else "transition-position")

@needs_numba
def test_kernels_transition_runs_the_12_state_kernel_for_the_papers_layout():
    """kernels.transition picks the unrolled kernel for the 12 states ('transition'; from LANES_MIN runs the
    runs in lanes, 'transition-lanes') and the generic loop for another layout ('transition-generic', warmed on
    one), with the same numbers as the generic loop."""
    assert kernels.transition_kernel(False, LAYOUT_12) == "transition"
    assert kernels.transition_kernel(False, LAYOUT_12, kernels.LANES_MIN - 1) == "transition"
    assert kernels.transition_kernel(False, LAYOUT_12, kernels.LANES_MIN) == "transition-lanes"
    other = StateLayout(("vel", "att", "bg"))
    assert kernels.transition_kernel(False, other) == kernels.transition_kernel(False, other, 100) == "transition-generic"
    assert kernels_for(["ekf"], other) == ("transition-generic",)
    assert kernels.transition_kernel(False, kernels.GENERIC_LAYOUT) == "transition-generic"
    from nespm_cli.filters.compiled import spans as tk

    pos, v, C, b_a, b_g, f, w, dt = _inputs(3)  # 10 runs: the lanes
    a = [pos.copy(), v.copy(), C.copy()]
    b = [pos.copy(), v.copy(), C.copy()]
    Phi = kernels.transition(*a, b_a, b_g, f, w, dt, 0, 50)
    ref = np.empty_like(Phi)
    tk.transition_span_common(*b, b_a, b_g, f, w, dt, 0, 50, ref, LAYOUT_12.offsets())
    assert _same_bits(Phi, ref) and all(_same_bits(x, y) for x, y in zip(a, b))


def test_no_numba_level_inlining_in_the_kernel_sources():
    """The helpers are `nav.kernels.helper` (inlined by LLVM, compiled once per process), never numba's
    `inline="always"`, which copies and re-types the helper at every call site."""
    from nespm_cli.nav.kernel_cache import KERNEL_SOURCES

    for rel in KERNEL_SOURCES:
        text = (PACKAGE / rel).read_text(encoding="utf-8")
        assert not re.search(r"@njit\([^)]*\binline=", text), rel


@needs_numba
@pytest.mark.parametrize("runs", [1, kernels.LANES_MIN])
def test_cold_mc_compiles_its_kernels_once_each(tmp_path, runs):
    """A cold `mc` of the default filters (ekf, ukf, ukf-nespm, and the PCRB) compiles the 12-state Φ kernel
    (from LANES_MIN runs in a chunk also its lanes, the PCRB keeping the run-by-run one) and the points
    kernel and nothing else of the top-level kernels, and every compiled function (kernels and helpers)
    for exactly one signature: the cache folder holds one machine-code file per function."""
    cache = tmp_path / "cache"
    env = {**env_without_data_dir(), "NESPM_CACHE_DIR": str(cache), "NESPM_KERNELS": "auto"}
    argv = [*console_script(), "mc", "--tracks", "5", "--runs", str(runs), "--window", "0:20", "--jobs", "1",
            "--no-progress", "--out", str(tmp_path / "out")]
    run = subprocess.run(argv, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    data = [p.name for p in cache.rglob("*.nbc")]
    per_function = collections.Counter(re.sub(r"-\d+\.py\d+\.\d+\.nbc$", "", name) for name in data)
    assert per_function, data
    assert all(n == 1 for n in per_function.values()), per_function
    kernels_compiled = {name.split(".")[1] for name in per_function if re.search(r"\.(transition|points)_(span|lanes)\w*$", name)}
    lanes = {"transition_lanes_12"} if runs >= kernels.LANES_MIN else set()
    assert kernels_compiled == {"transition_span_12", "points_span_soa", *lanes}, per_function
