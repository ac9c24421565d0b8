"""Optimizer methods: one class per ``optimizer.method`` (``tune --optimizer``), registered
once in :data:`METHODS`. The spec's check, the CLI's choices, the docs and the error messages
read the registry; a new method is one class here (with its test).

A method's :meth:`Method.search` drives one :class:`Run`: it asks points, hands them to
:meth:`Run.evaluate` (or :meth:`Run.submit` and :meth:`Run.collect`, to send each point of a
batch as soon as it is known), and stops when the history holds ``run.n_calls`` records. A
resumed run replays its history: a method proposes the same points again (checked by
:func:`~furuta_cosim.tuning.history.replayed`) and evaluates only what is new.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, ClassVar

if TYPE_CHECKING:
    from furuta_cosim.tuning.history import History

# this module is light to import (the CLI's parser reads METHODS for --optimizer): numpy, the
# history and the optimizers come in when a search runs
METHODS: dict[str, type[Method]] = {}


@dataclass
class Run:
    """One tuning run as a method sees it: the spec, where candidates are evaluated, the
    history so far, the budget and the clocks."""

    spec: object                 # TuningSpec
    folder: Path
    evaluator: object            # Evaluator
    executor: object             # tuning/executors.py
    history: History
    n_calls: int
    seed: int
    clock: dict                  # rundir.Clock: "optimizer" and "evaluation" seconds
    progress: Callable | None = None
    log: Callable[[str], None] | None = None
    prior: object = None         # tuning on a rig: the simulated fidelity (tuning/rig.py's Fidelity)

    @property
    def records(self) -> list[dict]:
        return self.history.records

    @property
    def batch(self) -> int:
        return self.spec.optimizer.batch

    def order(self, first: int) -> list[str]:
        """The order of a candidate's runs for a batch that starts at evaluation ``first``:
        the run broken most often before it goes first (a function of the history before the
        batch, so a resumed run orders its runs as the uninterrupted one did)."""
        from furuta_cosim.tuning.history import failing_first

        return failing_first(self.records[:first], [label for label, _, _ in self.evaluator.runs()])

    def submit(self, x, first: int):
        """Send ``x`` of the batch that starts at evaluation ``first`` to a worker."""
        return self.executor.submit(x, self.order(first))

    def collect(self, xs, pending, origins, surrogate=None) -> list[float]:
        """Wait for a batch's outcomes (the evaluation clock: time spent waiting), record them
        and report progress."""
        from furuta_cosim.tuning.history import record

        started = time.perf_counter()
        outcomes = self.executor.gather(pending) if pending else []
        self.clock["evaluation"] += time.perf_counter() - started
        names = self.evaluator.space.names
        for k, (x, outcome) in enumerate(zip(xs, outcomes)):
            self.history.append(record(len(self.records), x, names, outcome, origins[k], surrogate))
        self.report()
        return [outcome.objective for outcome in outcomes]

    def evaluate(self, xs, origin: str, first: int | None = None) -> list[float]:
        """Evaluate and record ``xs``, a batch that starts at evaluation ``first`` (default:
        the next one)."""
        first = len(self.records) if first is None else first
        return self.collect(xs, [self.submit(x, first) for x in xs], [origin] * len(xs))

    def report(self) -> None:
        self.clock.save()
        if self.progress:
            feasible = [r["objective"] for r in self.records if r["feasible"]]
            self.progress(len(self.records), self.n_calls, min(feasible) if feasible else None, len(feasible))


class Method:
    """One optimizer method; subclasses set ``name`` and ``description`` and implement
    :meth:`search`."""

    name: ClassVar[str]
    description: ClassVar[str]
    one_number: ClassVar[bool] = False      # minimizes one number: no tradeoff objective
    rig_only: ClassVar[bool] = False        # needs a rig in the loop (tune --board)

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.name in METHODS:
            raise ValueError(f"optimizer method {cls.name!r} registered twice")
        METHODS[cls.name] = cls

    @classmethod
    def refusal(cls, spec) -> str | None:
        """Why this method cannot search ``spec`` (its objective), or None."""
        if cls.one_number and spec.objective is not None and spec.objective.type == "tradeoff":
            return (f"{cls.name} ({cls.description}) minimizes one number; a tradeoff objective is "
                    f"searched by {' or '.join(n for n, m in METHODS.items() if not m.one_number)}")
        return None

    def search(self, run: Run) -> None:
        raise NotImplementedError


def method_for(name: str) -> Method:
    return METHODS[name]()


class Bayes(Method):
    """Constrained Bayesian optimization (tuning/bayesopt.py): GP of the objective and of
    feasibility, EI times the probability of feasibility in trust regions; for a tradeoff
    objective expected hypervolume improvement (two criteria) or ParEGO scalarizations."""

    name = "bo"
    description = "constrained Bayesian optimization"

    def search(self, run: Run) -> None:
        from furuta_cosim.tuning import pareto
        from furuta_cosim.tuning.history import replayed
        from furuta_cosim.tuning.mobo import HypervolumeBO
        from furuta_cosim.tuning.bayesopt import ConstrainedBO, batches

        spec, settings, records = run.spec, run.spec.optimizer, run.records
        if len(records) >= run.n_calls:
            return  # a finished run resumed: nothing to propose, no time to count
        started = time.perf_counter()
        tradeoff = spec.objective.type == "tradeoff"
        start = "space" if tradeoff else start_of(spec, run.n_calls, records)
        design = initial_design(spec, run.evaluator, run.seed, run.log, start)[:run.n_calls]
        if not any(o.startswith("initial design around") for _, o in design):
            start = "space"   # no baseline in the space to start around
        if run.log and not records:
            run.log(_start_line(spec, start, run.n_calls))
        replayed(records, [x for x, _ in design], 0)
        todo = design[len(records):]
        run.clock["optimizer"] += time.perf_counter() - started
        if todo:  # every point is known: all at once, whatever the workers
            xs = [x for x, _ in todo]
            run.collect(xs, [run.submit(x, len(design)) for x in xs], [o for _, o in todo])
        names = [c.name for c in spec.objective.criteria]
        parego = spec.objective.type == "tradeoff" and front_search(spec) == "parego"
        kind = HypervolumeBO if spec.objective.type == "tradeoff" and not parego else ConstrainedBO
        optimizer = kind(run.evaluator.space.bounds, run.seed, xi=settings.xi, n_initial_points=len(design),
                         batch=run.batch, gp_restarts=settings.gp_restarts, region=settings.region,
                         screen=_stable(run.evaluator),
                         **({"names": names} if kind is HypervolumeBO else {"start": start}))
        for number, first, count in batches(len(design), run.batch, run.n_calls):
            if first + count <= len(records):
                continue  # evaluated before a resume
            started = time.perf_counter()
            seen = records[:first]
            if parego:  # this batch's scalarization
                seen = pareto.scalarized(seen, names, run.seed, number)
            proposal = optimizer.propose(seen, len(design), number)
            points = proposal.points(count)
            xs, pending = [], []
            done = len(records) - first  # a resume in the middle of this batch: proposed again
            while True:  # each point goes out while the next one is computed
                started = started or time.perf_counter()
                x = next(points, None)
                run.clock["optimizer"] += time.perf_counter() - started
                started = None
                if x is None:
                    break
                if len(xs) < done:
                    replayed(records[first:], [x], len(xs))
                    xs.append(None)
                    continue
                xs.append(x)
                pending.append(run.submit(x, first))
            fresh = [x for x in xs if x is not None]
            run.collect(fresh, pending, [proposal.origin] * len(fresh), proposal.surrogate)


class Random(Method):
    """The same space drawn at random (a seeded sequence: a resumed run draws the same)."""

    name = "random"
    description = "random search"

    def search(self, run: Run) -> None:
        from furuta_cosim.tuning.bayesopt import RandomSearch

        sampler = RandomSearch(run.evaluator.space.bounds, run.seed)
        while len(run.records) < run.n_calls:
            # batches of run.batch from evaluation 0, also after a resume in the middle of one
            start = len(run.records) - len(run.records) % run.batch
            end = min(start + run.batch, run.n_calls)
            run.evaluate([sampler.point(k) for k in range(len(run.records), end)], "random", start)


class _Spent(Exception):
    """The budget is spent: ends scipy's differential evolution from inside."""


class DifferentialEvolution(Method):
    """scipy's differential evolution on the same space and budget; a resumed run replays the
    recorded evaluations (same seed, same proposals) and evaluates only what is new."""

    name = "de"
    description = "scipy's differential evolution"
    one_number = True

    def search(self, run: Run) -> None:
        import numpy as np
        from scipy.optimize import differential_evolution

        replay = list(run.records)

        def evaluate_all(_objective, points):  # scipy's map-like ``workers``
            xs = [list(map(float, x)) for x in points]
            ys = []
            while xs and replay and np.allclose(xs[0], replay[0]["x"], rtol=0, atol=1e-12):
                ys.append(replay.pop(0)["objective"])
                xs.pop(0)
            remaining = run.n_calls - len(run.records)
            if xs and remaining <= 0:
                raise _Spent()
            # a generation is one batch: its runs are ordered by the history before it
            ys += run.evaluate(xs[:remaining], "differential evolution", len(run.records) - len(ys))
            if len(xs) > remaining:
                raise _Spent()
            return ys

        dimensions = len(run.evaluator.space.bounds)
        budget = run.spec.optimizer.n_calls  # the spec's, not --n-calls: a longer run extends a shorter one
        started, waited = time.perf_counter(), run.clock["evaluation"]
        try:
            differential_evolution(lambda x: 0.0, run.evaluator.space.bounds, seed=run.seed, maxiter=10**9,
                                   popsize=max(5, min(15, budget // (4 * dimensions) or 1)),
                                   polish=False, updating="deferred", workers=evaluate_all, tol=0,
                                   init="latinhypercube")
        except _Spent:
            pass
        run.clock["optimizer"] += time.perf_counter() - started - (run.clock["evaluation"] - waited)


class Safe(Method):
    """Safe Bayesian optimization on a rig (tuning/safe.py): from the safe seed (the spec's
    first baseline), only candidates whose constraints hold at the upper confidence bound of
    the simulation plus a GP of the sim-to-rig gap. Tuning on a rig only."""

    name = "safe"
    description = "safe Bayesian optimization on a rig, the simulation its prior"
    one_number = True
    rig_only = True

    def search(self, run: Run) -> None:
        from furuta_cosim.controllers import load_controller
        from furuta_cosim.errors import ConfigError
        from furuta_cosim.tuning.history import record
        from furuta_cosim.tuning.safe import SafeBO

        if run.prior is None:
            raise ConfigError(["method: safe tunes on a rig (a `board`, or an external rig: `evaluator`): "
                               "in simulation use bo"])
        spec, space = run.spec, run.evaluator.space
        if not run.records:  # the safe seed: the first baseline's own trial
            cfile = load_controller(spec.baselines[0])
            x, how = space.point_of(cfile)
            if x is None:
                raise ConfigError([f"{spec.source}: baselines[0]: {cfile.name} is where the safe method "
                                   f"starts, and it is not a point of the search space ({how})"])
            started = time.perf_counter()
            outcome = run.evaluator.baseline_outcome(spec.baselines[0])
            outcome.simulation = run.prior.exact(x)
            run.clock["evaluation"] += time.perf_counter() - started
            run.history.append(record(0, x, space.names, outcome, f"safe seed {cfile.name}"))
            run.report()
        proposer = SafeBO(space.bounds, run.seed, run.prior, beta=spec.rig.beta, screen=_stable(run.evaluator))
        while len(run.records) < run.n_calls:
            started = time.perf_counter()
            proposal = proposer.propose(run.records, len(run.records))
            run.clock["optimizer"] += time.perf_counter() - started
            first = len(run.records)
            run.collect([proposal.x], [run.submit(proposal.x, first)], [proposal.origin], proposal.surrogate)


def start_of(spec, n_calls: int, records=()) -> str:
    """Where ``bo`` starts (tuning/bayesopt.py STARTS): ``optimizer.start``; ``auto`` is the
    baseline for a budget of at most FEW_EVALUATIONS, else the space. A resumed run keeps the
    start its history began with, whatever its new budget."""
    from furuta_cosim.tuning.bayesopt import FEW_EVALUATIONS

    if spec.optimizer.start != "auto":
        return spec.optimizer.start
    origins = [str(r.get("origin", "")) for r in records]
    if any(o.startswith("initial design around") for o in origins):
        return "baseline"
    if any(o == "initial design" for o in origins):
        return "space"
    return "baseline" if n_calls <= FEW_EVALUATIONS else "space"


def _start_line(spec, start: str, n_calls: int) -> str:
    from furuta_cosim.tuning.bayesopt import FEW_EVALUATIONS

    why = (f"optimizer.start: {spec.optimizer.start}" if spec.optimizer.start != "auto" else
           f"a budget of {n_calls} evaluations: "
           + (f"at most {FEW_EVALUATIONS} start at the baseline" if n_calls <= FEW_EVALUATIONS
              else f"more than {FEW_EVALUATIONS} start over the whole space"))
    where = ("around the first baseline, in small trust regions" if start == "baseline"
             else f"over the whole space ({spec.optimizer.n_initial_points} initial points)")
    return f"start: {where} ({why})"


def initial_design(spec, evaluator, seed: int, log=None, start: str = "space") -> list[tuple[list[float], str]]:
    """The initial design of ``bo``: the spec's baselines (unless ``optimizer.warm_start`` is
    false) and ``optimizer.initial`` controllers the space can represent (each said in one
    line, or why not), then a Latin hypercube up to ``optimizer.n_initial_points``; with
    ``start`` ``baseline``, a few points of a small Latin hypercube around the first of them
    instead (tuning/bayesopt.py LOCAL_POINTS)."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.tuning.bayesopt import LOCAL_POINTS, latin_hypercube, local_design

    design, seen = [], set()
    baselines = spec.baselines if spec.optimizer.warm_start else ()
    for kind, names in (("baseline", baselines), ("initial", spec.optimizer.initial)):
        for name in names:
            cfile = load_controller(name)
            if cfile.name in seen:
                continue
            seen.add(cfile.name)
            x, how = evaluator.space.point_of(cfile)
            if log:
                log(f"{kind} {cfile.name}: " + (f"in the initial design, {how}" if x is not None
                                                 else f"not in the initial design: {how}"))
            if x is not None:
                design.append((x, f"{kind} {cfile.name}"))
    if start == "baseline" and design:
        around = design[0][1].split(" ", 1)[1]
        fill = local_design(LOCAL_POINTS, design[0][0], evaluator.space.bounds, seed)
        return design + [(x, f"initial design around {around}") for x in fill]
    fill = latin_hypercube(spec.optimizer.n_initial_points - len(design), evaluator.space.bounds, seed)
    return design + [(x, "initial design") for x in fill]


def front_search(spec) -> str:
    """How ``bo`` searches a tradeoff: ``optimizer.front``, auto meaning ehvi for two criteria
    and parego for more."""
    if spec.optimizer.front != "auto":
        return spec.optimizer.front
    return "ehvi" if len(spec.objective.criteria) == 2 else "parego"


def _stable(evaluator):
    """The exact check of the loop's stability at a point (microseconds to a millisecond,
    against a co-simulation's tenths of a second): candidates that fail it are not proposed."""
    def screen(x) -> bool:
        try:
            return evaluator.loop_checks(evaluator.space.controller(x))[1] == 0
        except Exception:  # noqa: BLE001 - no controller there: not a candidate
            return False
    return screen
