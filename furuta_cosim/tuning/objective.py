"""The objective of a tuning and its constraints, for one candidate controller.

Cheap checks come first: the loop's stability with a margin on the design model (the
augmented matrix Abar, and the sampled loop at the control period) and, when asked, the
controller's own stability cost microseconds, so an unstable candidate never reaches a
co-simulation (``known`` in its outcome: ``bo`` checks these for its candidates itself).

A candidate's runs stop as soon as it is known infeasible (``constraints.stop_early``): a run
whose running ISE, IAE, ITAE, input energy or peak is past its constraint's bound stops there
(cosim/limits.py), and once one run has broken a constraint the candidate's other runs are
skipped. Its outcome then says which run stopped, when and why (``stopped``), which were not
run (``skipped``), and has no ``value``; its violation and margin are those of what was run,
lower bounds of the full runs'. The runs go in the order they are given (``order``: the one
broken most often so far first), and a candidate that is feasible scores the same in any order.
Baselines (:meth:`Evaluator.score`) always run to the end.

Each outcome carries what a constrained optimizer models separately (tuning/bayesopt.py):
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
from pathlib import Path
from dataclasses import dataclass, field

import numpy as np

from furuta_cosim.design.controller import GeneralizedController, augmented, discretize_controller
from furuta_cosim.documents import json_safe
from furuta_cosim.errors import ConfigError, DesignError, FmuError
from furuta_cosim.metrics import peak_metric
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
    criteria: dict | None = None    # tradeoff: each criterion's value (None where not computable)
    violated: list = field(default_factory=list)   # the runs that broke a constraint
    stopped: dict | None = None     # a run stopped early: {"run", "t", "metric", "value", "bound"}
    skipped: list = field(default_factory=list)    # the runs not simulated once one had failed
    known: bool = False             # decided by the loop's exact checks, never co-simulated
    slacks: dict | None = None      # each co-simulated constraint's slack, clipped to [-1, 1]
    trial: dict | None = None       # a rig trial: its folder, status, why it stopped, what failed
    simulation: dict | None = None  # a rig trial's candidate simulated: value, margin, feasible


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


def _linear(controller):
    """The generalized controller of a candidate: itself, or a swing-up file's balance controller."""
    return getattr(controller, "controller", controller)


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
        if spec.swingup is not None:
            from furuta_cosim.controllers import load_controller
            from furuta_cosim.tuning.space import SwingUpSpace

            self.space = SwingUpSpace(spec.blocks, load_controller(spec.swingup))
        else:
            self.space = Space(spec.blocks, self.model, spec.period, spec.discrete)
        self._runs = None  # [(label, prepared, session)], prepared on first use
        self._references = {}  # controller file -> its metrics by run (computed once)
        self._still = {}       # run -> the error metrics of an output that never moves
        self._named = None     # the slacks of the candidate being scored, by constraint name

    # -- the cheap checks ------------------------------------------------------------------
    def loop_checks(self, controller: GeneralizedController) -> tuple[dict, float]:
        """Constraint values on the design model and the total violation (0 when feasible)."""
        values, violation, _ = self._loop_checks(controller)
        return values, violation

    def _loop_checks(self, controller: GeneralizedController) -> tuple[dict, float, list]:
        controller = _linear(controller)  # a swing-up's loop is its balance controller's
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
    def __call__(self, x, order=None) -> Outcome:
        """A candidate's outcome: its runs in ``order`` (labels of :meth:`runs`, default the
        spec's), each stopped as soon as a constraint is known broken
        (``constraints.stop_early``), the rest then skipped."""
        started = time.perf_counter()
        outcome = self._score(x, order)
        outcome.wall_time = time.perf_counter() - started
        outcome.worker = os.getpid()
        return outcome

    def _score(self, x, order=None) -> Outcome:
        try:
            controller = self.space.controller(x)
        except (DesignError, np.linalg.LinAlgError, ValueError) as error:
            return Outcome(self.spec.constraints.penalty * 2, False, {}, {},
                           f"no controller at this point: {error}", known=True)
        return self._score_controller(controller, order, early=True)

    def score(self, controller: GeneralizedController) -> Outcome:
        """The objective and constraints of any controller (a candidate, or a baseline), every
        run to its end."""
        started = time.perf_counter()
        outcome = self._score_controller(controller)
        outcome.wall_time = time.perf_counter() - started
        return outcome

    def _score_controller(self, controller: GeneralizedController, order=None,
                          early: bool = False) -> Outcome:
        penalty = self.spec.constraints.penalty
        try:
            constraints, violation, slacks = self._loop_checks(controller)
        except (DesignError, np.linalg.LinAlgError, ValueError) as error:
            return Outcome(penalty * 2, False, {}, {}, f"the loop cannot be analysed: {error}", known=True)
        if not math.isfinite(violation):
            return Outcome(penalty * 2, False, constraints, {}, "the loop's modes are not finite",
                           known=True)
        if violation > 0:
            return Outcome(penalty + min(violation, penalty), False, constraints,
                           margin=_margin(slacks), known=True)
        if self.spec.objective.type == "spectral":
            # the paper's objective as stated: the largest |Re| of the loop's modes
            modes = spectral_abscissa(augmented(self.model, controller)[0], controller.period)
            value = float(np.max(np.abs(modes.real)))
            return Outcome(value, True, constraints, value=value, margin=_margin(slacks))
        # the loop's constraints are met and known exactly (the optimizer checks them itself):
        # the margin a surrogate models is the co-simulated constraints' alone
        return self._scenarios(controller, constraints, [], order, early)

    def traces(self, controller) -> dict:
        """``{run label: Trace}`` of ``controller`` (a candidate's matrices, or a swing-up
        file) on every scenario and plant variant, run as the objective runs it (the prefilter
        of each scenario's tracked output), every run to its end: for the figures of a run."""
        from furuta_cosim.cosim import compile_controller, evaluate

        found = {}
        for label, prepared, _ in self.runs():
            try:
                cfile = self.file_for(controller, prepared)
            except DesignError:
                continue
            try:
                found[label] = evaluate(prepared, self._session(prepared), compile_controller(prepared, cfile)).trace
            except (ConfigError, FmuError):
                continue
        return found

    def file_for(self, controller, prepared):
        """The controller file a run scores: a swing-up file as it is (its balance's own
        prefilter), a candidate's matrices with the prefilter of the run's tracked output
        (DesignError when it has none)."""
        from furuta_cosim.controllers import ControllerFile
        from furuta_cosim.design.prefilter import prefilter

        if isinstance(controller, ControllerFile):
            return controller
        F = prefilter(self.model, controller, prepared.tracked)
        return ControllerFile(controller, self.spec.period, self.spec.model, prepared.tracked, F)

    def prefilters(self, controller: GeneralizedController) -> dict[str, float]:
        """The prefilter F of ``controller`` for each output the spec's runs track."""
        from furuta_cosim.design.prefilter import prefilter

        tracked = dict.fromkeys(prepared.tracked for _, prepared, _ in self.runs())
        if controller is not _linear(controller) and controller.F is not None:  # a swing-up file's own
            return {controller.tracked_output: controller.F}
        return {name: prefilter(self.model, _linear(controller), name) for name in tracked}

    def _scenarios(self, controller: GeneralizedController, constraints: dict,
                   slacks: list, order=None, early: bool = False) -> Outcome:
        from furuta_cosim.cosim import compile_controller, evaluate

        spec, penalty = self.spec, self.spec.constraints.penalty
        early = early and spec.constraints.stop_early is not None
        scores, metrics, violation, slacks, violated = [], {}, 0.0, list(slacks), []
        self._named = {}
        runs = self.ordered(order)
        for position, (label, prepared, _) in enumerate(runs):
            session = self._session(prepared)
            try:
                cfile = self.file_for(controller, prepared)
            except DesignError as error:
                return Outcome(penalty * 2, False, constraints, metrics, f"{label}: no prefilter: {error}")
            limits = self.limits(label, prepared) if early else None
            try:
                result = evaluate(prepared, session, compile_controller(prepared, cfile), limits=limits)
            except (ConfigError, FmuError) as error:
                return Outcome(penalty * 2, False, constraints, metrics, f"{label}: {error}")
            if result.failure:
                metrics[label] = json_safe(result.metrics)
                self._named.update(dict.fromkeys(self.constraint_names(label), MARGIN_CAP))
                violation += 1.0
                constraints[f"{label}.diverged"] = True
                slacks.append(math.inf)
                violated.append(label)
                scores.append([math.inf] * len(spec.objective.criteria))
                continue
            if result.stopped:
                # what is known of a run stopped early: its watched metrics, each a lower bound
                watched = {m: result.metrics[m] for m in limits if m in result.metrics}
                metrics[label] = json_safe(watched)
                found = self._constraint_slacks(label, watched, constraints)
                violation += sum(max(0.0, slack) for slack in found)
                slacks += found
                violated.append(label)
                stopped = dict(result.stopped, run=label)
                return self._outcome([], violation, constraints, metrics, slacks, violated,
                                     stopped=stopped, skipped=[run[0] for run in runs[position + 1:]])
            metrics[label] = json_safe(result.metrics)
            found = self._constraint_slacks(label, result.metrics, constraints)
            violation += sum(max(0.0, slack) for slack in found)
            slacks += found
            if spec.constraints.requirements and not result.passed:
                failed = [k for k, v in result.requirements.items() if not v["pass"]]
                constraints[f"{label}.requirements"] = failed
                violation += 0.1 * len(failed)
                found.append(0.1 * len(failed))
                slacks.append(0.1 * len(failed))
            if any(slack > 0 for slack in found):
                violated.append(label)
                if early and position + 1 < len(runs):  # infeasible: the other runs cannot help
                    return self._outcome([], violation, constraints, metrics, slacks, violated,
                                         skipped=[run[0] for run in runs[position + 1:]])
            scores.append([self._criterion(criterion, label, result.metrics)
                           for criterion in spec.objective.criteria])
        if order is not None:  # the outcome reads as if the runs went in the spec's order
            position = {label: k for k, (label, _, _) in enumerate(self.runs())}
            ranks = [position[label] for label, _, _ in runs]
            scores = [score for _, score in sorted(zip(ranks, scores))]
        return self._outcome(scores, violation, constraints, metrics, slacks, violated)

    def _constraint_slacks(self, label: str, values: dict, constraints: dict) -> list[float]:
        """The slack of each co-simulated constraint on one run (> 0: broken), recorded in
        ``constraints`` (and by name, clipped, for the outcome's ``slacks``); a metric the run
        does not have counts as infinite."""
        spec, found = self.spec, []
        names = iter(self.constraint_names(label))
        for signal, bound in spec.constraints.max_abs:
            value = values.get(peak_metric(signal), math.inf)
            constraints[f"{label}.{signal}.max_abs"] = value
            found.append(value / bound - 1.0)
        for metric, factor in spec.constraints.no_worse_than:
            reference = self.baseline_metrics()[label].get(metric, math.inf)
            value = values.get(metric, math.inf)
            ratio = value / reference if reference > 0 else (0.0 if value <= 0 else math.inf)
            constraints[f"{label}.{metric}/{Path(spec.constraints.baseline).stem}"] = ratio
            found.append(ratio / factor - 1.0)
        named = getattr(self, "_named", None)
        if named is not None:
            named.update({name: _margin([slack]) for name, slack in zip(names, found)})
        return found

    def constraint_names(self, label: str) -> list[str]:
        """The names of a run's co-simulated constraints, in the order of their slacks."""
        return ([f"{label}.{signal}.max_abs" for signal, _ in self.spec.constraints.max_abs]
                + [f"{label}.{metric}" for metric, _ in self.spec.constraints.no_worse_than])

    def limits(self, label: str, prepared) -> dict[str, float]:
        """The bounds a run of ``label`` is watched against (cosim/limits.py): each constraint
        on a metric that only grows, at the value where its slack passes
        ``constraints.stop_early`` (a run past it has failed by at least that much)."""
        from furuta_cosim.cosim.limits import monotone

        spec, past = self.spec, self.spec.constraints.stop_early
        if past is None:
            return {}
        found = {}
        for signal, bound in spec.constraints.max_abs:
            if monotone(peak_metric(signal), prepared.outputs):
                found[peak_metric(signal)] = bound * (1.0 + past)
        for metric, factor in spec.constraints.no_worse_than:
            reference = self.baseline_metrics()[label].get(metric)
            if monotone(metric, prepared.outputs) and isinstance(reference, float) \
                    and math.isfinite(reference) and reference > 0:
                bound = reference * factor * (1.0 + past)
                found[metric] = min(bound, found.get(metric, math.inf))
        return found

    def ordered(self, order=None) -> list:
        """The runs, those named in ``order`` first and in that order (the ones that fail
        most often, tuning/methods.py's scenario_order), then the rest as the spec has them."""
        runs = self.runs()
        if not order:
            return list(runs)
        rank = {label: k for k, label in enumerate(order)}
        return sorted(runs, key=lambda run: rank.get(run[0], len(rank)))

    def by_variant(self, metrics: dict) -> list[float | None]:
        """The objective of one controller on each plant variant alone, from its metrics by run
        (the spec's own terms and aggregate over that variant's scenarios); None for a
        variant where a run has no finite value."""
        found = []
        for k in range(len(self.spec.variants)):
            suffix = f"[{k}]" if len(self.spec.variants) > 1 else ""
            labels = [label for label, _, _ in self.runs() if label.endswith(suffix)] if suffix else \
                [label for label, _, _ in self.runs()]
            scores = []
            for label in labels:
                values = metrics.get(label) or {}
                scores.append([self._criterion(c, label, {m: (v if isinstance(v, float) else math.inf)
                                                           for m, v in values.items()})
                               for c in self.spec.objective.criteria])
            totals = []
            for j, criterion in enumerate(self.spec.objective.criteria):
                column = [run[j] for run in scores]
                if not column or not all(math.isfinite(v) for v in column):
                    totals = None
                    break
                totals.append(max(column) if criterion.aggregate == "worst" else float(np.mean(column)))
            found.append(float(np.mean(totals)) if totals else None)
        return found

    def _criterion(self, criterion, label: str, metrics: dict) -> float:
        """One criterion's weighted terms on one run (a relative term divided by its
        controller's value on the same run)."""
        total = 0.0
        for term in criterion.terms:
            value = metrics.get(term.metric, math.inf)
            if term.relative_to:
                value = value / self.reference_metrics(term.relative_to)[label][term.metric]
            total += term.weight * value
        return total

    def _outcome(self, scores, violation, constraints, metrics, slacks, violated=(), *,
                 stopped=None, skipped=()) -> Outcome:
        """The outcome from each run's criteria: aggregated over the runs; the objective of a
        tradeoff is the mean of its criteria (what one number can say: random search's and the
        progress line's; the front is what the run is for). A stopped candidate has no value:
        its runs did not all go to the end."""
        spec, penalty = self.spec, self.spec.constraints.penalty
        criteria = {}
        for k, criterion in enumerate(spec.objective.criteria):
            column = [run[k] for run in scores]
            finite = bool(column) and all(math.isfinite(v) for v in column)
            criteria[criterion.name] = (max(column) if criterion.aggregate == "worst"
                                        else float(np.mean(column))) if finite else None
        known = [v for v in criteria.values() if v is not None]
        total = float(np.mean(known)) if len(known) == len(criteria) else None
        tradeoff = criteria if spec.objective.type == "tradeoff" else None
        named = getattr(self, "_named", None)
        extra = dict(margin=_margin(slacks), criteria=tradeoff, violated=list(violated),
                     stopped=stopped, skipped=list(skipped), slacks=dict(named) if named is not None else None)
        if violation > 0 or total is None or stopped or skipped:
            return Outcome(penalty + min(violation, penalty), False, constraints, metrics,
                           value=None if stopped or skipped else total, **extra)
        return Outcome(total, True, constraints, metrics, value=total, **extra)

    def baseline_metrics(self) -> dict:
        """The metrics of the constraints' baseline controller on every run (computed once)."""
        return self.reference_metrics(self.spec.constraints.baseline,
                                      "constraints.no_worse_than.controller")

    def reference_metrics(self, controller: str, key: str = "objective") -> dict:
        """The metrics of a controller file the spec names, on every run (computed once per
        process). A relative term's metric must be positive there: it is divided by it."""
        if controller not in self._references:
            found = self._reference_runs(controller, key)
            for k, criterion in enumerate(self.spec.objective.criteria):
                for n, term in enumerate(criterion.terms):
                    if term.relative_to != controller:
                        continue
                    for label, values in found.items():
                        value = values.get(term.metric)
                        if not (isinstance(value, float) and math.isfinite(value) and value > 0):
                            where = (f"objective.criteria[{k}].terms[{n}]" if self.spec.objective.type
                                     == "tradeoff" else f"objective.terms[{n}]")
                            raise ConfigError([f"{self.spec.source}: {where}.relative_to: "
                                               f"{Path(controller).stem} has {term.metric} = {value} "
                                               f"on {label}; a term is divided by it, so it must be "
                                               "a positive number"])
            self._references[controller] = found
        return self._references[controller]

    def _reference_runs(self, controller: str, key: str) -> dict:
        """The metrics of a controller file on every run (``label -> metrics``), each run to its
        end; what an output that never moves would score is noted on the way (:meth:`vacuous`)."""
        from furuta_cosim.cosim import compile_controller, evaluate
        from furuta_cosim.metrics import standing_still

        found = {}
        for label, prepared, session in self.runs():
            try:
                compiled = compile_controller(prepared, controller)
            except ConfigError as error:
                raise error.within(f"{self.spec.source}: {key}") from None
            result = evaluate(prepared, session, compiled)
            found[label] = result.metrics
            if label not in self._still:
                self._still[label] = standing_still(result.trace, prepared.scenario.error_window)
        return found

    def variants(self) -> tuple:
        """The plant variants every scenario runs on (the spec's)."""
        return self.spec.variants

    def vacuous(self) -> list[str]:
        """The tracking constraints an output that never moves would meet (its error metric
        within the factor of the baseline's), run by run, in words: they test nothing there."""
        found = []
        constraints = self.spec.constraints
        if not constraints.no_worse_than:
            return found
        baseline = self.baseline_metrics()
        for metric, factor in constraints.no_worse_than:
            for label, still in self._still.items():
                value = baseline.get(label, {}).get(metric)
                if metric in still and value is not None and still[metric] <= factor * value:
                    found.append(f"constraints.no_worse_than.{metric} is vacuous on {label}: "
                                 f"{Path(constraints.baseline).stem} scores {value:.4g}, an output "
                                 f"that never moves {still[metric]:.4g}, within the factor "
                                 f"{factor:g}: the constraint does not test tracking there")
        return found

    def check_references(self) -> None:
        """Every controller the spec compares with, scored on every run before the search."""
        if self.spec.constraints.no_worse_than:
            self.baseline_metrics()
        for term in self.spec.objective.all_terms:
            if term.relative_to:
                self.reference_metrics(term.relative_to)

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
                    if spec.plant is not None:
                        from furuta_cosim.cosim.master import on_plant

                        scenario = on_plant(scenario, spec.plant)
                except ConfigError as error:
                    raise error.within(f"{spec.source}: objective.scenarios[{j}]") from None
                variants = self.variants()
                for k, overrides in enumerate(variants):
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
                        if problem(peak_metric(signal), prepared.metrics):
                            raise ConfigError([f"{spec.source}: constraints.max_abs.{signal}: "
                                               f"scenario {scenario.name} records no {signal} "
                                               f"(signals: {', '.join(prepared.metrics)})"])
                    named = [(f"objective.terms[{n}].metric", t.metric)
                             for n, t in enumerate(spec.objective.terms)]
                    named += [(f"objective.criteria[{c}].terms[{n}].metric", t.metric)
                              for c, criterion in enumerate(spec.objective.criteria_)
                              for n, t in enumerate(criterion.terms)]
                    named += [(f"constraints.no_worse_than.metrics.{m}", m)
                              for m, _ in spec.constraints.no_worse_than]
                    for key, metric in named:
                        wrong = problem(metric, prepared.metrics)
                        if wrong:
                            raise ConfigError([f"{spec.source}: {key}: scenario {scenario.name}: {wrong}"])
                    label = scenario.name + (f"[{k}]" if len(variants) > 1 else "")
                    runs.append((label, prepared, session))
            self._runs = runs
        return self._runs

    def _session(self, prepared):
        """This process's usable session on the run's FMU (a new one after a fatal error)."""
        from furuta_cosim.cosim.worker import session_for

        return session_for(prepared)
