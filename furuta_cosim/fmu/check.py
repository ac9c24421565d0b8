"""Checks of an FMU by engines we did not write: fmpy's validation and simulation, and Ecos.

``validate(path)`` returns a list of :class:`Finding` (name, ok, detail); the CLI prints them
and exits non-zero if any failed. ``run_fmpy`` and ``run_ecos`` run an FMU open loop with
constant inputs so that their outputs can be compared. In ``validate`` every run of the FMU's
binary (our smoke run, fmpy's, Ecos's) is contained in a child process
(:mod:`furuta_cosim.fmu.contained`): a crash or a hang is that check's verdict, the other
checks still report, and nothing is left in the temporary directory. The zip is checked
before anything extracts it (:mod:`furuta_cosim.fmu.archive`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from furuta_cosim.errors import FmuError
from furuta_cosim.fmu.archive import check_archive
from furuta_cosim.fmu.contained import EngineFailed, contained
from furuta_cosim.fmu.session import FmuBinary, PlantSession, model_description
from furuta_cosim.fmu.variables import declared_conversion, dimension_problem, is_real, unit_problems


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
        return "ecospy is not installed (the ecos extra: pip install -e '.[ecos]')"
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
    """Several FMUs connected output to input (``("plant::y", "controller::y")``)
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


def validate(fmu: str | Path, timeout: float = 120.0) -> list[Finding]:
    """fmpy's validation, then a smoke run in our session and in fmpy and a cross-check in Ecos
    of the floating-point outputs, for FMI 2.0 and 3.0. fmpy's problems are reported as such and
    the runs still run: an FMU that fmpy flags may still run, and the user learns both. Never
    raises: whatever goes wrong is a finding; ``timeout`` bounds each contained run (seconds)."""
    fmu = Path(fmu)
    if not fmu.is_file():
        return [Finding("file", False, f"{fmu}: no such file")]
    findings: list[Finding] = []
    try:
        _validate(fmu, findings, timeout)
    except Exception as error:  # an FMU is hostile input: whatever it does becomes a finding
        findings.append(Finding("unexpected", False, f"{type(error).__name__}: {error}"))
    return findings


def smoke_run(fmu: str | Path, outputs: Sequence[str], step: float, steps: int = 100) -> list:
    """``steps`` steps of ``fmu`` in our session with its start values, the ``outputs`` after each."""
    with FmuBinary(fmu) as binary:
        with PlantSession.for_binary(binary) as session:
            session.reset()
            session.set_io([], outputs)
            return [session.step([], step) for _ in range(steps)]


def _dimensions(md) -> list[str]:
    """The units a session would refuse: a variable named as one of this project's plant
    variables (the view a plant FMU is run in without a mapping) must be in a unit of the same
    quantity (an angle in rad or deg, never mm), as :mod:`furuta_cosim.cosim.master` judges."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.plants import load_plant

    ours = {v.name: v.unit for v in model_description(build_fmu(load_plant())).modelVariables}
    found = []
    for v in md.modelVariables:
        if is_real(v) and v.name in ours:
            problem = dimension_problem(md, v, ours[v.name])
            if problem:
                found.append(f"{problem} (the plant's {v.name}: a session refuses it without a "
                             "mapping that scales it)")
    return found


def _validate(fmu: Path, findings: list[Finding], timeout: float) -> None:
    from fmpy.validation import validate_fmu

    try:
        check_archive(fmu)
    except FmuError as error:
        findings.append(Finding("zip", False, str(error)))
        return
    try:
        problems = validate_fmu(str(fmu))
    except Exception as error:  # fmpy raises bare Exceptions
        problems = [str(error)]
    findings.append(Finding("fmpy validate", not problems,
                            "no problems" if not problems else "; ".join(problems)))
    try:
        md = model_description(fmu)
    except FmuError as error:
        findings.append(Finding("model description", False, str(error)))
        return
    variables = md.modelVariables
    problems = unit_problems(md) or _dimensions(md)
    converted = []
    for v in variables if not problems else ():
        conversion = declared_conversion(md, v) if is_real(v) else None
        if conversion:
            converted.append(f"{v.name} by {conversion[0]:g}" + (f" + {conversion[1]:g}" if conversion[1] else ""))
    findings.append(Finding("units", not problems, "; ".join(problems) if problems else
                            (f"converted to SI: {', '.join(converted)}" if converted else "no conversions")))
    outputs = [v.name for v in variables if v.causality == "output" and is_real(v)]
    others = {}
    for v in variables:
        if v.causality == "output" and not is_real(v):
            kind = f"{v.type} array" if getattr(v, "dimensions", None) else v.type
            others[kind] = others.get(kind, 0) + 1
    unread = ", ".join(f"{n} {kind}" for kind, n in sorted(others.items()))
    described = f"FMI {md.fmiVersion}, " + ", ".join(
        name for name, part in (("co-simulation", md.coSimulation), ("model exchange", md.modelExchange),
                                ("scheduled execution", md.scheduledExecution)) if part is not None)
    clocks = sum(1 for v in variables if v.type == "Clock")
    runnable = md.coSimulation is not None or md.modelExchange is not None
    findings.append(Finding("interfaces", runnable and not clocks, described
                            + (f"; {clocks} clock(s): clocked FMUs are refused" if clocks else "")
                            + ("" if runnable else ": no co-simulation or model exchange, nothing can run it")))
    smoke = "smoke run (100 steps, PlantSession)"
    if md.coSimulation is None:
        findings.append(Finding(smoke, None, "not run: the smoke runs need co-simulation"
                                + (" (scheduled execution, with clocks, is not supported)"
                                   if md.scheduledExecution else "")))
        return
    step = float(md.defaultExperiment.stepSize) if md.defaultExperiment and md.defaultExperiment.stepSize else 1e-3
    try:
        values = contained(smoke_run, fmu, outputs, step, engine="PlantSession", timeout=timeout)
        finite = all(math.isfinite(v) for row in values for v in row)
        findings.append(Finding(smoke, finite, (f"{len(outputs)} floating-point outputs finite" if finite
                                                else "non-finite outputs")
                                + (f" ({unread} outputs not read)" if unread else "")))
    except FmuError as error:
        findings.append(Finding(smoke, False, str(error)))
    # each engine is asked whatever the one before said: a crash in one is its own verdict
    stop, reference = 100 * step, None
    try:
        reference = contained(run_fmpy, fmu, {}, outputs, stop, step, engine="fmpy", timeout=timeout)
        findings.append(Finding("fmpy simulate_fmu", bool(np.all(np.isfinite(reference))),
                                f"{len(reference)} steps"))
    except EngineFailed as error:
        findings.append(Finding("fmpy simulate_fmu", False, str(error)))
    reason = ecos_available()
    if reason:
        findings.append(Finding("Ecos", None, f"not run: {reason}"))
        return
    try:
        other = contained(run_ecos, fmu, {}, outputs, stop, step, engine="Ecos", timeout=timeout)
        if reference is None:
            finite = bool(np.all(np.isfinite(other)))
            findings.append(Finding("Ecos", finite, f"{len(other)} steps, {'finite' if finite else 'non-finite'} "
                                    "outputs (fmpy gave nothing to compare with)"))
        else:
            difference = relative_difference(other, reference)
            findings.append(Finding("Ecos (same run as fmpy)", difference <= 1e-12,
                                    f"max relative difference {difference:.2e} (limit 1e-12)"))
    except EngineFailed as error:
        findings.append(Finding("Ecos" if reference is None else "Ecos (same run as fmpy)", False, str(error)))


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape:
        return math.inf
    # relative to each output's largest magnitude over the run
    scale = np.maximum(np.max(np.abs(b), axis=0), 1e-300)
    return float(np.max(np.abs(a - b) / scale, initial=0.0))
