"""Writing the closed loop as an SSP archive (:func:`export_ssp`).

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
                                 ``simulate LOOP.ssp`` runs the system: :mod:`.system`)

Each component binds its sets in order, the first the default (libcosim applies a component's
first binding when no set is named; Ecos applies the set named at its ``init``). The loop is
the Ecos loop of the controller FMU (``export.ecos_closed_loop``): each step every FMU steps,
then every output is copied to its input (Jacobi); the controller holds its command one sample,
so that exchange runs the master's one-sample-delayed loop (a Gauss-Seidel master, one FMU after
the other, runs another: docs' SSP page).
"""

from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from furuta_cosim.errors import ConfigError
from furuta_cosim.ssp.common import (ENTRY, OSP, SET_NAME, SSC, SSD, SSV, base_unit, is_real, schema_problems,
                                     unit_of, variables_of)

# an exported loop's eigenvalue this close above 1 is an integrator (an angle no law holds), not a
# growing mode: measured 1 + 4e-13 for bo-paper on the paper's plant, 1.004 for lqr-qube there
MARGINAL = 1e-9


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
    if controller is None and scenario.controllers:
        # the scenario's own controller, resolved beside the scenario that names it
        from furuta_cosim.controllers import controller_path

        controller = controller_path(scenario.controllers[0], beside=scenario.folder)
    if controller is None:
        raise ConfigError([f"{scenario.source}: names no controller: give one (`controller=NAME`)"])
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
        name = set_name(load_plant(variant.plant, beside=variant.folder)) if variant.plant else variant.name
        if not SET_NAME.fullmatch(name):
            raise ConfigError([f"{given or variant.plant}: its name {name!r} is no parameter set's name "
                               "(letters, digits, '_', '.', '-'; at most 64)"])
        if any(name == s["name"] for s in sets):
            raise ConfigError([f"plants {given}: the parameter set {name!r} is there twice"])
        sets.append({"name": name, "prepared": prepared, "plant": variant.plant})
    first = sets[0]["prepared"]
    for s in sets[1:]:
        p = s["prepared"]
        if (p.control_period, p.steps, p.control_input, p.states) != \
                (first.control_period, first.steps, first.control_input, first.states):
            raise ConfigError([f"{s['plant']}: its loop differs from {sets[0]['plant']}'s (period, "
                               "length, input or states): one SSP holds one loop"])
    plant_fmu = (first.fmu if fmi_version == "2.0"
                 else build_fmu(first.plant if first.plant is not None else load_plant(), log=log,
                                fmi_version="3.0"))
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
            if "V_max" not in variables_of(plant_md):
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


def _units_element(parent, tag: str, units) -> None:
    if not units:
        return
    holder = ET.SubElement(parent, tag)
    for unit in sorted(units):
        element = ET.SubElement(holder, f"{{{SSC}}}Unit", name=unit)
        ET.SubElement(element, f"{{{SSC}}}BaseUnit", {k: str(e) for k, e in (base_unit(unit) or {}).items()})


def _ssv(name: str, values: dict, md) -> bytes:
    variables = variables_of(md)
    root = ET.Element(f"{{{SSV}}}ParameterSet", version="1.0", name=name)
    parameters = ET.SubElement(root, f"{{{SSV}}}Parameters")
    units = set()
    for key, value in values.items():
        v = variables[key]
        p = ET.SubElement(parameters, f"{{{SSV}}}Parameter", name=key)
        if is_real(v):
            attributes = {"value": repr(float(value))}
            unit = unit_of(v)
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
        variables = variables_of(md)
        used = [(x if a == component else y, "output" if a == component else "input")
                for a, x, b, y in connections if component in (a, b)]
        for variable, kind in used:
            connector = ET.SubElement(connectors, f"{{{SSD}}}Connector", name=variable, kind=kind)
            unit = unit_of(variables[variable])
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
