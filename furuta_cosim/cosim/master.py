"""Preparing a scenario for co-simulation: the plant FMU, its variables seen as the
controller sees them, timing, reference and noise.

A prepared scenario holds everything a run needs except the controller, so that one
preparation serves any number of controllers (:func:`furuta_cosim.cosim.evaluation.evaluate`),
and it pickles, so that worker processes receive it once.

The controller's view: the fed-back states in the controller's order (the order the plant's
declaration gives them), the control input, and named disturbance inputs.
For an FMU built by this project the view follows its conventions (states are the outputs
with a ``<name>_start`` parameter, which also sets the initial state); any other FMI 2.0
co-simulation FMU is mapped onto the view by the scenario's ``plant.mapping``. Every name a
scenario uses (initial states, reference output, noise, disturbances, estimator,
requirements, plot) is a view name.
"""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from furuta_cosim.defaults import PAPER_PERIOD
from furuta_cosim.errors import ConfigError, DesignError, FmuError, PlantUnfit
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.plants import PlantSet, load_plant, voltage_limit
from furuta_cosim.fmu.session import SESSIONS, model_description, refuse_clocks
from furuta_cosim.fmu.variables import declared_conversion, dimension_problem, is_real, settable_start, unit_problems
from furuta_cosim.metrics import catalogue, problem, step_segments
from furuta_cosim.scenario import Scenario
from furuta_cosim.signals import COMMAND, estimate, is_controller_state, start_parameter

# A run keeps its trace in memory: about 300 bytes per sample with the pendulum's signals.
MAX_STEPS = 10_000_000
BYTES_PER_SAMPLE = 300
MAX_SUBSTEPS_PER_SAMPLE = 10_000


@dataclass
class Prepared:
    """A scenario resolved against its plant FMU: names checked, timing fixed, signals drawn.

    FMU-side names (``outputs``, ``control_input``, ``disturbance_inputs``, keys of
    ``start``) are what the session reads and writes; view names (``signals``, ``states``,
    ``disturbances``, ``tracked``, ``noisy``, ``measured``) are what the scenario, the
    controller, the trace and the metrics use.
    """

    scenario: Scenario
    plant: PlantSet | None        # None for an FMU that no plant file describes
    plant_name: str
    fmu: Path
    start: dict                   # FMU variable -> value, applied at every reset
    outputs: list[str]            # FMU outputs read at each sample
    signals: list[str]            # their names in the view, in the same order
    states: list[str]             # the fed-back states (view), in the controller's order
    control_input: str            # FMU input
    disturbance_inputs: list[str]  # FMU inputs the scenario drives besides the control input
    disturbances: list[str]       # their view names
    tracked: str
    control_period: float
    communication_step: float
    steps: int
    time_unit: str
    t: np.ndarray
    rbar: np.ndarray
    disturbance: np.ndarray       # steps x len(disturbances)
    measurement_noise: np.ndarray  # steps x len(noisy)
    noisy: list[str]
    measured: list[str] = field(default_factory=list)
    kalman: tuple | None = None   # (Ad, Bd, C, M) of the steady-state filter
    metrics: dict = field(default_factory=dict)   # the metric catalogue of this run
    units: dict = field(default_factory=dict)     # view name -> unit the FMU declares
    # FMU variable -> (scale, offset): view value = scale * FMU value + offset (plant.mapping,
    # or a declared unit such as deg); an input is set to (view value - offset) / scale
    conversions: dict = field(default_factory=dict)
    # the voltage limit every command is clipped to before the plant (None: none), the
    # smallest of the scenario's actuator.limit, the plant file's limits.voltage (the
    # amplifier's) and the model's V_max parameter: ``limit_of``
    limit: float | None = None
    # the view's states whose 0 is a pendulum upright (the declaration's ``upright``)
    upright: tuple = ()
    key: str = field(default_factory=lambda: uuid.uuid4().hex)
    _estimator: object = field(default=None, repr=False, compare=False)

    @property
    def source(self) -> str:
        return self.scenario.source

    @property
    def discrete_plant(self) -> bool:
        return bool(self.plant and self.plant.linear and self.plant.linear.discrete)

    @property
    def substeps(self) -> int:
        return int(round(self.control_period / self.communication_step))

    def estimator(self):
        """The compiled Kalman filter (None without one); compiled once per process."""
        if self.kalman is None:
            return None
        if self._estimator is None:
            from furuta_cosim.cosim.runtime import RuntimeEstimator

            self._estimator = RuntimeEstimator(*self.kalman)
        return self._estimator

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_estimator"] = None  # generated code: compiled again where it is unpickled
        return state


def prepare(scenario: Scenario, *, fmu: str | Path | None = None,
            overrides: dict | None = None) -> Prepared:
    """Resolve the plant (built, or the FMU given), the view, timing and signals; no controllers.

    Parameters
    ----------
    scenario : Scenario
    fmu : path, optional
        Run on this FMU instead of the scenario's plant (``simulate --fmu``). The scenario's
        parameter set applies only when the FMU declares all of its parameters (this
        project's FMU, rebuilt elsewhere); ``plant.overrides`` and ``overrides`` always do.
    overrides : mapping, optional
        FMU parameters set on top of the scenario's ``plant.overrides`` (plant variants).

    Returns
    -------
    Prepared
        What every run of the scenario shares: the FMU, its view, timing and signals.

    Raises
    ------
    ConfigError
        Naming the scenario file and key.
    FmuError
        For an unusable FMU.
    """
    problems: list[str] = []

    def fail(key: str, message: str) -> None:
        mapping = scenario.mapping
        if mapping and mapping.source and (key.startswith("plant.mapping.") or (
                key == "plant.control_input" and mapping.control_input)):
            # the mapping came from a file of its own: name that file and its key
            problems.append(f"{mapping.source}: {key.removeprefix('plant.mapping.').removeprefix('plant.')}: "
                            f"{message}")
        else:
            problems.append(f"{scenario.source}: {key}: {message}")

    plant, fmu_path = _plant(scenario, fmu)
    description = model_description(fmu_path)
    if description.fmiVersion not in SESSIONS or description.coSimulation is None:
        interfaces = [name for name, part in (("model exchange", description.modelExchange),
                                              ("scheduled execution", description.scheduledExecution))
                      if part is not None]
        raise FmuError(f"{fmu_path}: not an FMI {' or '.join(SESSIONS)} co-simulation FMU (FMI {description.fmiVersion}, "
                       f"{' and '.join(interfaces) or 'no interface'}{' only' if interfaces else ''})")
    refuse_clocks(fmu_path, description)
    variables = {v.name: v for v in description.modelVariables}
    identifier = description.coSimulation.modelIdentifier
    parameters = {n for n, v in variables.items() if v.causality == "parameter"}
    start: dict = {}
    if plant is not None and plant.linear is None and set(plant.parameters) <= parameters:
        start.update(plant.parameters)
    for name, value in {**scenario.overrides, **(overrides or {})}.items():
        if name not in parameters:
            fail(f"plant.overrides.{name}", f"not a parameter of {plant.name if plant else identifier} "
                 f"(parameters: {', '.join(sorted(parameters))})")
        elif variables[name].type in ("Integer", "Int32"):
            low, high = (float(b) if b is not None else None for b in (variables[name].min, variables[name].max))
            if value != int(value) or (low is not None and value < low) or (high is not None and value > high):
                fail(f"plant.overrides.{name}", f"expected a whole number in [{low:g}, {high:g}], got {value:g}"
                     if low is not None and high is not None else f"expected a whole number, got {value:g}")
        start[name] = value

    problems += [f"{fmu_path}: {problem}" for problem in unit_problems(description)]
    view = _view(scenario, variables, identifier, fail)
    outputs, signals, states, state_outputs, control_input, inputs, disturbance_names = view
    problems += _dimensions(description, variables, plant, fmu_path, scenario.mapping,
                            {**dict(zip(signals, outputs)), **inputs}, control_input)
    if problems:  # every other name is a view name: nothing more can be checked without it
        raise ConfigError(problems)
    conversions = _conversions(description, scenario.mapping,
                               outputs + list(inputs.values()) + [control_input])
    for name, value in scenario.initial.items():
        if name not in states:
            fail(f"plant.initial.{name}", f"not a state (states: {', '.join(states)})")
            continue
        output = state_outputs[states.index(name)]
        target = scenario.mapping.initial.get(name) if scenario.mapping else None
        key = f"plant.mapping.initial.{name}" if target else f"plant.initial.{name}"
        if target is None and start_parameter(output) not in parameters and settable_start(variables[output]):
            target = output  # the state takes its start value on itself (FMI's initial="exact")
        target = target or start_parameter(output)
        if target not in parameters and target != output:
            fail(key, f"{identifier} has no parameter {target!r} to set the start of {name}"
                 + ("" if key.startswith("plant.mapping") else
                    f" and its output {output!r} takes no start value; name the parameter that "
                    "does under plant.mapping.initial"))
            continue
        given = {**scenario.overrides, **(overrides or {})}
        if target in given:  # one of the two would be dropped without a word
            fail(f"plant.overrides.{target}", f"sets the start of {name}, which plant.initial.{name} "
                 "sets too: give it in one place")
            continue
        # a start parameter in units of its own, else in those of the state it starts
        scale, offset = declared_conversion(description, variables[target]) or conversions.get(output, (1.0, 0.0))
        start[target] = (value - offset) / scale

    tracked = scenario.reference.output or _default_tracked(plant, fmu_path, signals) or (states or signals)[0]
    if tracked not in signals:
        fail("reference.output", f"not an output (outputs: {', '.join(signals)})")
    process = list(scenario.noise.process) if scenario.noise else []
    for pulse in scenario.disturbances:
        if pulse.input not in process:
            process.append(pulse.input)
    for name in process:
        if name not in disturbance_names:
            key = (f"noise.process.{name}" if scenario.noise and name in scenario.noise.process
                   else f"disturbances[{[p.input for p in scenario.disturbances].index(name)}].input")
            fail(key, f"not a disturbance input (inputs besides {control_input}: "
                      f"{', '.join(disturbance_names) or 'none'})")
    process_inputs = [inputs[n] for n in process if n in inputs]

    period, step, steps, unit = _timing(scenario, plant, fail)
    measured = list(scenario.estimator.measured) if scenario.estimator else []
    for name in measured:
        if name not in signals:
            fail("estimator.measured", f"{name!r} is not an output (outputs: {', '.join(signals)})")
    noisy = list(scenario.noise.measurement) if scenario.noise else []
    allowed = measured or states
    for name in noisy:
        if name not in allowed:
            fail(f"noise.measurement.{name}", f"not a fed-back signal (fed back: {', '.join(allowed)})")

    limit = limit_of(scenario, plant, start)
    others = list(process) + ([COMMAND] if limit else []) + \
        ([estimate(n) for n in states] if scenario.estimator else [])
    t = np.arange(steps) * period
    rbar = scenario.reference(t)
    # step metrics need a step to measure: a reference that changes, or one away from the start
    stepped = scenario.reference.settles and len(rbar) > 2 and (
        bool(np.any(np.diff(rbar) != 0)) or abs(rbar[0] - scenario.initial.get(tracked, 0.0)) > 1e-12)
    declared = _units(description, outputs, signals, control_input, conversions)
    hanging = [n for n, v in scenario.initial.items() if declared.get(n) == "rad"
               and abs(math.remainder(v, 2 * math.pi)) > math.pi / 2]
    known = catalogue(tracked, signals, others, stepped, len(step_segments(rbar)) if stepped else 0,
                      hanging)
    for k, requirement in enumerate(scenario.requirements):
        wrong = problem(requirement.metric, known)
        if wrong:
            fail(f"requirements[{k}].metric", wrong)
    for name in scenario.plot:
        if name not in known and name != "u" and not is_controller_state(name):
            fail("plot", f"no signal {name!r} is recorded (signals: {', '.join(k for k in known if k != 'error')})")
    if scenario.error_window and steps:
        begin, end = scenario.error_window
        first = max(0, math.ceil(begin / period - 1e-9))
        if first >= steps or first * period >= end - 1e-12:
            fail("metrics.error_window", f"[{begin:g}, {end:g}] holds no sample of the run "
                 f"(samples every {period:g} {unit} from 0 to {(steps - 1) * period:g})")
    if problems:
        raise ConfigError(problems)

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

    prepared = Prepared(scenario, plant, plant.name if plant else fmu_path.name, fmu_path, start,
                        outputs, signals, states, control_input, process_inputs, process,
                        tracked, period, step, steps, unit, t, rbar, disturbance, measurement,
                        noisy, measured=measured, metrics=known,
                        units=declared,
                        conversions=conversions, limit=limit, upright=_upright(plant, signals))
    if scenario.estimator:
        prepared.kalman = _kalman(prepared, state_outputs)
    return prepared


def limit_of(scenario: Scenario, plant: PlantSet | None, start: dict) -> float | None:
    """The one voltage limit of a run: the smallest of those stated (None if none is).

    The amplifier's limit is a fact of the rig, stated once in its plant file as
    ``limits.voltage`` (the supervisor of ``rig run`` holds the rig to the same number); a
    scenario's ``actuator.limit`` is a design limit that may only tighten it; the model's
    ``V_max`` parameter (0 = none) is how the plant FMU carries a limit outside this tool. Every
    simulation clips the command to this limit before the plant, so the trace's ``u`` is the
    voltage the motor got and ``u_command`` what the controller asked for.
    """
    stated = [scenario.actuator_limit, voltage_limit(plant, start) if plant else None]
    stated = [v for v in stated if v is not None]
    return min(stated) if stated else None


def on_plant(scenario: Scenario, plant: str | Path) -> Scenario:
    """The scenario with its plant replaced by ``plant`` (a plant name or file), keeping its
    own ``plant.overrides``; NotApplicable when the scenario runs another model or an FMU."""
    from dataclasses import replace

    from furuta_cosim.errors import NotApplicable

    given = load_plant(plant)
    if scenario.fmu is not None:
        raise NotApplicable([f"{scenario.source}: runs the FMU {scenario.fmu.name}, not a plant file"])
    own = _own_plant(scenario)
    if own.model != given.model or own.linear is not None:
        # a linear plant is its own model: its states and inputs are its own
        raise NotApplicable([f"{scenario.source}: runs the {own.name} plant (model {own.model}); "
                             f"{given.name} is a {given.model} plant"])
    return replace(scenario, plant=str(given.path.resolve()))


def lacks(scenario: Scenario, names) -> list[str]:
    """Of ``names`` (plant parameters), those the scenario's own plant does not have."""
    from furuta_cosim.fmu.exporter import declaration

    if scenario.fmu is not None:
        return []
    model = declaration(_own_plant(scenario))
    known = {v.name for v in model.reals if v.causality == "parameter"} | {v.name for v in model.integers}
    return [name for name in names if name not in known]


def _own_plant(scenario: Scenario) -> PlantSet:
    try:
        return load_plant(scenario.plant or "furuta", beside=scenario.folder)
    except ConfigError as error:
        raise error.within(f"{scenario.source}: plant.model") from None


def _plant(scenario: Scenario, fmu: str | Path | None) -> tuple[PlantSet | None, Path]:
    """The plant set (when the scenario names one) and the FMU to run."""
    plant = None
    if scenario.plant:
        try:
            plant = load_plant(scenario.plant, beside=scenario.folder)
        except ConfigError as error:
            raise error.within(f"{scenario.source}: plant.model") from None
    given = fmu if fmu is not None else scenario.fmu
    if given is None:
        return plant, build_fmu(plant)
    from furuta_cosim.inputs import regular

    path = Path(given)
    where = f"fmu " if fmu is not None else f"{scenario.source}: plant.fmu: "
    if not path.exists() and not path.is_symlink():
        raise ConfigError([f"{where}{given}: no such FMU file"])
    return plant, regular(path, where)


def _default_tracked(plant: PlantSet | None, fmu_path, signals: list[str]) -> str | None:
    """The output a reference tracks when the scenario names none: the first output the
    plant's declaration says a sensor measures (its ``measured``), for the plant's own FMU."""
    if plant is None or plant.linear is not None or Path(fmu_path) != Path(build_fmu(plant)):
        return None
    from furuta_cosim.fmu.exporter import declaration

    measured = [name for name in declaration(plant).measured if name in signals]
    return measured[0] if measured else None


def _upright(plant: PlantSet | None, signals: list[str]) -> tuple:
    """The view's pendulum angles (0 upright): those the declaration of the scenario's plant
    (the default plant's when it names none) says are, among the signals."""
    from furuta_cosim.fmu.exporter import declaration

    base = plant if plant is not None else load_plant()
    if base.linear is not None:
        return ()
    return tuple(name for name in declaration(base).upright if name in signals)


def _view(scenario: Scenario, variables: dict, identifier: str, fail):
    """The FMU's outputs and inputs seen as the controller sees them (see the module doc)."""
    mapping = scenario.mapping
    reals = {n for n, v in variables.items() if is_real(v)}
    kind = "Float64" if any(v.type == "Float64" for v in variables.values()) else "Real"
    outputs = [n for n, v in variables.items() if v.causality == "output" and n in reals]
    inputs = [n for n, v in variables.items() if v.causality == "input" and n in reals]
    for name in mapping.ignore if mapping else ():
        if name not in outputs:
            fail("plant.mapping.ignore", f"{identifier} has no {kind} output {name!r} (outputs: {', '.join(outputs)})")
    outputs = [n for n in outputs if not (mapping and n in mapping.ignore)]
    if mapping and mapping.states:
        states = list(mapping.states)
        state_outputs = []
        for name, target in mapping.states.items():
            if target not in outputs:
                fail(f"plant.mapping.states.{name}", f"{identifier} has no {kind} output {target!r} "
                     f"(outputs: {', '.join(outputs)})")
            state_outputs.append(target)
    else:
        state_outputs = states = state_names_of(variables)
        if not states:
            fail("plant.mapping.states", f"{identifier} does not mark its states (outputs with a "
                 "<name>_start parameter): map its outputs to the fed-back states")
    rename = dict(zip(state_outputs, states))
    for name, target in (mapping.outputs if mapping else {}).items():
        if target not in outputs:
            fail(f"plant.mapping.outputs.{name}", f"{identifier} has no {kind} output {target!r} "
                 f"(outputs: {', '.join(outputs)})")
        elif target in rename:
            fail(f"plant.mapping.outputs.{name}", f"{target} is mapped to the state {rename[target]} already")
        else:
            rename[target] = name
    signals = [rename.get(n, n) for n in outputs]
    for name in dict.fromkeys(signals):
        if signals.count(name) > 1:
            part = "states" if name in states else "outputs"
            fail(f"plant.mapping.{part}.{name}", f"{identifier} has an unmapped output of the same name")

    control_input = scenario.control_input or (inputs[0] if inputs else "")
    if control_input not in inputs:
        fail("plant.control_input", f"not a {kind} input of {identifier} (inputs: {', '.join(inputs) or 'none'})")
    named = dict(mapping.disturbances) if mapping else {}
    for name, target in named.items():
        if target not in inputs or target == control_input:
            fail(f"plant.mapping.disturbances.{name}", f"{identifier} has no disturbance input "
                 f"{target!r} (inputs besides {control_input}: "
                 f"{', '.join(i for i in inputs if i != control_input) or 'none'})")
    view_of = {target: name for name, target in named.items()}
    disturbances = {view_of.get(n, n): n for n in inputs if n != control_input}
    return outputs, signals, states, state_outputs, control_input, disturbances, list(disturbances)


def _units(description, outputs, signals, control_input, conversions) -> dict[str, str]:
    """The unit of each recorded plant variable in the view, by its view name: the one it
    declares, or its SI base unit where it is converted from a declared unit; a variable
    without one, or scaled by the mapping alone, is left out."""
    variables = {v.name: v for v in description.modelVariables}
    definitions = {u.name: u for u in description.unitDefinitions}

    def unit(name) -> str | None:
        variable = variables[name]
        declared = getattr(variable, "declaredType", None)
        text = variable.unit or (declared.unit if declared is not None else None)
        if name in conversions:
            definition = definitions.get(text)
            if definition is None or definition.baseUnit is None or \
                    conversions[name] != declared_conversion(description, variable):
                return None
            return _si(definition.baseUnit) or None
        return text

    named = dict(zip(signals, outputs))
    if control_input in variables:
        named[control_input] = control_input
    return {name: unit(target) for name, target in named.items() if unit(target)}


def _dimensions(description, variables, plant, fmu_path, mapping, named, control_input) -> list[str]:
    """A foreign FMU's declared units against the quantities of the view (the units the
    scenario's own plant declares, the default plant's when it names none): an angle must
    come in an angle unit. A variable the mapping scales itself is the mapping's business."""
    plant = plant if plant is not None else load_plant()
    if plant.linear is not None or Path(fmu_path) == Path(build_fmu(plant)):
        return []
    own = model_description(build_fmu(plant)).modelVariables
    ours = {v.name: v.unit for v in own}
    # the control input in the view is the plant's own first input (the Furuta's V)
    own_input = next((v.name for v in own if v.causality == "input"), None)
    if own_input is not None:
        named = {**named, own_input: control_input}
    given = mapping.conversions if mapping else {}
    problems = []
    for name, target in named.items():
        if target in variables and target not in given:
            problem = dimension_problem(description, variables[target], ours.get(name))
            if problem:
                problems.append(f"{fmu_path}: {problem} (the view's {name}); give the variable a "
                                "scale in the mapping, or correct the FMU's unit")
    return problems


def _si(base) -> str:
    """A base unit's SI name from its exponents (rad, rad/s, kg.m2/s2)."""
    up, down = [], []
    for symbol in ("kg", "m", "s", "A", "K", "mol", "cd", "rad"):
        power = int(getattr(base, symbol, 0) or 0)
        if power:
            (up if power > 0 else down).append(symbol + (str(abs(power)) if abs(power) != 1 else ""))
    return ".".join(up or (["1"] if down else [])) + "".join("/" + d for d in down)


def _conversions(description, mapping, names) -> dict[str, tuple[float, float]]:
    """FMU variable -> (scale, offset) with view value = scale * FMU value + offset: from the
    mapping, else from the unit the variable declares; only the variables that need one."""
    variables = {v.name: v for v in description.modelVariables}
    given = dict(mapping.conversions) if mapping else {}
    found = {}
    for name in names:
        if name in given:
            found[name] = given[name]
        elif name in variables and (declared := declared_conversion(description, variables[name])):
            found[name] = declared
    return found


def state_names_of(variables: dict) -> list[str]:
    """This project's convention: the outputs that have a ``<name>_start`` parameter."""
    return [n for n, v in variables.items()
            if v.causality == "output" and start_parameter(n) in variables]


def _bounds(low, high) -> str:
    return " and ".join(part for part in (f"min {low:g}" if low is not None else "",
                                          f"max {high:g}" if high is not None else "") if part)


def _timing(scenario: Scenario, plant: PlantSet | None, fail) -> tuple[float, float, int, str]:
    """Control period, communication step, number of samples and time unit. Runs beyond the
    documented limits are refused with an estimate, before anything is allocated."""
    linear = plant.linear if plant else None
    sample = linear.period if linear and linear.discrete else None
    unit = linear.time_unit if linear else "s"
    period = scenario.control_period or sample or PAPER_PERIOD
    step = scenario.communication_step or period
    ratio = period / step
    if not ratio <= MAX_SUBSTEPS_PER_SAMPLE:
        fail("timing.communication_step", f"{ratio:.3g} communication steps per control period; "
             f"at most {MAX_SUBSTEPS_PER_SAMPLE:,}")
        return period, step, 0, unit
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        fail("timing.control_period", f"must be a whole multiple of timing.communication_step "
             f"({step:g}), got {period:g}")
    low, high = plant.control_period if plant else (None, None)
    if (low is not None and period < low * (1 - 1e-12)) or (high is not None and period > high * (1 + 1e-12)):
        fail("timing.control_period", f"{period:g} s is outside what the {plant.name} plant allows "
             f"({plant.path.name}: limits.control_period: {_bounds(low, high)})")
    if sample:
        k = step / sample
        if not k <= MAX_SUBSTEPS_PER_SAMPLE or abs(k - round(k)) > 1e-9 * k or round(k) < 1:
            fail("timing.communication_step", f"must be a whole number of the plant's sample "
                 f"periods ({sample:g}), got {step:g}")
    samples = scenario.duration / period
    if not samples <= MAX_STEPS:
        estimate = (f"{samples:.3g} samples, whose trace alone would need about "
                    f"{samples * BYTES_PER_SAMPLE / 1e9:.3g} GB" if math.isfinite(samples)
                    else "more samples than a float counts")
        fail("timing.duration", f"{scenario.duration:g} {unit} at a control period of {period:g} "
             f"{unit} is {estimate}; a run holds at most {MAX_STEPS:,} samples")
        return period, step, 0, unit
    return period, step, max(int(math.floor(samples + 1e-9)), 0), unit


def _kalman(prepared: Prepared, state_outputs: list[str]) -> tuple:
    """The steady-state Kalman filter on the plant's linearization at the control period, its
    state in the controller's order."""
    import control

    from furuta_cosim.design.estimator import kalman_gain
    from furuta_cosim.fmu.linearize import linearize

    scenario = prepared.scenario
    to_fmu = dict(zip(prepared.signals, prepared.outputs))
    inputs = [prepared.control_input] + prepared.disturbance_inputs
    measured = [to_fmu[n] for n in prepared.measured]
    description = model_description(prepared.fmu)
    if description.modelExchange is None:
        raise PlantUnfit([f"{scenario.source}: estimator: the Kalman design linearizes the plant "
                          f"through model exchange, which {prepared.fmu.name} does not offer"])
    try:
        lin = linearize(prepared.fmu, parameters=prepared.start, inputs={n: 0.0 for n in inputs},
                        outputs=measured)
    except FmuError as error:
        raise PlantUnfit([f"{scenario.source}: estimator: the plant FMU cannot be linearized "
                          f"for the Kalman design ({error})"]) from None
    if sorted(lin.states) != sorted(state_outputs):
        raise PlantUnfit([f"{scenario.source}: estimator: the FMU's states ({', '.join(lin.states)}) "
                          f"are not the fed-back states ({', '.join(state_outputs)})"])
    order = [lin.states.index(n) for n in state_outputs]
    # in the view's units: x_view = Sx x_fmu, u_view = Su u_fmu, y_view = Sy y_fmu
    scale = [prepared.conversions.get(n, (1.0, 0.0))[0] for n in state_outputs]
    Sx, Sx_inv = np.diag(scale), np.diag(1.0 / np.array(scale))
    Su_inv = np.diag([1.0 / prepared.conversions.get(n, (1.0, 0.0))[0] for n in inputs])
    Sy = np.diag([prepared.conversions.get(n, (1.0, 0.0))[0] for n in measured])
    system = control.ss(Sx @ lin.A[np.ix_(order, order)] @ Sx_inv, Sx @ lin.B[order] @ Su_inv,
                        Sy @ lin.C[:, order] @ Sx_inv, Sy @ lin.D @ Su_inv)
    if not lin.period:
        system = control.c2d(system, prepared.control_period, method="zoh")
    elif abs(lin.period - prepared.control_period) > 1e-12:
        raise ConfigError([f"{scenario.source}: estimator: the estimator needs the control period "
                           "to equal the plant's sample period"])
    Ad, Bd, C = np.asarray(system.A), np.asarray(system.B), np.asarray(system.C)
    process_sigma = [scenario.noise.process.get(n, 0.0) if scenario.noise else 0.0
                     for n in prepared.disturbances]
    measurement_sigma = [scenario.noise.measurement.get(n, 0.0) if scenario.noise else 0.0
                         for n in prepared.measured]
    try:
        M = kalman_gain(Ad, Bd[:, 1:], C, process_sigma, measurement_sigma)
    except DesignError as error:
        raise ConfigError([f"{scenario.source}: estimator: {error}"]) from None
    return Ad, Bd[:, :1], C, M

