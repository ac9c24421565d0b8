"""Checks of an FMU by engines we did not write: fmpy's validation and simulation, and Ecos.

``validate(path)`` returns a list of :class:`Finding` (name, ok, detail); the CLI prints them
and exits non-zero if any failed. ``run_fmpy`` and ``run_ecos`` run an FMU open loop with
constant inputs so that their outputs can be compared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from furuta_cosim.errors import FmuError
from furuta_cosim.fmu.session import FmuBinary, PlantSession


@dataclass(frozen=True)
class Finding:
    check: str
    ok: bool | None  # None: not run (the engine is not installed)
    detail: str


def run_fmpy(fmu: str | Path, start_values: Mapping[str, float], outputs: Sequence[str],
             stop_time: float, step: float) -> np.ndarray:
    """Outputs at every communication point after the start, by fmpy's co-simulation loop."""
    from fmpy import simulate_fmu

    result = simulate_fmu(str(fmu), stop_time=stop_time, step_size=step, output_interval=step,
                          start_values=dict(start_values), output=list(outputs),
                          fmi_type="CoSimulation")
    return np.array([[row[name] for name in outputs] for row in result[1:]])


def ecos_available() -> str | None:
    """None when Ecos can run, else why not."""
    try:
        import ecospy  # noqa: F401  (loads the engine's shared library)
    except ImportError:
        return "ecospy is not installed (pip install ecospy)"
    except OSError as error:
        return f"ecospy cannot load its engine ({error}); install Debian's libtbb12"
    return None


def run_ecos(fmu: str | Path, start_values: Mapping[str, float], outputs: Sequence[str],
             stop_time: float, step: float) -> np.ndarray:
    """The same run in Ecos, a C++ co-simulation engine."""
    from ecospy import EcosSimulation, EcosSimulationStructure

    steps = int(round(stop_time / step))
    rows = []
    with EcosSimulationStructure() as structure:
        structure.add_model("plant", str(Path(fmu).resolve()))
        structure.add_parameter_set("initial", {f"plant::{k}": float(v) for k, v in start_values.items()})
        with EcosSimulation(structure=structure, step_size=step) as simulation:
            simulation.init(parameter_set="initial")
            for _ in range(steps):
                simulation.step()
                rows.append([simulation.get_real(f"plant::{name}") for name in outputs])
            simulation.terminate()
    return np.array(rows)


def run_ecos_connected(fmus: Mapping[str, str | Path], connections: Sequence[tuple[str, str]],
                       start_values: Mapping[str, float], outputs: Sequence[str],
                       steps: int, step: float) -> np.ndarray:
    """Several FMUs connected output to input (``("plant::theta0", "controller::theta0")``)
    in Ecos: the ``outputs`` (``instance::variable``) at t = 0 and before each later step,
    ``steps`` rows. Ecos steps every FMU, then copies every connected output to its input."""
    from ecospy import EcosSimulation, EcosSimulationStructure

    rows = []
    with EcosSimulationStructure() as structure:
        for name, fmu in fmus.items():
            structure.add_model(name, str(Path(fmu).resolve()))
        for source, sink in connections:
            structure.make_real_connection(source, sink)
        structure.add_parameter_set("initial", {k: float(v) for k, v in start_values.items()})
        with EcosSimulation(structure=structure, step_size=step) as simulation:
            simulation.init(parameter_set="initial")
            for _ in range(steps):
                rows.append([simulation.get_real(name) for name in outputs])
                simulation.step()
            simulation.terminate()
    return np.array(rows)


def validate(fmu: str | Path) -> list[Finding]:
    """fmpy validation, a smoke run in our session and in fmpy, and a cross-check in Ecos."""
    from fmpy.validation import validate_fmu

    fmu = Path(fmu)
    findings = []
    if not fmu.is_file():
        return [Finding("file", False, f"{fmu}: no such file")]
    problems = validate_fmu(str(fmu))
    findings.append(Finding("fmpy validate", not problems,
                            "no problems" if not problems else "; ".join(problems)))
    if problems:
        return findings
    try:
        with FmuBinary(fmu) as binary:
            md = binary.model_description
            step = float(md.defaultExperiment.stepSize) if md.defaultExperiment and md.defaultExperiment.stepSize else 1e-3
            outputs = [v.name for v in md.modelVariables if v.causality == "output"]
            with PlantSession(binary) as session:
                session.reset()
                session.set_io([], outputs)
                values = [session.step([], step) for _ in range(100)]
            finite = all(math.isfinite(v) for row in values for v in row)
            findings.append(Finding("smoke run (100 steps, PlantSession)", finite,
                                    f"{len(outputs)} outputs finite" if finite else "non-finite outputs"))
    except FmuError as error:
        findings.append(Finding("smoke run (100 steps, PlantSession)", False, str(error)))
        return findings
    stop = 100 * step
    try:
        reference = run_fmpy(fmu, {}, outputs, stop, step)
        findings.append(Finding("fmpy simulate_fmu", bool(np.all(np.isfinite(reference))),
                                f"{len(reference)} steps"))
    except Exception as error:  # fmpy raises bare Exceptions
        findings.append(Finding("fmpy simulate_fmu", False, str(error)))
        return findings
    reason = ecos_available()
    if reason:
        findings.append(Finding("Ecos", None, f"not run: {reason}"))
        return findings
    try:
        other = run_ecos(fmu, {}, outputs, stop, step)
        difference = relative_difference(other, reference)
        findings.append(Finding("Ecos (same run as fmpy)", difference <= 1e-12,
                                f"max relative difference {difference:.2e} (limit 1e-12)"))
    except Exception as error:  # ecospy raises bare Exceptions
        findings.append(Finding("Ecos (same run as fmpy)", False, str(error)))
    return findings


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape:
        return math.inf
    # relative to each output's largest magnitude over the run
    scale = np.maximum(np.max(np.abs(b), axis=0), 1e-300)
    return float(np.max(np.abs(a - b) / scale, initial=0.0))
