"""Replay: an experiment's logged inputs (and its loop, when it names one) run on a plant, outputs compared.

A :class:`Target` is the plant to replay on: this project's FMU of a plant file, or a plant
FMU from another tool with a mapping file (its names and units as ``regress --mapping`` reads
them). Experiments name the plant's variables in this project's terms (``V``, ``theta0``,
``theta1``, ``i``); the target translates them.

    target = target_for(plant="qube-servo-3")
    with open_session(target) as session:
        simulated = simulate(session, target, experiment, {"C1": 2e-6})
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np

from furuta_cosim.config import Frozen, excerpt
from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.identify.experiment import Experiment, Free
from furuta_cosim.signals import start_parameter


class SimulationFailed(RuntimeError):
    """A replay that could not run to the end (the FMU refused a step, an output not finite)."""


@dataclass(frozen=True)
class Target:
    """Where experiments are replayed. ``plant``: the plant file (this project's FMU, built
    from it); ``mapping``: for a foreign FMU, its names and conversions."""

    label: str
    fmu: str
    plant: object | None = None
    mapping: object | None = None
    fixed: Mapping[str, float] = field(default_factory=lambda: Frozen({}))

    def output(self, name: str) -> tuple[str, float, float]:
        """(FMU variable, scale, offset) of the experiment's output ``name``: view = scale * FMU + offset."""
        if self.mapping is None:
            return name, 1.0, 0.0
        variable = self.mapping.states.get(name) or self.mapping.outputs.get(name) or name
        scale, offset = self.mapping.conversions.get(variable, (1.0, 0.0))
        return variable, scale, offset

    def input(self, name: str) -> tuple[str, float, float]:
        if self.mapping is None:
            return name, 1.0, 0.0
        if name == "V" and self.mapping.control_input:
            variable = self.mapping.control_input
        else:
            variable = self.mapping.disturbances.get(name, name)
        scale, offset = self.mapping.conversions.get(variable, (1.0, 0.0))
        return variable, scale, offset

    def start(self, state: str, value: float) -> tuple[str, float]:
        """(FMU parameter, value in the FMU's unit) that starts ``state`` at ``value``."""
        variable, scale, offset = self.output(state)
        if self.mapping is not None and state in self.mapping.initial:
            return self.mapping.initial[state], (value - offset) / scale
        return start_parameter(variable), (value - offset) / scale


def target_for(plant: str | Path | None = None, fmu: str | Path | None = None,
               mapping: str | Path | None = None, fmi_version: str = "2.0") -> Target:
    """The target of ``--plant PLANT`` (a plant file or name, this project's FMU built from it)
    or of ``--fmu FMU [--mapping FILE]``."""
    if fmu is not None:
        if plant is not None:
            raise ConfigError(["fmu: give a plant or an FMU (`plant`), not both"])
        from furuta_cosim.scenario import load_mapping

        path = Path(fmu)
        if not path.is_file():
            raise ConfigError([f"fmu {fmu}: no such FMU"])
        view = load_mapping(mapping) if mapping else None
        return Target(path.name + (f"#{Path(mapping).name}" if mapping else ""), str(path),
                      mapping=view)
    if mapping is not None:
        raise ConfigError(["mapping: maps the variables of a plant FMU given as `fmu`; give one"])
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.plants import load_plant

    loaded = load_plant(plant or "furuta")
    if loaded.linear is not None:
        raise ConfigError([f"{loaded.path}: a linear plant; replay and identify need a plant "
                           "model with physical parameters"])
    return Target(loaded.name, str(build_fmu(loaded, fmi_version=fmi_version)), plant=loaded,
                  fixed=loaded.parameters)


def recorded_plant(paths) -> tuple[str | None, str]:
    """(the plant a set of logs was recorded on, a line saying so) when every log is a rig
    run's experiment file naming the same plant (``rig.plant``), found beside the log or among
    the shipped plants; (None, "") when they name none or different ones. A plant found by
    name whose content is not the one the run used is named in the line. Only the experiment
    files are read here (not their logs): :func:`load_experiment` checks them whole after."""
    from furuta_cosim.config import load_yaml
    from furuta_cosim.fmu.plants import content_sha256, load_plant

    found = set()
    for path in paths:
        try:
            data = load_yaml(path)
        except ConfigError:
            return None, ""   # load_experiment names the problem
        rig = data.get("rig") if isinstance(data, dict) else None
        name = rig.get("plant") if isinstance(rig, dict) else None
        digest = rig.get("plant_sha256", "") if isinstance(rig, dict) else ""
        if not isinstance(name, str) or not name:
            return None, ""
        if "/" in name or "\\" in name or name.startswith("."):
            raise ConfigError([f"{path}: rig.plant: {excerpt(name)}: expected a plant file's name (rig run writes "
                               "its file name, never a path); give the plant (`plant`)"])
        found.add(((name, digest if isinstance(digest, str) else ""), Path(path).resolve().parent))
    names = {name for (name, _), _ in found}
    if len(names) != 1:
        return None, ""
    (name, digest), beside = next(iter(found))
    plant = None
    for candidate in (name, Path(name).stem):
        try:
            plant = load_plant(candidate, beside=beside)
            break
        except ConfigError:
            continue
    if plant is None:
        raise ConfigError([f"rig.plant: the log was recorded on {name}, which is neither beside it nor a "
                           "shipped plant: give the rig's plant file (`plant`)"])
    same = not digest or content_sha256(plant) == digest
    return str(plant.path), (f"replayed on {plant.name}, the plant the rig run ran on (rig.plant; --plant "
                             "chooses another)" + ("" if same else f"; its file {plant.path.name} has changed "
                                                   "since the run (another sha256)"))


@contextmanager
def open_session(target: Target) -> Iterator:
    from furuta_cosim.fmu.session import PlantSession

    session = PlantSession.open(target.fmu)
    try:
        yield session
    finally:
        session.close()


def check_names(target: Target, experiments, free: tuple[str, ...] = (), source: str = "") -> None:
    """Every name the experiments (and the fit's ``free`` parameters, of the spec ``source``)
    use exists in the target's FMU with a role that fits: one ConfigError naming each file
    and key otherwise."""
    prefix = f"{source}: " if source else ""
    from furuta_cosim.fmu.session import model_description

    md = model_description(target.fmu)
    variables = {v.name: v for v in md.modelVariables}
    settable = {n for n, v in variables.items() if v.causality in ("parameter", "input")
                or (v.initial in ("exact", "approx") and v.causality != "output")}
    settable |= {n for n, v in variables.items() if v.causality == "parameter"}
    problems = []
    for experiment in experiments:
        where = str(experiment.path)
        if experiment.loop is not None and target.plant is not None and target.plant.model != "furuta":
            # the closed loop's readings are the pendulum's encoders and current: the Furuta's
            problems.append(f"{where}: loop: a closed-loop log is replayed through the Furuta pendulum's "
                            f"loop (its encoders, current and laws); {target.label} is another plant: "
                            "state its log open loop (the command as an input column)")
            continue
        for name in experiment.inputs:
            variable = target.input(name)[0]
            if variables.get(variable) is None or variables[variable].causality != "input":
                inputs = [n for n, v in variables.items() if v.causality == "input"]
                problems.append(f"{where}: inputs.{name}: {target.label} has no input {variable} "
                                f"(inputs: {', '.join(inputs) or 'none'})")
        outputs = [n for n, v in variables.items() if v.causality == "output"]
        for name in experiment.outputs:
            variable = target.output(name)[0]
            if variable not in variables:
                problems.append(f"{where}: outputs.{name}: {target.label} has no variable {variable} "
                                f"(outputs: {', '.join(outputs)})")
            elif variables[variable].causality != "output":
                problems.append(f"{where}: outputs.{name}: {variable} is an {variables[variable].causality} "
                                f"of {target.label}, not an output it computes (outputs: {', '.join(outputs)})")
        for name, unit in experiment.units.items():
            variable = (target.output(name) if name in experiment.outputs else target.input(name))[0]
            wrong = _unit_problem(md, variables.get(variable), unit)
            if wrong:
                key = "outputs" if name in experiment.outputs else "inputs"
                problems.append(f"{where}: {key}.{name}.unit: {wrong}")
        for state in experiment.start:
            parameter = target.start(state, 0.0)[0]
            if parameter in experiment.parameters:
                problems.append(f"{where}: parameters.{parameter}: sets the start of {state}, which "
                                f"start.{state} sets too: give it in one place")
        for name in experiment.start:
            parameter = target.start(name, 0.0)[0]
            if parameter not in variables:
                problems.append(f"{where}: start.{name}: {target.label} has no state {name} "
                                f"(no {parameter} to start it with)")
        for name in experiment.parameters:
            if name not in settable:
                problems.append(f"{where}: parameters.{name}: not a parameter of {target.label}")
    started = {target.start(state, 0.0)[0]: (experiment, state) for experiment in experiments
               for state in experiment.start}
    for name in free:
        variable = variables.get(name)
        if variable is None or variable.causality != "parameter":
            kind = ("not a variable" if variable is None else
                    f"a{'n' if variable.causality[0] in 'aeiou' else ''} {variable.causality}")
            problems.append(f"{prefix}free.{name}: only a plant parameter can be fitted ({name} is {kind} "
                            f"of {target.label}; initial states are freed in an experiment's start, "
                            "sensor zero errors as an output's bias)")
        elif variable.type not in ("Real", "Float64"):
            problems.append(f"{prefix}free.{name}: a {variable.type} setting of {target.label}, not a "
                            "physical value: it cannot be fitted")
        elif name in started:
            experiment, state = started[name]
            problems.append(f"{prefix}free.{name}: {experiment.path} sets it (start.{state}), so the fit "
                            f"could not move it there: free the start in the experiment instead "
                            f"(start.{state}: {{free: [lo, hi]}})")
    if problems:
        raise ConfigError(problems)


# the SI unit of each unit an experiment may name, for the dimension check
_SI = {"rad": "rad", "deg": "rad", "rev": "rad", "rad/s": "rad/s", "deg/s": "rad/s", "rpm": "rad/s",
       "A": "A", "mA": "A", "V": "V", "s": "s", "ms": "s"}


def _unit_problem(md, variable, unit: str) -> str | None:
    """Why a column in ``unit`` cannot be ``variable`` (a current in A on an angle), or None."""
    from furuta_cosim.fmu.variables import DIMENSIONS, dimension_problem

    si = _SI.get(unit)
    if variable is None or si is None:
        return None
    declared = variable.unit or (variable.declaredType.unit if getattr(variable, "declaredType", None) else None)
    if declared in DIMENSIONS:
        if DIMENSIONS[declared] != DIMENSIONS[si]:
            return (f"{unit} is a unit of {_QUANTITY[si]}, but {variable.name} is in {declared} "
                    f"({_QUANTITY.get(declared, declared)})")
        return None
    problem = dimension_problem(md, variable, si)
    return f"{unit} is a unit of {_QUANTITY[si]}: {problem}" if problem else None


_QUANTITY = {"rad": "an angle", "rad/s": "an angular velocity", "A": "a current", "V": "a voltage",
             "s": "a time", "rad/s2": "an angular acceleration", "1/s": "a rate", "m": "a length",
             "Nm": "a torque"}


def overrides(target: Target, experiment: Experiment, values: Mapping[str, float]) -> dict[str, float]:
    """What the FMU is reset with for one run: ``values`` (fitted plant parameters;
    ``<experiment>.<state>`` for free initial states), then the experiment's own parameters,
    which hold in it whatever the fit does elsewhere (an arm clamped in one log is clamped
    there even while its inertia is fitted on another), then the initial states."""
    found = {k: v for k, v in values.items() if "." not in k}
    found.update(experiment.parameters)
    for state, start in experiment.start.items():
        value = values.get(f"{experiment.name}.{state}", start.start) if isinstance(start, Free) else start
        name, converted = target.start(state, float(value))
        found[name] = converted
    return found


def simulate(session, target: Target, experiment: Experiment,
             values: Mapping[str, float] | None = None, record: dict | None = None) -> dict[str, np.ndarray]:
    """The experiment's outputs as the plant gives them at every sample of its window, in the
    experiment's (SI) units; raises SimulationFailed when the run cannot reach its end. With a
    ``loop`` the controller that ran closes the loop again (:func:`closed_loop`; ``record``
    takes its mode switches)."""
    if experiment.loop is not None:
        return closed_loop(session, target, experiment, values, record=record)[0]
    names = list(experiment.outputs)
    inputs = list(experiment.inputs)
    fmu_out = [target.output(n) for n in names]
    fmu_in = [target.input(n) for n in inputs]
    columns = [(experiment.input_at(n, values) - offset) / scale for n, (_, scale, offset) in zip(inputs, fmu_in)]
    u = np.column_stack(columns) if columns else np.zeros((experiment.samples, 0))
    # the outputs go straight into one array, the inputs are read a block at a time: a log of
    # 10^6 samples replays in tens of MB, not in lists of Python floats
    raw = np.empty((experiment.samples, len(names)))
    try:
        session.reset(parameters=overrides(target, experiment, values or {}),
                      start_time=float(experiment.t[0]))
        session.set_io(inputs=[v for v, _, _ in fmu_in], outputs=[v for v, _, _ in fmu_out])
        raw[0] = session.get([v for v, _, _ in fmu_out])
        h, step, block = experiment.period, session.step, 4096
        # a log that records when each sample was read (a rig's `late`), or whose clock jitters (a
        # closed loop's, replayed open loop: split.delayed), is stepped to those times
        timed = experiment.late is not None or experiment.jittered
        steps = np.diff(experiment.read_at).tolist() if timed else None
        for first in range(0, experiment.samples - 1, block):
            for k, row in enumerate(u[first:min(first + block, experiment.samples - 1)].tolist(), start=first):
                if steps is None:
                    raw[k + 1] = step(row, h)
                else:
                    moved = _held(session, row, steps[k], h, many=True)
                    raw[k + 1] = raw[k] if moved is None else moved
    except FmuError as error:
        raise SimulationFailed(str(error)) from None
    if not np.all(np.isfinite(raw)):
        k = int(np.argmax(~np.all(np.isfinite(raw), axis=1)))
        raise SimulationFailed(f"{target.label}: an output is not finite at t = {experiment.t[k]:g} s")
    return {n: raw[:, j] * scale + offset for j, (n, (_, scale, offset)) in enumerate(zip(names, fmu_out))}


def _held(session, value, seconds: float, longest: float, many: bool = False):
    """Step ``session`` ``seconds`` with its input(s) held at ``value``, in steps no longer than
    ``longest`` (the log's period: the plant file's integration is stable at it, a late
    sample's long interval is not); returns the outputs at the end, or None where ``seconds``
    is no time (two readings at one instant: the plant has not moved)."""
    if seconds <= 1e-9 * longest:
        return None
    pieces = max(1, int(math.ceil(seconds / longest - 1e-9)))
    inputs = value if many else [value]
    for _ in range(pieces - 1):
        session.step(inputs, seconds / pieces)
    return session.step(inputs, seconds / pieces)


def period(t: np.ndarray, y: np.ndarray) -> float | None:
    """The mean period of an oscillating signal: its upward crossings of its own mean
    (interpolated between samples), each counted only after the signal has been below the
    mean by a quarter of its standard deviation, so that encoder steps near rest add none.
    None with fewer than four crossings."""
    centred = y - np.mean(y)
    band = 0.25 * float(np.std(centred))
    if band == 0.0:
        return None
    crossings, armed = [], False
    for k in range(len(centred) - 1):
        if centred[k] < -band:
            armed = True
        if armed and centred[k] < 0 <= centred[k + 1]:
            crossings.append(t[k] - centred[k] * (t[k + 1] - t[k]) / (centred[k + 1] - centred[k]))
            armed = False
    if len(crossings) < 4:
        return None
    return float((crossings[-1] - crossings[0]) / (len(crossings) - 1))


def compare(experiment: Experiment, simulated: Mapping[str, np.ndarray]) -> dict:
    """Per output: RMS and largest error (SI units), the weight ``sigma``, and for an
    oscillating output the measured and simulated periods."""
    found = {}
    for name, measured in experiment.outputs.items():
        error = simulated[name] - measured.values
        entry = {"rms": float(math.sqrt(np.mean(error ** 2))), "max": float(np.max(np.abs(error))),
                 "sigma": measured.sigma, "sigma_from": measured.sigma_from}
        if measured.quantum:
            entry["quantum"] = measured.quantum
        p_measured, p_simulated = period(experiment.t, measured.values), period(experiment.t, simulated[name])
        if p_measured is not None:
            entry["period"] = {"measured": p_measured, "simulated": p_simulated,
                               "error": None if p_simulated is None else p_simulated / p_measured - 1.0}
        found[name] = entry
    return found


def chatter(session, target: Target, experiment: Experiment, simulated: Mapping[str, np.ndarray],
            values: Mapping[str, float] | None = None) -> dict[str, float]:
    """Per output that no encoder counts (the current), what a loop closed on counted angles
    cannot reproduce: the RMS difference between ``simulated`` and a second replay whose
    encoders' zero is half a count away. The command's chatter that the rounding drives is
    a different draw in every run; on a swing-up log of the virtual board it moves the current
    by 0.17 A RMS between two such replays while the angles stay within a quantum of the log.
    Empty for a log without a loop, or one whose angles are estimated (a balancing log: its
    controller sees what it logged)."""
    if experiment.loop is None or experiment.loop.estimate:
        return {}
    names = [n for n, m in experiment.outputs.items() if n == "i" and not m.quantum]
    if not names:
        return {}
    shifted, _ = closed_loop(session, target, experiment, values, phase=0.5)
    return {n: float(math.sqrt(np.mean((shifted[n] - simulated[n]) ** 2))) for n in names}


def rebuilt_command(experiment: Experiment, readings: Mapping[str, np.ndarray] | None = None) -> np.ndarray | None:
    """The command the log's loop computes from what the log recorded (no plant: the logged
    angles as its encoders counted them, their rates by the loop's filter, the logged current,
    the reference and feedforward), clipped to its limit; None without a loop or the logged
    voltage. ``readings`` replaces logged outputs (another reading of a column: identify/
    precheck.py loop_hint). On a log of the loop it names, this is the logged command to
    rounding; a column read in the wrong unit, sign or zero, or another loop, shows."""
    loop = experiment.loop
    if loop is None or "V" not in experiment.inputs or np.isscalar(experiment.inputs["V"]):
        return None
    n = experiment.samples
    values = {name: m.values for name, m in experiment.outputs.items()}
    values.update(readings or {})
    zeros = np.zeros(n)
    a0, a1, current = (values.get(name, zeros) for name in ("theta0", "theta1", "i"))
    feedforward = loop.feedforward if loop.feedforward is not None else zeros
    command = _commander(loop, experiment)
    found = np.zeros(n)
    for k in range(n):
        found[k] = command(k, float(a0[k]), float(a1[k]), float(current[k])) + float(feedforward[k])
    if loop.voltage is not None:
        found = np.clip(found, -loop.voltage, loop.voltage)
    return found


_RUNTIMES: dict = {}   # (controller file or law, its sha256, period) -> (file, runtime), in this process


def _commander(loop, experiment: Experiment):
    """A function (k, theta0, theta1, i as the controller saw them, SI) -> its command (V,
    before the feedforward) at sample k of the window, its state at the window's start: the
    loop's own law (its state from the rows before the window: identify/laws.py), or its
    controller with the rates by the loop's filter, both run first over the rows before a
    window that cuts the log mid-run (``loop.lead_in``), as they ran on the rig. A swing-up
    whose log records its mode (``loop.mode``) runs each sample of the window in the logged
    mode; where its own rule would have made another, ``command.own()`` says so."""
    if loop.linear is not None:
        step = loop.linear.stepper()

        def law(k, a0, a1, current):
            return step(k, {"theta0": a0, "theta1": a1, "i": current})
        law.switches = list
        return law
    from furuta_cosim.measurement import RateFilter

    runtime = _runtime(loop, experiment.period)
    runtime.reset()
    rates = RateFilter(experiment.period, loop.rate_filter)
    reference = loop.reference if loop.reference is not None else np.zeros(experiment.samples)
    lead = loop.lead_in
    logged = [experiment.outputs[n].values[0] if n in experiment.outputs else 0.0 for n in ("theta0", "theta1")]

    def warm(a0, a1):
        # the rows before the window as the controller saw them, moved by what it sees at the
        # window's first sample less what was logged there (the replay's departure from the log,
        # taken as it is at the cut): its filter sees no jump where the replay takes over
        shift = (a0 - logged[0], a1 - logged[1])
        for (b0, b1), current, r in zip(lead.angles.tolist(), lead.current.tolist(), lead.reference.tolist()):
            b0, b1 = b0 + shift[0], b1 + shift[1]
            r0, r1 = rates((b0, b1))
            runtime.control([b0, r0, b1, r1, current], r)

    warmed = []   # the control calls of the lead-in, before the window's first sample

    follow = loop.mode if loop.mode is not None and hasattr(runtime, "follow") else None

    def command(k, a0, a1, current):
        if k == 0 and lead is not None:
            warm(a0, a1)
            warmed.append(len(lead.current))
        r0, r1 = rates((a0, a1))
        if follow is not None:
            runtime.follow(float(follow[k]))
        return float(runtime.control([a0, r0, a1, r1, current], float(reference[k])))

    def window(found):
        skip = warmed[0] if warmed else 0
        return [(k - skip, m) for k, m in found if k >= skip]

    def switches():
        """A swing-up's mode switches in the window: (sample, new mode)."""
        return window(getattr(runtime, "switches", []))

    def own():
        """Following the logged mode: (sample, the mode its own rule gave) where they differ."""
        return window(getattr(runtime, "own", [])) if follow is not None else None
    command.switches, command.own = switches, own
    return command


def _runtime(loop, period: float):
    key = (str(loop.controller), loop.sha256, period)
    if key not in _RUNTIMES:
        from furuta_cosim.cosim.runtime import runtime_for

        _RUNTIMES.clear()  # one loop at a time is the usual case; a fit of several rebuilds
        _RUNTIMES[key] = runtime_for(loop.controller_file(), period, where="the log's loop")
    return _RUNTIMES[key][1]


# ``<experiment>.noise_draw`` in a replay's values: a draw (its seed, > 0) of the smoother's own
# error added to the angles its controller sees (estimate.noise_draw); 0 or absent: none
NOISE_DRAW = "noise_draw"


def closed_loop(session, target: Target, experiment: Experiment,
                values: Mapping[str, float] | None = None,
                phase: float = 0.0, record: dict | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(outputs, the voltage the controller wrote) of the experiment with its loop closed: at each
    sample the controller sees what it saw on the rig (the angles as the encoders count them,
    rates by the same filter, the current), the log's feedforward is added, the command is
    clipped to the loop's voltage limit and reaches the motor ``delay`` seconds later (the
    board's transport and computation delay, any number of samples), held over each sample
    (furuta_cosim.measurement; rig/runner.py). The controller's state and the rates' filter
    start at zero at the window's start.

    With the loop's ``estimate`` (a balancing log, identify/estimate.py) the controller sees
    the angles it logged moved by the simulation's departure from their true values as
    estimated on the plant at ``values``; else it sees the simulated angles rounded to
    counts, the encoders' zero moved by ``phase`` counts (:func:`chatter`)."""
    import math as _math

    from furuta_cosim.measurement import counted

    loop = experiment.loop
    command = _commander(loop, experiment)
    names = list(experiment.outputs)
    seen = ["theta0", "theta1", "i"]
    fmu_out = [target.output(n) for n in names + seen]
    v_name, v_scale, v_offset = target.input("V")
    n = experiment.samples
    raw = np.full((n, len(names)), np.nan)
    volts = np.zeros(n)
    feedforward = loop.feedforward if loop.feedforward is not None else np.zeros(n)
    per_count = 2.0 * _math.pi / loop.counts
    limit, h = loop.voltage, experiment.period
    noise = None
    if loop.estimate:
        from furuta_cosim.identify.estimate import estimated_noise

        at = {**experiment.parameters, **(values or {})}
        noise = estimated_noise(experiment, target, at)
        draw = int((values or {}).get(f"{experiment.alias or experiment.name}.{NOISE_DRAW}", 0))
        if draw:   # the smoother's estimate moved as its own error could (identify/reach.py)
            from furuta_cosim.identify.estimate import noise_draw

            moved = noise_draw(experiment, target, at, draw)
            noise = (noise[0] + moved[0], noise[1] + moved[1])
    # a delay of m whole samples and a fraction f of one: over [t_k, t_k + f) the motor gets the
    # command of sample k - m - 1, over the rest of the sample that of k - m; before the window's
    # start, the command logged there (a window that cuts the log mid-run), else 0
    delay = experiment.loop_delay(values)   # as stated, or where the fit has it
    whole = int(_math.floor(delay / h + 1e-9))
    part = delay - whole * h
    if part < 1e-12 * h:
        part = 0.0
    logged = loop.lead_in.command if loop.lead_in is not None and loop.lead_in.command is not None else np.zeros(0)

    def written(j: int) -> float:
        """The command of sample j of the window (j < 0: before it)."""
        if j >= 0:
            return volts[j]
        return float(logged[j]) if -j <= len(logged) else 0.0
    # a log that records when each sample was read and its command written (a rig's `late` and
    # `compute`), or whose clock jitters: the plant is stepped to each reading, its voltage
    # switched at each write plus the delay, wherever those fall
    timed = experiment.late is not None or loop.compute is not None or experiment.jittered
    read = experiment.read_at
    arrive = read + (loop.compute if loop.compute is not None else 0.0) + delay
    pending: list[tuple[float, float]] = []
    level, now_t = 0.0, float(read[0])
    for j in range(-whole - 2, 0):   # the rows before the window, written on time
        when = now_t + j * h + delay
        if when <= now_t + 1e-12:
            level = written(j)
        else:
            pending.append((when, written(j)))
    try:
        session.reset(parameters=overrides(target, experiment, values or {}), start_time=float(experiment.t[0]))
        session.set_io(inputs=[v_name], outputs=[v for v, _, _ in fmu_out])
        y = session.get([v for v, _, _ in fmu_out])
        from furuta_cosim.identify.native import replay_in_c

        found = replay_in_c(session, experiment, names=names, fmu_out=fmu_out, first=y,
                            v_scale=v_scale, v_offset=v_offset, noise=noise, phase=phase, delay=delay,
                            logged=logged, runtime_of=lambda: _runtime(loop, experiment.period),
                            timed=timed, read=read, arrive=arrive, pending=pending, level=level)
        if found is not None:   # the same loop in C (identify/native.py)
            raw, volts, _ = found
        for k in range(n if found is None else 0):
            si = [value * scale + offset for value, (_, scale, offset) in zip(y, fmu_out)]
            raw[k] = si[:len(names)]
            theta0, theta1, current = si[len(names):]
            if not all(_math.isfinite(v) for v in si):
                break
            if noise is not None:   # what it logged, moved as the simulation is from the truth
                a0, a1 = theta0 + noise[0][k], theta1 + noise[1][k]
            else:
                shift = phase * per_count
                a0, a1 = counted(theta0, shift, per_count), counted(theta1, _math.pi + shift, per_count)
            u = command(k, a0, a1, current) + float(feedforward[k])
            if limit is not None:
                u = max(-limit, min(limit, u))
            volts[k] = u
            if timed and k < n - 1:
                pending.append((max(float(arrive[k]), pending[-1][0] if pending else now_t), u))
                end = float(read[k + 1])
                while pending and pending[0][0] < end - 1e-12:
                    when, value = pending.pop(0)
                    if when - now_t > 1e-12:
                        _held(session, (level - v_offset) / v_scale, when - now_t, h)
                        now_t = when
                    level = value
                y = _held(session, (level - v_offset) / v_scale, end - now_t, h) or y
                now_t = max(now_t, end)
            elif k < n - 1:
                now = written(k - whole)
                if part > 0.0:  # the command before it reaches the motor for the first part
                    session.step([(written(k - whole - 1) - v_offset) / v_scale], part)
                y = session.step([(now - v_offset) / v_scale], h - part)
    except FmuError as error:
        raise SimulationFailed(str(error)) from None
    if record is not None:   # a swing-up's switches (sample of the window, new mode), as replayed
        record["switches"] = command.switches()
        record["own"] = command.own()   # following the logged mode: where its own rule differed
    if not np.all(np.isfinite(raw)) or not np.all(np.isfinite(volts)):
        k = int(np.argmax(~(np.all(np.isfinite(raw), axis=1) & np.isfinite(volts))))
        raise SimulationFailed(f"{target.label}: the closed loop is not finite at t = {experiment.t[k]:g} s")
    return {name: raw[:, j] for j, name in enumerate(names)}, volts
