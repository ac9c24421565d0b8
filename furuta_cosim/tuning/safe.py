"""The ``safe`` method: Bayesian optimization on a rig that proposes only candidates its model
says meet every constraint, the simulation as its prior (docs: Tuning on the rig).

The model. A trial's objective value f and each constraint's slack g (tuning/objective.py: a
normalized slack, <= 0 when met, clipped to [-1, 1]) are the simulation's plus a gap,

    f_rig(x) = f_sim(x) + d_f(x),        g_rig(x) = g_sim(x) + d_g(x),

the autoregressive multi-fidelity model of Kennedy and O'Hagan (Biometrika 87, 2000) with its
scale fixed to 1, as Marco, Berkenkamp, Hennig, Schoellig, Krause, Schaal and Trimpe trade
simulations against physical experiments ("Virtual vs. real", ICRA 2017), and the simulation as
the prior mean of the rig's function, as in Cully, Clune, Tarapore and Mouret ("Robots that can
adapt like animals", Nature 521, 2015). A simulation costs milliseconds, a trial tens of
seconds: the simulation is run at every point considered for the rig, and only the gap is
learned from trials. f_sim and each g_sim are GPs over the simulated tuning's history
(``simulation/``) and every candidate simulated for a trial (tuning/gp.py, their
hyperparameters fitted once on that history); each gap is a GP over the trials' residuals (the
trial minus the same candidate simulated) with a kernel fixed before the first trial
(:data:`GAP`): a constant part (the rig offset from the model everywhere), a local part at
half the simulation GP's length scales, and a trial's noise, the one hyperparameter fitted,
and only upward from its floor; a new trial is predicted with that noise's upper confidence
bound (:data:`NOISE_CONFIDENCE`), not the fitted value a few trials give. Fixed, because a handful of trials cannot fit
hyperparameters, and a fit that shrinks the gap's variance would make the model sure of what
it has not seen. A constraint on plant variants counts as its worst variant's.

The safe set (Sui, Gotovos, Burdick and Krause, "Safe exploration for optimization with
Gaussian processes", ICML 2015; Berkenkamp, Krause and Schoellig, "Bayesian optimization with
safety constraints: safe and automatic parameter tuning in robotics", Machine Learning 2021):
a candidate may run on the rig only if for every constraint the simulation at x plus the gap's
mean plus ``beta`` of its standard deviations is <= 0, the simulation at x did not fail, and
the loop's exact stability checks pass. The first trial is the safe seed (the spec's first
baseline, the LQR): where the gap is first measured. Among the safe candidates the one with
the lowest lower confidence bound of the objective runs (optimism inside the safe set, GP-LCB
as in Srinivas, Krause, Kakade and Seeger, ICML 2010); if none of the best ``TRIES`` passes
with its simulation, the most uncertain safe candidates are tried (SafeOpt's expanders: where a
trial teaches the most); if none at all, the best safe trial runs again. Candidates are drawn
around the safe trials, around the simulation's best points and over the whole space.

The guarantee, honestly: with probability about Phi(beta) per constraint and trial (97.7 % at
beta = 2), and only while each gap really is like a draw of its kernel (smooth at those length
scales, of that size, the noise no larger than its upper bound), a proposed trial meets the
constraints. A rig whose gap is larger or rougher can break them; the supervisor's limits
still hold the rig, and the summary lists every trial that broke a constraint.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from furuta_cosim.tuning.gp import Surrogate

# the gap between simulation and rig as the model assumes it before any trial (standard
# deviations): of its constant part, of its local part, and of one trial's noise (its floor);
# in the units of a slack (normalized: 0.1 is a tenth of a bound) and of the objective
# (relative terms: a tenth of the baseline's); the local part's length scales are this fraction
# of the simulation GP's. A trial's noise measured on the virtual QUBE (a tracking ratio's
# trial-to-trial deviation): 0.02 for the LQR; for a low-gain candidate 0.04 (IAE), 0.09 (ISE)
GAP = {"offset": 0.3, "local": 0.2, "noise": 0.03, "lengths": 0.5}
# the trial noise is fitted from this many trials on, up to this standard deviation; a new
# trial's spread is predicted with the noise's upper confidence bound at this level
NOISE_FIT, NOISE_MAX = 3, 0.5
NOISE_CONFIDENCE = 0.95
# candidates per proposal: over the whole space, around each of the best safe trials, around each
# of the simulation's best points
GLOBAL, AROUND_TRIALS, AROUND_SIMULATION = 1024, 512, 256
BEST_TRIALS, BEST_SIMULATED = 8, 5
# the safe candidates simulated at most per proposal and kind (best lower bound, then most
# uncertain) before the best safe trial runs again
TRIES = 16


@dataclass
class SafeProposal:
    """One point, what proposed it, and what the model predicted there."""

    x: list
    origin: str
    surrogate: dict


def _unit(bounds):
    low, high = (np.array(b, dtype=float) for b in zip(*bounds))
    return low, high


class SafeBO:
    """The proposals of the ``safe`` method (module docstring) over a box ``bounds``.

    Parameters
    ----------
    bounds : list of (low, high)
        The search space.
    seed : int
        Its random streams (one per proposal number).
    fidelity : Fidelity
        The simulated fidelity (tuning/rig.py): its history, and ``exact(x)``.
    beta : float
        The confidence bounds' width in standard deviations.
    screen : callable, optional
        ``screen(x) -> bool``: the loop's exact checks.
    """

    def __init__(self, bounds, seed: int, fidelity, *, beta: float = 2.0, screen=None):
        self.low, self.high = _unit(bounds)
        self.d = len(self.low)
        self.seed, self.fidelity, self.beta, self.screen = seed, fidelity, beta, screen
        self._theta = None  # the simulation GPs' hyperparameters, fitted once on its history

    def _u(self, x) -> np.ndarray:
        return (np.asarray(x, dtype=float) - self.low) / (self.high - self.low)

    def _x(self, u) -> list[float]:
        return (self.low + np.clip(u, 0.0, 1.0) * (self.high - self.low)).tolist()

    # -- the simulation's GPs --------------------------------------------------------------
    def _simulated(self, records) -> list[tuple]:
        """(x, value, slacks by constraint) of every simulated candidate: the simulated tuning's
        history and the candidates simulated for trials. A constraint on plant variants is the
        worst variant's (``run[k].metric`` -> ``run.metric``)."""
        found = [(r["x"], r.get("value"), r.get("slacks")) for r in self.fidelity.records if not r.get("known")]
        found += [(r["x"], r["simulation"].get("value"), r["simulation"].get("slacks"))
                  for r in records if isinstance(r.get("simulation"), dict) and not r["simulation"].get("known")]
        return [(x, value, _worst_variant(slacks)) for x, value, slacks in found]

    def _simulation(self, points, names):
        """GPs of the simulated value and of each constraint's slack. Their hyperparameters are
        fitted once, on the simulated tuning's history alone (the first ``len(fidelity.records)``
        points, the same in a resumed run), then kept."""
        if self._theta is None:
            own = points[:len([r for r in self.fidelity.records if not r.get("known")])]
            self._theta = {name: model.theta for name, model in self._fit(own, names, None).items()}
        return self._fit(points, names, self._theta)

    def _fit(self, points, names, theta) -> dict:
        X = np.array([self._u(x) for x, _, _ in points]).reshape(-1, self.d)
        refit = theta is None
        theta = theta or {}
        valued = [k for k, (_, v, _) in enumerate(points) if _finite(v)]
        models = {"value": Surrogate(X[valued], [points[k][1] for k in valued], theta.get("value"), refit, 0,
                                     self.seed)}
        for name in names:
            have = [k for k, (_, _, slacks) in enumerate(points) if _finite(slacks.get(name))]
            if len(have) >= 2 and (refit or name in theta):
                models[name] = Surrogate(X[have], [points[k][2][name] for k in have], theta.get(name), refit, 0,
                                         self.seed)
        return models

    # -- the gap's GPs ---------------------------------------------------------------------
    @staticmethod
    def _gap(X, residuals, lengths):
        from scipy.stats import chi2
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        X = np.asarray(X, dtype=float).reshape(-1, len(lengths))
        if not len(X):
            return None
        # a trial's noise is the one hyperparameter fitted (by likelihood, from 3 trials on), and
        # only upward from its floor: a rig noisier than assumed widens the bounds
        fitted = len(X) >= NOISE_FIT
        kernel = (ConstantKernel(GAP["offset"] ** 2, "fixed")
                  + ConstantKernel(GAP["local"] ** 2, "fixed")
                  * Matern(np.asarray(lengths) * GAP["lengths"], "fixed", nu=2.5)
                  + WhiteKernel(GAP["noise"] ** 2, (GAP["noise"] ** 2, NOISE_MAX ** 2) if fitted else "fixed"))
        gp = GaussianProcessRegressor(kernel, optimizer="fmin_l_bfgs_b" if fitted else None,
                                      normalize_y=False, alpha=1e-10)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the noise at its floor: expected
            gp.fit(X, np.asarray(residuals, dtype=float))
        # the noise fitted from n trials is itself uncertain (on the worn rig a constraint's
        # noise came out under what its trials then showed, and 4 trials in 300 broke it at
        # beta 2): a new trial's spread takes its upper confidence bound, the fitted variance
        # times n / chi2_(1 - NOISE_CONFIDENCE)(n) (its standard deviation 2.1 times the fitted one after
        # 5 trials, 1.3 times after 30)
        noise = gp.kernel_.k2.noise_level
        upper = noise * len(X) / chi2.ppf(1.0 - NOISE_CONFIDENCE, len(X)) if fitted else noise
        gp.noise_variances = (noise, upper)
        return gp

    @staticmethod
    def _predict(gap, C):
        """(mean, standard deviation) of a new trial's gap at the candidates ``C``: the GP's
        mean, and its spread with the trial noise's upper confidence bound."""
        if gap is None:
            return np.zeros(len(C)), np.full(len(C), math.sqrt(GAP["offset"] ** 2 + GAP["local"] ** 2
                                                                + GAP["noise"] ** 2))
        mean, std = gap.predict(C, return_std=True)
        fitted, upper = gap.noise_variances
        return mean, np.sqrt(np.maximum(std ** 2 - fitted, 0.0) + upper)

    def propose(self, records: list[dict], number: int) -> SafeProposal:
        """The next trial from the trials so far (``records``: the run's history, the safe
        seed first); ``number`` seeds its random stream."""
        rng = np.random.default_rng([self.seed, 11, number])
        trials = [r for r in records if isinstance(r.get("simulation"), dict) and not r.get("known")
                  and isinstance(r.get("slacks"), dict)]
        names = sorted(set().union(*(r["slacks"] for r in trials))) if trials else []
        models = self._simulation(self._simulated(records), names)
        names = [name for name in names if name in models]
        X = np.array([self._u(r["x"]) for r in trials]).reshape(-1, self.d)
        simulated = [_worst_variant(r["simulation"].get("slacks")) for r in trials]
        gaps = {}
        for name in names:
            have = [k for k, r in enumerate(trials) if _finite(r["slacks"].get(name)) and _finite(simulated[k].get(name))]
            gaps[name] = self._gap(X[have], [trials[k]["slacks"][name] - simulated[k][name] for k in have],
                                   models[name].length_scales())
        valued = [k for k, r in enumerate(trials) if _finite(r.get("value")) and _finite(r["simulation"].get("value"))]
        gap_f = self._gap(X[valued], [trials[k]["value"] - trials[k]["simulation"]["value"] for k in valued],
                          models["value"].length_scales())

        C = self._candidates(records, models["value"], rng)
        upper = np.full(len(C), -np.inf)
        bounds = {}
        for name in names:
            mean, std = models[name].predict(C)
            gm, gs = self._predict(gaps[name], C)
            bounds[name] = (gm, gs)
            upper = np.maximum(upper, mean + gm + self.beta * np.sqrt(std ** 2 + gs ** 2))
        mean_f, std_f = models["value"].predict(C)
        fm, fs = self._predict(gap_f, C)
        lower_f = mean_f + fm - self.beta * np.sqrt(std_f ** 2 + fs ** 2)
        safe = np.flatnonzero(upper <= 0.0)
        # the lowest objective bound first; then, should none of those pass the exact check, the
        # most uncertain (where a trial would teach the most: SafeOpt's expanders)
        width = np.max([bounds[name][1] for name in names], axis=0) if names else np.zeros(len(C))
        for kind, order in (("safe", safe[np.argsort(lower_f[safe], kind="stable")]),
                            ("safe (expanding: the most uncertain safe candidate)",
                             safe[np.argsort(-width[safe], kind="stable")])):
            tried = 0
            for k in order:
                if tried >= TRIES:
                    break
                x = self._x(C[k])
                if self.screen is not None and not self.screen(x):
                    continue
                tried += 1
                exact = self.fidelity.exact(x)
                slacks = _worst_variant(exact.get("slacks"))
                if exact.get("known") or not _finite(exact.get("value")) \
                        or any(not _finite(slacks.get(name)) for name in names):
                    continue  # the simulation failed there: no candidate for a rig
                # the simulation itself at x, each constraint's gap bound on top of it
                predicted = {name: (slacks[name] + bounds[name][0][k], bounds[name][1][k]) for name in names}
                worst = max((m + self.beta * s for m, s in predicted.values()), default=-math.inf)
                if worst <= 0.0:
                    active = max(predicted, key=lambda n: predicted[n][0] + self.beta * predicted[n][1])
                    return SafeProposal(x, kind, {
                        "beta": self.beta, "safe_candidates": int(len(safe)), "simulated": tried,
                        "predicted": {"constraint": active, "slack": float(predicted[active][0]),
                                      "slack_std": float(predicted[active][1]), "bound": float(worst),
                                      "value": float(exact["value"] + fm[k]), "value_std": float(fs[k])}})
        # nothing new is safe enough: the best safe trial again (its second measurement)
        best = _best_safe(records)
        return SafeProposal(list(best["x"]), "safe (no new candidate is safe enough: the best safe trial again)",
                            {"beta": self.beta, "safe_candidates": int(len(safe))})

    def _candidates(self, records, model, rng) -> np.ndarray:
        weights = _weights(model.length_scales())
        parts = [rng.random((GLOBAL, self.d))]
        safe = sorted((r for r in records if r.get("feasible") and r.get("trial")),
                      key=lambda r: (r["objective"], r["index"]))[:BEST_TRIALS]
        for r in safe:
            center = self._u(r["x"])
            for scale in (0.03, 0.1):
                parts.append(center + rng.normal(0.0, scale, (AROUND_TRIALS // 2, self.d)) * weights)
        simulated = sorted((r for r in self.fidelity.records if r.get("feasible")),
                           key=lambda r: (r["objective"], r["index"]))[:BEST_SIMULATED]
        for r in simulated:
            parts.append(self._u(r["x"]) + rng.normal(0.0, 0.05, (AROUND_SIMULATION, self.d)) * weights)
        return np.clip(np.vstack(parts), 0.0, 1.0)


def _worst_variant(slacks) -> dict:
    """Slacks by constraint with the plant variants' folded into their worst (``run[k].x`` ->
    ``run.x``); only finite numbers."""
    found = {}
    for name, value in (slacks or {}).items():
        if not _finite(value):
            continue
        run, dot, rest = name.partition(".")
        key = (run.split("[", 1)[0] + dot + rest) if run.endswith("]") else name
        found[key] = max(found.get(key, -math.inf), float(value))
    return found


def _weights(scales) -> np.ndarray:
    scales = np.asarray(scales, dtype=float)
    return scales / np.exp(np.mean(np.log(scales)))


def _best_safe(records):
    feasible = [r for r in records if r.get("feasible") and r.get("trial")]
    if feasible:
        return min(feasible, key=lambda r: (r["objective"], r["index"]))
    return records[0]


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _number(value, default: float) -> float:
    return float(value) if _finite(value) else default
