"""One operation, three steps: prepare a scenario (:func:`~furuta_cosim.cosim.master.prepare`),
compile a controller against it (:func:`compile_controller`), evaluate it on an open plant
session (:func:`evaluate`) -> :class:`~furuta_cosim.cosim.result.RunResult`.

    prepared = prepare(load_scenario("paper-step"))
    with PlantSession.open(prepared.fmu) as session:
        for name in ("lqr-paper", "bo-paper"):
            result = evaluate(prepared, session, name)
            print(name, result.metrics["u.peak_abs"], result.passed)

At each control sample k (period Tc) the master reads the fed-back signals (with measurement
noise; through the estimator when there is one), the controller computes u[k] from them and
F*rbar[k], u[k] is held over the period (zero-order hold, after the actuator limit), the
disturbance inputs take their k-th value, and the FMU advances by Tc in communication steps.
The session is reset at the start of every evaluation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from furuta_cosim.controllers import ControllerFile, fit, load_controller
from furuta_cosim.cosim.limits import EVERY, Watch, monotone
from furuta_cosim.cosim.loop import loop_for
from furuta_cosim.cosim.master import Prepared
from furuta_cosim.cosim.native import NativeLoop
from furuta_cosim.cosim.result import RunResult
from furuta_cosim.cosim.runtime import RuntimeController
from furuta_cosim.cosim.trace import Trace
from furuta_cosim.design.controller import GeneralizedController, discretize_controller
from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.metrics import compute, verdicts
from furuta_cosim.signals import COMMAND, controller_state, estimate

# samples per chunk of the loop when progress is reported (about 0.1 s of plant time each)
CHUNK = 50_000


@dataclass
class Compiled:
    """A controller checked against a prepared scenario and generated for its hot loop."""

    cfile: ControllerFile
    runtime: RuntimeController  # or a SwingUpRuntime around one

    @property
    def name(self) -> str:
        return self.cfile.name


def compile_controller(prepared: Prepared, controller, *, key: str | None = None,
                       beside: Path | None = None) -> Compiled:
    """Check ``controller`` against ``prepared`` and compile it: the one place that checks
    shapes, period, prefilter and tracked output.

    Parameters
    ----------
    prepared : Prepared
        The scenario the controller is to run in, from :func:`prepare`.
    controller : Compiled, ControllerFile, GeneralizedController, str or path
        A name of ``scenarios/controllers`` or a file; a relative file is taken beside
        ``beside`` when given. A ``Compiled`` is returned as it is.
    key : str, optional
        Where the controller was named, for messages (``controllers[1]``, ``--controller``).
    beside : path, optional
        The folder relative controller files are read from (the scenario's folder, for the
        scenario's own controllers).

    Returns
    -------
    Compiled
        The controller's checked matrices and generated step code.

    Raises
    ------
    ConfigError
        Naming the scenario, ``key``, the controller file and its key.
    """
    if isinstance(controller, Compiled):
        return controller
    where = f"{prepared.source}: {key}" if key else prepared.source
    try:
        if isinstance(controller, GeneralizedController):
            cfile = ControllerFile(controller, controller.period)
        elif isinstance(controller, ControllerFile):
            cfile = controller
        else:
            cfile = load_controller(controller, beside)
        scenario = prepared.scenario

        def model():
            from furuta_cosim.models import load_model

            if cfile.model:
                return load_model(cfile.model, cfile.path.parent if cfile.path else None)
            return load_model(scenario.plant, scenario.folder)

        has_model = bool(cfile.model or (prepared.plant and scenario.plant))
        cfile = fit(cfile, plant=f"plant {prepared.plant_name}", states=len(prepared.states),
                    period=prepared.control_period, discrete_plant=prepared.discrete_plant,
                    tracked=prepared.tracked if cfile.tracked_output else None,
                    model=model if has_model else None)
    except ConfigError as error:
        raise error.within(where) from None
    c = discretize_controller(cfile.controller, prepared.control_period)
    F = cfile.F if cfile.F is not None else 1.0
    if cfile.swingup is not None:  # the delay is the swing-up's, for both its modes
        from furuta_cosim.swingup import SwingUpRuntime

        runtime = SwingUpRuntime(RuntimeController(c, F), cfile.swingup, delay=prepared.scenario.delay)
    else:
        runtime = RuntimeController(c, F, delay=prepared.scenario.delay)
    return Compiled(cfile, runtime)


def scenario_controllers(prepared: Prepared, names: Sequence | None = None) -> list[Compiled]:
    """The scenario's own controllers (relative files beside the scenario file), or ``names``
    given on a command line (relative to the working directory)."""
    if names:
        return [compile_controller(prepared, n, key=f"controllers {n}") for n in names]
    folder = prepared.scenario.folder
    return [compile_controller(prepared, n, key=f"controllers[{k}]", beside=folder)
            for k, n in enumerate(prepared.scenario.controllers)]


def evaluate(prepared: Prepared, session, controller, *,
             progress: Callable[[int, int], None] | None = None,
             limits: dict[str, float] | None = None) -> RunResult:
    """Run ``controller`` through the prepared scenario on ``session`` (reset here): the trace,
    its metrics, the requirement verdicts, why it stopped early if it did, and the wall time.

    A plant that gives up (a diverging loop) ends the run early; the result keeps its samples
    and says why in ``failure``. A run whose running value of a metric in ``limits`` passes
    its bound stops there too (:mod:`furuta_cosim.cosim.limits`): ``stopped`` says which and
    when, and the metrics are those of the samples run (lower bounds for the watched ones).

    Parameters
    ----------
    prepared : Prepared
        The scenario, from :func:`prepare`.
    session : PlantSession
        An open session on ``prepared.fmu``; it is reset before the run.
    controller : Compiled, ControllerFile, GeneralizedController, str or path
        Anything :func:`compile_controller` takes.
    progress : callable, optional
        ``progress(k, steps)``, called every :data:`CHUNK` samples.
    limits : dict, optional
        ``{metric: bound}`` of metrics that only grow along a run (registered with ``grows``
        in furuta_cosim/metrics.py: ``error.ISE``, ``u.peak_abs``, ``<output>.max_abs``, ...):
        the run stops as soon as one is past its bound.

    Returns
    -------
    RunResult
        Trace, metrics, requirement verdicts, ``failure``, ``stopped`` and wall time.

    Raises
    ------
    ValueError
        When a metric of ``limits`` is not one that only grows.
    """
    started = time.perf_counter()
    compiled = compile_controller(prepared, controller)
    watch = None
    if limits:
        wrong = [m for m in limits if not monotone(m, prepared.outputs)]
        if wrong:
            raise ValueError(f"limits: {', '.join(wrong)} do not only grow along a run")
        dt = prepared.t[1] - prepared.t[0] if len(prepared.t) > 1 else 1.0
        watch = Watch(dict(limits), list(prepared.signals), prepared.tracked, float(dt))
    trace, stopped = _run(prepared, session, compiled, progress, watch)
    scenario = prepared.scenario
    metrics = compute(trace, scenario.reference.settles, scenario.error_window)
    checks = verdicts(metrics, scenario.requirements, compiled.name)
    return RunResult(scenario.name, compiled.name, trace, metrics, checks, trace.failure,
                     time.perf_counter() - started, prepared.time_unit, stopped)


def runs(prepared: Prepared, controllers: Sequence | None = None, *,
         progress: Callable[[str, int, int], None] | None = None) -> Iterator[RunResult]:
    """Each controller in turn on one FMU instance: a result as soon as its run ends, so a
    caller can save it before the next run starts.

    Parameters
    ----------
    prepared : Prepared
        From :func:`furuta_cosim.cosim.master.prepare`.
    controllers : sequence, optional
        Names, files or compiled controllers; default the scenario's.
    progress : callable, optional
        ``progress(controller, step, steps)`` while a run goes.

    Yields
    ------
    RunResult
        The trace, metrics and requirement verdicts of one run.
    """
    from furuta_cosim.fmu.session import PlantSession

    compiled = scenario_controllers(prepared, controllers)
    with PlantSession.open(prepared.fmu) as session:
        for c in compiled:
            report = (lambda k, n, name=c.name: progress(name, k, n)) if progress else None
            try:
                yield evaluate(prepared, session, c, progress=report)
            except FmuError as error:
                raise FmuError(f"{prepared.source}: controller {c.name}: {error}") from None


def simulate(prepared: Prepared, controllers: Sequence | None = None) -> dict[str, RunResult]:
    """Every controller (default: the scenario's): ``{controller name: RunResult}``."""
    return {result.controller: result for result in runs(prepared, controllers)}


def _first_not_finite(prepared: Prepared, table: np.ndarray, us) -> tuple[int, str] | None:
    """The first sample where a plant output (or the input computed from them) is NaN or
    infinite, and what it is in words; None when every one is finite."""
    if not len(table):
        return None
    bad = ~np.isfinite(table)
    inputs = ~np.isfinite(np.asarray(us[:len(table)], dtype=float))
    if not bad.any() and not inputs.any():
        return None
    first_row = int(np.argmax(bad.any(axis=1))) if bad.any() else len(table)
    first_input = int(np.argmax(inputs)) if inputs.any() else len(table)
    if first_row <= first_input:
        column = int(np.argmax(bad[first_row]))
        return first_row, f"the plant's output {prepared.signals[column]} is {table[first_row, column]}"
    return first_input, f"the input {prepared.control_input} is {float(us[first_input])}"


def _converted(prepared: Prepared, session):
    """The session's step and a reader of its outputs, both in the view's units: the plain
    step when no variable is converted (the common case costs nothing)."""
    conversions = prepared.conversions
    if not conversions:
        return session.step, list
    fed = [prepared.control_input] + prepared.disturbance_inputs
    into = [conversions.get(name, (1.0, 0.0)) for name in fed]
    out = [conversions.get(name, (1.0, 0.0)) for name in prepared.outputs]

    def read(values):
        return [a * v + b for (a, b), v in zip(out, values)]

    def step(inputs, h):
        return read(session.step([(v - b) / a for (a, b), v in zip(into, inputs)], h))

    return step, read


def _run(prepared: Prepared, session, compiled: Compiled, progress, watch=None):
    controller = compiled.runtime
    scenario = prepared.scenario
    outputs = prepared.outputs
    session.reset(prepared.start)
    session.set_io([prepared.control_input] + prepared.disturbance_inputs, outputs)
    controller.reset()
    estimator = prepared.estimator()
    if estimator:
        estimator.reset()
    sources = prepared.measured if estimator else prepared.states
    pick = [prepared.signals.index(n) for n in sources]
    limit = prepared.limit
    loop = loop_for(len(sources), None if pick == list(range(len(outputs))) else tuple(pick),
                    tuple(sources.index(n) for n in prepared.noisy), bool(estimator),
                    controller.n_xc > 0, bool(limit), len(prepared.disturbances), prepared.substeps)
    rows, us, commands, xcs, estimates = [], [], [], [], []
    failure = None
    step, read = _converted(prepared, session)
    values = read(session.get(outputs))
    steps = prepared.steps
    chunk = CHUNK if progress else max(steps, 1)
    if watch is not None:
        chunk = min(chunk, max(1, int(round(EVERY / prepared.control_period))))
    stopped = None
    noisy = [sources.index(n) for n in prepared.noisy]
    native = NativeLoop.on(prepared, session, controller, pick, noisy, values)
    if native is not None:
        rows, us, commands, xcs = native.rows, native.us, native.commands, native.xcs
    else:
        arguments = (step, controller.control, controller.state,
                     estimator.correct if estimator else None,
                     estimator.predict if estimator else None, prepared.rbar.tolist(),
                     prepared.measurement_noise.tolist() if prepared.noisy else None,
                     prepared.disturbance.tolist() if prepared.disturbances else None,
                     prepared.communication_step)
    done = 0  # samples run (the C loop's records are allocated for all of them)
    try:
        for first in range(0, steps, chunk):
            last = min(first + chunk, steps)
            if native is not None:
                failed = native.run(first, last)
                done = last if not failed else native.failed_at + 1
                if failed:
                    native.raise_failure(failed, prepared.disturbance)
            else:
                values = loop(*arguments, first, last, values, limit or 0.0, rows.append,
                              us.append, commands.append, xcs.append, estimates.append)
                done = len(us)
            if progress:
                progress(last, steps)
            if watch is not None:
                past = watch.update(prepared.t[first:last], prepared.rbar[first:last],
                                    rows[first:last], us[first:last])
                if past:
                    stopped = {"t": float(prepared.t[last - 1]), "metric": past,
                               "value": watch.values[past], "bound": watch.bounds[past]}
                    break
    except FmuError as error:
        # the plant gave up (a diverging loop): keep the samples up to that point
        done = len(us) if native is None else done
        peak = max(map(abs, us[:done])) if done else 0.0
        failure = (f"stopped at t = {prepared.t[max(done - 1, 0)]:.6g} with the loop diverging "
                   f"(peak |u| {peak:.3g}): {error}")
    n = done
    # the Python loop appended a failed step's row; the C loop's arrays hold every sample
    table = np.array(rows[:n], dtype=float).reshape(n, len(prepared.signals))
    cut = _first_not_finite(prepared, table, us)
    if cut is not None:
        # a plant output that is not a number ends the run there, whatever its FMU says: no
        # metric or requirement may be computed from it
        n, what = cut
        table = table[:n]
        failure = f"{what} at t = {prepared.t[n]:.6g}: the run stops there"
    signals = {name: column for name, column in zip(prepared.signals, table.T)} if n else \
        {name: np.zeros(0) for name in prepared.signals}
    if limit:
        signals[COMMAND] = np.array(commands[:n])
    for j, column in enumerate(np.array(xcs[:n]).T if n and controller.n_xc else []):
        signals[controller_state(j + 1)] = column
    for j, column in enumerate(np.array(estimates[:n]).T if estimates else []):
        signals[estimate(prepared.states[j])] = column
    for j, name in enumerate(prepared.disturbances):
        signals[name] = prepared.disturbance[:n, j]
    trace = Trace(compiled.name, prepared.t[:n], prepared.rbar[:n], np.array(us[:n]), signals,
                  prepared.tracked, prepared.control_input, failure, dict(prepared.units))
    return trace, (None if failure else stopped)
