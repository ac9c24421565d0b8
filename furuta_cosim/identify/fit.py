"""The fit: plant parameters by least squares on simulated outputs (scipy's ``least_squares``).

Every residual evaluation is a co-simulation of an experiment through the project's plant
session; the experiments of one evaluation and the columns of a finite-difference Jacobian
run at once on the worker processes (or Dask). Residuals are ``(simulated - measured) /
sigma`` per sample, ``sigma`` from each output's noise and encoder quantum.

A long log is fitted in stages: the first seconds of every experiment's window first, then
longer ones (``horizon``; by default a sixteenth of the longest window, an eighth, a quarter
and a half), then the whole windows, each stage starting from the last one's
values, so that a swing whose period is far off at the start cannot trap the fit in a phase
slip.

Intervals. The residuals of a fit to a real log are far from independent (a small misfit in
a swing is the same misfit for hundreds of samples), so the textbook covariance
``s^2 (J^T J)^-1`` is too narrow. The covariance here is the Newey-West sandwich
``(J^T J)^-1 S (J^T J)^-1``: ``S`` the long-run covariance of the score ``J_t r_t`` of each
(experiment, output) series, summed over lags with Bartlett weights up to a window chosen
from the series' own integrated autocorrelation time (Sokal's rule: the smallest window
M >= 5 tau(M)). Intervals are value +- 1.96 standard errors (95 %), widened on each side by
the reach of the start state a log gives (identify/reach.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.estimate import prepared
from furuta_cosim.identify.problem import BudgetSpent, Problem, Runner, unknowns
from furuta_cosim.identify.replay import Target, check_names
from furuta_cosim.identify.spec import IdentifySpec
from furuta_cosim.identify.verdict import far_line

Z95 = 1.959963984540054
NOT_SEPARABLE = 0.95
_INTERVALS = ("Newey-West sandwich covariance (Bartlett weights, window from each residual "
              "series' integrated autocorrelation time); 95 % = +-1.96 standard errors")
_REACH = ("; widened on each side by the reach of the start state the logs give: of the counted start "
          "angles (the largest move of the value over the corners of half an encoder count up or down "
          "from the logged ones) and of a balancing log's freed start rates (each held one standard "
          "deviation of its smoother's estimate up and down, the moves propagated to 95 % through their "
          "correlation), and of a balancing log's smoother's own error (8 draws of it, the mean move and "
          "its 95 % spread), added (identify/reach.py)")


DELAY_GRID = 11   # a fitted delay's start: the best of at most this many whole-sample delays
DELAY_RESCANS = 2   # after a fit, its delays scanned again at the fitted values at most this often


def _delay_starts(runner, spec, items: list, log) -> list:
    """``items`` with each fitted delay's start the best of a scan over whole samples within
    its bounds (at most DELAY_GRID, the other unknowns at their starts): the replay's error is
    not convex in a delay (an oscillation's period away fits too), so the local fit starts in
    the right well. The scan's simulations count in the fit's."""
    from dataclasses import replace

    delays = [k for k, u in enumerate(items) if u.name.endswith(".delay")]
    if not delays:
        return items
    period = min(e.period for e in spec.experiments)
    problem = Problem(runner, spec.experiments, items, None, math.inf, lambda *a: None)
    x = np.array([u.start / u.scale for u in items])
    for k in delays:
        grid = _delay_grid(items[k], period)
        costs = []
        for value in grid:
            x[k] = value / items[k].scale
            r = problem.fun(x)
            costs.append(0.5 * float(r @ r))
        best = float(grid[int(np.argmin(costs))])
        x[k] = best / items[k].scale
        items[k] = replace(items[k], start=best)
        log(f"  {items[k].name}: starts at {best * 1000:g} ms, the best of {len(grid)} whole-sample delays "
            f"from {grid[0] * 1000:g} to {grid[-1] * 1000:g} ms at the start values")
    return items


def _delay_grid(item, period: float) -> np.ndarray:
    """The whole-sample delays (s) within a fitted delay's bounds, at most DELAY_GRID of them
    (else that many evenly spread)."""
    lo, hi = item.bounds
    grid = np.arange(math.ceil(lo / period - 1e-9), math.floor(hi / period + 1e-9) + 1) * period
    if not 0 < len(grid) <= DELAY_GRID:   # bounds within one sample, or logs of other periods
        grid = np.linspace(lo, hi, DELAY_GRID if len(grid) else 2)
    return np.clip(grid, lo, hi)


def _delay_rescan(runner, spec, items: list, x: np.ndarray, log) -> np.ndarray | None:
    """After a fit: each fitted delay's whole-sample scan again, the other unknowns at the
    fit's values. A delay's well is narrow where the loop is near its margin (a lab's PD 7 ms
    late: 6 to 7.5 ms), and the scan at the start values can pick the wrong one when a
    parameter starts far off; the point of the scan that beats the fit (None if none does),
    from which the fit runs again."""
    delays = [k for k, u in enumerate(items) if u.name.endswith(".delay")]
    if not delays:
        return None
    period = min(e.period for e in spec.experiments)
    problem = Problem(runner, spec.experiments, items, None, math.inf, lambda *a: None)
    r = problem.fun(x)
    best_cost, best = 0.5 * float(r @ r), None
    for k in delays:
        for value in _delay_grid(items[k], period):
            y = x.copy()
            y[k] = value / items[k].scale
            r = problem.fun(y)
            cost = 0.5 * float(r @ r)
            if cost < best_cost * (1.0 - 1e-6):
                best_cost, best = cost, y
    if best is not None:
        moved = [f"{items[k].name} {best[k] * items[k].scale * 1000:g} ms" for k in delays if best[k] != x[k]]
        log(f"  the whole-sample scan at the fitted values finds a lower cost at {', '.join(moved)}: "
            "fitting again from there")
    return best


# -- intervals ------------------------------------------------------------------------------
def autocorrelation_time(series: np.ndarray, c: float = 5.0) -> tuple[float, int]:
    """(tau, window): the integrated autocorrelation time of ``series`` with Sokal's automatic
    window (the smallest M with M >= c tau(M)), through the FFT."""
    x = np.asarray(series, dtype=float) - np.mean(series)
    n = len(x)
    if n < 4 or not np.any(x):
        return 1.0, 0
    size = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(x, size)
    acf = np.fft.irfft(f * np.conjugate(f), size)[:n]
    acf /= acf[0]
    taus = 2.0 * np.cumsum(acf) - 1.0
    window = np.arange(n) >= c * taus
    m = int(np.argmax(window)) if np.any(window) else n - 1
    return max(float(taus[m]), 1.0), m


def sandwich(blocks: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, dict]:
    """(Newey-West covariance, textbook covariance, diagnostics) from ``(J_b, r_b)`` blocks:
    the Jacobian and residuals of each (experiment, output) series."""
    J = np.vstack([b[0] for b in blocks])
    r = np.concatenate([b[1] for b in blocks])
    p = J.shape[1]
    bread = np.linalg.pinv(J.T @ J)
    dof = max(len(r) - p, 1)
    plain = bread * float(r @ r) / dof
    meat = np.zeros((p, p))
    windows = []
    for Jb, rb in blocks:
        scores = Jb * rb[:, None]
        window = max(autocorrelation_time(scores[:, j])[1] for j in range(p))
        windows.append(window)
        meat += scores.T @ scores
        for lag in range(1, min(window, len(rb) - 1) + 1):
            gamma = scores[lag:].T @ scores[:-lag]
            meat += (1.0 - lag / (window + 1.0)) * (gamma + gamma.T)
    covariance = bread @ meat @ bread
    return covariance, plain, {"windows": windows}


# -- the fit --------------------------------------------------------------------------------
def stages(spec: IdentifySpec) -> list[float | None]:
    """Horizons in seconds, then None (the whole windows): the spec's, else a sixteenth of the
    longest window, doubled until it reaches that window (five stages). Segments of multiple
    shooting (identify/split.py) are short by design: their windows at once."""
    longest = max(float(e.t[-1] - e.t[0]) for e in spec.experiments)
    if all("@" in e.name and e.alias for e in spec.experiments):
        return [None]
    if spec.horizon is not None:
        horizons = list(spec.horizon)
    else:
        horizons = [longest / 16.0 * 2 ** k for k in range(4)]
    return [h for h in horizons if h < longest] + [None]


@dataclass
class FitResult:
    spec: IdentifySpec
    target: Target
    items: list
    start: dict
    values: dict
    covariance: np.ndarray
    plain: np.ndarray
    windows: list
    experiments: dict              # name -> {output: comparison} at the fit
    validation: dict
    before: dict                   # name -> {output: comparison} at the start values
    simulated: dict                # name -> {"start": outputs, "fit": outputs}
    stages: list
    simulations: int
    seconds: float
    cost: float
    message: str
    unseen: tuple = ()             # unknowns the data do not depend on (not identifiable)
    optima: list = None            # a multi-start's distinct optima (lowest cost first)
    precheck: dict | None = None   # the Jacobian at the start values read (identify/precheck.py)
    reach: dict | None = None      # name -> what the counted start angles can move it by (identify/reach.py)
    reach_from: dict | None = None
    shared: dict | None = None     # a validation log's delay -> {value, from: the fitted logs' keys}

    def document(self) -> dict:
        """fit.json: every value with its interval, the correlations, the residuals."""
        sd = np.sqrt(np.maximum(np.nan_to_num(np.diag(self.covariance)), 0.0))
        sd_plain = np.sqrt(np.maximum(np.nan_to_num(np.diag(self.plain)), 0.0))
        scales = np.array([u.scale for u in self.items])
        parameters = {}
        for k, u in enumerate(self.items):
            value, err = self.values[u.name], float(sd[k] * scales[k])
            reach = (self.reach or {}).get(u.name, 0.0)
            lo, hi = u.bounds
            at_bound = bool(np.isclose(value, lo, rtol=1e-9, atol=1e-12 * u.scale)
                            or np.isclose(value, hi, rtol=1e-9, atol=1e-12 * u.scale))
            seen = u.name not in self.unseen
            parameters[u.name] = {
                "value": value, "start": self.start[u.name],
                # a seen unknown's verdict is read from its interval (identify/verdict.py
                # read_intervals) or its profile (identify/run.py), never assumed
                "identifiable": False if not seen else None,
                "verdict": "not judged" if seen else
                           "structurally not identifiable from these experiments: the data do not "
                           "depend on it (kept at its start)",
                "rests_on": "the data do not depend on it" if not seen else "nothing yet",
                "stderr": err if seen else None,
                "stderr_plain": float(sd_plain[k] * scales[k]) if seen else None,
                "interval": [value - Z95 * err - reach, value + Z95 * err + reach] if seen else None,
                "reach": reach if seen else None,
                "bounds": [lo, hi], "at_bound": at_bound and seen}
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = self.covariance / np.outer(sd, sd)
        corr = np.where(np.isfinite(corr), corr, 0.0)
        np.fill_diagonal(corr, 1.0)  # an unknown the data do not see: correlated with nothing
        names = [u.name for u in self.items]
        pairs = [[names[i], names[j], float(corr[i, j])] for i in range(len(names))
                 for j in range(i + 1, len(names)) if abs(corr[i, j]) > NOT_SEPARABLE]
        return {"name": self.spec.name, "plant": self.target.label, "fmu_sha256": _sha(self.target.fmu),
                "parameters": parameters,
                "interval_method": _INTERVALS + (_REACH if self.reach else ""),
                "reach": self.reach_from or None,
                "correlation": {"names": names, "matrix": corr.tolist()},
                "not_separable": pairs,
                "experiments": self.experiments, "validation": self.validation,
                "at_start": self.before,
                "data": {e.name: {"file": e.data.name, "sha256": e.sha256, "window": [float(e.t[0]), float(e.t[-1])],
                                  "samples": e.samples}
                         for e in self.spec.experiments + self.spec.validation},
                "stages": self.stages, "simulations": self.simulations,
                "seconds": self.seconds, "cost": self.cost, "message": self.message,
                "precheck": self.precheck,
                # validation logs scored at a delay fitted on the fitted logs (fit.shared_values)
                "shared": self.shared or {},
                "starts": {"count": sum(len(o["starts"]) for o in self.optima or []) or 1,
                           "optima": [{"cost": o["cost"], "values": o["values"], "starts": o["starts"]}
                                      for o in self.optima or []]}}


def _sha(path) -> str:
    import hashlib
    from pathlib import Path

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def start_points(items, count: int, seed: int = 0) -> list[np.ndarray]:
    """``count`` starts in scaled units: the spec's own first, then a Latin hypercube (scipy's,
    seeded) around it over the plant parameters, each within a factor of 10 of its start (on a
    log scale, for a positive start and bounds) or a quarter of its bounds' width, inside the
    bounds; free initial states and biases keep their start."""
    from scipy.stats import qmc

    x0 = np.array([u.start / u.scale for u in items])
    if count <= 1:
        return [x0]
    unit = qmc.LatinHypercube(d=len(items), seed=np.random.default_rng([seed, 3])).random(count - 1)
    found = [x0]
    for row in unit:
        x = x0.copy()
        for k, u in enumerate(items):
            if "." in u.name:
                continue
            lo, hi = u.bounds
            if u.start > 0 and lo >= 0:
                a, b = math.log(max(lo, u.start / 10.0, 1e-300)), math.log(min(hi, u.start * 10.0))
                value = math.exp(a + row[k] * (b - a))
            else:
                half = 0.25 * (hi - lo)
                a, b = max(lo, u.start - half), min(hi, u.start + half)
                value = a + row[k] * (b - a)
            x[k] = min(max(value, lo), hi) / u.scale
        found.append(x)
    return found


# two optima of a multi-start are the same when their costs and every value agree this closely
SAME_COST, SAME_VALUE = 1e-6, 1e-3


def distinct_optima(optima: list[dict], items) -> list[dict]:
    """The optima of a multi-start, the same ones merged: each with its cost, values and the
    starts that reached it, the lowest cost first."""
    found: list[dict] = []
    cost_of = lambda o: o["cost"] if math.isfinite(o["cost"]) else math.inf  # noqa: E731
    for k, o in sorted(enumerate(optima), key=lambda pair: (cost_of(pair[1]), pair[0])):
        x = np.array(o["x"])
        for group in found:
            y = np.array(group["x"])
            if math.isfinite(o["cost"]) and \
                    abs(o["cost"] - group["cost"]) <= SAME_COST * max(abs(group["cost"]), 1e-300) and \
                    np.all(np.abs(x - y) <= SAME_VALUE * np.maximum(np.abs(y), 1.0)):
                group["starts"].append(k)
                break
        else:
            found.append({"cost": float(o["cost"]), "x": list(map(float, x)), "starts": [k],
                          "values": {u.name: float(v) * u.scale for u, v in zip(items, x)},
                          "message": o.get("message", "")})
    return found


def fit(spec: IdentifySpec, target: Target, *, workers: int = 1, dask: str | None = None,
        progress: Callable[[str, int, float], None] = lambda stage, n, cost: None,
        log: Callable[[str], None] = lambda line: None, resume: dict | None = None,
        on_stage: Callable[[dict], None] = lambda state: None, starts: int = 1, seed: int = 0,
        force: bool = False) -> FitResult:
    """Fit the spec's free parameters on ``target``; see the module docstring.

    With ``starts`` > 1 the staged fit runs from each of :func:`start_points` (``seed``: their
    design), each with the spec's budget; the lowest cost is kept and the distinct optima
    found are reported. ``on_stage(state)`` is called after every finished stage with what a
    later call needs to go on from there (``resume=state``): the start and stage, the values,
    the stages' record, the optima so far and the simulations spent. A resumed fit gives the
    fit an uninterrupted one gives.

    Before the first stage the Jacobian at the start values is read (identify/precheck.py):
    unknowns the experiments cannot separate stop the fit with a NotSeparable error naming
    them, unless ``force``."""
    started = time.perf_counter()
    check_names(target, spec.experiments + spec.validation, tuple(p.name for p in spec.free),
                str(spec.path))
    check_ranges(spec, target)
    _commands_within_the_amplifier(spec, target)
    plant_values = _plant_values(target, [p.name for p in spec.free])
    items = unknowns(spec, plant_values)
    if resume is None and not force:   # a resumed run passed this check when it began
        _loops_rebuild(spec, log)
    spec = prepared(spec, target)
    _no_delay_through_a_smoother(spec)
    everything = list(spec.experiments) + list(spec.validation)
    runner = Runner(target, everything, workers, dask)
    items = _delay_starts(runner, spec, items, log)
    points = start_points(items, starts, seed)
    x0 = points[0].copy()
    lower = np.array([u.bounds[0] / u.scale for u in items])
    upper = np.array([u.bounds[1] / u.scale for u in items])
    plan = stages(spec)
    state = {"start": 0, "stage": 0, "x": None, "record": [], "message": "", "optima": []}
    try:
        start_outputs = Problem(runner, spec.experiments, items, None, math.inf, lambda *a: None) \
            .outputs_at(x0, everything)
        if resume is not None:  # its count holds these start runs already
            state.update({k: resume[k] for k in ("stage", "x", "record", "message") if k in resume})
            state["start"], state["optima"] = int(resume.get("start", 0)), list(resume.get("optima", []))
            runner.count = int(resume["simulations"])
        failed = [f"{e.path}: the simulation fails at the start values: {why}"
                  for e, (_, why) in zip(everything, start_outputs) if why]
        if failed:
            raise ConfigError(failed)
        far = _say_far(everything, start_outputs, items, log)
        misread = [e for e in far if e.get("loop")]
        if misread and resume is None and not force:
            from furuta_cosim.identify.precheck import loop_line

            raise ConfigError([f"{e['file']}: {loop_line(e)}" for e in misread]
                              + ["the fit stopped before it began: read that column as named (its unit:, the sign, "
                                 "or its offset:) and fit again; `force=True` fits anyway"])
        if resume is None:  # a resumed run passed this check when it began
            readings = _separable_or_stop(runner, spec, items, x0, force, log)
        else:
            readings = resume.get("precheck")
        if readings is not None:
            readings["far"] = far
        state["precheck"] = readings
        for s in range(state["start"], len(points)):
            resumed = s == state["start"] and state["x"] is not None
            x = np.array(state["x"], dtype=float) if resumed else points[s].copy()
            first = int(state["stage"]) if resumed else 0
            record = list(state["record"]) if resumed else []
            message = str(state["message"]) if resumed else ""
            budget = (int(state.get("budget_from", 0)) if resumed else runner.count) + spec.max_simulations
            if len(points) > 1:
                log(f"  start {s + 1}/{len(points)}" + (" (the spec's)" if s == 0 else ""))
            for rescan in range(DELAY_RESCANS + 1):
                for k, horizon in enumerate(plan):
                    if k < first or message.startswith("stopped"):
                        continue
                    x, message = _stage(runner, spec, items, x, lower, upper, k, plan, budget, record,
                                        message, progress, log, f" of start {s + 1}" if len(points) > 1 else "")
                    state = {"start": s, "stage": k + 1, "x": [float(v) for v in x], "record": record,
                             "message": message, "optima": state["optima"],
                             "budget_from": budget - spec.max_simulations, "precheck": readings}
                    on_stage({**state, "simulations": runner.count})
                moved = None
                if rescan < DELAY_RESCANS and not message.startswith("stopped") and runner.count < budget:
                    # the same scan in an uninterrupted and a resumed run: both go on alike
                    moved = _delay_rescan(runner, spec, items, x, log)
                if moved is None:
                    break
                x, first, message = moved, 0, ""
            cost = record[-1]["cost"] if record else math.nan
            state["optima"] = state["optima"] + [{"x": [float(v) for v in x], "cost": float(cost),
                                                  "message": message, "record": record}]
            state.update({"start": s + 1, "stage": 0, "x": None, "record": [], "message": ""})
            on_stage({**state, "simulations": runner.count})
        optima = distinct_optima(state["optima"], items)
        chosen = min(range(len(state["optima"])),
                     key=lambda k: (state["optima"][k]["cost"] if math.isfinite(state["optima"][k]["cost"])
                                    else math.inf, k))
        x = np.array(state["optima"][chosen]["x"], dtype=float)
        record, message = state["optima"][chosen]["record"], state["optima"][chosen]["message"]
        if len(points) > 1:
            log(f"  {len(points)} starts reached {len(optima)} distinct optim{'um' if len(optima) == 1 else 'a'}: "
                + "; ".join(f"cost {o['cost']:.6g} from {len(o['starts'])} start(s)" for o in optima))
        final = Problem(runner, spec.experiments, items, None, math.inf, lambda *a: None)
        J = final.jac(x)
        r = final.fun(x)
        x, J, r, unseen = _without_effect(final, x, x0, J, r)
        outputs = final.outputs_at(x, everything)
    finally:
        simulations = runner.count
        runner.close()
    for k in unseen:
        log(f"  {items[k].name}: the data do not depend on it (its column of the Jacobian is "
            f"zero): not identifiable from these experiments, kept at {items[k].start:.6g}")
    seen = [k for k in range(len(items)) if k not in unseen]
    blocks, row = [], 0
    for experiment in spec.experiments:
        for _ in experiment.outputs:
            blocks.append((J[row:row + experiment.samples][:, seen], r[row:row + experiment.samples]))
            row += experiment.samples
    covariance, plain = np.full((len(items),) * 2, np.nan), np.full((len(items),) * 2, np.nan)
    windows: list = []
    if seen:
        part, part_plain, diagnostics = sandwich(blocks)
        covariance[np.ix_(seen, seen)], plain[np.ix_(seen, seen)] = part, part_plain
        windows = diagnostics["windows"]
    values = final.values(x)
    from furuta_cosim.identify.reach import start_reach
    from furuta_cosim.identify.replay import compare

    reach, reach_from = start_reach(target, spec.experiments, items, x, J[:, seen], seen, workers, dask)
    simulations += reach_from.get("simulations", 0)

    scored, held, before, simulated = {}, {}, {}, {}
    starts = {u.name: u.start for u in items}
    for experiment, (fitted, why), (first, _) in zip(everything, outputs, start_outputs):
        first = experiment.corrected(first, starts)
        before[experiment.name] = compare(experiment, first)
        if fitted is None:
            fitted_to = ", ".join(e.name for e in spec.experiments)
            raise ConfigError(_far_lines(everything, start_outputs, starts)
                              + [f"{experiment.path}: {experiment.name}'s simulation fails at the values fitted "
                                 f"to {fitted_to}"
                                 + (" (it was not fitted: the values it fails at come from the others)"
                                    if experiment not in spec.experiments else "") + f": {why}"])
        fitted = experiment.corrected(fitted, values)
        (scored if experiment in spec.experiments else held)[experiment.name] = compare(experiment, fitted)
        simulated[experiment.name] = {"start": first, "fit": fitted}
    shared = {key: {"value": values[key], "from": sources} for key, sources in final.shares.items()}
    return FitResult(spec, target, items, {u.name: u.start for u in items}, values, covariance,
                     plain, windows, scored, held, before, simulated, record,
                     simulations, time.perf_counter() - started, float(0.5 * r @ r), message,
                     tuple(items[k].name for k in unseen), optima, readings, reach, reach_from, shared)


def far_columns(experiments, start_outputs, starts: dict) -> list[dict]:
    """Each output whose replay at the start values is hundreds of noise floors off
    (identify/precheck.py FAR): experiment, output, its column and unit, the floors, and the
    other reading of the column that would replay far better (``hint``, None if none does)."""
    from furuta_cosim.identify.precheck import far_outputs, unit_hint
    from furuta_cosim.identify.replay import compare
    from furuta_cosim.identify.verdict import floor_of

    simulated = {e.name: e.corrected(outputs, starts) for e, (outputs, _) in zip(experiments, start_outputs)
                 if outputs is not None}
    by_name = {e.name: e for e in experiments}
    before = {name: compare(by_name[name], outputs) for name, outputs in simulated.items()}
    found = []
    for name, output, ratio in far_outputs(before, floor_of):
        e = by_name[name]
        unit = e.units.get(output)
        hint = unit_hint(e.outputs[output].values, simulated[name][output], unit, floor_of(before[name][output])[0])
        found.append({"experiment": name, "file": str(e.path), "output": output,
                      "column": e.outputs[output].column, "unit": unit, "floors": ratio,
                      "hint": None if hint is None else {"reading": hint[0], "floors": hint[1]}})
    return found


def _far_lines(experiments, start_outputs, starts: dict) -> list[str]:
    return [f"{e['file']}: outputs.{e['output']}: {far_line(e)}" for e in far_columns(experiments, start_outputs, starts)]


# a logged command beyond this many times the amplifier's limit is a column read in the wrong unit
# or scale (mV as V: 1000 times), not a command: replayed, it diverges the plant's integration,
# whose message then blames the step size
BEYOND_AMPLIFIER = 3.0


def _commands_within_the_amplifier(spec, target) -> None:
    """A ConfigError for each log whose command column goes beyond BEYOND_AMPLIFIER times the
    plant's amplifier limit (the plant file's limits.voltage or V_max), naming the column, the
    first such sample and the factor."""
    from furuta_cosim.fmu.plants import voltage_limit

    if target.plant is None:
        return
    limit = voltage_limit(target.plant)
    if not limit:
        return
    found = []
    for e in spec.experiments + spec.validation:
        if "V" not in e.inputs:
            continue
        values = np.atleast_1d(np.asarray(e.input_at("V"), dtype=float))
        beyond = np.abs(values) > BEYOND_AMPLIFIER * limit
        if np.any(beyond):
            k = int(np.argmax(beyond))
            when = f" at t = {e.t[k]:g} s" if k < len(e.t) else ""
            found.append(f"{e.path}: inputs.V: reads {values[k]:.4g} V{when}, {abs(values[k]) / limit:.3g} times the "
                         f"amplifier's limit ({limit:g} V, {target.plant.name}): a command beyond what the amplifier "
                         "gives is a column in another unit or scale (inputs.V: unit, scale)")
    if found:
        raise ConfigError(found)


def _no_delay_through_a_smoother(spec) -> None:
    """A ConfigError for each balancing log whose loop's delay is free: its replay closes the
    loop through the angles its smoother estimates (identify/estimate.py), and the fit's cost
    does not tell the delay there. Measured on a lab's PD 5 ms late (tools/bench_loop.py,
    10 seeds): 3.99 ms every time, its interval 0.04 ms wide, the truth outside it on all ten;
    replayed on the counted angles instead the log picks 5 ms, but that replay is a staircase
    in the parameters a fit cannot differentiate."""
    found = [f"{e.path}: loop.delay: a balancing log is replayed through the angles its smoother estimates, "
             "and a delay fitted there is not the rig's (a lab's PD 5 ms late gave 3.99 ms on ten seeds of "
             "ten, its interval 0.04 ms wide): state the delay (a number of seconds), or fit it on an open-loop "
             "log of the same rig (inputs.V.delay: {free: [lo, hi]}: a chirp 12 ms late came out within "
             "0.013 ms)"
             for e in spec.experiments + spec.validation
             if e.loop is not None and e.loop.estimate and e.loop.free_delay is not None]
    if found:
        raise ConfigError(found)


def _loops_rebuild(spec, log) -> None:
    """Each log's stated loop rebuilds its logged command (identify/mismatch.py), checked
    without the plant before any simulation: a ConfigError naming each that does not."""
    from furuta_cosim.identify.precheck import wrong_loop

    started = time.perf_counter()
    wrong = [line for e in spec.experiments + spec.validation if e.loop is not None
             for line in [wrong_loop(e)] if line]
    if wrong:
        raise ConfigError(wrong + [f"the fit stopped before it began ({time.perf_counter() - started:.1f} s): "
                                   "state the loop that ran (loop: in each experiment file), or fix the column "
                                   "named; `force=True` fits anyway"])
    if any(e.loop is not None for e in spec.experiments + spec.validation):
        log(f"  each log's loop rebuilds its logged command ({time.perf_counter() - started:.1f} s)")


def _say_far(experiments, start_outputs, items, log) -> list[dict]:
    from furuta_cosim.identify.precheck import loop_hint, loop_line

    found = far_columns(experiments, start_outputs, {u.name: u.start for u in items})
    for entry in found:
        log(f"  note: {far_line(entry)}")
    for experiment in experiments:
        entry = loop_hint(experiment)
        if entry is not None and entry["hint"] is not None:
            entry["loop"] = True
            found.append(entry)
            log(f"  note: {loop_line(entry)}")
    return found


class NotSeparable(ConfigError):
    """The experiments cannot separate some free unknowns (identify/precheck.py): the fit
    stopped before it began; ``readings`` holds what the Jacobian at the start said."""

    def __init__(self, problems: list[str], readings: dict):
        super().__init__(problems)
        self.readings = readings


def _separable_or_stop(runner, spec, items, x0, force: bool, log) -> dict:
    """The Jacobian at the start values read (identify/precheck.py): logged, and a
    NotSeparable error when a combination of unknowns is not separable (unless ``force``)."""
    from furuta_cosim.identify.precheck import describe, natural, next_step, separability

    clock = time.perf_counter()
    before = runner.count
    problem = Problem(runner, spec.experiments, items, None, math.inf, lambda *a: None)
    J = problem.jac(x0)
    J, widths = natural(J, items)
    readings = separability(J, [u.name for u in items], J.shape[0], widths)
    readings["simulations"] = runner.count - before
    readings["seconds"] = time.perf_counter() - clock
    if not readings["groups"]:
        log(f"  separable: every free unknown moves the outputs at the start values "
            f"({readings['simulations']} simulations, {readings['seconds']:.1f} s)")
        return readings
    lines = [describe(g) for g in readings["groups"]]
    outputs = {o for e in spec.experiments for o in e.outputs}
    step = next_step(readings["groups"], outputs, True)
    if force:
        for line in lines:
            log(f"  warning: {line}; fitted all the same (--force)")
        return readings
    raise NotSeparable([f"{spec.path}: free: {line}" for line in lines]
                       + [f"{spec.path}: the fit stopped before it began (the Jacobian at the start values, "
                          f"{readings['simulations']} simulations, {readings['seconds']:.1f} s); next: {step}"],
                       readings)


def _stage(runner, spec, items, x, lower, upper, k: int, plan, budget: int, record: list, message: str,
           progress, log, which: str) -> tuple[np.ndarray, str]:
    """Stage ``k`` of the plan from ``x``: least squares on that horizon, within ``budget``
    simulations in all; its record appended. Returns the stage's values and message."""
    from scipy.optimize import least_squares

    horizon = plan[k]
    label = f"stage {k + 1}/{len(plan)}{which} ({'whole windows' if horizon is None else f'first {horizon:g} s'})"
    problem = Problem(runner, spec.experiments, items, horizon, budget,
                      lambda n, cost: progress(label, n, cost))
    before = runner.count
    try:
        result = least_squares(problem.fun, x, jac=problem.jac, bounds=(lower, upper),
                               x_scale="jac", method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-10)
        x, message = result.x, str(result.message)
        cost = float(result.cost)
    except BudgetSpent:
        message = f"stopped at max_simulations ({spec.max_simulations}) in {label}"
        best = _best(problem)
        if best is not None:  # else the budget ran out as the stage began: the last x stands
            x, cost = best, problem.best_cost
        else:
            cost = math.nan
    record.append({"horizon": horizon, "cost": cost, "simulations": runner.count - before})
    log(f"  {label}: " + (f"cost {cost:.6g} after {runner.count - before} simulations"
                          if runner.count > before else "the budget was spent before it began"))
    if message.startswith("stopped"):
        log(f"  {message}: the fit is the best point so far")
    return x, message


# a column of the weighted Jacobian (in scaled units) this much smaller than the largest is
# zero: the data do not depend on that unknown
UNSEEN = 1e-9


def _without_effect(problem: Problem, x, x0, J, r):
    """The unknowns the data do not depend on (a zero column of the Jacobian: an end stop the
    arm never reaches, a friction of a joint that never moves), set back to their start, where
    the fit is the same: (x, J, r, their indices). Such a value is whatever the optimizer left,
    and an interval for it would be of zero width; it is reported as not identifiable."""
    norms = np.linalg.norm(J, axis=0)
    largest = float(np.max(norms)) if norms.size else 0.0
    unseen = [k for k, n in enumerate(norms) if not n > UNSEEN * largest]
    if not unseen:
        return x, J, r, []
    back = x.copy()
    back[unseen] = x0[unseen]
    r_back = problem.fun(back)
    cost, cost_back = float(r @ r), float(r_back @ r_back)
    if abs(cost_back - cost) <= 1e-9 * max(cost, 1e-300):  # the same fit: report the start
        return back, problem.jac(back), r_back, unseen
    return x, J, r, unseen


def physical_ranges(target: Target) -> dict[str, tuple[float | None, float | None, bool]]:
    """Each parameter's physical range on the target: ``(low, high, low is strict)``; from the
    plant's declaration (a mass > 0, a friction >= 0) or a foreign FMU's min and max."""
    from furuta_cosim.fmu.session import model_description

    found: dict = {}
    for v in model_description(target.fmu).modelVariables:
        bounds = []
        for bound in (v.min, v.max):
            try:
                bounds.append(float(bound) if bound is not None else None)
            except (TypeError, ValueError):
                bounds.append(None)
        if bounds != [None, None]:
            found[v.name] = (bounds[0], bounds[1], False)
    if target.plant is not None:
        from furuta_cosim.fmu.exporter import parameter_ranges

        for name, (low, strict) in parameter_ranges(target.plant).items():
            found[name] = (low, found.get(name, (None, None, False))[1], strict)
    return found


def outside(value: float, rng: tuple) -> str | None:
    """Why ``value`` is outside the physical range ``rng``, or None."""
    low, high, strict = rng
    if low is not None and (value <= low if strict else value < low):
        return f"must be {'>' if strict else '>='} {low:g}"
    if high is not None and value > high:
        return f"must be <= {high:g}"
    return None


def check_ranges(spec: IdentifySpec, target: Target) -> None:
    """Bounds of a free parameter beyond its physical range (a resistance below 0) are refused:
    the fit, and variants drawn from it later, would run a plant that does not exist."""
    ranges = physical_ranges(target)
    problems = []
    for experiment in list(spec.experiments) + list(spec.validation):   # what a log sets for itself
        for name, value in experiment.parameters.items():
            why = outside(float(value), ranges[name]) if name in ranges else None
            if why:
                problems.append(f"{experiment.path}: parameters.{name}: {name} {why} (its physical range), "
                                f"got {float(value):g}")
    for p in spec.free:
        rng = ranges.get(p.name)
        if rng is None:
            continue
        for side, value in zip(("lo", "hi"), p.bounds):
            why = outside(value, rng)
            if why:
                problems.append(f"{spec.path}: free.{p.name}.bounds: {p.name} {why} (its physical "
                                f"range), the bounds' {side} is {value:g}")
                break
    if problems:
        raise ConfigError(problems)


def _best(problem: Problem) -> np.ndarray | None:
    """The best point this stage evaluated, None if it evaluated none."""
    if not problem._cache:
        return None
    best = min(problem._cache.items(), key=lambda item: float(item[1] @ item[1]))
    return np.frombuffer(best[0], dtype=float).copy()


def _plant_values(target: Target, names: Sequence[str]) -> dict[str, float]:
    """The target's own values of ``names``: the plant file's, else the FMU's start values."""
    from furuta_cosim.fmu.session import model_description

    found = {}
    variables = {v.name: v for v in model_description(target.fmu).modelVariables}
    for name in names:
        if name in target.fixed:
            found[name] = float(target.fixed[name])
        elif name in variables and variables[name].start is not None:
            try:
                found[name] = float(variables[name].start)
            except (TypeError, ValueError):
                pass
    return found


def with_values(result: FitResult) -> dict[str, float]:
    """The fitted plant parameters alone (no initial states)."""
    return {k: v for k, v in result.values.items() if "." not in k}


