"""Named linear models for control design.

- ``paper-printed``: the paper's printed (A, B, C) (``scenarios/plants/paper-printed.yaml``);
- ``derived`` or ``derived:<parameter set>``: the linearization of the plant FMU at the
  upright equilibrium, input V, outputs the ones its model declares measured (the paper's C);
- ``toy``: the paper's discrete toy plant;
- any linear plant file (``model: linear``), by name in ``scenarios/plants`` or by path;
- a plant FMU from any tool, ``PLANT.fmu`` or ``PLANT.fmu#MAPPING.yaml``: its linearization at
  its start state through model exchange, the states named, ordered and converted to the
  view's units by the mapping file (as ``regress --mapping`` reads it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from furuta_cosim.design.linear import LinearModel
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import load_plant

def load_model(name: str | Path = "paper-printed", beside: Path | None = None) -> LinearModel:
    """Resolve a model name or file to a :class:`LinearModel` (see the module docstring).

    Parameters
    ----------
    name : str or path, optional
        A plant name or file, ``derived[:<parameter set>]``, or ``file.fmu[#mapping.yaml]``
        (linearized). The default is the paper's printed model.
    beside : path, optional
        The folder of the file that names it, where names and relative paths are looked up first.

    Returns
    -------
    LinearModel
    """
    text = str(name)
    fmu, _, mapping = text.partition("#")
    if fmu.endswith(".fmu"):
        return from_fmu(_beside(fmu, beside), _beside(mapping, beside) if mapping else None)
    if text == "derived" or text.startswith("derived:"):
        return derived(text.partition(":")[2] or "paper-calibrated", beside)
    plant = load_plant(name, also=("derived", "derived:<parameter set>"), beside=beside)
    if plant.linear is None:
        # a parameter set of a nonlinear plant: its linearization
        return derived(plant.path)
    spec = plant.linear
    return LinearModel(plant.name, np.array(spec.A), np.array(spec.B), np.array(spec.C),
                       np.array(spec.D), tuple(spec.states), tuple(spec.inputs),
                       tuple(spec.outputs), spec.period if spec.discrete else 0.0,
                       {"source": str(plant.path)}, spec.time_unit)


def derived(parameter_set: str | Path = "paper-calibrated", beside: Path | None = None) -> LinearModel:
    """The plant FMU linearized with ``parameter_set`` at the upright equilibrium."""
    from furuta_cosim.fmu.exporter import build_fmu, declaration
    from furuta_cosim.fmu.linearize import linearize

    plant = load_plant(parameter_set, beside=beside)
    if plant.linear is not None:
        raise ConfigError([f"{plant.path}: a linear plant has no 'derived' model; use its name"])
    model = declaration(plant)
    inputs = [v.name for v in model.reals if v.causality == "input"]
    parameters, note = without_nonsmooth(plant, model)
    result = linearize(build_fmu(plant), parameters=parameters, inputs={inputs[0]: 0.0},
                       outputs=list(model.measured) or None)
    name = "derived" if plant.name == "paper-calibrated" else f"derived:{plant.name}"
    provenance = {"linearized": plant.name, "plant_file": str(plant.path)}
    if note:
        provenance["note"] = note
    return LinearModel(name, result.A, result.B, result.C, result.D, tuple(result.states),
                       tuple(result.inputs), tuple(result.outputs), 0.0, provenance)


def without_nonsmooth(plant, model) -> tuple[dict, str]:
    """The plant's parameters for linearization, with the model's nonsmooth terms (Coulomb
    friction) set to 0, and a line saying so when any was present (else empty)."""
    parameters = dict(plant.parameters)
    present = {n: parameters[n] for n in model.nonsmooth if parameters.get(n, 0.0) != 0.0}
    if not present:
        return parameters, ""
    parameters.update({n: 0.0 for n in present})
    listed = ", ".join(f"{n} = {v:g}" for n, v in present.items())
    return parameters, (f"Coulomb friction ({listed}) is left out of the linear model: at zero "
                        "speed it has no derivative (its smoothed slope is an artefact of the "
                        "smoothing); the nonlinear plant keeps it")


def linearize_plant(parameter_set: str | Path, inputs=None):
    """The plant FMU of ``parameter_set`` built and linearized at its start state with the
    ``inputs`` named (all, when None) at 0; returns (plant, fmu path, Linearization, note):
    the note says what the linear model leaves out (Coulomb friction), else it is empty."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.linearize import linearize

    from furuta_cosim.fmu.exporter import declaration

    plant = load_plant(parameter_set)
    fmu = build_fmu(plant)
    parameters, note = without_nonsmooth(plant, declaration(plant)) if plant.linear is None else (
        dict(plant.parameters), "")
    result = linearize(fmu, parameters=parameters,
                       inputs={name: 0.0 for name in inputs} if inputs else None)
    return plant, fmu, result, note


def _beside(name: str, folder: Path | None) -> Path:
    path = Path(name)
    return folder / path if folder is not None and not path.is_absolute() and (folder / path).exists() else path


def from_fmu(fmu: str | Path, mapping: str | Path | None = None) -> LinearModel:
    """Any plant FMU linearized at its start state through its model-exchange interface: the
    control input (the mapping's ``control_input``, else the FMU's first floating-point
    input) at 0, the other inputs at their start values, the outputs the states. A mapping file
    names the states (its ``states``, in its order; every state of the FMU must be mapped) and
    converts their units (``scale``, or the units the FMU declares)."""
    from furuta_cosim.errors import FmuError
    from furuta_cosim.fmu.linearize import linearize
    from furuta_cosim.fmu.session import model_description, state_names
    from furuta_cosim.fmu.variables import declared_conversion, is_real
    from furuta_cosim.scenario import load_mapping

    from furuta_cosim.inputs import regular

    fmu = Path(fmu)
    if not fmu.exists() and not fmu.is_symlink():
        raise ConfigError([f"{fmu}: no such FMU file"])
    regular(fmu)
    md = model_description(fmu)
    where = str(fmu)
    if md.modelExchange is None:
        raise ConfigError([f"{where}: linearization needs model exchange (states set, derivatives "
                           f"read); this FMU has only {'co-simulation' if md.coSimulation else 'scheduled execution'}"
                           ": export it with model exchange as well"])
    states = state_names(md)
    if not states:
        raise ConfigError([f"{where}: declares no continuous states (ModelStructure has no derivatives)"])
    view = load_mapping(mapping) if mapping else None
    variables = {v.name: v for v in md.modelVariables}
    inputs = [v.name for v in md.modelVariables if v.causality == "input" and is_real(v)]
    control = (view.control_input if view and view.control_input else None) or (inputs[0] if inputs else None)
    if control not in inputs:
        raise ConfigError([f"{mapping or where}: control_input: {control!r} is not a floating-point "
                           f"input of {fmu.name} (inputs: {', '.join(inputs) or 'none'})"])
    if view and view.states:
        named = dict(view.states)  # view name -> FMU variable
        unmapped = [s for s in states if s not in named.values()]
        strangers = [f"{k} -> {v}" for k, v in named.items() if v not in states]
        if unmapped or strangers:
            raise ConfigError([f"{mapping}: states: " + "; ".join(
                ([f"the FMU's states {', '.join(unmapped)} are not mapped"] if unmapped else [])
                + ([f"{', '.join(strangers)} not a state of the FMU (its states: {', '.join(states)})"]
                   if strangers else []))])
    else:
        named = {s: s for s in states}
    order = list(named.values())
    try:
        result = linearize(fmu, inputs={control: 0.0}, outputs=order)
    except FmuError as error:
        raise ConfigError([f"{where}: cannot be linearized: {error}"]) from None
    given = dict(view.conversions) if view else {}

    def scale(name):
        return (given.get(name) or declared_conversion(md, variables[name]) or (1.0, 0.0))[0]

    index = [result.states.index(n) for n in order]
    Sx = np.diag([scale(n) for n in order])
    Su = np.array([[scale(control)]])
    A = Sx @ result.A[np.ix_(index, index)] @ np.linalg.inv(Sx)
    B = Sx @ result.B[index] @ np.linalg.inv(Su)
    C = Sx @ result.C[:, index] @ np.linalg.inv(Sx)
    D = Sx @ result.D @ np.linalg.inv(Su)
    names = tuple(named)
    label = fmu.name + (f"#{Path(mapping).name}" if mapping else "")
    return LinearModel(label, A, B, C, D, names, (control,), names, 0.0,
                       {"source": str(fmu), "mapping": str(mapping) if mapping else None})
