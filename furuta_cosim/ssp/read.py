"""Reading an SSP archive, ours or another tool's, as hostile input (:func:`read_ssp`,
:func:`open_archive`): the entries it reads must lie inside the archive's folder, within size
and count limits; the system description must be well-formed SSP, each connector a variable of
its FMU, each parameter a parameter (or input) of its component's FMU with the type and unit
the FMU declares."""

from __future__ import annotations

import hashlib
import io
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree as ET

from furuta_cosim.errors import ConfigError
from furuta_cosim.ssp.common import ENTRY, OSP, SET_NAME, SSD, SSV, is_real, unit_of, variables_of

# a hostile archive: at most this many entries, this many bytes in one entry read, in all
MAX_ENTRIES, MAX_ENTRY, MAX_TOTAL = 1000, 200 * 2**20, 500 * 2**20


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
        variables = variables_of(md)
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
        parameters = set_values(ssv, source, md, fail, archive.warnings)
        accepted(target, parameters, fail, source, chosen, set_name)
    stop, step = default_experiment(archive.root, fail)
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


def set_values(ssv, entry: str, md, fail, warnings: list | None = None) -> dict:
    """The numbers of a parameter set for ``md``'s FMU, each checked against the variable it
    sets; a name the FMU does not have is ignored, as the standard says a tool does, and said
    in ``warnings``."""
    variables = variables_of(md)
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
        if kind in ("Real", "Float64") and not is_real(v):
            raise fail(entry, f"parameter {name!r}: a Real value for the FMU's {v.type}")
        if kind in ("Integer", "Int32") and is_real(v):
            raise fail(entry, f"parameter {name!r}: an Integer value for the FMU's {v.type}")
        try:
            value = float(typed[0].get("value"))
        except (TypeError, ValueError):
            raise fail(entry, f"parameter {name!r}: value {typed[0].get('value')!r} is not a number") from None
        if not math.isfinite(value):
            raise fail(entry, f"parameter {name!r}: value {value} is not finite")
        unit, declared = typed[0].get("unit"), unit_of(v)
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


def default_experiment(root, fail) -> tuple[float | None, float | None]:
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
