"""Named linear models for control design.

- ``paper-printed``: the paper's printed (A, B, C) (``scenarios/plants/paper-printed.yaml``);
- ``derived`` or ``derived:<parameter set>``: the linearization of the plant FMU at the
  upright equilibrium, input V, outputs the ones its model declares measured (the paper's C);
- ``toy``: the paper's discrete toy plant;
- any linear plant file (``model: linear``), by name in ``scenarios/plants`` or by path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from furuta_cosim.design.linear import LinearModel
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import load_plant

def load_model(name: str | Path = "paper-printed", beside: Path | None = None) -> LinearModel:
    """Resolve a model name or file to a :class:`LinearModel` (see the module docstring);
    ``beside``: the folder of the file that names it, where names and relative paths are
    looked up first."""
    text = str(name)
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
    result = linearize(build_fmu(plant), parameters=dict(plant.parameters), inputs={inputs[0]: 0.0},
                       outputs=list(model.measured) or None)
    name = "derived" if plant.name == "paper-calibrated" else f"derived:{plant.name}"
    return LinearModel(name, result.A, result.B, result.C, result.D, tuple(result.states),
                       tuple(result.inputs), tuple(result.outputs), 0.0,
                       {"linearized": plant.name})


def linearize_plant(parameter_set: str | Path, inputs=None):
    """The plant FMU of ``parameter_set`` built and linearized at its start state with the
    ``inputs`` named (all, when None) at 0; returns (plant, fmu path, Linearization)."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.linearize import linearize

    plant = load_plant(parameter_set)
    fmu = build_fmu(plant)
    result = linearize(fmu, parameters=dict(plant.parameters),
                       inputs={name: 0.0 for name in inputs} if inputs else None)
    return plant, fmu, result
