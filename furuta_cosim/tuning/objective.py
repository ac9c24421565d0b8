"""The objective of a tuning and its constraints, for one candidate controller.

Cheap checks come first: the loop's stability with a margin on the design model (the
augmented matrix Abar, and the sampled loop at the control period) and, when asked, the
controller's own stability cost microseconds, so an unstable candidate never reaches a
co-simulation.

Each outcome carries what a constrained optimizer models separately (tuning/optimizers.py):
``value``, the objective computed whether or not the candidate is feasible (None where it
cannot be: an unstable loop, a run that diverged), and ``margin``, the largest of the
constraints' normalized slacks (each <= 0 when met: a peak over its bound is value / bound - 1,
a tracking ratio over its allowance ratio / factor - 1, a mode right of the stability margin
its distance in units of the margin), clipped to [-1, 1]. Optimizers that take one number
(random search, differential evolution) are told ``objective``: the value when feasible, else
``penalty + violation``, a constant above any feasible score plus how far it is from
feasibility.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from furuta_cosim.design.controller import GeneralizedController, augmented, discretize_controller
from furuta_cosim.documents import json_safe
from furuta_cosim.errors import ConfigError, DesignError, FmuError
from furuta_cosim.tuning.spec import TuningSpec
from furuta_cosim.tuning.space import Space


# the feasibility margin is clipped to [-1, 1]: near 0 is where it decides, and one run that
# diverged must not flatten every other difference for the surrogate
MARGIN_CAP = 1.0


@dataclass
class Outcome:
    """What one evaluation found: the score the optimizer is told and why."""

    objective: float
    feasible: bool
    constraints: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)     # "<scenario>[<variant>]" -> {metric: value}
    error: str | None = None
    wall_time: float = 0.0
    worker: int | None = None       # the process that evaluated it (None: unknown, it died)
    value: float | None = None      # the objective, feasible or not (None: not computable)
    margin: float = MARGIN_CAP      # largest normalized constraint slack, in [-1, 1] (<= 0: met)


def _margin(slacks) -> float:
    """The largest slack, clipped to [-MARGIN_CAP, MARGIN_CAP] (none: every constraint met
    by as much as can be said)."""
    largest = max(slacks, default=-MARGIN_CAP)
    if not math.isfinite(largest):
        return MARGIN_CAP if largest > 0 or math.isnan(largest) else -MARGIN_CAP
    return float(min(max(largest, -MARGIN_CAP), MARGIN_CAP))


# a loop mode's slack is its distance right of the stability margin in units of the margin
# (this many 1/s at least, for a margin of 0)
STABILITY_SCALE = 0.01


def _peak(signal: str) -> str:
    """The metric of a signal's largest magnitude (the input's is ``u.peak_abs``)."""
    return "u.peak_abs" if signal == "u" else f"{signal}.max_abs"


def spectral_abscissa(Abar: np.ndarray, period: float) -> np.ndarray:
    """Eigenvalues of Abar read as continuous-time modes s (ln(z)/T for a discrete loop)."""
    eigenvalues = np.linalg.eigvals(Abar)
    if period > 0:
        with np.errstate(divide="ignore"):
            return np.log(eigenvalues.astype(complex)) / period
    return eigenvalues


class Evaluator:
    """Scores candidates of one spec; holds its prepared scenarios and plant sessions, so a
    worker builds it once and evaluates candidate after candidate."""

    def __init__(self, spec: TuningSpec):
        from furuta_cosim.models import load_model

        self.spec = spec
        self.model = load_model(spec.model)
        self.space = Space(spec.blocks, self.model, spec.period, spec.discrete)
        self._runs = None  # [(label, prepared, session)], prepared on first use
        self._baseline = None  # the no_worse_than baseline's metrics by run

    # -- the cheap checks ------------------------------------------------------------------
    def loop_checks(self, controller: GeneralizedController) -> tuple[dict, float]:
        """Constraint values on the design model and the total violation (0 when feasible)."""
        values, violation, _ = self._loop_checks(controller)
        return values, violation

    def _loop_checks(self, controller: GeneralizedController) -> tuple[dict, float, list]:
        margin = self.spec.constraints.stability_margin
        scale = max(margin, STABILITY_SCALE)  # a mode's slack in units of the margin
        values, violation, slacks = {}, 0.0, []
        modes = spectral_abscissa(augmented(self.model, controller)[0], controller.period)
        values["abscissa"] = float(np.max(modes.real))
        violation += max(0.0, values["abscissa"] + margin)
        slacks.append((values["abscissa"] + margin) / scale)
        if not controller.discrete and self.spec.period > 0 and not self.model.discrete:
            sampled = discretize_controller(controller, self.spec.period)
            sampled_modes = spectral_abscissa(augmented(self.model, sampled)[0], self.spec.period)
            values["sampled_abscissa"] = float(np.max(sampled_modes.real))
            violation += max(0.0, values["sampled_abscissa"] + margin)
            slacks.append((values["sampled_abscissa"] + margin) / scale)
        if self.spec.constraints.controller_stable and controller.n_xc:
            ac = spectral_abscissa(controller.Ac, controller.period)
            values["controller_abscissa"] = float(np.max(ac.real))
            violation += max(0.0, values["controller_abscissa"])
            slacks.append(values["controller_abscissa"] / scale)
        return values, violation, slacks

    # -- one candidate ---------------------------------------------------------------------
    def __call__(self, x) -> Outcome:
        started = time.perf_counter()
        outcome = self._score(x)
        outcome.wall_time = time.perf_counter() - started
        outcome.worker = os.getpid()
        return outcome

    def _score(self, x) -> Outcome:
        try:
            controller = self.space.controller(x)
        except (DesignError, np.linalg.LinAlgError, ValueError) as error:
            return Outcome(self.spec.constraints.penalty * 2, False, {}, {},
                           f"no controller at this point: {error}")
        return self.score(controller)

    def score(self, controller: GeneralizedController) -> Outcome:
        """The objective and constraints of any controller (a candidate, or a baseline)."""
        started = time.perf_counter()
        outcome = self._score_controller(controller)
        outcome.wall_time = time.perf_counter() - started
        return outcome

    def _score_controller(self, controller: GeneralizedController) -> Outcome:
        penalty = self.spec.constraints.penalty
        try:
            constraints, violation, slacks = self._loop_checks(controller)
        except (DesignError, np.linalg.LinAlgError, ValueError) as error:
            return Outcome(penalty * 2, False, {}, {}, f"the loop cannot be analysed: {error}")
        if not math.isfinite(violation):
            return Outcome(penalty * 2, False, constraints, {}, "the loop's modes are not finite")
        if violation > 0:
            return Outcome(penalty + min(violation, penalty), False, constraints,
                           margin=_margin(slacks))
        if self.spec.objective.type == "spectral":
            # the paper's objective as stated: the largest |Re| of the loop's modes
            modes = spectral_abscissa(augmented(self.model, controller)[0], controller.period)
            value = float(np.max(np.abs(modes.real)))
            return Outcome(value, True, constraints, value=value, margin=_margin(slacks))
        return self._scenarios(controller, constraints, slacks)

    def prefilters(self, controller: GeneralizedController) -> dict[str, float]:
        """The prefilter F of ``controller`` for each output the spec's runs track."""
        from furuta_cosim.design.prefilter import prefilter

        tracked = dict.fromkeys(prepared.tracked for _, prepared, _ in self.runs())
        return {name: prefilter(self.model, controller, name) for name in tracked}

    def _scenarios(self, controller: GeneralizedController, constraints: dict,
                   slacks: list) -> Outcome:
        from furuta_cosim.controllers import ControllerFile
        from furuta_cosim.cosim import compile_controller, evaluate
        from furuta_cosim.design.prefilter import prefilter

        spec, penalty = self.spec, self.spec.constraints.penalty
        scores, metrics, violation, slacks = [], {}, 0.0, list(slacks)
        for label, prepared, _ in self.runs():
            session = self._session(prepared)
            try:
                F = prefilter(self.model, controller, prepared.tracked)
            except DesignError as error:
                return Outcome(penalty * 2, False, constraints, metrics, f"{label}: no prefilter: {error}")
            cfile = ControllerFile(controller, spec.period, spec.model, prepared.tracked, F)
            try:
                result = evaluate(prepared, session, compile_controller(prepared, cfile))
            except (ConfigError, FmuError) as error:
                return Outcome(penalty * 2, False, constraints, metrics, f"{label}: {error}")
            metrics[label] = json_safe(result.metrics)
            if result.failure:
                violation += 1.0
                constraints[f"{label}.diverged"] = True
                slacks.append(math.inf)
                scores.append(math.inf)
                continue
            for signal, bound in spec.constraints.max_abs:
                value = result.metrics.get(_peak(signal), math.inf)
                constraints[f"{label}.{signal}.max_abs"] = value
                violation += max(0.0, value / bound - 1.0)
                slacks.append(value / bound - 1.0)
            for metric, factor in spec.constraints.no_worse_than:
                reference = self.baseline_metrics()[label].get(metric, math.inf)
                value = result.metrics.get(metric, math.inf)
                ratio = value / reference if reference > 0 else (0.0 if value <= 0 else math.inf)
                constraints[f"{label}.{metric}/{spec.constraints.baseline}"] = ratio
                violation += max(0.0, ratio / factor - 1.0)
                slacks.append(ratio / factor - 1.0)
            if spec.constraints.requirements and not result.passed:
                failed = [k for k, v in result.requirements.items() if not v["pass"]]
                constraints[f"{label}.requirements"] = failed
                violation += 0.1 * len(failed)
                slacks.append(0.1 * len(failed))
            score = sum(term.weight * result.metrics.get(term.metric, math.inf)
                        for term in spec.objective.terms)
            scores.append(score)
        finite = all(math.isfinite(s) for s in scores)
        total = (max(scores) if spec.objective.aggregate == "worst" else float(np.mean(scores))) \
            if finite else None
        if violation > 0 or not finite:
            return Outcome(penalty + min(violation, penalty), False, constraints, metrics,
                           value=total, margin=_margin(slacks))
        return Outcome(float(total), True, constraints, metrics, value=float(total),
                       margin=_margin(slacks))

    def baseline_metrics(self) -> dict:
        """The metrics of the constraints' baseline controller on every run (computed once)."""
        if self._baseline is None:
            from furuta_cosim.cosim import compile_controller, evaluate

            self._baseline = {}
            for label, prepared, session in self.runs():
                try:
                    compiled = compile_controller(prepared, self.spec.constraints.baseline)
                except ConfigError as error:
                    raise error.within(f"{self.spec.source}: constraints.no_worse_than.controller") from None
                self._baseline[label] = evaluate(prepared, session, compiled).metrics
        return self._baseline

    def runs(self):
        """Every scenario on every plant variant, prepared once, each with its open session."""
        if self._runs is None:
            from furuta_cosim.cosim import prepare
            from furuta_cosim.cosim.worker import session_for
            from furuta_cosim.scenario import load_scenario

            from furuta_cosim.metrics import problem

            spec = self.spec
            runs = []
            for j, path in enumerate(spec.objective.scenarios):
                try:
                    scenario = load_scenario(path)
                except ConfigError as error:
                    raise error.within(f"{spec.source}: objective.scenarios[{j}]") from None
                for k, overrides in enumerate(spec.variants):
                    where = f"{spec.source}: variants[{k}]"
                    try:
                        prepared = prepare(scenario, overrides=dict(overrides))
                        session = session_for(prepared)
                        session.reset(prepared.start)  # the FMU's own checks of the variant
                    except ConfigError as error:
                        raise error.within(where) from None
                    except FmuError as error:
                        raise ConfigError([f"{where}: {error}"]) from None
                    # every metric the spec names must be one this run records: a term on an
                    # unrecorded metric would make every candidate, and the baseline, infeasible
                    for signal, _ in spec.constraints.max_abs:
                        if problem(_peak(signal), prepared.metrics):
                            raise ConfigError([f"{spec.source}: constraints.max_abs.{signal}: "
                                               f"scenario {scenario.name} records no {signal} "
                                               f"(signals: {', '.join(prepared.metrics)})"])
                    named = [(f"objective.terms[{n}].metric", t.metric)
                             for n, t in enumerate(spec.objective.terms)]
                    named += [(f"constraints.no_worse_than.metrics.{m}", m)
                              for m, _ in spec.constraints.no_worse_than]
                    for key, metric in named:
                        wrong = problem(metric, prepared.metrics)
                        if wrong:
                            raise ConfigError([f"{spec.source}: {key}: scenario {scenario.name}: {wrong}"])
                    label = scenario.name + (f"[{k}]" if len(spec.variants) > 1 else "")
                    runs.append((label, prepared, session))
            self._runs = runs
        return self._runs

    def _session(self, prepared):
        """This process's usable session on the run's FMU (a new one after a fatal error)."""
        from furuta_cosim.cosim.worker import session_for

        return session_for(prepared)
