"""Plant files (``scenarios/plants/*.yaml``): parameter sets of a declared model, or linear
state-space plants that the exporter turns into FMUs of their own."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from furuta_cosim import paths
from furuta_cosim.config import Checker, Frozen, excerpt, load_yaml, resolve_file
from furuta_cosim.errors import ConfigError


@dataclass(frozen=True)
class LinearSpec:
    """A linear plant; ``discrete`` plants advance once per ``period``."""

    identifier: str
    description: str
    discrete: bool
    period: float
    substeps: int
    A: list
    B: list
    C: list
    D: list
    inputs: list
    outputs: list
    states: list
    x0: list
    time_unit: str = "s"          # what one unit of time is: "s", or "samples" for a plant in samples
    # (name, unit, description) of inputs and outputs that say more than "control input" and
    # "measured output" (a controller FMU's: what each fed-back signal is, its unit, its zero)
    signals: tuple = ()


@dataclass(frozen=True)
class PlantSet:
    """One plant file: ``model`` names the folder in ``fmu_src/``."""

    name: str
    path: Path
    model: str
    description: str
    parameters: Mapping[str, float] = field(default_factory=lambda: Frozen({}))
    linear: LinearSpec | None = None
    # the rig's own limits: control_period (min, max) in s, either None when not stated
    control_period: tuple = (None, None)
    # what a supervisor holds a rig to (``limits``: voltage, current, theta0, stall) and how the
    # rig's sensors read it (``sensors``): see RIG_LIMITS and SENSORS
    limits: Mapping[str, float] = field(default_factory=lambda: Frozen({}))
    sensors: Mapping[str, float] = field(default_factory=lambda: Frozen({}))
    # a user's plant folder (its model.py and model.c) when ``model`` names one, else None
    folder: Path | None = None


def model_folder(plant: PlantSet) -> Path:
    """Where the plant's declaration and equations are: the user's folder it names, or its
    model's folder in ``fmu_src/``."""
    return plant.folder if plant.folder is not None else paths.fmu_sources() / plant.model


def folder_problem(folder: Path) -> str | None:
    """Why ``folder`` is not a plant folder (None when it is): it holds the declaration
    ``model.py`` and the equations ``model.c``."""
    if not folder.is_dir():
        return f"{folder}: no such folder"
    missing = [name for name in ("model.py", "model.c") if not (folder / name).is_file()]
    if missing:
        return (f"{folder}: a plant folder holds model.py (the declaration) and model.c (the "
                f"equations); {' and '.join(missing)} missing (`furuta-cosim new-plant NAME` "
                "writes a folder to start from)")
    return None


def folder_plant(folder: str | Path) -> PlantSet:
    """The plant of a user's plant folder at its declared defaults (``build-fmu FOLDER``).

    Parameters
    ----------
    folder : path
        A plant folder: ``model.py`` (the declaration) and ``model.c`` (the equations).

    Returns
    -------
    PlantSet
        Named after the folder, with no parameters of its own (the declaration's defaults).

    Raises
    ------
    ConfigError
        When the folder is missing or lacks one of its two files.
    """
    folder = Path(folder)
    problem = folder_problem(folder)
    if problem:
        raise ConfigError([problem])
    folder = folder.resolve()
    return PlantSet(folder.name, folder / "model.py", str(folder),
                    f"the plant of {folder.name}/ at its declared defaults", folder=folder)


def is_folder(name: str | Path, beside: Path | None = None) -> Path | None:
    """The folder ``name`` is, when it is one (beside the naming file first), else None."""
    path = Path(name)
    for candidate in ([beside / path] if beside is not None and not path.is_absolute() else []) + [path]:
        if candidate.is_dir():
            return candidate
    return None


def voltage_limit(plant: PlantSet, parameters: Mapping[str, float] | None = None) -> float | None:
    """The amplifier's voltage limit a plant file states (None: none): its ``limits.voltage``,
    or the model's ``V_max`` parameter when that is > 0 (the smaller if both are stated).

    ``parameters`` are the values in force (a variant's) when not the file's own. One number
    serves the simulation (every command clipped to it before the plant) and the rig's
    supervisor (every command clipped to it before the board).
    """
    values = parameters if parameters is not None else plant.parameters
    stated = [plant.limits.get("voltage"), values.get("V_max") if plant.linear is None else None]
    stated = [float(v) for v in stated if v is not None and float(v) > 0.0]
    return min(stated) if stated else None


def content_sha256(plant: PlantSet) -> str:
    """A digest of what a plant is, whatever file holds it and whatever it extends: its model,
    its resolved parameters and its limits (two files with the same values give the same)."""
    import hashlib
    import json

    if plant.linear is not None:
        body = {"model": plant.model, "linear": repr(plant.linear)}
    else:
        model = plant.model
        if plant.folder is not None:   # a user's folder: what it holds, wherever it is
            model = {name: hashlib.sha256((plant.folder / name).read_bytes()).hexdigest()
                     for name in ("model.py", "model.c")}
        body = {"model": model, "parameters": dict(sorted(plant.parameters.items())),
                "control_period": list(plant.control_period), "limits": dict(plant.limits),
                "sensors": dict(plant.sensors)}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def plant_path(name: str | Path, also: tuple[str, ...] = (), beside: Path | None = None) -> Path:
    """A file path, a plant name in ``scenarios/plants``, or a model's default set; ``also``
    names what the caller accepts besides (listed in the error for an unknown name);
    ``beside``: the folder of the file that names the plant (see ``resolve_file``)."""
    if str(name) in model_names():
        name = _default_set(paths.fmu_sources() / str(name) / "model.py")
    return resolve_file(name, paths.scenarios() / "plants", "plant", beside=beside,
                        also=tuple(model_names()) + also)


# models of fmu_src/ the exporter builds from something else than a plant file: a scenario's
# source (export-ssp), never a plant
NOT_PLANTS = ("source",)


def models() -> list[str]:
    """The plant models of ``fmu_src/`` (a folder with a model.py and a plain name): the names
    a plant file's ``model`` may take; any other value is the path of a user's plant folder,
    whose ``model.py`` runs as the plant's declaration (a folder is code: name folders you trust)."""
    return sorted(p.parent.name for p in paths.fmu_sources().glob("*/model.py")
                  if re.fullmatch(r"[a-z][a-z0-9_]*", p.parent.name) and p.parent.name not in NOT_PLANTS)


def model_names() -> list[str]:
    """The plant models that have a default parameter set (``furuta``): names a plant may take."""
    return [name for name in models() if _default_set(paths.fmu_sources() / name / "model.py")]


def _default_set(model_py: Path) -> str | None:
    match = re.search(r'^DEFAULT_PARAMETER_SET\s*=\s*"([^"]+)"', model_py.read_text(), re.M)
    return match.group(1) if match else None


def load_plant(name: str | Path = "furuta", also: tuple[str, ...] = (),
               beside: Path | None = None) -> PlantSet:
    """Read and validate a plant file.

    Parameters
    ----------
    name : str or path
        A plant's name (``paper-calibrated``, ``qube-servo-3``), a model's name (its default
        set) or a file.
    also : tuple of str
        What the caller accepts besides, listed in the error for an unknown name.
    beside : path, optional
        The folder of the file that names it, where a relative path or a name is looked up
        first.

    Returns
    -------
    PlantSet

    Raises
    ------
    ConfigError
        Listing every problem of the file (and of the files it extends).
    """
    folder = is_folder(name, beside) if str(name) not in model_names() else None
    if folder is not None and any((folder / f).exists() for f in ("model.py", "model.c")):
        return folder_plant(folder)   # a plant folder (any other folder: "a folder, not a file")
    return _load(plant_path(name, also, beside), seen=())


def _load(path: Path, seen: tuple) -> PlantSet:
    data = load_yaml(path)
    check = Checker(path)
    if isinstance(data, dict) and "rejected" in data:
        # identify's fit that did not reproduce its data (identify/verdict.py): no plant to use
        why = data["rejected"] if isinstance(data["rejected"], str) else "see fit.json beside it"
        check.fail("rejected", f"identify judged this fit untrustworthy ({excerpt(why, 300)}); fit again, "
                               "or run identify with `accept=True` to write it as a plant all the same")
        check.done()
    top = check.mapping(data, "", required=("model",), optional=_NONLINEAR_KEYS + _LINEAR_KEYS)
    if top is None or "model" not in top:
        check.done()
    model = check.string(top["model"], "model")
    if model is None:
        check.done()
    # the keys of one kind of plant only: A in a furuta plant, extends in a linear one, would
    # otherwise be silently ignored
    own, other = ((_LINEAR_KEYS, _NONLINEAR_KEYS) if model == "linear" else (_NONLINEAR_KEYS, _LINEAR_KEYS))
    for key in top:
        if key in other and key not in own:
            check.fail(key, f"not a key of a {model} plant (its keys: model, description, "
                            f"{', '.join(k for k in own if k != 'description')})")
    folder = None
    if model not in models() and model != "linear" and _names_folder(model, path):
        # a user's plant folder, beside this file: model: path/to/folder
        folder = (path.parent / model).resolve()
        problem = folder_problem(folder)
        if problem:
            check.fail("model", problem)
            check.done()
        model = str(folder)
    elif model not in models():
        check.fail("model", f"expected the name of a plant model of fmu_src ({', '.join(models())}) "
                            f"or a plant folder's path (with a /, beside this file), got {_brief(model)}")
        check.done()
    description = check.text(top["description"], "description") if "description" in top else ""
    if model == "linear":
        return PlantSet(path.stem, path, model, str(description), linear=_linear(top, path, check))
    parameters = {}
    if "extends" in top:
        base_name = check.string(top["extends"], "extends")
        check.done()
        try:
            base_path = plant_path(base_name, beside=path.parent)
            where = base_path.resolve()
        except ConfigError as error:
            raise error.within(f"{path}: extends") from None
        except (RuntimeError, OSError, ValueError):   # a loop of links, a NUL in the name
            raise ConfigError([f"{path}: extends: {excerpt(str(base_name))}: a loop of symbolic links or not "
                               "a usable file name"]) from None
        if where in seen:
            raise ConfigError([f"{path}: extends: circular ({base_name})"])
        if len(seen) + 1 >= MAX_EXTENDS:
            raise ConfigError([f"{path}: extends: a chain of more than {MAX_EXTENDS} plant files "
                               f"(the first: {seen[0] if seen else path}); a plant extends a few at most"])
        try:
            base = _load(base_path, seen + (path.resolve(),))
        except ConfigError as error:   # the parent's problem, seen from the file that extends it
            # (a problem of a file further up the chain already names the file that extends it)
            raise ConfigError([problem if ": extends: " in problem else f"{path}: extends: {problem}"
                               for problem in error.problems]) from None
        if base.model != model:
            check.fail("extends", f"{base_name} is a {base.model} plant, not {model}")
        parameters.update(base.parameters)
    parameters.update(check.numbers(top.get("parameters", {}), "parameters"))
    period = base.control_period if "extends" in top else (None, None)
    limits = dict(base.limits) if "extends" in top else {}
    sensors = dict(base.sensors) if "extends" in top else {}
    if "limits" in top:
        period = _limits(check, top["limits"], period)
        limits.update(_rig_limits(check, top["limits"]))
    if "sensors" in top:
        section = check.mapping(top["sensors"], "sensors", optional=tuple(SENSORS))
        for key, value in (section or {}).items():
            if key in SENSORS:
                low, high, _ = SENSORS[key]
                number = check.number(value, f"sensors.{key}", minimum=low, maximum=high,
                                      integer=key == "encoder_counts")
                if number is not None and key.endswith("_sign") and number not in (1.0, -1.0):
                    check.fail(f"sensors.{key}", f"expected 1 or -1, got {number:g}")
                elif number is not None:
                    sensors[key] = number
    if "provenance" in top:  # where the values come from (identify writes it): read by people only
        check.mapping(top["provenance"], "provenance", optional=tuple(top["provenance"])
                      if isinstance(top["provenance"], dict) else ())
    check.done()
    return PlantSet(path.stem, path, model, str(description), Frozen(parameters),
                    control_period=period, limits=Frozen(limits), sensors=Frozen(sensors),
                    folder=folder)


def _names_folder(model: str, path: Path) -> bool:
    """A plant file's ``model`` names a folder: a path (``./cart``, ``plants/cart``) or a
    folder beside the file."""
    return "/" in model or model in (".", "..") or (path.parent / model).is_dir()


# what a supervisor holds a rig to; each is optional, and a rig plant without ``voltage`` is
# driven unlimited (``rig run`` says so)
RIG_LIMITS = {
    "voltage": (0.0, 1e3, "the amplifier's limit: every command is clipped to +-voltage (V)"),
    "current": (0.0, 1e3, "a current beyond +-current trips the supervisor (A)"),
    "theta0": (0.0, 1e3, "an arm angle beyond +-theta0 trips the supervisor (rad)"),
    "stall_voltage": (0.0, 1e3, "a command above this for stall_seconds while the arm stands still trips (V)"),
    "stall_seconds": (0.0, 1e3, "see stall_voltage (s)"),
}
# the limits that bound a signal of a run: limits key -> (the signal, its unit); a simulated run
# beyond one has left what the rig's supervisor allows (the QUBE's arm and current)
LIMITED_SIGNALS = {"theta0": ("theta0", "rad"), "current": ("i", "A")}
# how a rig's sensors read it: encoder counts per revolution of each, the sense of each angle
# against the model's, and the current sensor's noise (the virtual board reads the plant so)
SENSORS = {
    "encoder_counts": (1.0, 1e9, "encoder counts per revolution, quadrature (2048 on a QUBE)"),
    "arm_sign": (-1.0, 1.0, "+1 when the arm encoder counts up as the model's theta0 grows"),
    "pendulum_sign": (-1.0, 1.0, "+1 when the pendulum encoder counts up as theta1 grows"),
    "current_noise": (0.0, 1e3, "standard deviation of the current sensor (A)"),
}


def _rig_limits(check: Checker, value) -> dict:
    limits = value if isinstance(value, dict) else {}  # its keys are checked by _limits
    found = {}
    for key in RIG_LIMITS:
        if key in limits:
            low, high, _ = RIG_LIMITS[key]
            number = check.number(limits[key], f"limits.{key}", positive=True, maximum=high)
            if number is not None:
                found[key] = number
    if ("stall_voltage" in limits) != ("stall_seconds" in limits):
        check.fail("limits", "give stall_voltage and stall_seconds together")
    return found


def _limits(check: Checker, value, inherited: tuple) -> tuple:
    """``limits: {control_period: {min: S, max: S}}``: the periods the rig allows (its I/O
    hardware, the model's substeps); either bound may be left out, and one not given is the
    base plant's."""
    limits = check.mapping(value, "limits", optional=("control_period",) + tuple(RIG_LIMITS))
    if not limits or "control_period" not in limits:
        return inherited
    bounds = check.mapping(limits["control_period"], "limits.control_period", optional=("min", "max"))
    if bounds is None:
        return inherited
    low, high = inherited
    if "min" in bounds:
        low = check.period(bounds["min"], "limits.control_period.min")
    if "max" in bounds:
        high = check.period(bounds["max"], "limits.control_period.max")
    if low is not None and high is not None and low > high:
        check.fail("limits.control_period", f"min ({low:g}) is above max ({high:g})")
    return low, high


MAX_EXTENDS = 32  # plant files in one extends chain: a fitted plant on a rig's on a shipped one is 3
_NONLINEAR_KEYS = ("description", "extends", "parameters", "provenance", "limits", "sensors")
_LINEAR_KEYS = ("description", "identifier", "time", "period", "substeps", "A", "B", "C", "D",
                "inputs", "outputs", "time_unit", "states", "x0")
# an identifier names the FMU's C functions and files: no C keyword, no FMI name
_RESERVED = frozenset("""auto break case char const continue default do double else enum extern
float for goto if inline int long register restrict return short signed sizeof static struct
switch typedef union unsigned void volatile while _Bool _Complex _Imaginary""".split())


def _linear(top: dict, path: Path, check: Checker) -> LinearSpec:
    missing = [key for key in ("A", "B", "C", "time") if key not in top]
    for key in missing:
        check.fail(key, "missing (a linear plant needs A, B, C and time)")
    if missing:
        check.done()
    time = check.string(top["time"], "time", ("continuous", "discrete"))
    A = check.matrix(top["A"], "A")
    n = len(A) if A else None
    if A and len(A[0]) != n:
        check.fail("A", f"must be square, got {len(A)}x{len(A[0])}")
    B = check.matrix(top["B"], "B", rows=n)
    C = check.matrix(top["C"], "C", cols=n)
    if A is None or B is None or C is None:
        check.done()
    nu, ny = len(B[0]), len(C)
    D = check.matrix(top.get("D", [[0.0] * nu] * ny), "D", rows=ny, cols=nu)
    inputs = check.names(top.get("inputs", [f"u{k + 1}" for k in range(nu)] if nu > 1 else ["u"]),
                         "inputs", nu)
    outputs = check.names(top.get("outputs", [f"y{k + 1}" for k in range(ny)] if ny > 1 else ["y"]),
                          "outputs", ny)
    states = check.names(top.get("states", [f"x{k + 1}" for k in range(n)]), "states", n)
    x0 = check.vector(top.get("x0", [0.0] * n), "x0", n)
    period = check.period(top.get("period", 1.0), "period")
    substeps = check.number(top.get("substeps", 10), "substeps", minimum=1, integer=True)
    identifier = top.get("identifier") or "".join(p.capitalize() for p in re.split(r"[^A-Za-z0-9]+", path.stem))
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,63}", str(identifier)):
        check.fail("identifier", f"must be a C identifier (a letter, then letters, digits or _; "
                                 f"at most 64), got {_brief(identifier)}")
    elif identifier in _RESERVED or str(identifier).lower().startswith("fmi"):
        check.fail("identifier", f"{identifier!r} is a C keyword or an FMI name; choose another")
    if inputs and outputs and states and len(set(inputs + outputs + states)) != nu + ny + n:
        check.fail("inputs/outputs/states", "names must differ from each other")
    if time == "continuous" and "period" in top:
        check.fail("period", "only a discrete plant has a sample period")
    unit = check.string(top["time_unit"], "time_unit") if "time_unit" in top else "s"
    check.done()
    return LinearSpec(str(identifier), str(top.get("description", "")), time == "discrete",
                      period, substeps, A, B, C, D, inputs, outputs, states, x0, unit or "s")


def _brief(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
