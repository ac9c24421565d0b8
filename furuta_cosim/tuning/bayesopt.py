"""Bayesian optimization's internals (the `bo` method of tuning/methods.py, the registry): where a
tuning's candidates come from.

``bo`` is constrained Bayesian optimization after Gardner, Kusner, Xu, Weinberger and
Cunningham, "Bayesian Optimization with Inequality Constraints" (ICML 2014), the method
BoTorch's ``ConstrainedExpectedImprovement`` implements: two Gaussian processes (scikit-learn's,
a Matern 5/2 kernel with a length scale per parameter, on the unit cube):

- one of the objective, on every evaluated point where it could be computed, feasible or
  not: near the boundary of the feasible set, where the best controllers are, the infeasible
  side tells as much about the objective as the feasible one;
- one of the feasibility margin (tuning/objective.py: the largest normalized slack of the
  co-simulated constraints, <= 0 when every one is met), on every point but those the loop's
  exact checks refused: failures count as clearly infeasible.

The loop's own constraints (its stability margin on the design model, the sampled loop's
abscissa, the controller's stability) are not learned: they cost a millisecond, so the
acquisition's candidates are checked exactly, best first, and the best one that passes is
proposed (``screen``); a candidate that fails them is never co-simulated.

The acquisition is Expected Improvement over the best feasible value times the probability of
feasibility; until a feasible point is known, the probability alone. It is maximized over
candidates drawn in trust regions (``region: trust``, the default: TuRBO's, Eriksson, Pearce,
Gardner, Turner and Poloczek, NeurIPS 2019; a region doubles after 3 improving batches in a
row and halves after max(4, d) / batch batches without one) or in the whole space (``region:
global``). There are two regions (``LANES``), taking turns point by point: one around the best
feasible point of all, one around the best of its own points and the run's first point (the
warm start), so that a run whose best has moved early to another basin still searches
around the controller it started from. A region's sides follow the objective's length scales
(TuRBO's weights); the second region's are at most its length (``OWN_WIDEST``), so that one
long length scale does not stretch it across the whole box and away from the basin it
follows (10 seeds each: docs, Performance). The points of a
batch come one after another, each told to the surrogates at its predicted value (the kriging
believer) before the next is computed.

Every proposal is a function of the history before its batch, the seed and the batch's number,
so that a run's history depends only on the spec, the seed and ``optimizer.batch``: never on
the number of workers, and a resumed run proposes exactly what the uninterrupted run did. The
kernel's hyperparameters are fitted at every ``REFIT_EVERY``-th batch, to convergence from the
ones the batch before used (recorded in the history: ``surrogate``) and from the kernel's
defaults, keeping the likelier (tuning/gp.py), and reused in between.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from scipy.stats import norm, qmc

from furuta_cosim.tuning.gp import Surrogate

# the kernel hyperparameters are fitted at every this many batches (reused between)
REFIT_EVERY = 3
# acquisition candidates per point (drawn in the region, then this many again around the best)
CANDIDATES = 2048
# TuRBO's trust region, as side lengths of the unit cube
REGION_START, REGION_MIN, REGION_MAX = 0.8, 0.5**7, 1.6
SUCCESSES = 3
# trust regions, taking turns point by point: around the best of all, and one that follows its
# own points from the warm start (_region)
LANES = 2
# the widest side of the second region, in units of its length (the first: as the length
# scales make it, up to the box)
OWN_WIDEST = 1.0
REGIONS = ("trust", "global")
# where bo starts (optimizer.start): around the spec's first baseline, or over the whole space;
# auto starts at the baseline for a budget of at most FEW_EVALUATIONS. Measured over 10 seeds
# on effort (tools/bench_tune.py; docs: Tuning): at 20, 30, 50 and 100 evaluations the start at
# the baseline reached a median of 1.065, 1.057, 1.052 and 1.023 where the space-filling start
# reached 1.101, 1.101, 1.086 and 1.048; at 150 the space-filling start's worst seed was better
# (1.030 against 1.036), so it stays the start of long runs
STARTS = ("auto", "baseline", "space")
FEW_EVALUATIONS = 100
# the start at the baseline: this many points of a Latin hypercube in a box of side BOX_SIDE
# (of the unit cube) around it, trust regions from BASELINE_REGION, and candidates that move
# about PERTURBED coordinates of their center at a time (TuRBO moves 20 of them: in 11
# dimensions, every one; at 30 evaluations fewer moves found better controllers)
LOCAL_POINTS, BOX_SIDE, BASELINE_REGION, PERTURBED = 3, 0.2, 0.1, 3.0
# a tradeoff's search: auto is ehvi for two criteria, parego for more (tuning/mobo.py, pareto.py)
FRONTS = ("auto", "ehvi", "parego")


@dataclass
class Proposal:
    """One batch: its points one at a time (``points(count)``), and what proposed them."""

    origin: str                 # "bo", or "bo (no feasible point yet ...)"
    surrogate: dict             # hyperparameters and region: recorded with each point
    _next: object = None        # computes the next point

    def points(self, count: int) -> Iterator[list[float]]:
        for _ in range(count):
            yield self._next()


@dataclass
class _Batch:
    """What every proposal of a batch starts from (ConstrainedBO._batch)."""

    rng: np.random.Generator    # the batch's random stream
    fit_seed: int               # the GPs' random state
    X: np.ndarray               # the history on the unit cube
    previous: dict              # the hyperparameters the batch before used
    refit: bool                 # whether this batch fits them again
    margins: np.ndarray         # the feasibility margins
    feasibility: Surrogate      # and their GP


def latin_hypercube(n: int, bounds, seed: int) -> list[list[float]]:
    """``n`` points of a Latin hypercube over ``bounds`` (scipy's, seeded): the initial design."""
    if n <= 0:
        return []
    low, high = (np.array(b, dtype=float) for b in zip(*bounds))
    unit = qmc.LatinHypercube(d=len(low), seed=np.random.default_rng([seed, 0])).random(n)
    return (low + unit * (high - low)).tolist()


class RandomSearch:
    """Uniform draws from the same space: the i-th point depends on the seed and i only."""

    def __init__(self, bounds, seed: int):
        self._low, self._high = (np.array(b, dtype=float) for b in zip(*bounds))
        self._seed = seed

    def point(self, index: int) -> list[float]:
        rng = np.random.default_rng([self._seed, 1, index])
        return (self._low + rng.random(len(self._low)) * (self._high - self._low)).tolist()


def local_design(n: int, center, bounds, seed: int, side: float = BOX_SIDE) -> list[list[float]]:
    """``n`` points of a Latin hypercube (scipy's, seeded) in a box of ``side`` (a fraction of
    each bound's width) around ``center``, clipped to ``bounds``: the start at a baseline."""
    if n <= 0:
        return []
    low, high = (np.array(b, dtype=float) for b in zip(*bounds))
    middle = (np.asarray(center, dtype=float) - low) / (high - low)
    unit = qmc.LatinHypercube(d=len(low), seed=np.random.default_rng([seed, 0])).random(n)
    return (low + np.clip(middle + (unit - 0.5) * side, 0.0, 1.0) * (high - low)).tolist()


def _region(records, start: int, batch: int, d: int, lane: int | None = None,
            lanes: int = 1, initial: float = REGION_START) -> tuple[float, list]:
    """The trust region's side length after the batches recorded from ``start`` on (TuRBO's
    rule, replayed over the history), and its best feasible record so far. Without ``lane``
    the region of the whole history: its center is the best point of all. With ``lane``, the
    region that follows only its own points (record ``k`` belongs to lane ``(k - start) %
    lanes``) from the run's first point (the warm start: the spec's first baseline, or the
    initial design's first point in a run without one)."""
    length, successes, failures = initial, 0, 0
    patience = max(1, math.ceil(max(4, d) / batch))
    best = _best(records[:start]) if lane is None else _best(records[:1])
    for first in range(start, len(records), batch):
        chunk = records[first:first + batch]
        if len(chunk) < batch and first + len(chunk) == len(records):
            break  # a batch still being evaluated
        if lane is not None:
            chunk = [r for r in chunk if (r["index"] - start) % lanes == lane]
            if not chunk:
                continue
        new = _best(chunk)
        if new is not None and (best is None or new["objective"] < best["objective"]
                                - 1e-3 * abs(best["objective"])):
            successes, failures = successes + 1, 0
        else:
            successes, failures = 0, failures + 1
        if new is not None and (best is None or new["objective"] < best["objective"]):
            best = new
        if successes >= SUCCESSES:
            length, successes = min(2 * length, REGION_MAX), 0
        elif failures >= patience:
            length, failures = length / 2, 0
        if length < REGION_MIN:  # converged: start again around the incumbent
            length, successes, failures = initial, 0, 0
    return length, best


def _best(records):
    feasible = [r for r in records if r["feasible"]]
    return min(feasible, key=lambda r: (r["objective"], r["index"])) if feasible else None


class ConstrainedBO:
    """The proposals of ``bo`` (module doc) over a box ``bounds``."""

    def __init__(self, bounds, seed: int, *, xi: float, n_initial_points: int, batch: int,
                 gp_restarts: int = 0, region: str = "trust", screen=None, start: str = "space"):
        self.low, self.high = (np.array(b, dtype=float) for b in zip(*bounds))
        # a start at the baseline searches close to it (STARTS)
        self.initial = BASELINE_REGION if start == "baseline" else REGION_START
        self.perturbed = PERTURBED if start == "baseline" else 20.0
        self.d = len(self.low)
        self.seed, self.xi, self.batch = seed, xi, batch
        self.n_initial_points, self.restarts, self.region = n_initial_points, gp_restarts, region
        self.screen = screen  # x -> bool: a constraint cheap enough to check exactly (stability)

    def _unit(self, x) -> np.ndarray:
        return (np.asarray(x, dtype=float) - self.low) / (self.high - self.low)

    def _box(self, u: np.ndarray) -> list[float]:
        return (self.low + np.clip(u, 0.0, 1.0) * (self.high - self.low)).tolist()

    def propose(self, records: list[dict], start: int, number: int) -> Proposal:
        """Batch ``number`` (0 = the first after the initial design) from the ``records``
        before it; ``start``: where the batches begin in the history. The surrogates are
        fitted here; each point is computed when asked for."""
        b = self._batch(records, number)
        rng, X, margins, feasibility = b.rng, b.X, b.margins, b.feasibility
        valued = [k for k, r in enumerate(records) if _finite(r.get("value"))]
        best = _best(records)
        objective = None
        if best is not None and len(valued) >= 2:
            objective = Surrogate(X[valued], [records[k]["value"] for k in valued],
                                   _theta(b.previous.get("objective"), self.d), b.refit,
                                   self.restarts, b.fit_seed)
        length, _ = _region(records, start, self.batch, self.d, initial=self.initial)
        if best is not None:
            center = self._unit(best["x"])
        else:  # nothing feasible yet: around the point closest to feasibility
            center = X[int(np.argmin(margins))]
        regions = [(center, length, None)]
        for lane in range(1, LANES):
            own_length, own = _region(records, start, self.batch, self.d, lane, LANES, self.initial)
            where, size = (self._unit(own["x"]), own_length) if own is not None else (center, length)
            regions.append((where, size, OWN_WIDEST))

        told = []  # the batch's points so far: each is believed before the next is computed

        def next_point() -> list[float]:
            if told:
                feasibility.believe(told[-1])
                if objective is not None:
                    objective.believe(told[-1])
            where, size, widest = regions[(len(records) + len(told) - start) % LANES]
            u = self._maximize(objective, feasibility, best, where, size, rng, widest)
            told.append(u)
            return self._box(u)

        sizes = [size for _, size, _ in regions]
        surrogate = {"feasibility": feasibility.theta,
                     "objective": objective.theta if objective else None,
                     "region": sizes if self.region == "trust" else None}
        origin = "bo" if best is not None else "bo (no feasible point yet: feasibility only)"
        return Proposal(origin, surrogate, next_point)

    def _batch(self, records: list[dict], number: int) -> _Batch:
        """What every proposal of batch ``number`` starts from: its random stream, the history
        on the unit cube, the hyperparameters the batch before used, whether to refit them,
        the feasibility margins and their GP."""
        rng = np.random.default_rng([self.seed, 2, number])
        fit_seed = int(rng.integers(2**31 - 1))
        X = np.array([self._unit(r["x"]) for r in records])
        previous = records[-1].get("surrogate") if records else None
        previous = previous if isinstance(previous, dict) else {}
        refit = number % REFIT_EVERY == 0
        margins = np.array([_number(r.get("margin"), 1.0) for r in records])
        # a point the loop's exact checks refused is left out: those constraints are checked
        # for every candidate (screen), not learned
        modelled = [k for k, r in enumerate(records) if not r.get("known")] or list(range(len(records)))
        feasibility = Surrogate(X[modelled], margins[modelled], _theta(previous.get("feasibility"), self.d),
                                 refit, self.restarts, fit_seed)
        return _Batch(rng, fit_seed, X, previous, refit, margins, feasibility)

    def _candidates(self, center, length, weights, rng, n) -> np.ndarray:
        if self.region == "global":
            return rng.random((n, self.d))
        half = 0.5 * length * weights
        low, high = np.clip(center - half, 0, 1), np.clip(center + half, 0, 1)
        box = low + rng.random((n, self.d)) * (high - low)
        # TuRBO: perturb only some coordinates of the center, so that high dimensions still
        # move in few directions at a time
        mask = rng.random((n, self.d)) <= min(1.0, self.perturbed / self.d)
        empty = ~mask.any(axis=1)
        mask[empty, rng.integers(self.d, size=int(empty.sum()))] = True
        return np.where(mask, box, center)

    def _maximize(self, objective, feasibility, best, center, length, rng,
                  widest: float | None = None) -> np.ndarray:
        weights = _weights((objective or feasibility).length_scales(), widest)
        C = self._candidates(center, length, weights, rng, CANDIDATES)
        top, score = self._pick(C, self._acquisition(C, objective, feasibility, best))
        # a second, finer look around the best candidate
        near = np.clip(top + rng.normal(0.0, 0.02 * length, (CANDIDATES // 4, self.d)) * weights, 0, 1)
        closer, closer_score = self._pick(near, self._acquisition(near, objective, feasibility, best))
        return closer if closer_score > score else top

    def _pick(self, C, scores) -> tuple[np.ndarray, float]:
        """The best candidate by acquisition that passes the exact cheap check (its score),
        or the best one (score -inf) when none does. Candidates are checked best first, so
        the check costs one candidate's where the acquisition's best passes."""
        order = np.argsort(-scores, kind="stable")
        for k in order:
            if self.screen is None or self.screen(self._box(C[k])):
                return C[k], float(scores[k])
        return C[order[0]], -math.inf

    def _acquisition(self, C, objective, feasibility, best) -> np.ndarray:
        mean_g, std_g = feasibility.predict(C)
        feasible = norm.cdf(-mean_g / np.maximum(std_g, 1e-12))
        if objective is None:
            return feasible
        mean, std = objective.predict(C)
        spread = float(np.std(objective.y)) or 1.0
        improvement = best["objective"] - mean - self.xi * spread
        std = np.maximum(std, 1e-12)
        z = improvement / std
        ei = improvement * norm.cdf(z) + std * norm.pdf(z)
        return np.maximum(ei, 0.0) * feasible


def _weights(scales, widest: float | None = None) -> np.ndarray:
    """A region's sides in units of its length: the length scales over their geometric mean
    (TuRBO's), each at most ``widest`` when given."""
    weights = np.asarray(scales, dtype=float) / np.exp(np.mean(np.log(scales)))
    return weights if widest is None else np.minimum(weights, widest)


def _number(value, default: float) -> float:
    return float(value) if _finite(value) else default


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _theta(value, d: int):
    """Hyperparameters recorded in the history, when they fit this kernel (else None)."""
    if isinstance(value, list) and len(value) == d + 2 and all(_finite(v) for v in value):
        return value
    return None


def batches(n_initial: int, batch: int, total: int) -> Iterator[tuple[int, int, int]]:
    """(number, first index, count) of each batch after the initial design of a run of
    ``total`` evaluations."""
    number, first = 0, n_initial
    while first < total:
        count = min(batch, total - first)
        yield number, first, count
        number, first = number + 1, first + count
