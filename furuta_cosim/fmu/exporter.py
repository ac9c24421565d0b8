"""The exporter: a plant declaration plus its C equations -> a native FMI 2.0 or 3.0 FMU.

``build_fmu(plant)`` loads ``fmu_src/<model>/model.py``, generates ``modelDescription.xml``
and ``model_vars.h`` from the declaration, compiles the generic glue and the model with the
machine's C compiler against the FMI headers shipped inside fmpy, and zips the binary with
a complete ``sources/`` folder. FMUs are cached by a hash of everything that goes into them.
An FMI 3.0 FMU (``fmi_version="3.0"``) adds ``fmi3_glue.c``, which implements FMI 3.0 on the
FMI 2.0 glue: the same model, modes and integration, so the two give the same numbers.
"""

from __future__ import annotations

import hashlib
import importlib.util
import shutil
import subprocess
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import fmpy

from furuta_cosim import __version__, paths
from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.files import atomic, copy, temporary_folder
from furuta_cosim.fmu import versions
from furuta_cosim.fmu.compiler import CFLAGS, building, compiler, intact, seal, unwritable
from furuta_cosim.fmu.declaration import DeclarationError, Model
from furuta_cosim.fmu.plants import NOT_PLANTS, PlantSet, load_plant, model_folder, models

# FURUTA_COSIM_EXTRA_CFLAGS adds flags, for example sanitizers in the tests; they are part of
# the cache key, so such builds never mix with ordinary ones
_KINDS = {"parameter": "KIND_PARAMETER", "input": "KIND_INPUT", "output": "KIND_OUTPUT",
          "local": "KIND_LOCAL"}


def fmi_headers() -> Path:
    """The FMI 2.0 and 3.0 headers that fmpy ships."""
    return Path(fmpy.__file__).parent / "c-code"


def parameter_ranges(plant: PlantSet) -> dict[str, tuple[float, bool]]:
    """The physical range of each Real parameter that has one: ``(low, strict)``, the value
    must be > low (strict) or >= low."""
    found = {}
    for v in declaration(plant).reals:
        if v.causality != "parameter":
            continue
        if v.positive:
            found[v.name] = (0.0, True)
        elif v.minimum is not None:
            found[v.name] = (float(v.minimum), False)
    return found


def declaration(plant: PlantSet) -> Model:
    """Run the plant's ``declare()`` with its parameter set or linear spec (only a model of
    ``fmu_src/``, by its plain name: code named anywhere else is never run)."""
    if plant.folder is not None:
        from furuta_cosim.fmu.folder import declare_folder

        return declare_folder(plant)
    if plant.model not in models() and not (plant.model in NOT_PLANTS and plant.linear is not None):
        raise ConfigError([f"{plant.path}: model: expected one of {', '.join(models())}, "
                           f"got {plant.model!r}"])
    model_py = paths.fmu_sources() / plant.model / "model.py"
    spec = importlib.util.spec_from_file_location(f"_furuta_cosim_plant_{plant.model}", model_py)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if plant.linear is not None:
        model = module.declare(plant.linear)
    else:
        try:
            model = module.declare(dict(plant.parameters))
        except KeyError as error:
            raise ConfigError([f"{plant.path}: parameters.{error.args[0]}: missing"]) from None
        except DeclarationError as error:
            if error.variable in plant.parameters:
                raise ConfigError([f"{plant.path}: parameters.{error.variable}: {error.reason}"]) from None
            raise
        checked(plant, model)
    model.check()
    return model


def checked(plant: PlantSet, model: Model) -> None:
    """The plant file's parameters against the declaration: whole numbers where it declares an
    Integer, and no name it does not declare."""
    # the declaration takes int() of an Integer's start: 2.5 would quietly become 2
    fractional = [f"{plant.path}: parameters.{v.name}: expected a whole number, got "
                  f"{plant.parameters[v.name]:g}" for v in model.integers
                  if v.name in plant.parameters and plant.parameters[v.name] != int(plant.parameters[v.name])]
    if fractional:
        raise ConfigError(fractional)
    known = {v.name for v in model.reals if v.causality == "parameter"}
    known |= {v.name for v in model.integers}
    unknown = sorted(set(plant.parameters) - known)
    if unknown:
        raise ConfigError([f"{plant.path}: parameters.{name}: unknown parameter of model "
                           f"{Path(plant.model).name}" for name in unknown])


def _c_name(name: str) -> str:
    return name.replace("der(", "der_").replace(")", "").replace("[", "_").replace(",", "_").replace("]", "")


def _number(value: float) -> str:
    return repr(float(value))


def generate_header(model: Model, guid: str) -> str:
    """``model_vars.h``: counts, value references, start values and checks for the glue."""
    reals, integers = model.reals, model.integers
    offset = len(reals)
    lines = ["/* Generated by furuta-cosim from the plant declaration: do not edit. */",
             "#ifndef MODEL_VARS_H", "#define MODEL_VARS_H", "",
             f"#define MODEL_IDENTIFIER {model.identifier}",
             f'#define MODEL_IDENTIFIER_STRING "{model.identifier}"',
             f'#define INSTANTIATION_TOKEN "{guid}"',
             f"#define N_REALS {len(reals)}", f"#define N_INTEGERS {len(integers)}",
             f"#define INTEGER_VR_OFFSET {offset}", f"#define N_STATES {len(model.states)}",
             f"#define MODEL_DISCRETE {int(model.discrete)}"]
    if model.substeps:
        lines.append(f"#define SUBSTEPS_VR {model.value_reference(model.substeps)}")
    if model.sample_period:
        lines.append(f"#define SAMPLE_PERIOD_VR {model.value_reference(model.sample_period)}")
    lines += [f"#define {name} {value}" for name, value in model.constants.items()]
    lines.append("")
    lines += [f"#define VR_{_c_name(v.name)} {k}" for k, v in enumerate(reals)]
    lines += [f"#define VR_{_c_name(v.name)} {offset + k}" for k, v in enumerate(integers)]

    def table(ctype, name, values, size):
        body = ", ".join(values) if values else "0"
        return f"static const {ctype} {name}[{max(size, 1)}] = {{{body}}};"

    real_starts = [_number(v.start) if v.start is not None else "0.0" for v in reals]
    lines += ["",
              table("char *const", "REAL_NAMES", [f'"{v.name}"' for v in reals], len(reals)),
              table("double", "REAL_START", real_starts, len(reals)),
              table("unsigned char", "REAL_KIND", [_KINDS[v.causality] for v in reals], len(reals)),
              table("unsigned char", "REAL_POSITIVE", [str(int(v.positive)) for v in reals], len(reals)),
              table("char *const", "INTEGER_NAMES", [f'"{v.name}"' for v in integers], len(integers)),
              table("int", "INTEGER_START", [str(v.start) for v in integers], len(integers)),
              table("int", "INTEGER_MIN", [str(v.minimum) for v in integers], len(integers)),
              table("int", "INTEGER_MAX", [str(v.maximum) for v in integers], len(integers)),
              table("int", "STATE_VR", [str(model.value_reference(s.name)) for s in model.states],
                    len(model.states)),
              table("int", "STATE_START_VR",
                    [str(model.value_reference(s.start_parameter)) for s in model.states],
                    len(model.states)),
              table("int", "STATE_DER_VR",
                    [str(model.value_reference(s.derivative)) if s.derivative else "0"
                     for s in model.states], len(model.states)),
              "", "#endif", ""]
    return "\n".join(lines)


def generate_model_description(model: Model, guid: str, sources: list[str]) -> str:
    """``modelDescription.xml`` (FMI 2.0): co-simulation, and model exchange when continuous."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": model.identifier, "guid": guid,
        "description": model.description, "generationTool": f"furuta-cosim {__version__}",
        "variableNamingConvention": "structured", "numberOfEventIndicators": "0"})
    capabilities = {"modelIdentifier": model.identifier, "canGetAndSetFMUstate": "true",
                    "canSerializeFMUstate": "true", "canNotUseMemoryManagementFunctions": "true"}
    interfaces = [] if model.discrete else ["ModelExchange"]
    interfaces.append("CoSimulation")
    for interface in interfaces:
        attributes = dict(capabilities)
        if interface == "CoSimulation":
            attributes["canHandleVariableCommunicationStepSize"] = "true"
        element = ET.SubElement(root, interface, attributes)
        files = ET.SubElement(element, "SourceFiles")
        for name in sources:
            if name.endswith(".c"):
                ET.SubElement(files, "File", {"name": name})
    _units_logs_experiment(root, model)

    variables = ET.SubElement(root, "ModelVariables")
    index = {}
    continuity = "discrete" if model.discrete else "continuous"
    for k, v in enumerate(model.reals):
        attributes = {"name": v.name, "valueReference": str(k), "causality": v.causality}
        if v.description:
            attributes["description"] = v.description
        real = {}
        if v.causality == "parameter":
            attributes.update(variability="fixed", initial="exact")
            real["start"] = _number(v.start)
        elif v.causality == "input":
            attributes["variability"] = continuity
            real["start"] = _number(v.start)
        else:
            attributes.update(variability=continuity, initial="calculated")
        if v.unit:
            real["unit"] = v.unit
        if v.minimum is not None:
            real["min"] = _number(v.minimum)
        if v.maximum is not None:
            real["max"] = _number(v.maximum)
        element = ET.SubElement(variables, "ScalarVariable", attributes)
        index[v.name] = k + 1
        ET.SubElement(element, "Real", real)
    for k, v in enumerate(model.integers):
        attributes = {"name": v.name, "valueReference": str(len(model.reals) + k),
                      "causality": "parameter", "variability": "fixed", "initial": "exact"}
        if v.description:
            attributes["description"] = v.description
        element = ET.SubElement(variables, "ScalarVariable", attributes)
        index[v.name] = len(model.reals) + k + 1
        ET.SubElement(element, "Integer", {"start": str(v.start), "min": str(v.minimum),
                                           "max": str(v.maximum)})
    for state in model.states:
        if state.derivative:
            element = variables[index[state.derivative] - 1].find("Real")
            element.set("derivative", str(index[state.name]))

    structure = ET.SubElement(root, "ModelStructure")
    outputs = [index[v.name] for v in model.reals if v.causality == "output"]
    derivatives = [index[s.derivative] for s in model.states if s.derivative]
    ET.SubElement(structure, "Outputs").extend(
        ET.Element("Unknown", {"index": str(i)}) for i in outputs)
    if derivatives:
        ET.SubElement(structure, "Derivatives").extend(
            ET.Element("Unknown", {"index": str(i)}) for i in derivatives)
    ET.SubElement(structure, "InitialUnknowns").extend(
        ET.Element("Unknown", {"index": str(i)}) for i in sorted(outputs + derivatives))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _units_logs_experiment(root: ET.Element, model: Model) -> None:
    """The elements both FMI versions write alike, in this order: unit definitions, log
    categories, the default experiment."""
    units = sorted({v.unit for v in model.reals if v.unit})
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            ET.SubElement(definitions, "Unit", {"name": unit})
    categories = ET.SubElement(root, "LogCategories")
    for name in ("logStatusError", "logAll"):
        ET.SubElement(categories, "Category", {"name": name})
    step = model_period(model)
    ET.SubElement(root, "DefaultExperiment",
                  {"startTime": "0.0", "stopTime": _number(100 * step), "stepSize": _number(step)})


def generate_model_description_3(model: Model, guid: str) -> str:
    """``modelDescription.xml`` (FMI 3.0): the same variables with the same value references
    as the FMI 2.0 description, as Float64 and Int32, plus the independent variable ``time``."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": model.identifier, "instantiationToken": guid,
        "description": model.description, "generationTool": f"furuta-cosim {__version__}",
        "variableNamingConvention": "structured"})
    capabilities = {"modelIdentifier": model.identifier, "canGetAndSetFMUState": "true",
                    "canSerializeFMUState": "true"}
    if not model.discrete:
        ET.SubElement(root, "ModelExchange", capabilities)
    ET.SubElement(root, "CoSimulation", {**capabilities, "canHandleVariableCommunicationStepSize": "true",
                                         "hasEventMode": "false"})
    _units_logs_experiment(root, model)
    variables = ET.SubElement(root, "ModelVariables")
    time_vr = len(model.reals) + len(model.integers)  # TIME_VR of fmi3_glue.c
    ET.SubElement(variables, "Float64", {"name": "time", "valueReference": str(time_vr),
                                         "causality": "independent", "variability": "continuous",
                                         "description": "simulation time"})
    continuity = "discrete" if model.discrete else "continuous"
    derivative_of = {s.derivative: s.name for s in model.states if s.derivative}
    for k, v in enumerate(model.reals):
        attributes = {"name": v.name, "valueReference": str(k), "causality": v.causality}
        if v.description:
            attributes["description"] = v.description
        if v.causality == "parameter":
            attributes.update(variability="fixed", initial="exact", start=_number(v.start))
        elif v.causality == "input":
            attributes.update(variability=continuity, start=_number(v.start))
        else:
            attributes.update(variability=continuity, initial="calculated")
        if v.unit:
            attributes["unit"] = v.unit
        if v.minimum is not None:
            attributes["min"] = _number(v.minimum)
        if v.maximum is not None:
            attributes["max"] = _number(v.maximum)
        if v.name in derivative_of:
            attributes["derivative"] = str(model.value_reference(derivative_of[v.name]))
        ET.SubElement(variables, "Float64", attributes)
    for k, v in enumerate(model.integers):
        attributes = {"name": v.name, "valueReference": str(len(model.reals) + k),
                      "causality": "parameter", "variability": "fixed", "initial": "exact"}
        if v.description:
            attributes["description"] = v.description
        attributes.update(start=str(v.start), min=str(v.minimum), max=str(v.maximum))
        ET.SubElement(variables, "Int32", attributes)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [model.value_reference(v.name) for v in model.reals if v.causality == "output"]
    derivatives = [model.value_reference(s.derivative) for s in model.states if s.derivative]
    for vr in outputs:
        ET.SubElement(structure, "Output", {"valueReference": str(vr)})
    for vr in derivatives:
        ET.SubElement(structure, "ContinuousStateDerivative", {"valueReference": str(vr)})
    for vr in sorted(outputs + derivatives):
        ET.SubElement(structure, "InitialUnknown", {"valueReference": str(vr)})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def generate_build_description(model: Model, sources: list[str]) -> str:
    """``sources/buildDescription.xml`` (FMI 3.0): the C files that make the binary."""
    root = ET.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    configuration = ET.SubElement(root, "BuildConfiguration", {"modelIdentifier": model.identifier})
    files = ET.SubElement(configuration, "SourceFileSet", {"language": "C99"})
    for name in sources:
        if name.endswith(".c"):
            ET.SubElement(files, "SourceFile", {"name": name})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def model_period(model: Model) -> float:
    """Default communication step: the sample period, or 1 ms for continuous plants."""
    if model.sample_period:
        return next(v.start for v in model.reals if v.name == model.sample_period)
    return 1e-3


def build_fmu(plant: PlantSet | str = "furuta", output: str | Path | None = None,
              log=None, fmi_version: str = "2.0") -> Path:
    """Build (or take from the cache) the FMU of ``plant`` and return its path.

    Parameters
    ----------
    plant : PlantSet or str
        A plant file, or its name (``furuta``, ``table-literal``, ``toy``).
    output : path, optional
        Also copy the FMU there (a folder or a file name).
    log : callable, optional
        Receives one line per build step.
    fmi_version : {"2.0", "3.0"}
    """
    versions.fmi_version(fmi_version)
    if not isinstance(plant, PlantSet):
        plant = load_plant(plant)
    memo = repr((plant.model, sorted(plant.parameters.items()), plant.linear,
                 _source_stamps(model_folder(plant)), paths.cache(), fmi_version))
    target, stamp = _BUILT.get(memo, (None, None))
    if target is None or _stamp(target) != stamp:
        target = _build_cached(plant, log, fmi_version)
        _BUILT[memo] = target, _stamp(target)
    if output is not None:
        output = Path(output)
        if output.is_dir() or output.suffix != ".fmu":
            output = output / f"{target.name.split('-', 1)[0]}.fmu"  # <Identifier>.fmu (a C name: no dash)
        return copy(target, output)
    return target


# in-process memo: a scenario prepared a thousand times hashes its FMU once, and again only
# when the file changed on disk
_BUILT: dict[str, tuple[Path, tuple]] = {}


def _stamp(path: Path) -> tuple | None:
    try:
        status = path.stat()
    except OSError:
        return None
    return status.st_mtime_ns, status.st_size, status.st_ino


def _source_stamps(folder: Path) -> tuple:
    files = [*(paths.fmu_sources() / "common").iterdir(), *folder.iterdir()]
    return tuple(sorted((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in files if f.is_file()))


def _build_cached(plant: PlantSet, log, fmi_version: str = "2.0") -> Path:
    """The FMU of ``plant`` in the cache, built there if it is not (or is damaged). The key
    does not depend on which compiler is installed, so a warm cache needs none."""
    model = declaration(plant)
    model_dir = model_folder(plant)
    common = paths.fmu_sources() / "common"
    version = versions.fmi_version(fmi_version)
    files = {name: (common / name).read_text() for name in version.glue}
    files["model.c"] = (model_dir / "model.c").read_text()
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name].encode() + b"\0")
    digest.update(generate_header(model, "").encode())
    digest.update(version.model_description(model, "", sorted(files)).encode())
    digest.update(" ".join(CFLAGS).encode())
    key = digest.hexdigest()
    guid = "{" + str(uuid.UUID(key[:32])) + "}"
    target = paths.cache() / f"{model.identifier}{version.cache_tag}-{key[:16]}.fmu"
    if intact(target, log):
        return target
    cc = compiler()
    with building(target):  # a second process building the same entry waits, then finds it
        if not intact(target, log):
            if log:
                where = plant.folder if plant.folder is not None else f"fmu_src/{plant.model}"
                log(f"building {model.identifier} from {where} ({plant.path.name})")
            files["model_vars.h"] = generate_header(model, guid)
            try:
                _build(model, files, guid, cc, target, fmi_version, plant.folder)
                seal(target)
            except OSError as error:
                raise unwritable(error) from None
            _accepts_its_defaults(plant, target)
    return target


def _accepts_its_defaults(plant: PlantSet, target: Path) -> None:
    """Initialize the new FMU with its own start values; a set the FMU's checks refuse (C0 < 0,
    say) is an error of the plant file, and no FMU is left in the cache for it."""
    from furuta_cosim.fmu.session import PlantSession

    try:
        with PlantSession.open(target) as session:
            session.reset()
    except FmuError as error:
        target.unlink(missing_ok=True)
        reason = str(error).split("failed: ", 1)[-1]
        raise ConfigError([f"{plant.path}: parameters: the FMU refuses these values: {reason}"]) from None


def _build(model: Model, files: dict, guid: str, cc: str, target: Path, fmi_version: str = "2.0",
           folder: Path | None = None) -> None:
    sources = sorted(files)
    work = temporary_folder("build")
    try:
        for name, text in files.items():
            (work / name).write_text(text)
        binary = work / f"{model.identifier}.so"
        command = [cc, *CFLAGS, f"-I{work}", f"-I{fmi_headers()}",
                   *(str(work / n) for n in sources if n.endswith(".c")), "-o", str(binary), "-lm"]
        try:
            result = subprocess.run(command, capture_output=True, text=True)
        except OSError as error:
            raise FmuError(f"cannot run the C compiler {cc}: {error.strerror}") from None
        if result.returncode != 0:
            if folder is not None:   # a user's equations: the first error, at its file and line
                from furuta_cosim.fmu.folder import compile_error

                raise ConfigError([compile_error(result.stderr, work, folder)])
            raise FmuError(f"compiling {model.identifier} failed:\n{result.stderr.strip()}", multiline=True)
        version = versions.fmi_version(fmi_version)
        description = version.model_description(model, guid, sources)
        # atomic: a concurrent build or a crash never leaves half an FMU under its name
        with atomic(target) as partial:
            with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
                # fixed dates: the same sources give the same bytes, whichever build wins
                _member(archive, "modelDescription.xml", description.encode())
                _member(archive, f"binaries/{version.platform}/{model.identifier}.so",
                        binary.read_bytes(), 0o755)
                for name in sources:
                    _member(archive, f"sources/{name}", files[name].encode())
                for name, data in version.extra_sources(model, sources).items():
                    _member(archive, f"sources/{name}", data)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _member(archive: zipfile.ZipFile, name: str, data: bytes, mode: int = 0o644) -> None:
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = (0o100000 | mode) << 16
    archive.writestr(info, data)
