"""The 15-state common-error Φ kernel (compiled.spans.transition_span_position, F's structural
zeros skipped) against the generic row loop (transition_span_common with the 15-state offsets): the same
bits, Φ and the propagated solution, over random states, biases and IMU samples."""
import numpy as np
import pytest

from nespm_cli.filters.compiled import spans as tk
from nespm_cli.filters.kernels import compiled_enabled
from nespm_cli.nav.state import LAYOUT_15


@pytest.mark.parametrize("seed", [1, 2])
def test_position_kernel_is_bit_identical_to_generic(seed):
    if not compiled_enabled():
        pytest.skip("numba not available")
    rng = np.random.default_rng(seed)
    R, M = 12, 250
    lat = rng.uniform(-1.3, 1.3, R)
    pos = np.column_stack([lat, rng.uniform(-3, 3, R), rng.uniform(-500, 10, R)])
    v = 3.0 * rng.standard_normal((R, 3))
    C = np.stack([np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in range(R)])
    b_a, b_g = 0.05 * rng.standard_normal((R, 3)), 1e-3 * rng.standard_normal((R, 3))
    f = np.tile([0.0, 0.0, -9.8], (R, M, 1)) + 0.5 * rng.standard_normal((R, M, 3))
    w = 0.05 * rng.standard_normal((R, M, 3))
    dt = rng.uniform(0.005, 0.02, M)
    out = []
    for kernel in ("generic", "position"):
        s = [pos.copy(), v.copy(), C.copy()]
        Phi = np.empty((R, 15, 15))
        if kernel == "generic":
            tk.transition_span_common(*s, b_a, b_g, f, w, dt, 3, M, Phi, LAYOUT_15.offsets())
        else:
            tk.transition_span_position(*s, b_a, b_g, f, w, dt, 3, M, Phi)
        out.append((Phi, *s))
    for a, b in zip(*out):
        assert np.array_equal(a, b)
    assert np.abs(out[0][0][:, 9:, :] - np.eye(15)[9:]).max() == 0.0  # bias rows stay identity rows
    assert np.abs(out[0][0][:, :9, :9] - np.eye(9)).max() > 1e-3  # the product did move Φ

