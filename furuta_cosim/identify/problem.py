"""The fit's problem: the free unknowns, their shares between logs, and the residuals of a
point, each evaluation a co-simulation of every experiment on this process, local workers or
Dask (:class:`Runner`); the lowest layer of the fit, the profiles, the reach and the bootstrap,
which all step a :class:`Problem`.

Residuals are ``(simulated - measured) / sigma`` per sample, ``sigma`` from each output's
noise and encoder quantum; a sample whose simulation failed at a trial point gets
:data:`FAILED_RESIDUAL`, so that least_squares rejects the step.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import Experiment
from furuta_cosim.identify.replay import SimulationFailed, Target, simulate
from furuta_cosim.identify.spec import IdentifySpec

# the residual of a sample whose simulation failed at a trial point: large, so that
# least_squares rejects the step and shrinks its trust region
FAILED_RESIDUAL = 1e4


# -- evaluation in workers ----------------------------------------------------------------
_CONTEXT: dict = {}


def _set_context(target: Target, experiments: Sequence[Experiment]) -> None:
    _CONTEXT["target"], _CONTEXT["experiments"] = target, list(experiments)
    _CONTEXT["cut"] = {}


def _experiment(index: int, horizon: float | None) -> Experiment:
    experiment = _CONTEXT["experiments"][index]
    if horizon is None:
        return experiment
    key = (index, horizon)
    cut = _CONTEXT["cut"].get(key)
    if cut is None:
        cut = _CONTEXT["cut"][key] = experiment.truncated(horizon)
    return cut


def run_task(task) -> tuple:
    """One simulation: ``(experiment index, horizon, values)`` -> ``(outputs, None)`` or
    ``(None, why it failed)``; the session of this process is opened on first use."""
    from furuta_cosim.cosim.worker import session_on

    index, horizon, values = task
    target = _CONTEXT["target"]
    session = session_on(target.fmu)
    try:
        return simulate(session, target, _experiment(index, horizon), values), None
    except SimulationFailed as error:
        return None, str(error)


def _run_with(context, task) -> tuple:  # a Dask worker: the context arrives with the task
    if _CONTEXT.get("key") != context[2]:
        _set_context(context[0], context[1])
        _CONTEXT["key"] = context[2]
    return run_task(task)


class Runner:
    """Runs simulations in this process (``workers=1``), on local worker processes, or on
    Dask (``dask``: an address or ``local``); ``map`` keeps the order of its tasks."""

    def __init__(self, target: Target, experiments: Sequence[Experiment], workers: int = 1,
                 dask: str | None = None):
        self.count = 0
        self.experiments = list(experiments)   # what task k simulates: experiments[k]
        self._fmu = target.fmu
        self._pool = self._client = self._cluster = None
        if dask is not None:
            self._start_dask(target, experiments, dask, workers)
        elif workers > 1:
            from furuta_cosim.cosim.worker import start_pool

            self._pool = start_pool(workers, _set_context, (target, list(experiments)))
        else:
            _set_context(target, experiments)
        self.where = ("on Dask" if dask else f"on {workers} worker processes" if workers > 1
                      else "in this process")

    def _start_dask(self, target, experiments, address, workers) -> None:
        from furuta_cosim.cosim.worker import connect_dask

        self._client, self._cluster = connect_dask(address, workers)
        context = (target, list(experiments), f"{id(self)}-{time.time_ns()}")
        [self._context] = self._client.scatter([context], broadcast=True)

    def map(self, tasks: Sequence) -> list[tuple]:
        self.count += len(tasks)
        if self._client is not None:
            futures = [self._client.submit(_run_with, self._context, task, pure=False) for task in tasks]
            try:
                return self._client.gather(futures)
            except Exception as error:  # noqa: BLE001 (a lost scheduler or worker: the fit cannot go on)
                from furuta_cosim.errors import RunStopped

                raise RunStopped(f"the Dask cluster failed during the fit ({type(error).__name__}: "
                                 f"{error}); nothing was written: run identify again") from None
        if self._pool is not None:
            return list(self._pool.map(run_task, tasks))
        return [run_task(task) for task in tasks]

    def close(self) -> None:
        if self._pool is not None:
            from furuta_cosim.cosim.worker import stop_pool

            stop_pool(self._pool)
            self._pool = None
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        from furuta_cosim.cosim.worker import close_session

        close_session(self._fmu)  # this process's (workers remove theirs when they end)


# -- the problem ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Unknown:
    """A fitted value: a plant parameter, or an experiment's free initial state
    (``<experiment>.<state>``); fitted as ``value / scale``."""

    name: str
    start: float
    bounds: tuple[float, float]
    scale: float


def unknowns(spec: IdentifySpec, plant_values: Mapping[str, float]) -> list[Unknown]:
    found, named = [], set()
    for p in spec.free:
        start = p.start if p.start is not None else plant_values.get(p.name)
        if start is None:
            raise ConfigError([f"{spec.path}: free.{p.name}: give a start (the plant has no value for it)"])
        start = min(max(float(start), p.bounds[0]), p.bounds[1])
        found.append(Unknown(p.name, start, p.bounds, _scale(start, p.bounds)))
    for experiment in spec.experiments:
        for state, free in experiment.free_starts().items():  # states, sensor biases, delays
            # a sensor's bias and an input's delay are the whole log's, in each of its parts
            # (identify/split.py)
            owner = (experiment.alias or experiment.name) if state.endswith((".bias", ".delay")) else experiment.name
            if f"{owner}.{state}" in named:   # a delay each of a log's segments shares
                continue
            named.add(f"{owner}.{state}")
            found.append(Unknown(f"{owner}.{state}", free.start, free.bounds,
                                 _scale(free.start, free.bounds)))
    return found


def shared_values(fitted, others) -> dict[str, list[str]]:
    """The delays a validation log shares with the fitted logs: for each log of ``others``
    whose delay (an input's or its loop's) is free and is not one of the fit's unknowns (a log
    held out whole, not a part of a fitted one), the fitted logs' unknowns of the same delay
    (``{key: [fitted keys]}``): it is scored at their value (their mean), not at its start. A
    delay is the rig's (its board, its transport), the same in every log of it; a sensor's zero
    (a bias) or a start state is each log's own and is not shared."""
    def delays(experiment):
        owner = experiment.alias or experiment.name
        return {suffix: f"{owner}.{suffix}" for suffix in experiment.free_starts() if suffix.endswith(".delay")}

    fitted_keys: dict[str, list[str]] = {}
    for experiment in fitted:
        for suffix, key in delays(experiment).items():
            if key not in fitted_keys.setdefault(suffix, []):
                fitted_keys[suffix].append(key)
    known = {key for keys in fitted_keys.values() for key in keys}
    found = {}
    for experiment in others:
        for suffix, key in delays(experiment).items():
            if key not in known and fitted_keys.get(suffix):
                found[key] = list(fitted_keys[suffix])
    return found


def with_shared(values: Mapping[str, float], shares: Mapping[str, list[str]]) -> dict[str, float]:
    """``values`` with each shared key (:func:`shared_values`) at its sources' mean."""
    found = dict(values)
    for key, sources in shares.items():
        found[key] = float(np.mean([values[s] for s in sources]))
    return found


def _scale(start: float, bounds: tuple[float, float]) -> float:
    """A typical size: the start's magnitude, else a hundredth of the larger bound's."""
    return abs(start) if start != 0 else max(abs(bounds[0]), abs(bounds[1])) / 100.0


class Problem:
    """The residual vector and its finite-difference Jacobian over a set of experiments."""

    def __init__(self, runner: Runner, experiments: Sequence[Experiment], items: Sequence[Unknown],
                 horizon: float | None, budget: int, progress: Callable[[int, float], None]):
        self.runner, self.items, self.horizon = runner, list(items), horizon
        self.experiments = [e.truncated(horizon) if horizon else e for e in experiments]
        self.budget, self.progress = budget, progress
        self.best_cost = math.inf
        self._cache: dict = {}
        # a validation log's free delay, at the fitted logs' value (shared_values)
        self.shares = shared_values(experiments, getattr(runner, "experiments", ()))

    def values(self, x: np.ndarray) -> dict[str, float]:
        found = {u.name: float(v) * u.scale for u, v in zip(self.items, x)}
        return with_shared(found, self.shares) if self.shares else found

    def _residuals(self, results, values) -> np.ndarray:
        parts = []
        for experiment, (outputs, failure) in zip(self.experiments, results):
            if outputs is not None:
                outputs = experiment.corrected(outputs, values)
            for name, measured in experiment.outputs.items():
                if outputs is None:
                    parts.append(np.full(experiment.samples, FAILED_RESIDUAL))
                else:
                    parts.append((outputs[name] - measured.values) / measured.sigma)
        return np.concatenate(parts)

    def _evaluate(self, xs: Sequence[np.ndarray]) -> list[np.ndarray]:
        missing = [x for x in xs if x.tobytes() not in self._cache]
        if missing and self.runner.count >= self.budget:
            raise BudgetSpent()
        tasks = [(k, self.horizon, self.values(x)) for x in missing for k in range(len(self.experiments))]
        results = self.runner.map(tasks) if tasks else []
        n = len(self.experiments)
        for j, x in enumerate(missing):
            r = self._residuals(results[j * n:(j + 1) * n], self.values(x))
            self._cache[x.tobytes()] = r
            self.best_cost = min(self.best_cost, 0.5 * float(r @ r))
        self.progress(self.runner.count, self.best_cost)
        return [self._cache[x.tobytes()] for x in xs]

    def fun(self, x: np.ndarray) -> np.ndarray:
        return self._evaluate([np.asarray(x, dtype=float)])[0]

    def steps(self, x: np.ndarray) -> np.ndarray:
        """Forward-difference steps, turned backward at an upper bound."""
        h = 1e-6 * np.maximum(np.abs(x), 1.0)
        upper = np.array([u.bounds[1] / u.scale for u in self.items])
        return np.where(x + h > upper, -h, h)

    def jac(self, x: np.ndarray, columns=None) -> np.ndarray:
        """The forward-difference Jacobian at ``x``, of every unknown or of ``columns`` (a
        profile holds one unknown fixed)."""
        x = np.asarray(x, dtype=float)
        h = self.steps(x)
        columns = range(len(x)) if columns is None else columns
        shifted = [x + np.eye(len(x))[j] * h[j] for j in columns]
        results = self._evaluate([x] + shifted)
        return np.column_stack([(r - results[0]) / h[j] for r, j in zip(results[1:], columns)])

    def outputs_at(self, x: np.ndarray, experiments: Sequence[Experiment], offset: int = 0) -> list:
        tasks = [(offset + k, None, self.values(x)) for k in range(len(experiments))]
        return self.runner.map(tasks)


class BudgetSpent(RuntimeError):
    """The fit reached its spec's ``max_simulations``."""
