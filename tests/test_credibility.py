"""Li and Zhao's noncredibility index (experiments.assembly.Credibility) and the bias truth."""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.data.corruption import CorruptionConfig, draw, imu_errors, true_biases
from nespm_cli.experiments.assembly import Credibility


def _errors(rng, R, N, Sigma):
    return rng.standard_normal((R, N, 3)) @ np.linalg.cholesky(Sigma).T


@pytest.mark.parametrize("scale, expected_db", [(1.0, 0.0), (0.25, 10 * np.log10(4.0)), (4.0, -10 * np.log10(4.0))])
def test_nci_of_a_covariance_scaled_by_a_known_factor(scale, expected_db):
    """Errors drawn from Σ, the filter's P = scale·Σ: ε/ε* → 1/scale, so NCI → −10 log10(scale) dB.
    Two chunks (the index needs Σ over every run before the ratios). Sampling spread of the NCI
    over 400 runs at one epoch: std 0.17 dB over 200 seeds; 0.7 dB (4 std) asked."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((3, 3))
    Sigma = A @ A.T + 0.5 * np.eye(3)
    N = 4
    chunks = [_errors(rng, 200, N, Sigma) for _ in range(2)]
    P_inv = np.linalg.inv(scale * Sigma)
    cred = Credibility(N)
    for E in chunks:
        cred.add_mse(E)
    for E in chunks:
        cred.add_ratio(E, np.einsum("rni,ij,rnj->rn", E, P_inv, E))
    nci = cred.result()
    assert np.all(np.abs(nci - expected_db) < 0.7), nci


def test_nci_does_not_depend_on_the_chunking():
    rng = np.random.default_rng(4)
    E = _errors(rng, 60, 3, np.diag([1.0, 2.0, 3.0]))
    nees = np.einsum("rni,rni->rn", E, E)
    one, three = Credibility(3), Credibility(3)
    one.add_mse(E)
    one.add_ratio(E, nees)
    for part in np.split(E, 3):
        three.add_mse(part)
    for part in np.split(E, 3):
        three.add_ratio(part, np.einsum("rni,rni->rn", part, part))
    np.testing.assert_allclose(one.result(), three.result(), rtol=0, atol=1e-12)


def test_nci_leaves_out_lost_runs():
    rng = np.random.default_rng(5)
    E = _errors(rng, 50, 2, np.eye(3))
    nees = np.einsum("rni,rni->rn", E, E)
    E_lost = E.copy()
    E_lost[7] = np.nan
    a, b = Credibility(2), Credibility(2)
    keep = np.ones(50, dtype=bool)
    keep[7] = False
    a.add_mse(E[keep])
    a.add_ratio(E[keep], nees[keep])
    b.add_mse(E_lost)
    b.add_ratio(E_lost, nees)
    np.testing.assert_allclose(a.result(), b.result(), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dynamic_bias", ["run", "segment"])
def test_true_biases_are_the_bias_part_of_the_imu_errors(dynamic_bias):
    """With zero white noise the IMU errors are the biases alone: true_biases at a step's end time
    equals that step's error."""
    cfg = CorruptionConfig(schedule="dynamic", dynamic_bias=dynamic_bias, acc_noise=0.0, gyro_noise=0.0,
                           segment_s=7.0)
    t = np.arange(0.0, 30.0, 0.5)
    real = draw(0, 1, np.arange(4), float(t[-1]), cfg)
    e_f, e_w = imu_errors(real, t)
    b_a, b_g = true_biases(real, t[1:] - t[0])
    np.testing.assert_array_equal(b_a, e_f)
    np.testing.assert_array_equal(b_g, e_w)
    assert np.ptp(b_a[0, :, 0]) > 0 if dynamic_bias == "segment" else np.ptp(b_a[0, :, 0]) == 0


def test_nci_is_nan_where_the_errors_are_all_zero():
    """A block known exactly at an epoch (a position error of 0 at the start): no index there, no error."""
    rng = np.random.default_rng(6)
    E = _errors(rng, 30, 3, np.eye(3))
    E[:, 0] = 0.0
    nees = np.einsum("rni,rni->rn", E, E)
    c = Credibility(3)
    c.add_mse(E)
    c.add_ratio(E, nees)
    r = c.result()
    assert np.isnan(r[0]) and np.isfinite(r[1:]).all()
