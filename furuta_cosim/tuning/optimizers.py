"""Where a tuning's candidates come from: scikit-optimize's GP + Expected Improvement, or
uniform random draws, behind one interface: ``batch(count)`` hands out the points of a batch
one at a time (so a worker can start on the first while the next is computed), ``tell(xs, ys)``
gives back what they scored.

:class:`BayesOptimizer` is scikit-optimize's ``Optimizer`` with two costs cut:

- a batch: scikit-optimize's ``ask(n)`` copies the optimizer (a full refit and acquisition
  over again) and then fits once per point with a made-up observation (the constant lie), the
  last of those unused: n + 1 fits and acquisitions for n points. ``batch`` tells the lie to
  the optimizer itself, with the GP only conditioning on it (no hyperparameter fit), and takes
  the lies back when the batch is out: n - 1 fits, the real tell makes the n-th.
- sampling: at every tell 2,000 points are drawn and transformed to the unit cube through
  Python lists of lists; over real dimensions the same draws are packed as arrays.

The points are scikit-optimize's constant-liar points (lie: the best value so far), not
bit-for-bit the ones its ``ask(n)`` returns (that one draws from a fresh random state).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
from skopt import Optimizer
from skopt.space import Real, Space
from sklearn.utils import check_random_state

from furuta_cosim.tuning.gp import REFIT_EVERY, Memory, WarmGaussianProcess

# Expected Improvement maximized from the best of this many sampled points by this many L-BFGS
# starts (scikit-optimize's defaults: 10,000 and 5; tools/bench_tune.py compares)
ACQUISITION = {"n_points": 2000, "n_restarts_optimizer": 2}

_UNSET = object()


class _RealSpace(Space):
    """A space of real dimensions whose samples and transforms go through arrays: the same
    draws from the same random state, the same per-dimension transforms."""

    def rvs(self, n_samples=1, random_state=None):
        rng = check_random_state(random_state)
        columns = [dim.rvs(n_samples=n_samples, random_state=rng) for dim in self.dimensions]
        return np.column_stack(columns).tolist()

    def transform(self, X):
        X = np.asarray(X, dtype=float).reshape(len(X), self.n_dims)
        return np.column_stack([dim.transform(X[:, j]) for j, dim in enumerate(self.dimensions)])


class BayesOptimizer(Optimizer):
    """scikit-optimize's ask/tell optimizer with cheaper batches and sampling (module doc)."""

    def __init__(self, dimensions, *, memory=None, **options):
        super().__init__(dimensions, **options)
        self.memory = memory
        if self.space.constraint is None and all(isinstance(d, Real) for d in self.space.dimensions):
            self.space = _RealSpace(self.space.dimensions)

    def replay(self, xs, ys) -> None:
        """A resumed run: everything evaluated so far, told at once."""
        self.tell([list(x) for x in xs], list(ys))

    def batch(self, count: int) -> Iterator[list]:
        """``count`` points by the constant liar (the lie: the best value so far), one at a
        time; when the batch is out the optimizer is as before it (lies taken back)."""
        told, models, initial = len(self.Xi), len(self.models), self._n_initial_points
        saved = {name: self.__dict__.get(name, _UNSET) for name in ("_next_x", "next_xs_")}
        try:
            for k in range(count):
                x = self.ask()
                yield x
                if k + 1 < count:
                    lie = float(np.min(self.yi)) if self.yi else 0.0
                    if self.memory is not None:
                        with self.memory.conditioning_only():
                            self._tell(x, lie)
                    else:
                        self._tell(x, lie)
        finally:
            del self.Xi[told:], self.yi[told:], self.models[models:]
            self._n_initial_points = initial
            for name, value in saved.items():
                if value is _UNSET:
                    self.__dict__.pop(name, None)
                else:
                    setattr(self, name, value)
            self.cache_ = {}


class RandomSearch:
    """Uniform draws from the same space, with the same interface (scikit-optimize's own
    "dummy" estimator does not run with current scikit-learn)."""

    def __init__(self, dimensions, seed: int):
        self._space, self._rng = Space(dimensions), np.random.RandomState(seed)

    def batch(self, count: int) -> Iterator[list]:
        for _ in range(count):
            yield self._space.rvs(1, random_state=self._rng)[0]

    def tell(self, xs, ys) -> None:
        pass

    def replay(self, xs, ys) -> None:
        """A resumed run: the same draws again, so the generator goes on where it was."""
        for _ in xs:
            self._space.rvs(1, random_state=self._rng)


def make(dimensions, method: str, seed: int, *, xi: float, n_initial_points: int, gp_restarts: int):
    """The optimizer of ``method`` (``bo`` or ``random``) over ``dimensions``; ``gp_restarts``:
    random starts, besides the last kernel, of each hyperparameter refit."""
    if method == "random":
        return RandomSearch(dimensions, seed)
    from skopt.utils import cook_estimator


    # scikit-optimize's GP with its default settings spends most of a run refitting kernel
    # hyperparameters from three starts at every tell; a fit every fifth tell (from the last
    # kernel and gp_restarts random starts; conditioning only in between), its noise level
    # fitted, and EI maximized from 2,000 sampled points and 2 L-BFGS starts cost a fraction
    # (tools/bench_tune.py measures against the defaults)
    memory = Memory()
    kernel = cook_estimator("GP", space=dimensions, random_state=seed).kernel
    gp = WarmGaussianProcess(kernel, random_state=seed, noise="gaussian", refit_every=REFIT_EVERY,
                             n_restarts_optimizer=gp_restarts, memory=memory)
    return BayesOptimizer(dimensions, memory=memory, base_estimator=gp, acq_func="EI",
                          acq_func_kwargs={"xi": xi}, n_initial_points=n_initial_points,
                          acq_optimizer="lbfgs", acq_optimizer_kwargs=dict(ACQUISITION),
                          random_state=seed)
