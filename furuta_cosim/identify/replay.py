"""Replay: the logged inputs of an experiment run open loop on a plant, outputs compared.

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

from furuta_cosim.config import Frozen
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


@contextmanager
def open_session(target: Target) -> Iterator:
    from furuta_cosim.fmu.session import PlantSession

    session = PlantSession.open(target.fmu)
    try:
        yield session
    finally:
        session.close()


def check_names(target: Target, experiments, free: tuple[str, ...] = ()) -> None:
    """Every name the experiments (and the fit's ``free`` parameters) use exists in the
    target's FMU with a role that fits: one ConfigError naming each file and key otherwise."""
    from furuta_cosim.fmu.session import model_description

    md = model_description(target.fmu)
    variables = {v.name: v for v in md.modelVariables}
    settable = {n for n, v in variables.items() if v.causality in ("parameter", "input")
                or (v.initial in ("exact", "approx") and v.causality != "output")}
    settable |= {n for n, v in variables.items() if v.causality == "parameter"}
    problems = []
    for experiment in experiments:
        where = str(experiment.path)
        for name in experiment.inputs:
            variable = target.input(name)[0]
            if variables.get(variable) is None or variables[variable].causality != "input":
                inputs = [n for n, v in variables.items() if v.causality == "input"]
                problems.append(f"{where}: inputs.{name}: {target.label} has no input {variable} "
                                f"(inputs: {', '.join(inputs) or 'none'})")
        for name in experiment.outputs:
            variable = target.output(name)[0]
            if variable not in variables:
                outputs = [n for n, v in variables.items() if v.causality == "output"]
                problems.append(f"{where}: outputs.{name}: {target.label} has no variable {variable} "
                                f"(outputs: {', '.join(outputs)})")
        for name in experiment.start:
            parameter = target.start(name, 0.0)[0]
            if parameter not in variables:
                problems.append(f"{where}: start.{name}: {target.label} has no state {name} "
                                f"(no {parameter} to start it with)")
        for name in experiment.parameters:
            if name not in settable:
                problems.append(f"{where}: parameters.{name}: not a parameter of {target.label}")
    for name in free:
        if name not in settable:
            problems.append(f"free.{name}: not a parameter of {target.label}")
    if problems:
        raise ConfigError(problems)


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
             values: Mapping[str, float] | None = None) -> dict[str, np.ndarray]:
    """The experiment's outputs as the plant gives them at every sample of its window, in the
    experiment's (SI) units; raises SimulationFailed when the run cannot reach its end."""
    names = list(experiment.outputs)
    inputs = list(experiment.inputs)
    fmu_out = [target.output(n) for n in names]
    fmu_in = [target.input(n) for n in inputs]
    columns = [(experiment.input_at(n) - offset) / scale for n, (_, scale, offset) in zip(inputs, fmu_in)]
    u = np.column_stack(columns).tolist() if columns else [[]] * experiment.samples
    try:
        session.reset(parameters=overrides(target, experiment, values or {}),
                      start_time=float(experiment.t[0]))
        session.set_io(inputs=[v for v, _, _ in fmu_in], outputs=[v for v, _, _ in fmu_out])
        rows = [session.get([v for v, _, _ in fmu_out])]
        h, step = experiment.period, session.step
        for k in range(experiment.samples - 1):
            rows.append(step(u[k], h))
    except FmuError as error:
        raise SimulationFailed(str(error)) from None
    raw = np.array(rows, dtype=float)
    if not np.all(np.isfinite(raw)):
        k = int(np.argmax(~np.all(np.isfinite(raw), axis=1)))
        raise SimulationFailed(f"{target.label}: an output is not finite at t = {experiment.t[k]:g} s")
    return {n: raw[:, j] * scale + offset for j, (n, (_, scale, offset)) in enumerate(zip(names, fmu_out))}


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
        p_measured, p_simulated = period(experiment.t, measured.values), period(experiment.t, simulated[name])
        if p_measured is not None:
            entry["period"] = {"measured": p_measured, "simulated": p_simulated,
                               "error": None if p_simulated is None else p_simulated / p_measured - 1.0}
        found[name] = entry
    return found
