"""Tests of GP regression (nespm_cli.learn.gp; gp-ukf.md eqs 4-10).

Tolerances: the fits below are to smooth functions sampled with known noise, so the
error of the posterior mean against the noiseless function is a fraction of the noise std.
All fits are single-threaded (BLAS oversubscription on a shared CPU makes a 1000-point
Cholesky 40x slower) and take well under a second each.
"""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from nespm_cli.errors import NespmError
from nespm_cli.learn.gp import GPModel, log_bounds, log_marginal_likelihood, theta_default


@pytest.fixture(autouse=True)
def _one_blas_thread():
    with threadpool_limits(1):
        yield


def sine_data(n=60, noise=0.05, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 2 * np.pi, (n, 1))
    return X, np.sin(X[:, 0]) + noise * rng.standard_normal(n)


@pytest.fixture(scope="module")
def sine_model():
    X, y = sine_data()
    with threadpool_limits(1):
        return GPModel(seed=0).fit(X, y)


def test_likelihood_and_gradient_match_sklearn():
    """Eqs 9-10 as coded equal scikit-learn's ConstantKernel*RBF(ARD)+WhiteKernel likelihood."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    rng = np.random.default_rng(1)
    X = rng.standard_normal((40, 3))
    y = np.sin(X).sum(axis=1) + 0.1 * rng.standard_normal(40)
    kernel = ConstantKernel(1.0) * RBF(np.ones(3)) + WhiteKernel(1e-2)
    ref = GaussianProcessRegressor(kernel, optimizer=None, alpha=1e-10).fit(X, y)
    for _ in range(5):
        theta = theta_default(3) + rng.normal(0, 0.7, 5)
        v_ref, g_ref = ref.log_marginal_likelihood(theta, eval_gradient=True)
        v, g = log_marginal_likelihood(theta, X, y)
        assert v == pytest.approx(v_ref, rel=1e-10, abs=1e-9)
        np.testing.assert_allclose(g, g_ref, rtol=1e-8, atol=1e-8)


def test_optimum_at_least_as_good_as_sklearn(sine_model):
    """Our L-BFGS-B reaches (at least) scikit-learn's maximum of the same likelihood."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    from nespm_cli.learn.gp import BOUNDS

    X, y = sine_data()
    kernel = (ConstantKernel(1.0, BOUNDS["constant"]) * RBF(1.0, BOUNDS["length"])
              + WhiteKernel(1e-2, BOUNDS["noise"]))
    Xs = (X - X.mean(0)) / X.std(0)
    ref = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=1, random_state=0).fit(Xs, y)
    assert sine_model.log_marginal_likelihood[0] >= ref.log_marginal_likelihood_value_ - 1e-4


def test_fit_1d_sine(sine_model):
    """60 points of sin(x) + N(0, 0.05²): mean within 0.03 RMS of sin, noise std learnt."""
    g = np.linspace(0.2, 2 * np.pi - 0.2, 300)[:, None]
    mean, var = sine_model.predict(g)
    rmse = np.sqrt(np.mean((mean[:, 0] - np.sin(g[:, 0])) ** 2))
    assert rmse < 0.03
    assert 0.03 < np.sqrt(sine_model.noise_var()[0]) < 0.08
    # the predictive std inside the data is about the noise std
    assert np.sqrt(var.max()) < 0.1


def test_variance_grows_away_from_data(sine_model):
    """Eq 6: the latent variance rises monotonically beyond the data towards the prior σ_f²."""
    out = np.array([6.5, 7.5, 8.5, 10.0, 15.0])[:, None]
    _, v_in = sine_model.predict(np.array([[np.pi]]), noise=False)
    _, v_out = sine_model.predict(out, noise=False)
    assert np.all(np.diff(v_out[:, 0]) > 0)
    assert v_out[0, 0] > 10 * v_in[0, 0]
    prior = sine_model.const[0] * sine_model.y_scale[0] ** 2
    assert v_out[-1, 0] == pytest.approx(prior, rel=1e-3)
    # with noise=True the learnt noise variance is added on top
    _, v_noisy = sine_model.predict(out)
    np.testing.assert_allclose(v_noisy - v_out, np.broadcast_to(sine_model.noise_var(), v_out.shape), rtol=1e-9)


def test_fit_2d_two_outputs():
    """Two outputs of a 2-D smooth function, one ARD GP each, within 0.02 RMS."""
    rng = np.random.default_rng(2)
    X = rng.uniform(-2, 2, (250, 2))
    F = np.stack([np.sin(X[:, 0]) * np.cos(X[:, 1]), 0.5 * X[:, 0] ** 2 - X[:, 1]], axis=1)
    Y = F + 0.01 * rng.standard_normal(F.shape)
    m = GPModel(seed=3).fit(X, Y)
    g = np.stack(np.meshgrid(np.linspace(-1.8, 1.8, 25), np.linspace(-1.8, 1.8, 25)), axis=-1)
    mean, var = m.predict(g)  # (25, 25, 2)
    truth = np.stack([np.sin(g[..., 0]) * np.cos(g[..., 1]), 0.5 * g[..., 0] ** 2 - g[..., 1]], axis=-1)
    rmse = np.sqrt(np.mean((mean - truth) ** 2, axis=(0, 1)))
    assert mean.shape == var.shape == (25, 25, 2)
    assert np.all(rmse < 0.02), rmse
    np.testing.assert_allclose(np.sqrt(m.noise_var()), 0.01, rtol=0.3)


def test_batched_predict_equals_single(sine_model):
    rng = np.random.default_rng(4)
    X = rng.uniform(-1, 8, (3, 4, 1))
    mean, var = sine_model.predict(X)
    assert mean.shape == var.shape == (3, 4, 1)
    for i in range(3):
        for j in range(4):
            m1, v1 = sine_model.predict(X[i, j])
            np.testing.assert_allclose(mean[i, j], m1, rtol=0, atol=1e-10)
            np.testing.assert_allclose(var[i, j], v1, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(sine_model.predict(X, return_var=False), mean)


def test_offsets_are_accurate_mean_differences(sine_model):
    """predict_offsets: the mean and its change, formed without cancellation, equal the
    difference of two means where that is accurate (large offsets), and stay smooth (exactly
    second order in the ± pair sums) at the UT's 1e-5-sized offsets."""
    rng = np.random.default_rng(6)
    X0 = rng.uniform(0.5, 5.5, (4, 3, 1))
    D = rng.standard_normal((4, 3, 5, 1))
    m0, dm = sine_model.predict_offsets(X0, 0.3 * D)
    assert m0.shape == (4, 3, 1) and dm.shape == (4, 3, 5, 1)
    np.testing.assert_allclose(m0, sine_model.predict(X0, return_var=False), rtol=0, atol=1e-12)
    ref = sine_model.predict(X0[..., None, :] + 0.3 * D, return_var=False) - m0[..., None, :]
    np.testing.assert_allclose(dm, ref, rtol=0, atol=1e-12)
    pair = [sum(sine_model.predict_offsets(X0, s * D)[1] for s in (h, -h)) for h in (1e-3, 1e-5)]
    np.testing.assert_allclose(pair[1], 1e-4 * pair[0], rtol=1e-5, atol=0)


def test_save_load_round_trip(sine_model, tmp_path):
    path = tmp_path / "gp.npz"
    sine_model.save(path)
    with np.load(path, allow_pickle=False) as f:  # no pickled objects in the file
        assert "X_train" in f.files
    m2 = GPModel.load(path)
    X = np.linspace(-1, 8, 50)[:, None]
    for a, b in zip(sine_model.predict(X), m2.predict(X)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(m2.length, sine_model.length)


def test_subset_of_data_is_seeded_and_capped():
    rng = np.random.default_rng(5)
    X = rng.uniform(0, 6, (400, 1))
    y = np.sin(X[:, 0]) + 0.05 * rng.standard_normal(400)
    y[7] = np.nan  # non-finite rows are dropped before subsampling
    a = GPModel(max_points=80, n_restarts=0, seed=1).fit(X, y)
    b = GPModel(max_points=80, n_restarts=0, seed=1).fit(X, y)
    c = GPModel(max_points=80, n_restarts=0, seed=2).fit(X, y)
    assert a.n_train == 80 and np.isfinite(a.Y_train).all()
    np.testing.assert_array_equal(a.X_train, b.X_train)
    assert not np.array_equal(a.X_train, c.X_train)
    g = np.linspace(0.3, 5.7, 100)[:, None]
    assert np.sqrt(np.mean((a.predict(g, return_var=False)[:, 0] - np.sin(g[:, 0])) ** 2)) < 0.04


def test_bad_inputs():
    with pytest.raises(NespmError):
        GPModel().predict(np.zeros((1, 1)))
    with pytest.raises(NespmError):
        GPModel().fit(np.zeros((5, 1)), np.zeros((4, 1)))
    m = GPModel(n_restarts=0).fit(*sine_data(20))
    with pytest.raises(NespmError):
        m.predict(np.zeros((3, 2)))
    lo, hi = log_bounds(1)
    assert np.all(lo < theta_default(1)) and np.all(theta_default(1) < hi)
