"""The tuning's optimizers: the same predictions and draws as scikit-optimize at less cost,
batches that leave the optimizer as they found it, and points sent out as soon as known."""

import dataclasses

import numpy as np
import pytest
from skopt.learning import GaussianProcessRegressor
from skopt.space import Real, Space
from skopt.utils import cook_estimator

from furuta_cosim.tuning import optimizers, run
from furuta_cosim.tuning.executors import Serial
from furuta_cosim.tuning.gp import Memory, WarmGaussianProcess
from furuta_cosim.tuning.spec import OptimizerSettings, load_spec

DIMENSIONS = [Real(-1.0, 2.0, name="a"), Real(-3.0, 3.0, name="b"), Real(0.0, 1.0, name="c")]


def objective(x):
    return float((x[0] - 0.5) ** 2 + 0.3 * np.sin(3 * x[1]) + (x[2] - 0.2) ** 2)


def fitted_gp(n=40):
    rng = np.random.RandomState(1)
    X = rng.uniform(size=(n, 3))
    y = np.sin(X @ np.array([3.0, -2.0, 1.0])) + 0.01 * rng.standard_normal(n)
    kernel = cook_estimator("GP", space=DIMENSIONS, random_state=0).kernel
    return WarmGaussianProcess(kernel, noise="gaussian", random_state=0, memory=Memory()).fit(X, y)


def test_the_lean_prediction_is_scikit_optimizes():
    gp = fitted_gp()
    X = np.random.RandomState(2).uniform(size=(500, 3))
    # the std is the root of a small difference of two near-equal variances: both ways of
    # computing it round differently, to about 1e-9 here (the values are 0.01 to 1)
    (mean, std), (their_mean, their_std) = (gp.predict(X, return_std=True),
                                            GaussianProcessRegressor.predict(gp, X, return_std=True))
    np.testing.assert_allclose(mean, their_mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(std, their_std, rtol=1e-6, atol=1e-7)
    # one point with the gradients the acquisition's L-BFGS asks for
    options = dict(return_std=True, return_mean_grad=True, return_std_grad=True)
    ours = gp.predict(X[:1], **options)
    theirs = GaussianProcessRegressor.predict(gp, X[:1], **options)
    for a, b, tolerance in zip(ours, theirs, (1e-9, 1e-6, 1e-9, 1e-5)):
        np.testing.assert_allclose(a, b, rtol=tolerance, atol=1e-7)
    np.testing.assert_allclose(gp.predict(X), GaussianProcessRegressor.predict(gp, X), rtol=1e-12)
    mean, cov = gp.predict(X[:5], return_cov=True)      # handed to scikit-optimize's own
    assert cov.shape == (5, 5)
    with pytest.raises(ValueError):
        gp.predict(X[:2], return_std=True, return_mean_grad=True)


def test_the_array_space_draws_and_transforms_like_scikit_optimizes():
    plain, ours = Space(DIMENSIONS), optimizers._RealSpace(DIMENSIONS)
    drawn = ours.rvs(200, random_state=7)
    assert drawn == [list(map(float, row)) for row in plain.rvs(200, random_state=7)]
    assert np.array_equal(ours.transform(drawn), plain.transform(drawn))
    with pytest.raises(ValueError):
        ours.transform([[5.0, 0.0, 0.0]])                # out of bounds, as scikit-optimize says


def told(n_points=12, seed=0, n_initial_points=5, gp_restarts=OptimizerSettings.gp_restarts):
    optimizer = optimizers.make(DIMENSIONS, "bo", seed, xi=0.01, n_initial_points=n_initial_points,
                                gp_restarts=gp_restarts)
    xs = Space(DIMENSIONS).rvs(n_points, random_state=seed + 100)
    optimizer.tell(xs, [objective(x) for x in xs])
    return optimizer


def test_a_batch_leaves_the_optimizer_as_it_was():
    optimizer = told()
    assert isinstance(optimizer.space, optimizers._RealSpace)
    before = (len(optimizer.Xi), len(optimizer.yi), len(optimizer.models),
              optimizer._n_initial_points, list(optimizer._next_x), optimizer.memory.fits)
    points = list(optimizer.batch(3))
    assert len(points) == 3 and all(x in optimizer.space for x in points)
    gaps = [np.abs(np.subtract(a, b)).max() for k, a in enumerate(points) for b in points[k + 1:]]
    assert min(gaps) > 1e-6                      # the lies push the next points elsewhere
    after = (len(optimizer.Xi), len(optimizer.yi), len(optimizer.models),
             optimizer._n_initial_points, list(optimizer._next_x), optimizer.memory.fits)
    assert after == before                        # lies taken back; no hyperparameter fit counted
    assert optimizer.ask() == points[0]
    # the same seed and history give the same batch
    assert list(told().batch(3)) == points
    optimizer.tell(points, [objective(x) for x in points])
    assert len(optimizer.Xi) == 15 and optimizer.memory.fits == before[-1] + 1


@pytest.mark.parametrize("restarts", [0, 2])
def test_hyperparameter_refits_start_from_the_last_kernel_and_gp_restarts_more(monkeypatch, restarts):
    from furuta_cosim.tuning.gp import WarmGaussianProcess

    starts, found = [], []
    real = WarmGaussianProcess._constrained_optimization

    def counted(self, *args):
        starts.append(args[1])                    # the initial hyperparameters
        found.append(real(self, *args))           # (hyperparameters, negative log likelihood)
        return found[-1]

    monkeypatch.setattr(WarmGaussianProcess, "_constrained_optimization", counted)
    optimizer = told(gp_restarts=restarts)        # the first fit: from the prior kernel + restarts
    assert len(starts) == 1 + restarts
    fitted = min(found, key=lambda result: result[1])[0]
    for k in range(optimizers.REFIT_EVERY):       # conditioning only, then one refit
        xs = Space(DIMENSIONS).rvs(1, random_state=k)
        optimizer.tell(xs, [objective(x) for x in xs])
    assert len(starts) == 2 * (1 + restarts)
    assert np.allclose(starts[1 + restarts], fitted)   # the refit's first start: the last kernel


def test_a_batch_across_the_end_of_the_random_start():
    optimizer = told(n_points=4, n_initial_points=5)
    points = list(optimizer.batch(3))
    assert len({tuple(x) for x in points}) == 3
    assert optimizer._n_initial_points == 1 and len(optimizer.Xi) == 4 and not optimizer.models


def test_each_point_of_a_batch_is_sent_before_the_next_is_computed(tmp_path, monkeypatch):
    events = []

    class Recording(Serial):
        def submit(self, x):
            events.append("submit")
            return super().submit(x)

        def gather(self, pending):
            events.append("gather")
            return super().gather(pending)

    real_tell = optimizers.BayesOptimizer._tell

    def tell(self, x, y, fit=True):
        models = len(self.models)
        result = real_tell(self, x, y, fit)
        events.append("fit" if len(self.models) > models else "tell")
        return result

    monkeypatch.setattr(optimizers.BayesOptimizer, "_tell", tell)
    monkeypatch.setattr(run, "_executor", lambda spec, evaluator, workers, dask: Recording(spec, evaluator))
    spec = load_spec("paper-spectral")
    spec = dataclasses.replace(spec, optimizer=dataclasses.replace(spec.optimizer, batch=2,
                                                                   n_initial_points=4))
    run.tune(spec, tmp_path / "run", n_calls=8)
    # the random start (4 points) takes two batches; then each batch's first point goes out
    # before the GP is fitted with its lie for the second
    assert events == (["submit", "tell", "submit", "gather", "tell"]
                      + ["submit", "tell", "submit", "gather", "fit"]
                      + ["submit", "fit", "submit", "gather", "fit"] * 2)


def test_the_optimizer_runs_on_one_blas_thread_serial_too(tmp_path, monkeypatch):
    from threadpoolctl import threadpool_info, threadpool_limits

    seen = []
    real_tell = optimizers.BayesOptimizer.tell

    def tell(self, xs, ys):
        seen.extend(pool["num_threads"] for pool in threadpool_info())
        return real_tell(self, xs, ys)

    monkeypatch.setattr(optimizers.BayesOptimizer, "tell", tell)
    with threadpool_limits(2):                   # whatever the caller allows
        run.tune(load_spec("paper-spectral"), tmp_path / "run", n_calls=12)
    assert seen and set(seen) == {1}
