"""The reach of a fit's start state and of a balancing log's smoother: how far the fitted values
can move because a log's first angles are known only to within an encoder count, a freed start
rate only to what the log's smoother knows of it, and the smoother's estimate of the true angles
only to within its own error.

A replay starts from the state the experiment gives; ``start: data`` takes each angle from
the log's first sample, which the encoder rounded to its nearest count, so the true start lies
anywhere within half a quantum of it. That is not noise the residuals show (it is one fixed
offset per log) and no sandwich covariance holds it: on a balancing log, whose arm the loop
holds weakly, a start half a count off drifts the whole replay, and the fitted values follow it
(on synthetic balancing logs of known truth, fixing the counted starts moved M_f by up to 3 %
and I_a by up to 9 %, several times their sandwich intervals).

Its reach is bounded as the Guide to the Expression of Uncertainty in Measurement treats a
quantity known only within limits (a Type B evaluation; JCGM 100:2008, 4.3.7): the fitted
values are found again with the counted angles at each corner of the box the counts allow
(each half a quantum up or down), by Gauss-Newton steps from the fit with its Jacobian held
(the first step is the least-squares response ``-(J^T J)^-1 J^T d`` to the corner's change of
the residuals ``d``; a few more follow the nonlinearity), and the reach of each unknown is its
largest move over the corners. With more than three counted angles (2^n corners) each angle's
response is read alone (half a quantum up and down, central difference) and the absolute
responses summed: the worst corner, to first order. An interval is then the sandwich's (or the
profile's, or the bootstrap's) widened by the reach on each side. On a 6 s synthetic balancing
log the reach took 16 simulations, and a whole fit again from a corner's start moved each value
by 0.83 to 1.18 times its reach: within the reach plus a fifth of the value's standard error
(the fits' own convergence).

A window cut from a balancing log mid-run starts with rates no reading shows: freed, the fit
takes them as unknowns, and they take up the counted angles' offsets, so the angles' reach is
small there; but the fitted values then follow the rates' own uncertainty, which the sandwich
underestimates (on ten synthetic balancing windows with their rates freed, the truth was within
every sandwich-and-angles interval on 2). What the log knows of the rates is what the smoother
of identify/estimate.py knows of them at the window's first sample (its Rauch-Tung-Striebel
covariance, about 0.008 rad/s on those logs; the fitted rates were up to 4 of those from the
smoother's estimates): each freed rate is held one such standard deviation up and down while
the other unknowns follow (first order, the fit's Jacobian), and the reach is the move that
takes the rates to the smoother's estimates plus the 95 % spread about them (propagated
through the rates' correlation), added to the angles' reach. A freed rate's own reach is its
distance to the smoother's estimate plus its smoothed 95 %.

A balancing log's replay feeds its controller the logged angles moved by the simulation's
departure from the smoother's estimate of the true angles (identify/estimate.py), and that
estimate has its own error, which no residual shows: on a synthetic window with its true start
state, I_a came out 4.3 % low (its sandwich interval +-1.5 %) with the smoother's estimate and
1.2 % low with the true reading errors in its place. Its reach is read from draws of that error
as the smoother's own noise model gives it (estimate.noise_draw: what the smoother makes of
reading noise alone): each of DRAWS draws added to the estimate, the other unknowns refitted to
first order, and the reach is the mean move plus the 95 % spread of the moves (the error works
on the fit in the square, not only linearly: full refits with three draws all moved I_a up, by
0.4 to 1.5 %). The draws are smaller than the smoother's real error on those logs (0.036 and
0.025 quanta RMS against 0.055 and 0.045: the linearized model's error is not in them), so this
reach is what the smoother's noise model says, a lower bound of what it misses.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from furuta_cosim.identify.experiment import Experiment, Free

# the start rates a balancing log's smoother estimates (identify's closed loop: the Furuta's)
RATES = ("dtheta0", "dtheta1")
Z95 = 1.959963984540054


def counted_angles(experiment: Experiment) -> list[tuple[str, float, float]]:
    """(state, value, quantum) of each start state the experiment takes from a counted log
    (``start: data`` on an output with a sensor ``quantum``: an encoder's angle or position)."""
    found = []
    for angle in experiment.outputs:
        measured = experiment.outputs.get(angle)
        value = experiment.start.get(angle)
        if measured is None or not measured.quantum or value is None or isinstance(value, Free):
            continue
        if angle in experiment.from_data:
            found.append((angle, float(value), float(measured.quantum)))
    return found


def start_reach(target, experiments: Sequence[Experiment], items: Sequence, x: np.ndarray,
                J: np.ndarray, seen: Sequence[int], workers: int = 1,
                dask: str | None = None) -> tuple[dict[str, float], dict]:
    """(name -> reach in the unknown's own unit, what it rests on) of each seen unknown of a
    fit at ``x`` (scaled, as fit.py's Problem holds it) with Jacobian ``J`` (its ``seen``
    columns, the fitted experiments' weighted residual rows). Empty when no fitted log starts
    from counted angles or frees the start rates of a balancing log."""
    from furuta_cosim.identify.problem import Problem, Runner, Unknown

    freed, extra = [], []
    for experiment in experiments:
        start = dict(experiment.start)
        for angle, value, quantum in counted_angles(experiment):
            start[angle] = Free((value - quantum, value + quantum), value)
            extra.append(Unknown(f"{experiment.name}.{angle}", value, (value - quantum, value + quantum), quantum))
        changed = start != dict(experiment.start)
        freed.append(replace(experiment, start=type(experiment.start)(start)) if changed else experiment)
    spreads = _rate_spreads(target, experiments, items, x, seen)
    estimated = [e for e in experiments if e.loop is not None and e.loop.estimate]
    if (not extra and not spreads and not estimated) or not len(seen):
        return {}, {}
    runner = Runner(target, freed, workers, dask)
    moves, how = [np.zeros(len(seen))], []
    try:
        problem = Problem(runner, freed, list(items) + extra, None, math.inf, lambda *a: None)
        base = np.concatenate([np.asarray(x, dtype=float), [u.start / u.scale for u in extra]])
        lower = np.array([items[k].bounds[0] / items[k].scale for k in seen])
        upper = np.array([items[k].bounds[1] / items[k].scale for k in seen])
        if extra and len(extra) <= CORNERS:
            moves = _refit(problem, base, J, seen, [np.array(c) for c in
                                                    itertools.product((0.5, -0.5), repeat=len(extra))], lower, upper)
            how.append(f"the angles refitted at each of the {len(moves)} corners")
        elif extra:
            moves = _linear(problem, base, J, len(extra))
            how.append("the angles to first order, summed")
        rates = np.zeros(len(seen))
        if spreads:  # the key None holds their correlations
            rates = _held_rates(problem, base, J, seen, spreads)
            how.append("the freed start rates moved to their smoother's estimates and held by its spread, the rest "
                       "refitted, to first order, propagated to 95 % and added")
        drawn = np.zeros(len(seen))
        if estimated:
            drawn = _drawn(runner, freed, list(items) + extra, base, J, estimated)
            how.append(f"the smoother's estimate of the angles moved by {DRAWS} draws of its own error, the rest "
                       "refitted, to first order: the mean move and the 95 % spread, added")
        simulations = runner.count
    finally:
        runner.close()
    moves = np.max(np.abs(np.array(moves)), axis=0) + rates + drawn
    reach = {items[k].name: float(moves[row] * items[k].scale) for row, k in enumerate(seen)}
    rates = {n: Z95 * sigma for n, (_, sigma, _) in ((n, v) for n, v in spreads.items() if n is not None)}
    for name, (_, sigma, off) in ((n, v) for n, v in spreads.items() if n is not None):
        # a held rate: as far as the smoother's estimate, and its smoothed 95 %
        reach[name] = max(reach[name], (abs(off) + Z95) * sigma)
    return reach, {"angles": [u.name for u in extra], "rates": rates,
                   "smoother": {items[k].name: float(drawn[row] * items[k].scale) for row, k in enumerate(seen)}
                   if estimated else {}, "simulations": simulations, "how": "; ".join(how)}


DRAWS = 8   # draws of a balancing log's smoother error (identify/estimate.py noise_draw)


def _drawn(runner, experiments, items: list, base: np.ndarray, J: np.ndarray, estimated) -> np.ndarray:
    """The move (scaled) of each seen unknown that the smoother's own error carries: the angles
    its estimate gives each balancing log's controller moved by DRAWS draws of that error
    (estimate.noise_draw), the seen unknowns refitted to first order (a Gauss-Newton step on the
    fit's Jacobian) at each; the mean move (the error works on the fit in the square as well as
    linearly) plus its 95 % spread."""
    from furuta_cosim.identify.problem import Problem, Unknown
    from furuta_cosim.identify.replay import NOISE_DRAW

    names = [f"{e.alias or e.name}.{NOISE_DRAW}" for e in estimated]
    draws = [Unknown(name, 0.0, (0.0, math.inf), 1.0) for name in names]
    problem = Problem(runner, experiments, items + draws, None, math.inf, lambda *a: None)
    start = np.concatenate([base, np.zeros(len(draws))])
    points = [start]
    for d in range(1, DRAWS + 1):
        point = start.copy()
        point[len(base):] = d + 100 * np.arange(len(draws))   # each log its own draws
        points.append(point)
    results = problem._evaluate(points)
    D = np.column_stack([r - results[0] for r in results[1:]])
    moves = -np.linalg.lstsq(J, D, rcond=None)[0]          # one column per draw
    return np.abs(moves.mean(axis=1)) + Z95 * moves.std(axis=1, ddof=1)


def _rate_spreads(target, experiments, items, x, seen) -> dict:
    """name -> (its row among ``seen``, its standard deviation, where it lies from the fitted
    rate in standard deviations) of each freed start rate of a log whose angles are estimated
    (a balancing log), as its smoother knows it from the log (identify/estimate.py) at the
    fitted values; and under the key None, their correlations (one block per log)."""
    from furuta_cosim.identify.estimate import start_state

    values = {u.name: float(v) * u.scale for u, v in zip(items, x)}
    plant = {k: v for k, v in values.items() if "." not in k}
    row_of = {items[k].name: row for row, k in enumerate(seen)}
    found, blocks = {}, []
    for experiment in experiments:
        if experiment.loop is None or not experiment.loop.estimate:
            continue
        rates = [r for r in RATES if f"{experiment.name}.{r}" in row_of]
        if not rates:
            continue
        at = {**experiment.parameters, **plant}
        states, first, S = start_state(experiment, target, at)
        rates = [r for r in rates if r in states]
        index = [states.index(r) for r in rates]
        block = S[np.ix_(index, index)]
        sigma = np.sqrt(np.diag(block))
        blocks.append(block / np.outer(sigma, sigma))
        for rate, s in zip(rates, sigma):
            name = f"{experiment.name}.{rate}"
            found[name] = (row_of[name], float(s), (first[states.index(rate)] - values[name]) / float(s))
    if found:
        from scipy.linalg import block_diag

        found[None] = block_diag(*blocks)
    return found


CORNERS = 3          # up to this many counted angles, each corner of their box is refitted
ITERATIONS = 4       # Gauss-Newton steps of a corner's refit (the fit's Jacobian, held)


def _refit(problem, base: np.ndarray, J: np.ndarray, seen, corners: list, lower, upper) -> list[np.ndarray]:
    """The seen unknowns' move (scaled) when the counted angles sit at each of ``corners``
    (half quanta): Gauss-Newton from the fit with its Jacobian held, the other unknowns
    refitted; the corners' replays of one step run together on the workers."""
    n = len(base) - len(corners[0])
    columns = list(seen)
    points = []
    for corner in corners:
        point = base.copy()
        point[n:] += corner
        points.append(point)
    going = list(range(len(points)))
    for _ in range(ITERATIONS):
        if not going:
            break
        results = problem._evaluate([points[c] for c in going])
        still = []
        for c, r in zip(going, results):
            moved = np.clip(points[c][columns] - np.linalg.lstsq(J, r, rcond=None)[0], lower, upper)
            if not np.allclose(moved, points[c][columns], rtol=1e-6, atol=0.0):
                still.append(c)
            points[c][columns] = moved
        going = still
    return [point[columns] - base[columns] for point in points]


def _linear(problem, base: np.ndarray, J: np.ndarray, angles: int) -> list[np.ndarray]:
    """Many counted angles: each angle's move (its residuals at half a quantum up and down,
    central difference) through the least-squares response, summed in absolute value (the
    worst corner, to first order); one row, the reach."""
    n = len(base) - angles
    shifted = []
    for j in range(angles):
        for sign in (0.5, -0.5):
            point = base.copy()
            point[n + j] += sign
            shifted.append(point)
    results = problem._evaluate(shifted)
    D = np.column_stack([(results[2 * j] - results[2 * j + 1]) / 2.0 for j in range(angles)])
    response = np.linalg.lstsq(J, D, rcond=None)[0]
    return [np.sum(np.abs(response), axis=1)]


def _held_rates(problem, base: np.ndarray, J: np.ndarray, seen, spreads: dict) -> np.ndarray:
    """The move of each seen unknown that the freed start rates carry, were they where their
    smoother puts them: each rate held one standard deviation up and down (central difference)
    while the other seen unknowns follow to first order (least squares on the fit's Jacobian
    without the held columns); the move to the smoother's estimates plus their 95 % spread,
    propagated through the rates' correlation."""
    rates = [v for n, v in spreads.items() if n is not None]
    held = [row for row, _, _ in rates]
    keep = [row for row in range(len(seen)) if row not in held]
    shifted = []
    for row, sigma, _ in rates:
        k = seen[row]
        for sign in (1.0, -1.0):
            point = base.copy()
            point[k] += sign * sigma / problem.items[k].scale
            shifted.append(point)
    results = problem._evaluate(shifted)
    D = np.column_stack([(results[2 * j] - results[2 * j + 1]) / 2.0 for j in range(len(held))])
    moves = np.zeros(len(seen))
    if keep:
        M = np.linalg.lstsq(J[:, keep], D, rcond=None)[0]     # per standard deviation of each rate
        toward = M @ np.array([d for _, _, d in rates])
        moves[keep] = np.abs(toward) + Z95 * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", M, spreads[None], M), 0.0))
    return moves


def widened(interval, reach: float | None):
    """``interval`` ([lo, hi], a side None where a profile never crossed) widened by ``reach``
    on each side."""
    if interval is None or not reach:
        return interval
    lo, hi = interval
    return [None if lo is None else lo - reach, None if hi is None else hi + reach]
