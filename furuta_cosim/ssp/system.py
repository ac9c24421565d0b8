"""An SSP run as its system says: its components' FMUs (ours or another tool's), its
connections, the parameter sets it binds and its default experiment, stepped by a Jacobi
master (every component steps from the values all of them had at the start of the step, then
every connection copies its output to its input), the exchange Ecos and libcosim make.

What :func:`load_system` checks before anything runs, each a line naming the archive, the
entry and what was expected (:class:`~furuta_cosim.errors.ConfigError`, exit 2):

- the description: SSP 1.0 with its ``version``, valid against the standard's schemas where
  ``pyssp-standard`` is installed (else said: not validated);
- each component: a co-simulation FMU (FMI 2.0 or 3.0); each connector a variable of it, of the
  kind (input, output, parameter) and unit that variable declares, a Real;
- each connection: from an output to an input of components that exist, along connectors they
  declare; at most one connection into an input; the system's own connectors are not driven;
- each input connector either connected or given a value by the chosen parameter set: an input
  left to its start value is where the system was cut, not a choice;
- the parameter set chosen by name, each of its values a parameter (or input) of that FMU in
  its type and unit; a name the FMU lacks is ignored and warned, as the standard says;
- the default experiment: its stop time, its step (the Open Simulation Platform's
  ``FixedStepAlgorithm`` annotation, which Ecos and libcosim read).

:func:`run_system` steps it: ``order=None`` is Jacobi; a list of component names steps them one
after the other, each from the values the ones before it just produced (Gauss-Seidel): a
different loop where a connection closes one, measured on the SSP page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.ssp.common import ENTRY, SSC, SSD, is_real, schema_problems, unit_of, variables_of
from furuta_cosim.ssp.read import accepted, default_experiment, open_archive, set_values

# a run of more steps than this is refused before it starts (memory: a row per step)
MAX_STEPS = 10_000_000
KINDS = {"input": "input", "output": "output", "parameter": "parameter",
         "calculatedParameter": "calculatedParameter"}


@dataclass
class Part:
    """One component: its name, extracted FMU, model description, declared connectors
    (name -> kind) and the values its chosen parameter set gives (name -> number)."""

    name: str
    fmu: Path
    md: object
    kinds: dict
    parameters: dict = field(default_factory=dict)
    set_name: str | None = None


@dataclass
class System:
    """An SSP's system, checked (:func:`load_system`): its parts by name, its connections
    ((element, connector) -> (element, connector)), the experiment (start, stop, step), what was
    read and ignored (``warnings``) and whether the schemas checked it (``validated``)."""

    path: Path
    parts: dict
    connections: list
    start: float
    stop: float
    step: float
    warnings: list = field(default_factory=list)
    validated: bool | None = None

    @property
    def steps(self) -> int:
        return int(round((self.stop - self.start) / self.step))

    def describe(self) -> str:
        parts = ", ".join(f"{p.name} ({p.fmu.name}, FMI {p.md.fmiVersion}"
                          + (f", set {p.set_name}" if p.set_name else "") + ")" for p in self.parts.values())
        return (f"{self.path}: {len(self.parts)} components: {parts}; {len(self.connections)} connections; "
                f"{self.start:g} to {self.stop:g} s in steps of {self.step:g} s")


@dataclass
class SystemRun:
    """The values of a run: ``t`` (the communication points, start to stop) and, for each
    connected connector and each output, ``values["element.connector"]`` at those times (an
    input: the value it steps from)."""

    t: np.ndarray
    values: dict
    order: str

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]


class SystemFailed(Exception):
    """A component failed or gave a value that is not finite: which, where and when."""


def load_system(path: str | Path, parameter_set: str | None = None, *,
                folder: str | Path | None = None) -> System:
    """Read and check the SSP at ``path`` (module docstring) with the parameter set named
    ``parameter_set`` (default: each component's first binding).

    Raises
    ------
    ConfigError
        One line naming the archive, the entry and the problem.
    """
    archive = open_archive(path, folder)
    fail, root = archive.fail, archive.root
    if not root.get("version"):
        raise fail(ENTRY, "ssd:SystemStructureDescription has no version (SSP 1.0 requires version=\"1.0\")")
    documents = {ENTRY: archive.read(ENTRY)}
    parts = {}
    for name, (component, target, md) in archive.described.items():
        if md.coSimulation is None:
            raise fail(ENTRY, f"component {name}: its FMU has no co-simulation interface (the master steps "
                              "co-simulation FMUs)")
        if md.fmiVersion not in ("2.0", "3.0"):
            raise fail(ENTRY, f"component {name}: an FMI {md.fmiVersion} FMU (FMI 2.0 and 3.0 are run)")
        variables = variables_of(md)
        kinds = {}
        for connector in component.iterfind(f"{{{SSD}}}Connectors/{{{SSD}}}Connector"):
            cname, kind = connector.get("name"), connector.get("kind")
            v = variables[cname]
            where = f"component {name}: connector {cname!r}"
            if kind not in KINDS:
                raise fail(ENTRY, f"{where}: kind {kind!r}; expected one of {', '.join(KINDS)}")
            if v.causality != KINDS[kind]:
                raise fail(ENTRY, f"{where} is kind {kind}, where its FMU declares it {v.causality}")
            typed = [c for c in connector if c.tag.startswith(f"{{{SSC}}}")]
            if typed and typed[0].tag != f"{{{SSC}}}Real" or not is_real(v):
                raise fail(ENTRY, f"{where}: not a Real (its FMU: {v.type}); the master exchanges Real values")
            unit = typed[0].get("unit") if typed else None
            if unit is not None and unit != (unit_of(v) or None):
                raise fail(ENTRY, f"{where} is in {unit}, where its FMU declares {unit_of(v) or 'no unit'} "
                                  "(no conversion is applied)")
            kinds[cname] = kind
        sets = archive.sets(name)
        names = [ssv.get("name") or "" for _, ssv in sets]
        parameters, chosen = {}, None
        if sets:
            if parameter_set is not None and parameter_set not in names:
                raise fail(None, f"no parameter set {parameter_set!r} for component {name} "
                                 f"(it has: {', '.join(names)})")
            k = names.index(parameter_set) if parameter_set is not None else 0
            source, ssv = sets[k]
            chosen = names[k]
            if source != ENTRY:
                documents[source] = archive.read(source)
            parameters = set_values(ssv, source, md, fail, archive.warnings)
            accepted(target, parameters, fail, source, name, chosen)
        parts[name] = Part(name, target, md, kinds, parameters, chosen)
    if parameter_set is not None and not any(p.set_name == parameter_set for p in parts.values()):
        raise fail(None, f"no component binds a parameter set {parameter_set!r}")
    problems = schema_problems(documents)
    if problems:
        raise fail(None, f"not valid against the SSP 1.0 schemas: {problems[0]}")
    connections = _connections(root, parts, fail)
    _every_input_fed(parts, connections, fail)
    stop, step = default_experiment(root, fail)
    experiment = root.find(f"{{{SSD}}}DefaultExperiment")
    try:
        start = float(experiment.get("startTime", 0.0)) if experiment is not None else 0.0
    except ValueError:
        raise fail(ENTRY, "ssd:DefaultExperiment: startTime is not a number") from None
    if stop is None:
        raise fail(ENTRY, "no ssd:DefaultExperiment with a stopTime: nothing says how long the system runs")
    if step is None:
        raise fail(ENTRY, "no step size: the master steps at the ssd:DefaultExperiment's "
                          "osp:FixedStepAlgorithm baseStepSize, which this archive does not give")
    if not (math.isfinite(start) and stop > start):
        raise fail(ENTRY, f"ssd:DefaultExperiment: stopTime {stop:g} is not after startTime {start:g}")
    if (stop - start) / step > MAX_STEPS:
        raise fail(ENTRY, f"{(stop - start) / step:.3g} steps (at most {MAX_STEPS})")
    return System(Path(path), parts, connections, start, stop, step, archive.warnings,
                  validated=problems is not None)


def _connections(root, parts: dict, fail) -> list:
    found, into = [], {}
    system = root.find(f"{{{SSD}}}System")
    own = {c.get("name") for c in system.iterfind(f"{{{SSD}}}Connectors/{{{SSD}}}Connector")}
    for connection in system.iterfind(f"{{{SSD}}}Connections/{{{SSD}}}Connection"):
        ends = []
        for side in ("start", "end"):
            element, connector = connection.get(f"{side}Element"), connection.get(f"{side}Connector")
            ends.append((element, connector))
        text = " -> ".join(f"{e}.{c}" if e else f"(system).{c}" for e, c in ends)
        where = f"connection {text}"
        for (element, connector), side, wanted in zip(ends, ("start", "end"), (("output", "calculatedParameter",
                                                                               "parameter"), ("input",))):
            if not connector:
                raise fail(ENTRY, f"{where}: no {side}Connector")
            if element is None:
                if connector not in own:
                    raise fail(ENTRY, f"{where}: the system has no connector {connector!r}")
                if side == "start":
                    raise fail(ENTRY, f"{where}: starts at the system's own connector, which nothing here drives")
                continue
            if element not in parts:
                raise fail(ENTRY, f"{where}: no element {element!r} (the system has: {', '.join(parts)})")
            kind = parts[element].kinds.get(connector)
            if kind is None:
                raise fail(ENTRY, f"{where}: component {element} declares no connector {connector!r}")
            if kind not in wanted:
                raise fail(ENTRY, f"{where}: its {side} is the {kind} {element}.{connector}; a connection runs "
                                  "from an output to an input")
        start, end = ends
        if end[0] is None:
            continue   # into the system's own output: nothing to run
        units = [unit_of(variables_of(parts[e].md)[c]) for e, c in ends]
        if units[0] and units[1] and units[0] != units[1]:
            raise fail(ENTRY, f"{where}: from {units[0]} to {units[1]} (no conversion is applied)")
        if end in into:
            raise fail(ENTRY, f"{where}: {end[0]}.{end[1]} is already fed by {into[end][0]}.{into[end][1]}")
        into[end] = start
        found.append((start, end))
    return found


def _every_input_fed(parts: dict, connections: list, fail) -> None:
    fed = {end for _, end in connections}
    for part in parts.values():
        for connector, kind in part.kinds.items():
            if kind == "input" and (part.name, connector) not in fed and connector not in part.parameters:
                raise fail(ENTRY, f"component {part.name}: input {connector!r} is connected to nothing and no "
                                  "parameter set gives it a value: the system would run it at its start value; "
                                  "connect it, or bind its value")


def run_system(system: System, order: Sequence[str] | None = None,
               progress: Callable[[int, int], None] | None = None) -> SystemRun:
    """Step ``system`` from its start to its stop (module docstring): Jacobi when ``order`` is
    None, else Gauss-Seidel in the order given.

    Raises
    ------
    SystemFailed
        A component's step failed, or one of its values is not finite: which, and when.
    """
    from furuta_cosim.fmu.session import PlantSession

    if order is not None and sorted(order) != sorted(system.parts):
        raise ConfigError([f"order: expected each component once ({', '.join(system.parts)}), got {list(order)}"])
    sources = {end: start for start, end in system.connections}
    inputs = {name: [c for c, k in part.kinds.items() if (name, c) in sources] for name, part in system.parts.items()}
    starts = {start for start, _ in system.connections}
    outputs = {name: sorted({c for e, c in starts if e == name} | {c for c, k in part.kinds.items() if k == "output"})
               for name, part in system.parts.items()}
    names = [f"{n}.{c}" for n in system.parts for c in outputs[n]]
    names += [f"{n}.{c}" for n in system.parts for c in inputs[n] if f"{n}.{c}" not in names]
    steps, h = system.steps, system.step
    rows = np.empty((steps + 1, len(names)))
    sessions = {}
    try:
        current = {}
        for name, part in system.parts.items():
            session = sessions[name] = PlantSession.open(part.fmu)
            try:
                session.reset(part.parameters, start_time=system.start)
                session.set_io(inputs[name], outputs[name])
                current.update(((name, c), v) for c, v in zip(outputs[name], session.get(outputs[name])))
            except FmuError as error:
                raise SystemFailed(f"component {name}: at its start: {error}") from None
        column = {n: k for k, n in enumerate(names)}
        sequence = list(order) if order is not None else list(system.parts)

        def record(k: int) -> None:
            for (e, c), v in current.items():
                rows[k, column[f"{e}.{c}"]] = v
            for name in system.parts:
                for c in inputs[name]:
                    rows[k, column[f"{name}.{c}"]] = current[sources[(name, c)]]
            bad = ~np.isfinite(rows[k])
            if bad.any():
                raise SystemFailed(f"{names[int(np.argmax(bad))]} is {rows[k, int(np.argmax(bad))]} at "
                                   f"t = {system.start + k * h:g} s: the run stopped there")

        record(0)
        for k in range(steps):
            new = {}
            for name in sequence:
                held = current if order is None else {**current, **new}
                try:
                    values = sessions[name].step([held[sources[(name, c)]] for c in inputs[name]], h)
                except FmuError as error:
                    raise SystemFailed(f"component {name}: the step from t = {system.start + k * h:g} s "
                                       f"failed: {error}") from None
                new.update(((name, c), v) for c, v in zip(outputs[name], values))
            current.update(new)
            record(k + 1)
            if progress is not None and (k + 1) % 1000 == 0:
                progress(k + 1, steps)
    finally:
        for session in sessions.values():
            session.close()
    t = system.start + h * np.arange(steps + 1)
    return SystemRun(t, {n: rows[:, k] for k, n in enumerate(names)},
                     "Jacobi" if order is None else "Gauss-Seidel: " + ", ".join(order))


def save_run(system: System, run: SystemRun, folder: str | Path) -> list[Path]:
    """The run as ``system.csv`` (time, then each value, named ``element.connector``) and a
    figure of each component's outputs (``system.png``, ``.svg``) in ``folder``, atomically."""
    from furuta_cosim.files import output_folder, write_text
    from furuta_cosim.report.figures import plot_system

    folder = output_folder(folder)
    names = list(run.values)
    table = np.column_stack([run.t, *[run.values[n] for n in names]])
    lines = [",".join(["time", *names])] + [",".join(repr(float(v)) for v in row) for row in table]
    written = [write_text(folder / "system.csv", "\n".join(lines) + "\n")]
    outputs = {n: run.values[n] for n in names
               if system.parts[n.split(".", 1)[0]].kinds.get(n.split(".", 1)[1]) == "output"}
    written += plot_system(run.t, outputs, folder / "system", f"{system.path.name} ({run.order})")
    return written
