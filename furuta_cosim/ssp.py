"""The closed loop as an SSP (System Structure and Parameterization 1.0, Modelica Association):
one ``.ssp`` archive that other co-simulation tools (Ecos, libcosim, OMSimulator, ...) run.

An exported archive holds::

    SystemStructure.ssd          the system: components, connectors, connections, the default
                                 experiment (start, stop; the step as libcosim's annotation)
    resources/plant.fmu          the plant FMU (the first plant's build; FMI 2.0 or 3.0)
    resources/controller.fmu     the controller FMU (export-controller's, one sample late)
    resources/source.fmu         the scenario's reference, noise and disturbances, one row per
                                 sample (when it has more than a constant reference)
    resources/SET.ssv            each plant's parameter set: every parameter of the plant FMU
                                 with its unit, and the scenario's start state
    resources/controller-SET.ssv the controller's reference, once per set (a tool that applies
                                 one named set, as Ecos does, gets the whole loop from it)
    resources/furuta-cosim/      the scenario and the controller file it came from (provenance;
                                 ``simulate LOOP.ssp`` runs the system: ssp_system.py)

Each component binds its sets in order, the first the default (libcosim applies a component's
first binding when no set is named; Ecos applies the set named at its ``init``). The loop is
the Ecos loop of the controller FMU (``export.ecos_closed_loop``): each step every FMU steps,
then every output is copied to its input (Jacobi); the controller holds its command one sample,
so that exchange runs the master's one-sample-delayed loop (a Gauss-Seidel master, one FMU after
the other, runs another: docs' SSP page).

:func:`read_ssp` reads an archive (ours or another tool's) as hostile input: the entries it
reads must lie inside the archive's folder, within size and count limits; the system
description must be well-formed SSP, each connector a variable of its FMU, each parameter a
parameter (or input) of its component's FMU with the type and unit the FMU declares.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree as ET

import numpy as np

from furuta_cosim.errors import ConfigError

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OURS = "org.furuta-cosim"
ENTRY = "SystemStructure.ssd"
# an exported loop's eigenvalue this close above 1 is an integrator (an angle no law holds), not a
# growing mode: measured 1 + 4e-13 for bo-paper on the paper's plant, 1.004 for lqr-qube there
MARGINAL = 1e-9
# a hostile archive: at most this many entries, this many bytes in one entry read, in all
MAX_ENTRIES, MAX_ENTRY, MAX_TOTAL = 1000, 200 * 2**20, 500 * 2**20
SET_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
# SI exponents (kg, m, s, A, K, mol, cd, rad) of the unit symbols the models use
BASE = {"kg": (1, 0, 0, 0, 0, 0, 0, 0), "m": (0, 1, 0, 0, 0, 0, 0, 0), "s": (0, 0, 1, 0, 0, 0, 0, 0),
        "A": (0, 0, 0, 1, 0, 0, 0, 0), "K": (0, 0, 0, 0, 1, 0, 0, 0), "rad": (0, 0, 0, 0, 0, 0, 0, 1),
        "N": (1, 1, -2, 0, 0, 0, 0, 0), "V": (1, 2, -3, -1, 0, 0, 0, 0), "Ohm": (1, 2, -3, -2, 0, 0, 0, 0),
        "H": (1, 2, -2, -2, 0, 0, 0, 0), "W": (1, 2, -3, 0, 0, 0, 0, 0), "J": (1, 2, -2, 0, 0, 0, 0, 0),
        "g": (1, 0, 0, 0, 0, 0, 0, 0)}
EXPONENTS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

for prefix, uri in (("ssd", SSD), ("ssc", SSC), ("ssv", SSV), ("osp", OSP)):
    ET.register_namespace(prefix, uri)


def base_unit(unit: str) -> dict[str, int] | None:
    """The SI exponents of a unit as the models write it (``N.m.s/rad``, ``kg.m2``, ``rad/s/s``),
    or None when a symbol is not one of :data:`BASE`'s. ``g`` is grams only in ``kg``."""
    total = np.zeros(8, dtype=int)
    for k, part in enumerate(unit.split("/")):
        for token in part.split("."):
            found = re.fullmatch(r"([A-Za-z]+)(-?\d*)", token)
            if not found or found.group(1) not in BASE or found.group(1) == "g":
                return None
            power = int(found.group(2) or 1)
            total += (1 if k == 0 else -1) * power * np.array(BASE[found.group(1)])
    return {name: int(e) for name, e in zip(EXPONENTS, total) if e}


@dataclass
class SspPlant:
    """A plant read from an SSP.

    Parameters
    ----------
    fmu : Path
        The plant component's FMU, extracted.
    component : str
        The plant component's name in the system.
    set_name : str or None
        The parameter set applied (None: the component binds none).
    parameters : dict
        That set's values, parameter name -> value (in the FMU's units).
    sets : list of str
        Every set name the component binds, the default first.
    stop : float or None
        The default experiment's stop time (None where the archive says none).
    step : float or None
        Its fixed step, from the Open Simulation Platform's annotation (else None).
    scenario : Path or None
        The scenario file an archive of ours carries, extracted (else None).
    controller : Path or None
        The controller file it carries, extracted (else None).
    warnings : list of str
        What was read and ignored (a parameter the FMU does not have), one line each.
    """

    fmu: Path
    component: str
    set_name: str | None
    parameters: dict = field(default_factory=dict)
    sets: list = field(default_factory=list)
    stop: float | None = None
    step: float | None = None
    scenario: Path | None = None
    controller: Path | None = None
    warnings: list = field(default_factory=list)


# --------------------------------------------------------------------------- writing --------


def export_ssp(scenario, controller: str | Path | None, output: str | Path, *, plants=(),
               fmi_version: str = "2.0", log=None) -> dict:
    """Write the closed loop of ``scenario`` under ``controller`` as an SSP (module docstring).

    Parameters
    ----------
    scenario : Scenario, str or path
        Its plant, start state, reference, noise, disturbances, actuator limit, control period
        and duration (a reference that changes, noise and disturbances through the source FMU:
        furuta_cosim/scenario_source.py); no estimator.
    controller : str or path, optional
        A controller file or name (default: the scenario's first controller).
    output : path
        The ``.ssp`` file to write (atomically).
    plants : sequence of str or path
        Plant files or names, one parameter set each, the first the default (default: the
        scenario's own plant). All must run the scenario's model.
    fmi_version : {"2.0", "3.0"}
        The FMI version of both FMUs.
    log : callable, optional
        Takes one line per build step.

    Returns
    -------
    dict
        ``path``, ``sets`` (names, the default first), ``connections`` (``a.x -> b.y``),
        ``step``, ``stop``, ``reference``, ``validated`` (checked against the standard's
        schemas: False when ``pyssp-standard`` is not installed).

    Raises
    ------
    ConfigError
        Naming what the scenario needs that the archive cannot hold (an estimator), a plant of another
        model, or a name that would not be a file name.
    """
    from furuta_cosim.cosim.master import on_plant, prepare
    from furuta_cosim.export import REFERENCE_INPUT, constant, controller_plant, loop_only
    from furuta_cosim.files import write_bytes
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.fmu.session import model_description
    from furuta_cosim.scenario import load_scenario
    from furuta_cosim.scenario_source import needs_source, same_signals, scenario_source

    if fmi_version not in ("2.0", "3.0"):
        raise ConfigError([f"fmi_version: expected 2.0 or 3.0, got {fmi_version!r}"])
    if isinstance(scenario, (str, Path)):
        scenario = load_scenario(scenario)
    controller = controller or (scenario.controllers[0] if scenario.controllers else None)
    if controller is None:
        raise ConfigError([f"{scenario.source}: names no controller: give one (--controller)"])
    output = Path(output)
    if output.suffix != ".ssp":
        raise ConfigError([f"{output}: an SSP archive's name ends in .ssp"])
    if scenario.estimator:
        raise ConfigError([f"{scenario.source}: estimator: the Kalman filter runs in furuta-cosim's master "
                           "between the plant and the controller, and the exporter builds no FMU of it: an SSP of "
                           "this loop would feed the controller the plant's states instead (nothing written)"])
    variants = [(None, scenario)] if not plants else [(p, on_plant(scenario, p)) for p in plants]
    sets = []
    for given, variant in variants:
        prepared = prepare(variant)
        loop_only(prepared, "an SSP of the plant, the controller and the scenario's source",
                  ("reference", "actuator limit", "noise", "disturbances"))
        name = set_name(load_plant(variant.plant)) if variant.plant else variant.name
        if not SET_NAME.fullmatch(name):
            raise ConfigError([f"{given or variant.plant}: its name {name!r} is no parameter set's name "
                               "(letters, digits, '_', '.', '-'; at most 64)"])
        if any(name == s["name"] for s in sets):
            raise ConfigError([f"--plant {given}: the parameter set {name!r} is there twice"])
        sets.append({"name": name, "prepared": prepared, "plant": variant.plant})
    first = sets[0]["prepared"]
    for s in sets[1:]:
        p = s["prepared"]
        if (p.control_period, p.steps, p.control_input, p.states) != \
                (first.control_period, first.steps, first.control_input, first.states):
            raise ConfigError([f"{s['plant']}: its loop differs from {sets[0]['plant']}'s (period, "
                               "length, input or states): one SSP holds one loop"])
    plant_fmu = (first.fmu if fmi_version == "2.0"
                 else build_fmu(load_plant(sets[0]["plant"] or "furuta"), log=log, fmi_version="3.0"))
    source = scenario_source(first, scenario.name) if needs_source(first) else None
    if source is not None:
        for s in sets[1:]:
            if not same_signals(first, s["prepared"]):
                raise ConfigError([f"{s['plant']}: the scenario's reference, noise or disturbances differ on this "
                                   f"plant from {sets[0]['plant']}'s: one SSP's source holds one"])
    from furuta_cosim.cosim.evaluation import compile_controller

    compiled = compile_controller(first, controller, key="controller")   # fits this plant: simulate's check
    warnings = [line for s in sets for line in [_unstable_as_exported(s["prepared"], compiled.cfile,
                                                                      s["plant"] or scenario.plant, scenario)] if line]
    made = controller_plant(controller, period=first.control_period, delay=1,
                            noise=tuple(first.noisy) if source is not None else ())
    controller_fmu = build_fmu(made, log=log, fmi_version=fmi_version)
    source_fmu = build_fmu(source.plant, log=log, fmi_version=fmi_version) if source is not None else None
    plant_md, controller_md = model_description(plant_fmu), model_description(controller_fmu)
    source_md = model_description(source_fmu) if source is not None else None
    outputs = dict(zip(first.states, first.outputs))
    connections = [("plant", outputs[s], "controller", s) for s in first.states]
    command = made.linear.outputs[0]
    connections.append(("controller", command, "plant", first.control_input))
    if source is not None:
        connections += [("source", output, component, name) for output, component, name in source.wiring]
    reference = float(first.rbar[0]) if len(first.rbar) else 0.0
    held = constant(first.rbar)
    stop = round(first.steps * first.control_period, 12)
    for s in sets:  # the amplifier's limit is the plant's own V_max in the SSP
        limit, start = s["prepared"].limit, s["prepared"].start
        if limit:
            if "V_max" not in _variables(plant_md):
                raise ConfigError([f"{s['plant']}: commands are clipped to {limit:g} V and the plant FMU has "
                                   "no V_max to carry that limit: an SSP of two FMUs cannot hold it"])
            s["start"] = {**start, "V_max": float(limit)}
        else:
            s["start"] = dict(start)

    files: dict[str, bytes] = {}
    order = []
    for s in sets:
        values = _parameter_values(model_description(s["prepared"].fmu), s["start"])
        files[f"resources/{s['name']}.ssv"] = _ssv(s["name"], values, plant_md)
        files[f"resources/controller-{s['name']}.ssv"] = _ssv(s["name"], {REFERENCE_INPUT: reference},
                                                              controller_md)
        order.append(s["name"])
    if source is None:
        note = f"the reference is the controller's input {REFERENCE_INPUT}, {reference:g} throughout"
    else:
        carried = ["the reference" + ("" if held else " as it changes")]
        if first.noisy:
            carried.append(f"the measurement noise on {', '.join(first.noisy)}")
        if len(first.disturbances):
            carried.append(f"the disturbances at {', '.join(first.disturbance_inputs)}")
        note = (f"{', '.join(carried)} come from the component source, one row per sample as furuta-cosim "
                "draws them" + (f" (seed {scenario.noise.seed})" if scenario.noise else ""))
    files[ENTRY] = _ssd(scenario.name, plant_md, controller_md, connections, order, stop,
                        first.control_period, controller, note, source_md)
    files["resources/plant.fmu"] = Path(plant_fmu).read_bytes()
    files["resources/controller.fmu"] = Path(controller_fmu).read_bytes()
    if source is not None:
        files["resources/source.fmu"] = Path(source_fmu).read_bytes()
    files.update(_carried(scenario, controller))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))  # the same bytes each time
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, data)
    validated = schema_problems(files)
    if validated:
        raise ConfigError([f"{output}: the archive would not be valid SSP 1.0 (nothing written): {validated[0]}"])
    write_bytes(output, buffer.getvalue())
    return {"path": str(output), "validated": validated is not None, "sets": order, "step": first.control_period, "stop": stop,
            "reference": reference, "reference_held": held, "note": note, "fmi_version": fmi_version,
            "source": source is not None, "warnings": warnings,
            "connections": [f"{a}.{x} -> {b}.{y}" for a, x, b, y in connections]}


def schema_problems(files: dict) -> list[str] | None:
    """Each ``.ssd`` and ``.ssv`` of ``files`` (entry -> bytes) against the SSP 1.0 XML schemas
    the standard publishes, as the ``pyssp-standard`` package carries them (read with
    ``xmlschema``): the problems, [] when valid, None when those packages are not installed
    (not validated, said as such)."""
    try:
        import pyssp_standard
        import xmlschema
    except ImportError:
        return None
    folder = Path(pyssp_standard.__file__).parent / "resources"
    schemas = {".ssd": "SystemStructureDescription.xsd", ".ssv": "SystemStructureParameterValues.xsd"}
    problems = []
    for name, data in files.items():
        schema = schemas.get(PurePosixPath(name).suffix)
        if schema is None:
            continue
        for error in xmlschema.XMLSchema(str(folder / schema)).iter_errors(io.BytesIO(data)):
            problems.append(f"{name}: {error.reason} (at {error.path})")
    return problems


def set_name(plant) -> str:
    """A plant's parameter set's name: the plant's own, but for the ``plant.yaml`` that
    identify writes into its run folder, which is named after that folder (``runs/qube-fit/
    plant.yaml``: ``qube-fit``); characters a set's name cannot hold become ``-``."""
    name = plant.name
    if plant.path is not None and Path(plant.path).name == "plant.yaml" and Path(plant.path).parent.name:
        name = Path(plant.path).resolve().parent.name
    return re.sub(r"[^A-Za-z0-9_.-]", "-", name).lstrip("-_.") or "plant"


def _parameter_values(md, start: dict) -> dict:
    """Every parameter of the plant FMU at its start value, the prepared start on top: a set
    applied to another plant's build of the same model gives this plant."""
    values = {}
    for v in md.modelVariables:
        if v.causality == "parameter" and v.type in ("Real", "Float64", "Integer", "Int32") and v.start is not None:
            values[v.name] = float(v.start)
    for name, value in start.items():
        if name in values:
            values[name] = float(value)
    return values


def _variables(md) -> dict:
    return {v.name: v for v in md.modelVariables}


def _unit_of(variable) -> str | None:
    unit = variable.declaredType.unit if variable.declaredType is not None and variable.declaredType.unit \
        else getattr(variable, "unit", None)
    return unit or None


def _is_real(variable) -> bool:
    return variable.type in ("Real", "Float64", "Float32")


def _units_element(parent, tag: str, units) -> None:
    if not units:
        return
    holder = ET.SubElement(parent, tag)
    for unit in sorted(units):
        element = ET.SubElement(holder, f"{{{SSC}}}Unit", name=unit)
        ET.SubElement(element, f"{{{SSC}}}BaseUnit", {k: str(e) for k, e in (base_unit(unit) or {}).items()})


def _ssv(name: str, values: dict, md) -> bytes:
    variables = _variables(md)
    root = ET.Element(f"{{{SSV}}}ParameterSet", version="1.0", name=name)
    parameters = ET.SubElement(root, f"{{{SSV}}}Parameters")
    units = set()
    for key, value in values.items():
        v = variables[key]
        p = ET.SubElement(parameters, f"{{{SSV}}}Parameter", name=key)
        if _is_real(v):
            attributes = {"value": repr(float(value))}
            unit = _unit_of(v)
            if unit and base_unit(unit) is not None:
                attributes["unit"] = unit
                units.add(unit)
            ET.SubElement(p, f"{{{SSV}}}Real", attributes)
        else:
            ET.SubElement(p, f"{{{SSV}}}Integer", value=str(int(round(value))))
    _units_element(root, f"{{{SSV}}}Units", units)
    return _xml(root)


def _ssd(name: str, plant_md, controller_md, connections, sets, stop: float, step: float,
         controller, note: str, source_md=None) -> bytes:
    root = ET.Element(f"{{{SSD}}}SystemStructureDescription", version="1.0", name=name,
                      generationTool="furuta-cosim")
    system = ET.SubElement(root, f"{{{SSD}}}System", name="loop",
                           description=f"{name}: the plant under controller {Path(str(controller)).stem}; {note}")
    elements = ET.SubElement(system, f"{{{SSD}}}Elements")
    units = set()
    components = [("plant", plant_md, "resources/plant.fmu"), ("controller", controller_md, "resources/controller.fmu")]
    if source_md is not None:
        components.append(("source", source_md, "resources/source.fmu"))
    for component, md, source in components:
        element = ET.SubElement(elements, f"{{{SSD}}}Component", name=component, source=source,
                                type="application/x-fmu-sharedlibrary")
        connectors = ET.SubElement(element, f"{{{SSD}}}Connectors")
        variables = _variables(md)
        used = [(x if a == component else y, "output" if a == component else "input")
                for a, x, b, y in connections if component in (a, b)]
        for variable, kind in used:
            connector = ET.SubElement(connectors, f"{{{SSD}}}Connector", name=variable, kind=kind)
            unit = _unit_of(variables[variable])
            attributes = {}
            if unit and base_unit(unit) is not None:
                attributes["unit"] = unit
                units.add(unit)
            ET.SubElement(connector, f"{{{SSC}}}Real", attributes)
        if component == "source":
            continue   # its table is its own: no parameter set
        bindings = ET.SubElement(element, f"{{{SSD}}}ParameterBindings")
        for s in sets:
            file = f"resources/{s}.ssv" if component == "plant" else f"resources/controller-{s}.ssv"
            ET.SubElement(bindings, f"{{{SSD}}}ParameterBinding", source=file)
    links = ET.SubElement(system, f"{{{SSD}}}Connections")
    for a, x, b, y in connections:
        ET.SubElement(links, f"{{{SSD}}}Connection", startElement=a, startConnector=x, endElement=b,
                      endConnector=y)
    _units_element(root, f"{{{SSD}}}Units", units)
    experiment = ET.SubElement(root, f"{{{SSD}}}DefaultExperiment", startTime="0", stopTime=repr(stop))
    notes = ET.SubElement(experiment, f"{{{SSD}}}Annotations")
    osp = ET.SubElement(notes, f"{{{SSC}}}Annotation", type="com.opensimulationplatform")
    algorithm = ET.SubElement(osp, f"{{{OSP}}}Algorithm")
    ET.SubElement(algorithm, f"{{{OSP}}}FixedStepAlgorithm", baseStepSize=repr(float(step)))
    return _xml(root)


def _unstable_as_exported(prepared, cfile, plant, scenario) -> str | None:
    """A warning when the loop is unstable as the archive runs it: the plant linearized at its
    start (the model ``analyze`` uses), the controller sampled at the control period, and the
    controller FMU's one-sample hold; its largest eigenvalue's modulus above 1. The archive is
    still the scenario's loop (simulate runs it too, and warns that it does not settle)."""
    from furuta_cosim.design.controller import discretize_controller
    from furuta_cosim.models import load_model

    try:
        model = load_model(plant, scenario.folder)
    except ConfigError:
        return None   # a plant no linear model describes: nothing to check it against here
    if model.discrete or model.B.shape[1] != 1 or any(s not in model.states for s in prepared.states):
        return None
    import scipy.linalg

    h = prepared.control_period
    order = [model.states.index(s) for s in prepared.states]
    A, B = model.A[np.ix_(order, order)], model.B[order, :]
    n = A.shape[0]
    block = scipy.linalg.expm(np.block([[A, B], [np.zeros((1, n + 1))]]) * h)   # zero-order hold
    Ad, Bd = block[:n, :n], block[:n, n:]
    c = discretize_controller(cfile.controller, h)
    m = c.n_xc
    loop = np.block([[Ad, np.zeros((n, m)), Bd],
                     [c.Bc, c.Ac, np.zeros((m, 1))],
                     [-c.Dc, -c.Cc, np.zeros((1, 1))]])
    radius = float(np.max(np.abs(np.linalg.eigvals(loop))))
    if radius <= 1.0 + MARGINAL:   # an eigenvalue at 1 (an arm left free) is marginal, not unstable
        return None
    return (f"controller {cfile.name} on plant {plant}: the loop this archive holds is UNSTABLE (linearized at "
            f"its start, sampled at {h:g} s, each command held one sample: largest eigenvalue {radius:.6g}, "
            f"above 1; `analyze {cfile.name} --model {plant}` judges the loop without the hold)")


def _xml(root) -> bytes:
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def _carried(scenario, controller) -> dict:
    """The scenario's and the controller's files, for ``simulate SSP`` here."""
    from furuta_cosim.controllers import load_controller, save_controller

    found = {}
    if scenario.path is not None:
        found["resources/furuta-cosim/scenario.yaml"] = Path(scenario.path).read_bytes()
    cfile = load_controller(controller)
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "controller.yaml"
        save_controller(cfile, path)
        found["resources/furuta-cosim/controller.yaml"] = path.read_bytes()
    return found


# --------------------------------------------------------------------------- reading --------


def split_ssp(text: str) -> tuple[str, str | None]:
    """``loop.ssp`` or ``loop.ssp:SET`` -> (path, set name or None)."""
    head, sep, tail = str(text).rpartition(":")
    if sep and head.endswith(".ssp") and tail:
        return head, tail
    return str(text), None


def is_ssp(text) -> bool:
    return split_ssp(str(text))[0].endswith(".ssp")


class Archive:
    """An SSP archive opened as hostile input (:func:`open_archive`): its system description
    (``root``), each component's element, extracted FMU and model description (``described``),
    its entries' names, and ``read(entry)`` within the limits; ``warnings`` collects what the
    standard says a tool ignores (an .ssv's parameter the FMU does not have)."""

    def __init__(self, path: Path, data: bytes, zipped: zipfile.ZipFile):
        self.path, self.where, self._zip = path, str(path), zipped
        self.names = {i.filename for i in zipped.infolist()}
        self.warnings: list[str] = []
        self._taken = 0          # bytes read in all: an entry's size in its header can lie
        self.key = hashlib.sha256(data).hexdigest()[:16]
        self.root = None
        self.described: dict = {}
        self.out: Path | None = None

    def fail(self, entry: str | None, message: str) -> ConfigError:
        return ConfigError([f"{self.where}" + (f" ({entry})" if entry else "") + f": {message}"])

    def read(self, entry: str) -> bytes:
        entry = str(PurePosixPath(entry))
        if entry not in self.names:
            raise self.fail(entry, "missing from the archive")
        try:
            with self._zip.open(entry) as handle:
                content = handle.read(MAX_ENTRY + 1)
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as error:
            raise self.fail(entry, f"a corrupt entry ({error})") from None
        if len(content) > MAX_ENTRY:
            raise self.fail(entry, f"larger than {MAX_ENTRY // 2**20} MB")
        self._taken += len(content)
        if self._taken > MAX_TOTAL:
            raise self.fail(entry, f"more than {MAX_TOTAL // 2**20} MB read from the archive in all")
        return content

    def sets(self, name: str) -> list[tuple[str, object]]:
        """Component ``name``'s parameter sets in binding order: (the entry it is in, its
        ssv:ParameterSet)."""
        component = self.described[name][0]
        found = []
        for binding in component.iterfind(f"{{{SSD}}}ParameterBindings/{{{SSD}}}ParameterBinding"):
            source = binding.get("source")
            if source:
                found.append((source, _parse(self.read(source), source, self.fail)))
            else:
                inline = binding.find(f"{{{SSD}}}ParameterValues/{{{SSV}}}ParameterSet")
                if inline is not None:
                    found.append((ENTRY, inline))
        return found


def open_archive(path: str | Path, folder: str | Path | None = None) -> Archive:
    """Open ``path`` as an SSP: within the limits, every entry inside the archive's folder, its
    ``SystemStructure.ssd`` well-formed SSP 1.0 with its components, each component's FMU
    extracted (to ``folder``, default a cache by the archive's hash) and readable, each of its
    connectors a variable of that FMU. One line naming the archive and the entry otherwise."""
    from furuta_cosim.files import write_bytes
    from furuta_cosim.fmu.session import model_description
    from furuta_cosim.paths import cache

    path = Path(path)
    probe = Archive.__new__(Archive)
    probe.where = str(path)
    fail = probe.fail
    from furuta_cosim.inputs import read_input, regular

    if not path.exists() and not path.is_symlink():
        raise fail(None, "no such file")
    regular(path)
    if path.stat().st_size > MAX_TOTAL:   # before a byte is read: a sparse 20 GB file is not read
        raise fail(None, f"larger than {MAX_TOTAL // 2**20} MB")
    data = read_input(path, MAX_TOTAL, beyond="not an SSP this reads")
    try:
        zipped = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile:
        raise fail(None, "not an SSP: not a zip archive") from None
    members = zipped.infolist()
    if len(members) > MAX_ENTRIES:
        raise fail(None, f"{len(members)} entries (at most {MAX_ENTRIES})")
    for info in members:
        name = PurePosixPath(info.filename)
        if name.is_absolute() or ".." in name.parts or "\\" in info.filename or ":" in info.filename:
            raise fail(info.filename, "an entry outside the archive's folder")
    if sum(i.file_size for i in members) > MAX_TOTAL:
        raise fail(None, f"more than {MAX_TOTAL // 2**20} MB when extracted")
    archive = Archive(path, data, zipped)
    root = archive.root = _parse(archive.read(ENTRY), ENTRY, fail)
    if root.tag != f"{{{SSD}}}SystemStructureDescription":
        raise fail(ENTRY, f"expected an ssd:SystemStructureDescription (SSP 1.0), found {_plain(root.tag)}")
    system = root.find(f"{{{SSD}}}System")
    elements = system.find(f"{{{SSD}}}Elements") if system is not None else None
    if elements is None:
        raise fail(ENTRY, "no ssd:System with ssd:Elements")
    components = elements.findall(f"{{{SSD}}}Component")
    if not components:
        raise fail(ENTRY, "ssd:Elements holds no ssd:Component")
    out = archive.out = Path(folder) if folder is not None else cache() / "ssp" / archive.key
    for component in components:
        name, source = component.get("name"), component.get("source")
        if not name or not source:
            raise fail(ENTRY, "an ssd:Component without its name or source")
        if not SET_NAME.fullmatch(name):
            raise fail(ENTRY, f"component {name!r}: not a plain name")
        if name in archive.described:
            raise fail(ENTRY, f"component {name!r}: two components of that name")
        entry = str(PurePosixPath(source))
        if entry not in archive.names:
            raise fail(entry, f"component {name}'s FMU is missing from the archive")
        target = out / f"{name}.fmu"
        content = archive.read(entry)
        if not target.is_file() or target.read_bytes() != content:
            write_bytes(target, content)
        try:
            md = model_description(target)
        except Exception as error:  # an FMU from another tool is hostile: any failure is its
            raise fail(entry, f"component {name}: not a readable FMU ({error})") from None
        variables = _variables(md)
        for connector in component.iterfind(f"{{{SSD}}}Connectors/{{{SSD}}}Connector"):
            cname = connector.get("name")
            if cname not in variables:
                raise fail(ENTRY, f"component {name}: connector {cname!r} is no variable of {entry}")
        archive.described[name] = (component, target, md)
    return archive


def read_ssp(path: str | Path, parameter_set: str | None = None, *, control_input: str = "V",
             folder: str | Path | None = None) -> SspPlant:
    """The plant of an SSP archive (module docstring): the component named ``plant``, else the
    one component whose FMU takes ``control_input``; its FMU extracted (to ``folder``, default a
    cache by the archive's hash) and the parameter set ``parameter_set`` (default its first).

    Parameters
    ----------
    path : path
        The ``.ssp`` archive.
    parameter_set : str, optional
        The name of one of the plant component's parameter sets (default: its first binding).
    control_input : str
        The plant's input the controller drives: how a component not named ``plant`` is found.
    folder : path, optional
        Where the FMUs (and the files of ours it carries) are extracted.

    Returns
    -------
    SspPlant

    Raises
    ------
    ConfigError
        One line naming the archive and the entry inside it: not a zip, an entry outside the
        archive's folder or beyond the limits, malformed XML, a missing FMU, a connector without
        its variable, a parameter of the wrong type or unit, an unknown set.
    """
    from furuta_cosim.files import write_bytes

    archive = open_archive(path, folder)
    read, fail, names, out = archive.read, archive.fail, archive.names, archive.out
    chosen = _plant_component(archive.described, control_input, fail)
    _, target, md = archive.described[chosen]
    sets = archive.sets(chosen)
    names_of = [ssv.get("name") or "" for _, ssv in sets]
    parameters, set_name = {}, None
    if parameter_set is not None and parameter_set not in names_of:
        raise fail(None, f"no parameter set {parameter_set!r} for component {chosen} "
                         f"(it has: {', '.join(names_of) or 'none'})")
    if sets:
        k = names_of.index(parameter_set) if parameter_set is not None else 0
        source, ssv = sets[k]
        set_name = names_of[k]
        parameters = _set_values(ssv, source, md, fail, archive.warnings)
        accepted(target, parameters, fail, source, chosen, set_name)
    stop, step = _experiment(archive.root, fail)
    carried = {}
    for kind in ("scenario", "controller"):
        entry = f"resources/furuta-cosim/{kind}.yaml"
        if entry in names:
            carried[kind] = out / "furuta-cosim" / f"{kind}.yaml"
            write_bytes(carried[kind], read(entry))
    return SspPlant(target, chosen, set_name, parameters, names_of, stop, step,
                    carried.get("scenario"), carried.get("controller"), archive.warnings)


def _plain(tag: str) -> str:
    return tag.rpartition("}")[2]


def _parse(content: bytes, entry: str, fail):
    if b"<!DOCTYPE" in content or b"<!ENTITY" in content:
        raise fail(entry, "declares a DOCTYPE or entities (refused: an SSP needs neither)")
    try:
        return ET.fromstring(content)
    except ET.ParseError as error:
        raise fail(entry, f"not well-formed XML ({error})") from None


def _plant_component(described: dict, control_input: str, fail) -> str:
    if "plant" in described:
        return "plant"
    takers = [name for name, (_, _, md) in described.items()
              if any(v.name == control_input and v.causality == "input" for v in md.modelVariables)]
    if len(takers) != 1:
        raise fail(ENTRY, f"which component is the plant? {len(takers)} take the input {control_input!r} "
                          f"({', '.join(takers) or 'none'}); name it 'plant'")
    return takers[0]


def _set_values(ssv, entry: str, md, fail, warnings: list | None = None) -> dict:
    """The numbers of a parameter set for ``md``'s FMU, each checked against the variable it
    sets; a name the FMU does not have is ignored, as the standard says a tool does, and said
    in ``warnings``."""
    variables = _variables(md)
    if ssv.tag != f"{{{SSV}}}ParameterSet":
        raise fail(entry, f"expected an ssv:ParameterSet, found {_plain(ssv.tag)}")
    values = {}
    for parameter in ssv.iterfind(f"{{{SSV}}}Parameters/{{{SSV}}}Parameter"):
        name = parameter.get("name")
        v = variables.get(name)
        if v is None:
            if warnings is not None:
                warnings.append(f"{entry}: parameter {name!r} is no variable of {md.modelName}'s FMU: ignored "
                                "(as the SSP standard has a tool do)")
                continue
            raise fail(entry, f"parameter {name!r} is no variable of the plant's FMU")
        if v.causality not in ("parameter", "input"):
            raise fail(entry, f"parameter {name!r}: the FMU declares it {v.causality}, not a parameter")
        typed = [child for child in parameter if child.tag.startswith(f"{{{SSV}}}")]
        if len(typed) != 1:
            raise fail(entry, f"parameter {name!r}: expected one value element")
        kind = _plain(typed[0].tag)
        if kind not in ("Real", "Integer", "Float64", "Int32"):
            raise fail(entry, f"parameter {name!r}: a {kind} value; the plant takes numbers")
        if kind in ("Real", "Float64") and not _is_real(v):
            raise fail(entry, f"parameter {name!r}: a Real value for the FMU's {v.type}")
        if kind in ("Integer", "Int32") and _is_real(v):
            raise fail(entry, f"parameter {name!r}: an Integer value for the FMU's {v.type}")
        try:
            value = float(typed[0].get("value"))
        except (TypeError, ValueError):
            raise fail(entry, f"parameter {name!r}: value {typed[0].get('value')!r} is not a number") from None
        if not math.isfinite(value):
            raise fail(entry, f"parameter {name!r}: value {value} is not finite")
        unit, declared = typed[0].get("unit"), _unit_of(v)
        if unit is not None and unit != declared:
            raise fail(entry, f"parameter {name!r}: in {unit}, where the FMU declares {declared or 'no unit'} "
                              "(no conversion is applied: give it in the FMU's unit)")
        values[name] = value
    return values


def accepted(fmu: Path, parameters: dict, fail, entry: str, component: str, name: str) -> None:
    """The FMU of ``component`` takes the set ``name`` (read from ``entry``): it is started with
    it once, and what it refuses (a resistance below 0: its own checks) is one line naming the
    archive and the entry, not the extracted copy it was run from."""
    from furuta_cosim.errors import FmuError
    from furuta_cosim.fmu.session import PlantSession

    try:
        with PlantSession.open(fmu) as session:
            session.reset(parameters)
    except FmuError as error:
        said = str(error).replace(str(fmu), f"component {component}'s FMU")
        raise fail(entry, f"parameter set {name!r}: the FMU of component {component} refuses it: {said}") from None


def _experiment(root, fail) -> tuple[float | None, float | None]:
    experiment = root.find(f"{{{SSD}}}DefaultExperiment")
    if experiment is None:
        return None, None
    stop = step = None
    try:
        if experiment.get("stopTime") is not None:
            stop = float(experiment.get("stopTime"))
        for algorithm in experiment.iterfind(f".//{{{OSP}}}FixedStepAlgorithm"):
            step = float(algorithm.get("baseStepSize"))
    except (TypeError, ValueError):
        raise fail(ENTRY, "ssd:DefaultExperiment: a time that is not a number") from None
    for value, what in ((stop, "stopTime"), (step, "baseStepSize")):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise fail(ENTRY, f"ssd:DefaultExperiment: {what} {value} is not a positive time")
    return stop, step


def on_ssp(scenario, text: str | Path):
    """The scenario run on the plant of an SSP (``loop.ssp`` or ``loop.ssp:SET``): the plant
    component's FMU with the parameter set (default the first) as ``plant.overrides``; the
    scenario's own overrides and initial state apply on top (a set's start of a state the
    scenario starts is dropped: the scenario decides the experiment)."""
    from dataclasses import replace

    from furuta_cosim.signals import start_parameter

    path, name = split_ssp(str(text))
    plant = read_ssp(path, name, control_input=scenario.control_input or "V")
    started = {start_parameter(state) for state in scenario.initial}
    overrides = {k: v for k, v in plant.parameters.items() if k not in started}
    overrides.update(scenario.overrides)
    return replace(scenario, fmu=plant.fmu, overrides=overrides), plant
