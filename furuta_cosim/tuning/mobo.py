"""The proposals of ``bo`` on a two-criteria ``tradeoff``: expected hypervolume improvement.

Expected hypervolume improvement (EHVI) is Emmerich, Giannakoglou and Naujoks' criterion
("Single- and multiobjective evolutionary optimization assisted by Gaussian random field
metamodels", IEEE Trans. Evol. Comput. 10(4), 2006): how much a candidate is expected to add to
the area the feasible front dominates. It is estimated here by Monte Carlo over the posterior
with one set of normal draws per batch shared by every candidate (common random numbers, as
BoTorch's qEHVI: Daulton, Balandat and Bakshy, NeurIPS 2020), the area added by each draw
exactly (tuning/pareto.py), and multiplied by the probability of feasibility as in the
single-criterion BO (tuning/bayesopt.py), whose Gaussian processes it reuses:

- one GP per criterion, on every evaluated point where the criterion could be computed, its
  values capped at twice the distance from the best to the reference point (a diverging
  controller's huge effort must not flatten the rest);
- the feasibility margin's GP, as for one number.

The reference point is the feasible front's worst value in each criterion plus a tenth of the
front's range, so the ends of the front count too. Candidates are drawn in the whole space and
around every front point (a few coordinates at a time, at three step sizes), so the search both
extends the front and fills it in. The points of a batch come one after another, each told to
the surrogates and to the front at its predicted value (the kriging believer). As there, every
proposal is a function of the history before its batch, the seed and the batch's number.
"""

from __future__ import annotations

import numpy as np

from furuta_cosim.tuning import pareto
from furuta_cosim.tuning.gp import Surrogate
from furuta_cosim.tuning.bayesopt import CANDIDATES, ConstrainedBO, Proposal, _theta

# posterior draws per candidate in the Monte Carlo estimate
DRAWS = 64
# candidates whose improvement is computed at once
CHUNK = 128
# the steps around a front point, as standard deviations on the unit cube
STEPS = (0.02, 0.08, 0.25)


class HypervolumeBO(ConstrainedBO):
    """EHVI times the probability of feasibility over a box ``bounds``, for criteria ``names``
    (two) recorded in each history line's ``criteria``."""

    def __init__(self, bounds, seed: int, names, **settings):
        super().__init__(bounds, seed, **settings)
        self.names = list(names)

    def propose(self, records: list[dict], _start: int, number: int) -> Proposal:
        b = self._batch(records, number)
        rng, X, feasibility = b.rng, b.X, b.feasibility
        rows = [pareto.criteria_of(r, self.names) for r in records]
        on_front = pareto.front_of(records, self.names)
        front = [rows[k] for k in on_front]
        known = [k for k, row in enumerate(rows) if row is not None]
        criteria, reference = [], None
        if front and len(known) >= 2:
            F = np.array(front)
            low, high = F.min(axis=0), F.max(axis=0)
            reference = high + 0.1 * np.where(high > low, high - low, np.abs(high) + 1e-9)
            cap = reference + (reference - low)
            thetas = b.previous.get("criteria") if isinstance(b.previous.get("criteria"), list) else []
            for j in range(len(self.names)):
                y = np.minimum([rows[k][j] for k in known], cap[j])
                theta = _theta(thetas[j], self.d) if j < len(thetas) else None
                criteria.append(Surrogate(X[known], y, theta, b.refit, self.restarts, b.fit_seed))
        draws = rng.standard_normal((DRAWS, len(self.names)))
        believed = [list(row) for row in front]
        centers = X[on_front] if front else X[[int(np.argmin(b.margins))]]

        def next_point() -> list[float]:
            C = self._around(centers, rng)
            if criteria:
                score = self._ehvi(C, criteria, feasibility, believed, reference, draws)
            else:  # nothing feasible yet: toward feasibility, around the closest point
                mean, std = feasibility.predict(C)
                score = _feasible(mean, std)
            u, _ = self._pick(C, score)
            feasibility.believe(u)
            if criteria:
                believed.append([float(s.gp.predict(u[None, :])[0]) for s in criteria])
                for s in criteria:
                    s.believe(u)
            return self._box(u)

        surrogate = {"feasibility": feasibility.theta,
                     "criteria": [s.theta for s in criteria] or None, "region": None}
        origin = "bo" if front else "bo (no feasible point yet: feasibility only)"
        return Proposal(origin, surrogate, next_point)

    def _around(self, centers: np.ndarray, rng) -> np.ndarray:
        """Half the candidates uniform over the space, half steps from ``centers``."""
        n = CANDIDATES // 2
        uniform = rng.random((n, self.d))
        base = centers[rng.integers(len(centers), size=n)]
        step = np.array(STEPS)[rng.integers(len(STEPS), size=n)][:, None]
        mask = rng.random((n, self.d)) <= min(1.0, 4.0 / self.d)
        empty = ~mask.any(axis=1)
        mask[empty, rng.integers(self.d, size=int(empty.sum()))] = True
        moved = np.clip(base + mask * rng.normal(0.0, 1.0, (n, self.d)) * step, 0.0, 1.0)
        return np.vstack([uniform, moved])

    def _ehvi(self, C, criteria, feasibility, front, reference, draws) -> np.ndarray:
        means, stds = zip(*(s.predict(C) for s in criteria))
        mean, std = np.column_stack(means), np.maximum(np.column_stack(stds), 1e-12)
        samples = (mean[:, None, :] + std[:, None, :] * draws[None, :, :]).reshape(-1, 2)
        gained, rows = pareto.staircase(front, reference), CHUNK * len(draws)
        # a few MB at a time, however long the front
        gain = np.concatenate([gained(samples[k:k + rows]) for k in range(0, len(samples), rows)])
        expected = gain.reshape(len(C), len(draws)).mean(axis=1)
        mean_g, std_g = feasibility.predict(C)
        return expected * _feasible(mean_g, std_g)


def _feasible(mean, std) -> np.ndarray:
    from scipy.stats import norm

    return norm.cdf(-mean / np.maximum(std, 1e-12))
