"""Linearization of an FMU at an operating point, by central finite differences.

Continuous plants are linearized through their model-exchange interface: states are set,
derivatives read, so no integration error enters. Each state or input j is perturbed by

    delta_j = eps**(1/3) * max(1, |z_j|)   (about 6e-6 for values of order one)

which balances the O(delta^2) truncation error of central differences against the
O(eps/delta) rounding error; entries come out with about 10 correct digits. Discrete plants
are linearized through one sample period of co-simulation; their map is affine, so any
perturbation gives the exact matrices up to rounding (delta_j = 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from furuta_cosim.errors import FmuError
from furuta_cosim.fmu.session import FmuBinary, PlantSession
from furuta_cosim.signals import start_parameter

_DELTA = np.finfo(float).eps ** (1.0 / 3.0)


@dataclass(frozen=True)
class Linearization:
    """(A, B, C, D) with the names of their rows and columns; ``period`` > 0 when discrete."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: list[str]
    inputs: list[str]
    outputs: list[str]
    period: float = 0.0

    def as_dict(self) -> dict:
        return {"A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                "D": self.D.tolist(), "states": self.states, "inputs": self.inputs,
                "outputs": self.outputs, "period": self.period}


def linearize(fmu: str | Path, parameters: Mapping[str, float] | None = None,
              state: Mapping[str, float] | None = None, inputs: Mapping[str, float] | None = None,
              outputs: Sequence[str] | None = None) -> Linearization:
    """Linearize ``fmu`` at the operating point (``state``, ``inputs``).

    Parameters
    ----------
    fmu : path
    parameters : mapping, optional
        Parameter values (for example a parameter set) applied before initialization.
    state : mapping, optional
        State values at the operating point; the others take their start values.
    inputs : mapping, optional
        Input values at the operating point (the others are 0); their order gives B's columns.
        By default every Real input, in declaration order.
    outputs : sequence of str, optional
        Rows of C and D; by default every output that is not a state... plus the states.
    """
    with FmuBinary(fmu) as binary:
        md = binary.model_description
        all_inputs = [v.name for v in md.modelVariables if v.causality == "input" and v.type in ("Real", "Float64")]
        input_names = list(inputs) if inputs else all_inputs
        u0 = np.array([float((inputs or {}).get(n, 0.0)) for n in input_names])
        output_names = list(outputs) if outputs else [
            v.name for v in md.modelVariables if v.causality == "output"]
        states = binary.states
        for name in (state or {}):
            if name not in states:
                raise FmuError(f"{binary.identifier}: {name!r} is not a state (states: {', '.join(states)})")
        start = dict(parameters or {})
        start.update({start_parameter(name): value for name, value in (state or {}).items()})
        if md.modelExchange is not None:
            return _continuous(binary, start, states, input_names, u0, output_names)
        period = float(md.defaultExperiment.stepSize) if md.defaultExperiment else 1.0
        if parameters and "Ts" in parameters:
            period = parameters["Ts"]
        return _discrete(binary, start, states, input_names, u0, output_names, float(period))


def _continuous(binary, start, states, input_names, u0, output_names) -> Linearization:
    with PlantSession.for_binary(binary, interface="ModelExchange") as session:
        session.reset(start)
        x0 = np.array(session.get(states))

        def evaluate(x, u):
            session.set(dict(zip(input_names, u)))
            dx = session.derivatives(x)
            return np.array(dx), np.array(session.get(output_names))

        return _differences(evaluate, x0, u0, states, input_names, output_names, _DELTA, 0.0)


def _discrete(binary, start, states, input_names, u0, output_names, period) -> Linearization:
    with PlantSession.for_binary(binary) as session:
        session.reset(start)
        x0 = np.array(session.get(states))
        session.set_io(input_names, list(states))

        def evaluate(x, u):
            session.reset({**start, **{start_parameter(n): v for n, v in zip(states, x)}})
            session.set(dict(zip(input_names, u)))
            y = np.array(session.get(output_names))
            return np.array(session.step(list(u), period)), y

        return _differences(evaluate, x0, u0, states, input_names, output_names, None, period)


def _differences(evaluate, x0, u0, states, input_names, output_names, relative, period):
    z0 = np.concatenate([x0, u0])
    nx = len(x0)
    columns_f, columns_g = [], []
    for j in range(len(z0)):
        delta = relative * max(1.0, abs(z0[j])) if relative else 1.0
        plus, minus = z0.copy(), z0.copy()
        plus[j] += delta
        minus[j] -= delta
        f_plus, g_plus = evaluate(plus[:nx], plus[nx:])
        f_minus, g_minus = evaluate(minus[:nx], minus[nx:])
        columns_f.append((f_plus - f_minus) / (2 * delta))
        columns_g.append((g_plus - g_minus) / (2 * delta))
    jf = np.array(columns_f).T.reshape(nx, len(z0))
    jg = np.array(columns_g).T.reshape(len(output_names), len(z0))
    if not (np.all(np.isfinite(jf)) and np.all(np.isfinite(jg))):
        raise FmuError("the linearization is not finite at this operating point and these parameters")
    return Linearization(jf[:, :nx], jf[:, nx:], jg[:, :nx], jg[:, nx:], list(states),
                         list(input_names), list(output_names), period)
