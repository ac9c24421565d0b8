"""A scenario's signals as an FMU, so that an SSP carries the scenario itself: the reference the
controller sees, the measurement noise on each fed-back signal and the disturbances at the
plant's inputs, one row per control sample, exactly as the master draws them (the same seed, the
same numbers). The FMU is ``fmu_src/source`` built by the project's exporter; ``export-ssp``
wires its outputs to the controller (``r``, ``n_<signal>``) and the plant (its disturbance
inputs).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from furuta_cosim.errors import ConfigError

REFERENCE = "r"


def noise_input(signal: str) -> str:
    """The controller FMU's input that adds measurement noise to ``signal``."""
    return f"n_{signal}"


@dataclass(frozen=True)
class SourceSpec:
    """What ``fmu_src/source/model.py`` declares: its outputs (name, unit, description), one
    row of values per sample of ``period``."""

    identifier: str
    description: str
    period: float
    outputs: tuple
    rows: tuple


@dataclass(frozen=True)
class Source:
    """A scenario's source: its plant set (for the exporter) and where each output goes, as
    (output, component, input)."""

    plant: object
    wiring: tuple


def needs_source(prepared) -> bool:
    """Whether the loop needs more than a constant reference: a reference that changes, noise,
    or disturbances."""
    rbar = prepared.rbar
    return (len(rbar) > 0 and bool(np.any(rbar != rbar[0]))) or bool(prepared.noisy) \
        or bool(len(prepared.disturbances))


def scenario_source(prepared, name: str) -> Source:
    """The source of ``prepared`` (a scenario the master prepared): its table and wiring."""
    from furuta_cosim.fmu.plants import PlantSet

    converted = [k for k in prepared.disturbance_inputs if k in prepared.conversions]
    if converted:
        raise ConfigError([f"{prepared.source}: disturbances: the plant's input {converted[0]} is converted "
                           "between the scenario's units and the FMU's: a source would need that conversion too"])
    unit = prepared.units.get(prepared.tracked, "")
    columns = [(REFERENCE, unit, f"reference for {prepared.tracked}, each control sample")]
    values = [np.asarray(prepared.rbar, dtype=float)]
    wiring = [(REFERENCE, "controller", REFERENCE)]
    for j, signal in enumerate(prepared.noisy):
        columns.append((noise_input(signal), prepared.units.get(signal, ""),
                        f"measurement noise on {signal} (seed {prepared.scenario.noise.seed})"))
        values.append(prepared.measurement_noise[:, j])
        wiring.append((noise_input(signal), "controller", noise_input(signal)))
    for j, (view, fmu_input) in enumerate(zip(prepared.disturbances, prepared.disturbance_inputs)):
        output = f"d_{fmu_input}"
        columns.append((output, prepared.units.get(view, ""), f"disturbance at the plant's {fmu_input}"
                        + (" (process noise and pulses)" if prepared.scenario.noise else " (pulses)")))
        values.append(prepared.disturbance[:, j])
        wiring.append((output, "plant", fmu_input))
    table = np.column_stack(values)
    if not np.all(np.isfinite(table)):
        raise ConfigError([f"{prepared.source}: the scenario's signals are not all finite"])
    identifier = "Source" + "".join(part.capitalize() for part in re.split(r"[^0-9A-Za-z]+", name) if part)
    spec = SourceSpec(identifier, f"the signals of scenario {name}, one row each {prepared.control_period:g} s",
                      float(prepared.control_period), tuple(columns),
                      tuple(tuple(float(v) for v in row) for row in table))
    plant = PlantSet(name, Path(f"{name}-source"), "source", spec.description, linear=spec)
    return Source(plant, tuple(wiring))


def same_signals(one, other) -> bool:
    """Whether two prepared variants of a scenario feed the loop the same signals."""
    return (np.array_equal(one.rbar, other.rbar) and np.array_equal(one.measurement_noise, other.measurement_noise)
            and np.array_equal(one.disturbance, other.disturbance) and one.noisy == other.noisy
            and list(one.disturbance_inputs) == list(other.disturbance_inputs))
