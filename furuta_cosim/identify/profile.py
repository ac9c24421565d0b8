"""Profile likelihoods of a fit, and a verdict per parameter (Raue, Kreutz, Maiwald, Bachmann,
Schilling, Klingmueller and Timmer, "Structural and practical identifiability analysis of
partially observed dynamical models by exploiting the profile likelihood", Bioinformatics 25,
2009; what PESTO and pyPESTO compute).

The profile of a free parameter is the fit's cost with that parameter held at a value and every
other unknown fitted again (from the neighbouring point's values), walked outward from the
estimate on both sides until it rises above a threshold or reaches a bound. Its interval is
where it stays below the threshold, read where it crosses.

The threshold. For independent Gaussian residuals a 95 % likelihood-ratio interval is where the
cost (half the sum of squared weighted residuals) rises less than chi2(1, 0.95) / 2 = 1.92
above its minimum, in units of the residuals' variance s^2. The residuals of a fit to a real
log are not independent (the sandwich covariance's reason, identify/fit.py), and that
threshold would give intervals as narrow as the textbook ones. The threshold here is adjusted
as Chandler and Bate adjust an independence likelihood for dependence ("Inference for clustered
data using the independence loglikelihood", Biometrika 94, 2007): for one parameter, scaled by
the ratio of its sandwich variance to its textbook variance. Where the profile is a parabola
the interval is then the sandwich interval; where it is not (skewed, flattening toward a bound)
the two differ, and the profile's is the one that follows the cost.

Verdicts: ``identifiable`` (the profile crosses the threshold on both sides within the bounds),
``practically not identifiable`` (it rises, but stays below the threshold up to a bound on one
side or both: the data bound the parameter on one side at most), ``structurally not
identifiable`` (it is flat: the data do not depend on the parameter, or only in a combination
the other unknowns make up for), ``not profiled`` (its profile ran out of the budget before it
crossed on both sides, or the fit had not converged: a profile from a point that is not the
optimum bounds nothing).

Cost. Each point's refit starts where the fit's own Jacobian predicts the other unknowns go
when this one is held (the linearized optimum), so that it converges in one or two
Gauss-Newton steps; a refit stops at a relative cost change of 1e-6 (a hundredth of a percent
of the threshold is all an interval's end needs). All profiles together spend at most the
spec's ``max_simulations``, each at most its share of it.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping

import numpy as np

from furuta_cosim.identify.problem import Problem, Runner

CHI2_95 = 3.841458820694124    # chi2 quantile, 1 degree of freedom
STEPS = 8                       # profile points per side at most (growing steps, the last at a bound)
FIRST_STEP = 1.0                # the first step, in sandwich standard errors (then 2, 4, ...)
GROWTH = 2.0
FLAT = 1e-3                     # a rise below this fraction of the threshold everywhere: flat
REFIT = 20                      # residual evaluations per refit at most
REFIT_TOLERANCE = 1e-6          # a refit's relative change of cost (and step) where it stops
VERDICTS = ("identifiable", "practically not identifiable", "structurally not identifiable", "not profiled")


def threshold(cost: float, dof: int, sandwich_var: float, plain_var: float) -> float:
    """The cost rise that bounds a 95 % interval (module docstring): chi2 / 2 times the residual
    variance times the sandwich-to-textbook variance ratio (at least 1)."""
    s2 = 2.0 * cost / max(dof, 1)
    ratio = sandwich_var / plain_var if plain_var > 0 and math.isfinite(sandwich_var / plain_var) else 1.0
    return 0.5 * CHI2_95 * s2 * max(ratio, 1.0)


def profile_all(spec, target, result, *, workers: int = 1, dask: str | None = None,
                names=None, done: Mapping | None = None, budget: int | None = None,
                progress: Callable[[str, int, float], None] = lambda name, n, cost: None,
                log: Callable[[str], None] = lambda line: None,
                on_profile: Callable[[str, dict], None] = lambda name, found: None) -> dict:
    """The profile of each free plant parameter of a fit (``result``: identify/fit.py's), and
    its interval and verdict; ``done`` holds profiles computed before (a resumed run).

    Returns name -> {"values", "rise" (the cost above the minimum at each), "threshold",
    "interval" ([lo, hi], None on a side that stays below the threshold), "verdict",
    "simulations"}. ``budget``: simulations for all profiles (the spec's max_simulations when
    None), shared equally; a profile that runs out of its share is ``not profiled``."""

    items = result.items
    index = {u.name: k for k, u in enumerate(items)}
    names = [p.name for p in spec.free] if names is None else list(names)
    x_hat = np.array([result.values[u.name] / u.scale for u in items])
    found = dict(done or {})
    budget = spec.max_simulations if budget is None else int(budget)
    todo = [n for n in names if n not in found and n not in result.unseen]
    share = budget // max(len(todo), 1)
    runner = Runner(target, spec.experiments, workers, dask)
    try:
        problem = Problem(runner, spec.experiments, items, None, math.inf, lambda n, c: None)
        r = problem.fun(x_hat)
        cost = 0.5 * float(r @ r)
        dof = len(r) - len(items)
        J = problem.jac(x_hat) if todo else None
        for name in names:
            if name in found:
                continue
            k = index[name]
            if name in result.unseen:
                found[name] = {"values": [result.values[name]], "rise": [0.0], "threshold": None,
                               "interval": None, "verdict": VERDICTS[2], "simulations": 0,
                               "why": "the data do not depend on it (its column of the Jacobian is zero)"}
            else:
                before = runner.count
                problem.budget = before + share
                found[name] = _profile(problem, items, x_hat, k, cost,
                                       threshold(cost, dof, result.covariance[k, k], result.plain[k, k]),
                                       math.sqrt(max(result.covariance[k, k], 0.0)),
                                       lambda n, c, name=name: progress(f"profile {name}", n, c),
                                       _drift(J, k))
                found[name]["simulations"] = runner.count - before
            log(f"  profile {name}: {found[name]['verdict']}"
                + (f", {_interval_text(found[name]['interval'])}" if found[name]["interval"] else ""))
            on_profile(name, found[name])
    finally:
        runner.close()
    return found


def _interval_text(interval) -> str:
    lo, hi = interval
    return f"[{'below its bound' if lo is None else format(lo, '.4g')}, {'above its bound' if hi is None else format(hi, '.4g')}]"


def _drift(J: np.ndarray | None, k: int) -> np.ndarray | None:
    """How the other unknowns' optimum moves per unit of unknown ``k`` held (scaled units), to
    first order: minus the least-squares solution of J_others dz = J_k."""
    if J is None or J.shape[1] < 2:
        return None
    others = [j for j in range(J.shape[1]) if j != k]
    found, *_ = np.linalg.lstsq(J[:, others], J[:, k], rcond=None)
    return -found if np.all(np.isfinite(found)) else None


def _profile(problem: Problem, items, x_hat: np.ndarray, k: int, cost: float, rise_max: float,
             stderr: float, progress, drift: np.ndarray | None = None) -> dict:
    """One parameter's profile: both sides walked from the estimate (module docstring); its
    refits start where ``drift`` (:func:`_drift`) predicts, and it ends ``not profiled`` when
    ``problem``'s budget runs out."""
    from furuta_cosim.identify.problem import BudgetSpent

    others = [j for j in range(len(items)) if j != k]
    lower = np.array([u.bounds[0] / u.scale for u in items])
    upper = np.array([u.bounds[1] / u.scale for u in items])
    # the covariance (and so ``stderr``) is in the fit's scaled units already, as x_hat is
    step0 = FIRST_STEP * stderr if math.isfinite(stderr) and stderr > 0 else math.inf
    points = {float(x_hat[k]): 0.0}
    crossing: list = [None, None]
    try:
        spent = _walk(problem, x_hat, k, cost, rise_max, step0, lower, upper, others, points,
                      crossing, progress, drift)
    except BudgetSpent:
        spent = True
    values = sorted(points)
    rises = [points[v] for v in values]
    scale = items[k].scale
    if spent and (crossing[0] is None or crossing[1] is None):
        return {"values": [v * scale for v in values], "rise": rises, "threshold": rise_max,
                "interval": None, "verdict": VERDICTS[3],
                "why": "its profile ran out of its share of the budget before it crossed the threshold "
                       "on both sides"}
    flat = max(rises) < FLAT * rise_max
    if flat:
        verdict = VERDICTS[2]
    elif crossing[0] is None or crossing[1] is None:
        verdict = VERDICTS[1]
    else:
        verdict = VERDICTS[0]
    interval = None if flat else [None if c is None else c * scale for c in crossing]
    return {"values": [v * scale for v in values], "rise": rises, "threshold": rise_max,
            "interval": interval, "verdict": verdict}


def _walk(problem, x_hat, k, cost, rise_max, step0, lower, upper, others, points, crossing,
          progress, drift) -> bool:
    """Walk both sides of unknown ``k`` (filling ``points`` and ``crossing``); False when done."""
    from scipy.optimize import least_squares

    for side, (edge, sign) in enumerate(((lower[k], -1.0), (upper[k], 1.0))):
        room = abs(edge - x_hat[k])
        if room <= 0:
            continue
        # from one standard error, doubling; the last point at the bound whatever it reached
        step = step0 if math.isfinite(step0) else room / GROWTH ** (STEPS - 1)
        z = x_hat[others].copy()
        last_value, last_rise = float(x_hat[k]), 0.0
        for n in range(STEPS):
            value = float(x_hat[k] + sign * min(step * GROWTH ** n, room))
            if n == STEPS - 1:
                value = float(edge)  # the last point at the bound
            full = x_hat.copy()

            def fun(zz, value=value):
                full[others], full[k] = zz, value
                return problem.fun(full.copy())

            def jac(zz, value=value):
                full[others], full[k] = zz, value
                return problem.jac(full.copy(), columns=others)

            if others:
                if drift is not None:  # where the other unknowns' optimum goes, to first order
                    z = z + drift * (value - last_value)
                z0 = np.clip(z, lower[others], upper[others])
                found = least_squares(fun, z0, jac=jac, bounds=(lower[others], upper[others]), x_scale="jac",
                                      method="trf", xtol=REFIT_TOLERANCE, ftol=REFIT_TOLERANCE,
                                      gtol=REFIT_TOLERANCE, max_nfev=REFIT)
                z, at = found.x, float(found.cost)
            else:  # the only unknown: nothing to fit again
                r = fun(z)
                at = 0.5 * float(r @ r)
            rise = max(at - cost, 0.0)
            points[value] = rise
            progress(problem.runner.count, at)
            if rise >= rise_max:
                # where it crosses: linear in the square root of the rise (exact for a parabola)
                a, b = math.sqrt(last_rise), math.sqrt(rise)
                t = (math.sqrt(rise_max) - a) / (b - a) if b > a else 1.0
                crossing[side] = last_value + t * (value - last_value)
                break
            last_value, last_rise = value, rise
            if value == edge:
                break
    return False
