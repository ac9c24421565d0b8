"""The co-simulation master: samples controllers on the plant FMU.

At each control sample k (period Tc): the fed-back signals are read (with measurement noise),
the controller computes u[k] from them and F*rbar[k] and is held over the period (zero-order
hold), the disturbance inputs take their k-th value (process noise and pulses), and the FMU
advances by Tc in communication steps. One FMU instance serves every run; it is reset in
between. Noise comes from a seeded numpy Generator, drawn once per scenario, so every
controller meets the same noise.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import control
import numpy as np

from furuta_cosim.controllers import ControllerFile, check_fits, load_controller
from furuta_cosim.cosim.runtime import RuntimeController, RuntimeEstimator
from furuta_cosim.cosim.trace import Trace
from furuta_cosim.design.controller import discretize_controller
from furuta_cosim.design.lqr import PAPER_PERIOD
from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.linearize import linearize
from furuta_cosim.fmu.plants import PlantSet, load_plant
from furuta_cosim.models import load_model
from furuta_cosim.fmu.session import PlantSession, model_description, state_names
from furuta_cosim.scenario import Scenario


@dataclass
class Prepared:
    """A scenario resolved against its plant FMU: names checked, signals drawn."""

    scenario: Scenario
    plant: PlantSet
    fmu: Path
    start: dict
    control_input: str
    process_inputs: list[str]
    outputs: list[str]
    feedback: list[str]
    tracked: str
    control_period: float
    communication_step: float
    steps: int
    t: np.ndarray
    rbar: np.ndarray
    disturbance: np.ndarray          # steps x len(process_inputs)
    measurement_noise: np.ndarray    # steps x len(noisy signals)
    noisy: list[str]
    controllers: list[tuple[ControllerFile, RuntimeController]] = field(default_factory=list)
    estimator: RuntimeEstimator | None = None
    measured: list[str] = field(default_factory=list)


def _fail(scenario: Scenario, key: str, message: str) -> ConfigError:
    return ConfigError([f"{scenario.source}: {key}: {message}"])


def prepare(scenario: Scenario, controllers: Sequence[str | Path] | None = None) -> Prepared:
    """Resolve plant, names, timing, signals and controllers; ConfigError names file and key."""
    try:
        plant = load_plant(scenario.plant)
    except ConfigError as error:
        raise error.within(f"{scenario.source}: plant.model") from None
    fmu = build_fmu(plant)
    description = model_description(fmu)
    variables = {v.name: v for v in description.modelVariables}
    states = state_names(description)
    inputs = [n for n, v in variables.items() if v.causality == "input" and v.type == "Real"]
    outputs = [n for n, v in variables.items() if v.causality == "output"]
    parameters = {n for n, v in variables.items() if v.causality == "parameter"}
    problems = []

    def fail(key, message):
        problems.append(f"{scenario.source}: {key}: {message}")

    start = dict(plant.parameters)
    for name, value in scenario.overrides.items():
        if name not in parameters:
            fail(f"plant.overrides.{name}", f"not a parameter of {plant.name} "
                 f"(parameters: {', '.join(sorted(parameters))})")
        start[name] = value
    for name, value in scenario.initial.items():
        if name not in states:
            fail(f"plant.initial.{name}", f"not a state (states: {', '.join(states)})")
        start[f"{name}_start"] = value
    control_input = scenario.control_input or inputs[0]
    if control_input not in inputs:
        fail("plant.control_input", f"not an input (inputs: {', '.join(inputs)})")
    tracked = scenario.reference.output or ("theta0" if "theta0" in outputs else outputs[0])
    if tracked not in outputs:
        fail("reference.output", f"not an output (outputs: {', '.join(outputs)})")
    process = list(scenario.noise.process) if scenario.noise else []
    for pulse in scenario.disturbances:
        if pulse.input not in process:
            process.append(pulse.input)
    for name in process:
        if name not in inputs or name == control_input:
            key = (f"noise.process.{name}" if scenario.noise and name in scenario.noise.process
                   else f"disturbances[{[p.input for p in scenario.disturbances].index(name)}].input")
            fail(key, f"not a disturbance input (inputs besides {control_input}: "
                 f"{', '.join(i for i in inputs if i != control_input)})")

    period, step, steps = _timing(scenario, plant, fail)
    measured = list(scenario.estimator.measured) if scenario.estimator else []
    for name in measured:
        if name not in outputs:
            fail("estimator.measured", f"{name!r} is not an output (outputs: {', '.join(outputs)})")
    signals = set(outputs) | set(process) | {"u", "error", "u_command"} | {f"{n}_hat" for n in states}
    for k, requirement in enumerate(scenario.requirements):
        signal = requirement.metric.split(".", 1)[0]
        if signal not in signals and not re.fullmatch(r"xc\d+", signal):
            fail(f"requirements[{k}].metric", f"no signal {signal!r} is recorded (signals: u, error, "
                 f"{', '.join(outputs)})")
    noisy = list(scenario.noise.measurement) if scenario.noise else []
    allowed = measured or states
    for name in noisy:
        if name not in allowed:
            fail(f"noise.measurement.{name}", f"not a fed-back signal (fed back: {', '.join(allowed)})")
    if problems:
        raise ConfigError(problems)

    t = np.arange(steps) * period
    rbar = scenario.reference(t)
    disturbance = np.zeros((steps, len(process)))
    measurement = np.zeros((steps, len(noisy)))
    if scenario.noise:
        rng = np.random.default_rng(scenario.noise.seed)
        sigma = np.array([scenario.noise.process.get(n, 0.0) for n in process])
        disturbance += rng.standard_normal((steps, len(process))) * sigma
        measurement += rng.standard_normal((steps, len(noisy))) * np.array(
            [scenario.noise.measurement[n] for n in noisy])
    for pulse in scenario.disturbances:
        active = (t >= pulse.start - 1e-12) & (t < pulse.start + pulse.duration - 1e-12)
        disturbance[active, process.index(pulse.input)] += pulse.value

    prepared = Prepared(scenario, plant, fmu, start, control_input, process, outputs, states,
                        tracked, period, step, steps, t, rbar, disturbance, measurement, noisy,
                        measured=measured)
    names = list(controllers) if controllers else list(scenario.controllers)
    for k, name in enumerate(names):
        key = f"controllers[{k}]" if not controllers else f"--controller {name}"
        prepared.controllers.append(_runtime(scenario, key, name, states, tracked, period))
    if scenario.estimator:
        prepared.estimator = _kalman(prepared)
    return prepared


def _timing(scenario: Scenario, plant: PlantSet, fail) -> tuple[float, float, int]:
    sample = plant.linear.period if plant.linear and plant.linear.discrete else None
    period = scenario.control_period or sample or PAPER_PERIOD
    step = scenario.communication_step or period
    ratio = period / step
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        fail("timing.control_period", f"must be a whole multiple of timing.communication_step "
             f"({step:g}), got {period:g}")
    if sample:
        k = step / sample
        if abs(k - round(k)) > 1e-9 * k or round(k) < 1:
            fail("timing.communication_step", f"must be a whole number of the plant's sample "
                 f"periods ({sample:g}), got {step:g}")
    steps = int(math.floor(scenario.duration / period + 1e-9))
    return period, step, max(steps, 0)


def _runtime(scenario, key, name, states, tracked, period):
    try:
        cfile = load_controller(name)
    except ConfigError as error:
        raise error.within(f"{scenario.source}: {key}") from None
    c = cfile.controller
    what = "K" if c.n_xc == 0 else "Dc"
    if c.Dc.shape != (1, len(states)):
        raise _fail(scenario, key, f"{cfile.source}: {what}: expected 1 row of {len(states)} values "
                    f"(the plant has {len(states)} states and one control input), got "
                    f"{c.Dc.shape[0]}x{c.Dc.shape[1]}")
    if c.discrete and abs(c.period - period) > 1e-12 * period:
        raise _fail(scenario, key, f"{cfile.source}: period: the controller runs at {c.period:g} s "
                    f"but the scenario's control period is {period:g} s")
    F = 1.0
    if cfile.tracked_output:
        if cfile.tracked_output != tracked:
            raise _fail(scenario, key, f"{cfile.source}: prefilter.output: {cfile.tracked_output} "
                        f"differs from the scenario's reference.output {tracked}")
        if cfile.F is None:
            try:
                cfile = check_fits(cfile, load_model(cfile.model or scenario.plant))
            except ConfigError as error:
                raise error.within(f"{scenario.source}: {key}") from None
        F = cfile.F
    return cfile, RuntimeController(discretize_controller(c, period), F)


def _kalman(prepared: Prepared) -> RuntimeEstimator:
    """Steady-state Kalman filter on the plant's linearization, sampled at the control period."""
    scenario = prepared.scenario
    inputs = [prepared.control_input] + prepared.process_inputs
    lin = linearize(prepared.fmu, parameters=prepared.start, inputs={n: 0.0 for n in inputs},
                    outputs=prepared.measured)
    system = control.ss(lin.A, lin.B, lin.C, lin.D)
    if not lin.period:
        system = control.c2d(system, prepared.control_period, method="zoh")
    elif abs(lin.period - prepared.control_period) > 1e-12:
        raise _fail(scenario, "estimator", "the estimator needs the control period to equal the "
                    "plant's sample period")
    Ad, Bd, Cm = np.asarray(system.A), np.asarray(system.B), np.asarray(system.C)
    process_sigma = np.array([scenario.noise.process.get(n, 0.0) if scenario.noise else 0.0
                              for n in prepared.process_inputs])
    G = Bd[:, 1:]
    # a small floor keeps the Riccati equation well posed when a channel is noise-free
    QN = G @ np.diag(process_sigma ** 2) @ G.T + 1e-10 * np.eye(len(Ad))
    measurement_sigma = np.array([scenario.noise.measurement.get(n, 0.0) if scenario.noise else 0.0
                                  for n in prepared.measured])
    RN = np.diag(np.maximum(measurement_sigma ** 2, 1e-12))
    _, P, _ = control.dlqe(Ad, np.eye(len(Ad)), Cm, QN, RN)
    M = P @ Cm.T @ np.linalg.inv(Cm @ P @ Cm.T + RN)
    return RuntimeEstimator(Ad, Bd[:, :1], Cm, M)


def _loop_source(n_sources: int, pick: tuple | None, noisy: tuple, estimator: bool,
                 record_state: bool, limited: bool, n_disturbances: int, substeps: int) -> str:
    """The sample loop for one configuration, as Python source: branches and index lookups
    are decided here, once, instead of at every one of the thousands of samples."""
    signal = [f"values[{i}]" for i in (pick if pick is not None else range(n_sources))]
    for position, j in enumerate(noisy):
        signal[j] += f" + m[{position}]"
    body = []
    if noisy:
        body.append("m = measurement[k]")
    body.append(f"s = [{', '.join(signal)}]" if pick is not None or noisy else "s = values")
    if estimator:
        body += ["s = correct(s)", "estimates(s)"]
    if record_state:
        body.append("states(state())")
    body.append("c = control(s, rbar[k])")
    if limited:
        body += ["u = c if -limit <= c <= limit else (limit if c > 0 else -limit)", "commands(c)"]
    else:
        body.append("u = c")
    if estimator:
        body.append("predict(u)")
    body += ["rows(values)", "inputs(u)"]
    if n_disturbances:
        body.append("d = disturbance[k]")
    applied = "[u" + "".join(f", d[{j}]" for j in range(n_disturbances)) + "]"
    if substeps == 1:
        body.append(f"values = step({applied}, h)")
    else:
        body += [f"applied = {applied}", f"for _ in range({substeps}):", "    values = step(applied, h)"]
    lines = ["def loop(step, control, state, correct, predict, rbar, measurement, disturbance,",
             "         h, steps, values, limit, rows, inputs, commands, states, estimates):",
             "    for k in range(steps):"]
    lines += [f"        {line}" for line in body]
    return "\n".join(lines) + "\n"


_LOOPS: dict = {}


def _loop(*configuration):
    if configuration not in _LOOPS:
        namespace: dict = {}
        exec(compile(_loop_source(*configuration), "<furuta-cosim loop>", "exec"), namespace)  # noqa: S102
        _LOOPS[configuration] = namespace["loop"]
    return _LOOPS[configuration]


def run(prepared: Prepared, plant: PlantSession, index: int) -> Trace:
    """One controller through the whole scenario on an open session (reset here)."""
    cfile, controller = prepared.controllers[index]
    scenario = prepared.scenario
    plant.reset(prepared.start)
    plant.set_io([prepared.control_input] + prepared.process_inputs, prepared.outputs)
    controller.reset()
    outputs = prepared.outputs
    estimator = prepared.estimator
    if estimator:
        estimator.reset()
    sources = prepared.measured if estimator else prepared.feedback
    pick = [outputs.index(n) for n in sources]
    if pick == list(range(len(outputs))):
        pick = None
    limit = scenario.actuator_limit
    substeps = int(round(prepared.control_period / prepared.communication_step))
    loop = _loop(len(sources), pick and tuple(pick), tuple(sources.index(n) for n in prepared.noisy), bool(estimator),
                 controller.n_xc > 0, bool(limit), len(prepared.process_inputs), substeps)
    rows, us, commands, xcs, estimates = [], [], [], [], []
    failure = None
    try:
        loop(plant.step, controller.control, controller.state,
             estimator.correct if estimator else None, estimator.predict if estimator else None,
             prepared.rbar.tolist(),
             prepared.measurement_noise.tolist() if prepared.noisy else None,
             prepared.disturbance.tolist() if prepared.process_inputs else None,
             prepared.communication_step, prepared.steps, plant.get(outputs), limit or 0.0,
             rows.append, us.append, commands.append, xcs.append, estimates.append)
    except FmuError as error:
        # the plant gave up (a diverging loop): keep the samples up to that point
        peak = max(map(abs, us)) if us else 0.0
        failure = (f"stopped at t = {prepared.t[len(us) - 1]:.6g} with the loop diverging "
                   f"(peak |u| {peak:.3g}): {error}")
    n = len(us)
    signals = {name: column for name, column in zip(outputs, np.array(rows).T)}
    if limit:
        signals["u_command"] = np.array(commands)
    for j, column in enumerate(np.array(xcs).T if xcs else []):
        signals[f"xc{j + 1}"] = column
    for j, column in enumerate(np.array(estimates).T if estimates else []):
        signals[f"{prepared.feedback[j]}_hat"] = column
    for j, name in enumerate(prepared.process_inputs):
        signals[name] = prepared.disturbance[:n, j]
    return Trace(cfile.name, prepared.t[:n], prepared.rbar[:n], np.array(us), signals,
                 prepared.tracked, prepared.control_input, failure)


def runs(prepared: Prepared) -> Iterator[Trace]:
    """Each controller of the prepared scenario in turn, on one FMU instance: a trace as soon
    as its run ends, so a caller can save it before the next run starts."""
    with PlantSession.open(prepared.fmu) as plant:
        for index, (cfile, _) in enumerate(prepared.controllers):
            try:
                yield run(prepared, plant, index)
            except FmuError as error:
                raise FmuError(f"{prepared.scenario.source}: controller {cfile.name}: {error}") from None


def simulate(prepared: Prepared) -> dict[str, Trace]:
    """Every controller of the prepared scenario: ``{controller name: Trace}``."""
    return {trace.controller: trace for trace in runs(prepared)}
