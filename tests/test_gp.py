"""The GPs' own arithmetic (tuning/gp.py) against scikit-learn's, which it stands in for."""

import math

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor

from furuta_cosim.tuning import gp


def _data(n, d, seed, constant=False):
    rng = np.random.default_rng(seed)
    X = rng.random((n, d))
    y = np.full(n, 2.5) if constant else np.sin(3 * X.sum(axis=1)) + 0.01 * rng.standard_normal(n)
    return rng, X, y


@pytest.mark.parametrize("n, d", [(150, 11), (40, 9), (5, 2)])
def test_the_likelihood_and_its_gradient_are_scikit_learns(n, d):
    """At random hyperparameters across their bounds: value and gradient as scikit-learn's
    log_marginal_likelihood(theta, eval_gradient=True), to 1e-7 relative."""
    rng, X, y = _data(n, d, n)
    reference = GaussianProcessRegressor(gp.kernel(d), normalize_y=True, alpha=gp.JITTER, optimizer=None)
    reference.fit(X, y)
    bounds = reference.kernel_.bounds
    for _ in range(6):
        theta = bounds[:, 0] + rng.random(d + 2) * (bounds[:, 1] - bounds[:, 0])
        theta[-1] = max(theta[-1], math.log(1e-4))  # far from singular: both sides well defined
        expected, expected_gradient = reference.log_marginal_likelihood(theta, eval_gradient=True)
        value, gradient = gp.negative_log_likelihood(theta, X, gp.normalized(y))
        assert value == pytest.approx(-expected, rel=1e-7)
        scale = np.max(np.abs(expected_gradient))
        np.testing.assert_allclose(gradient, -expected_gradient, rtol=1e-6, atol=1e-9 * scale)


def test_the_gradient_is_the_likelihoods_slope():
    """Central differences of the value agree with the gradient (the fit climbs on it)."""
    _, X, y = _data(30, 4, 3)
    y = gp.normalized(y)
    theta = np.log([0.8, 0.3, 0.6, 1.5, 0.2, 1e-3])
    _, gradient = gp.negative_log_likelihood(theta, X, y)
    for k in range(len(theta)):
        step = np.zeros_like(theta)
        step[k] = 1e-6
        slope = (gp.negative_log_likelihood(theta + step, X, y)[0]
                 - gp.negative_log_likelihood(theta - step, X, y)[0]) / 2e-6
        assert gradient[k] == pytest.approx(slope, rel=1e-4, abs=1e-6)


def test_a_matrix_that_is_not_positive_definite_is_refused_as_scikit_learn_does():
    """Duplicated points with no noise and an enormous length scale: +inf, no gradient."""
    X = np.repeat(np.random.default_rng(0).random((3, 2)), 2, axis=0)
    y = gp.normalized(np.arange(6.0))
    theta = np.array([math.log(1e3), math.log(1e2), math.log(1e2), math.log(1e-8)])
    value, gradient = gp.negative_log_likelihood(theta, X, y)
    if math.isfinite(value):  # LAPACK may factor it after all: then scikit-learn agrees
        reference = GaussianProcessRegressor(gp.kernel(2), normalize_y=True, alpha=gp.JITTER, optimizer=None)
        reference.fit(X, np.arange(6.0))
        assert value == pytest.approx(-reference.log_marginal_likelihood(theta), rel=1e-6)
    else:
        assert value == math.inf and not gradient.any()


def test_the_fit_finds_scikit_learns_optimum():
    """Fitted from the same start, our climb and scikit-learn's own (L-BFGS-B on its
    likelihood, uncapped) reach the same likelihood, to 1e-3 of its value."""
    _, X, y = _data(60, 5, 7)
    ours = gp.Surrogate(X, y, None, True, 0, 0)
    theirs = GaussianProcessRegressor(gp.kernel(5), normalize_y=True, alpha=gp.JITTER, random_state=0)
    theirs.fit(X, y)
    assert ours.gp.log_marginal_likelihood_value_ == pytest.approx(theirs.log_marginal_likelihood_value_,
                                                                   rel=1e-3)


def test_a_fit_leaves_the_optimum_where_every_length_scale_is_at_its_bound():
    """Warm-started at length scales all at their lower bound (the likelihood's gradient
    vanishes there, so a climb from there alone stays), a refit also climbs from the
    kernel's defaults and keeps the likelier fit: here far likelier, with length scales off
    the bound, and the GP predicts points it was not trained on."""
    rng, X, y = _data(40, 4, 3)
    stuck = np.r_[0.0, np.full(4, math.log(gp.LENGTH_BOUNDS[0])), math.log(1e-4)]
    alone = gp.negative_log_likelihood(stuck, X, gp.normalized(y))[0]
    fitted = gp.Surrogate(X, y, stuck.tolist(), True, 0, 0)
    value = gp.negative_log_likelihood(np.array(fitted.theta), X, gp.normalized(y))[0]
    assert value < alone - 10.0
    assert np.all(fitted.length_scales() > 10 * gp.LENGTH_BOUNDS[0])
    # not refitted, the given hyperparameters are kept as they are
    kept = gp.Surrogate(X, y, stuck.tolist(), False, 0, 0)
    np.testing.assert_allclose(kept.theta, stuck)
    C = rng.random((200, 4))
    truth = np.sin(3 * C.sum(axis=1))
    error = [float(np.sqrt(np.mean((s.predict(C)[0] - truth) ** 2))) for s in (fitted, kept)]
    assert error[0] < 0.5 * error[1]


@pytest.mark.parametrize("n, d", [(150, 11), (12, 3)])
def test_the_surrogates_prediction_is_scikit_learns(n, d):
    """The acquisition's own predict gives scikit-learn's mean and standard deviation, fitted
    and after a believed point, a constant history included."""
    for constant in (False, True):
        rng, X, y = _data(n, d, n, constant)
        surrogate = gp.Surrogate(X, y, None, True, 0, 0)
        for _ in range(2):
            C = np.vstack([rng.random((300, d)), X[:3]])  # at training points too
            mean, std = surrogate.gp.predict(C, return_std=True)
            ours = surrogate.predict(C)
            np.testing.assert_allclose(ours[0], mean, rtol=1e-9, atol=1e-10)
            np.testing.assert_allclose(ours[1], std, rtol=1e-6, atol=1e-6 * max(1.0, np.max(std)))
            surrogate.believe(C[0])
