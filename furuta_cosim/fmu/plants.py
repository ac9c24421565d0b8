"""Plant files (``scenarios/plants/*.yaml``): parameter sets of a declared model, or linear
state-space plants that the exporter turns into FMUs of their own."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from furuta_cosim import paths
from furuta_cosim.config import Checker, Frozen, load_yaml, resolve_file
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


@dataclass(frozen=True)
class PlantSet:
    """One plant file: ``model`` names the folder in ``fmu_src/``."""

    name: str
    path: Path
    model: str
    description: str
    parameters: Mapping[str, float] = field(default_factory=lambda: Frozen({}))
    linear: LinearSpec | None = None


def plant_path(name: str | Path, also: tuple[str, ...] = ()) -> Path:
    """A file path, a plant name in ``scenarios/plants``, or a model's default set; ``also``
    names what the caller accepts besides (listed in the error for an unknown name)."""
    model_py = paths.fmu_sources() / str(name) / "model.py"
    if Path(name).suffix not in (".yaml", ".yml") and model_py.is_file():
        default = _default_set(model_py)
        if default:
            name = default
    return resolve_file(name, paths.scenarios() / "plants", "plant", also=tuple(model_names()) + also)


def model_names() -> list[str]:
    """The plant models that have a default parameter set (``furuta``): names a plant may take."""
    return sorted(p.parent.name for p in paths.fmu_sources().glob("*/model.py") if _default_set(p))


def _default_set(model_py: Path) -> str | None:
    match = re.search(r'^DEFAULT_PARAMETER_SET\s*=\s*"([^"]+)"', model_py.read_text(), re.M)
    return match.group(1) if match else None


def load_plant(name: str | Path = "furuta", also: tuple[str, ...] = ()) -> PlantSet:
    """Read and validate a plant file; raises ConfigError listing every problem."""
    return _load(plant_path(name, also), seen=())


def _load(path: Path, seen: tuple) -> PlantSet:
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", required=("model",),
                        optional=("description", "extends", "parameters", "identifier", "time",
                                  "period", "substeps", "A", "B", "C", "D", "inputs", "outputs", "time_unit",
                                  "states", "x0"))
    if top is None or "model" not in top:
        check.done()
    model = check.string(top["model"], "model")
    if model is None:
        check.done()
    if not (paths.fmu_sources() / model / "model.py").is_file():
        known = sorted(p.name for p in paths.fmu_sources().iterdir() if (p / "model.py").is_file())
        check.fail("model", f"no plant model {model!r} in fmu_src (known: {', '.join(known)})")
        check.done()
    description = check.text(top["description"], "description") if "description" in top else ""
    if model == "linear":
        return PlantSet(path.stem, path, model, str(description), linear=_linear(top, path, check))
    parameters = {}
    if "extends" in top:
        base_name = check.string(top["extends"], "extends")
        check.done()
        base_path = Path(base_name)
        if base_path.suffix in (".yaml", ".yml") and not base_path.is_absolute():
            base_path = path.parent / base_path  # a relative file is relative to this one
        else:
            try:
                base_path = plant_path(base_name)
            except ConfigError as error:
                raise error.within(f"{path}: extends") from None
        if base_path.resolve() in seen:
            raise ConfigError([f"{path}: extends: circular ({base_name})"])
        base = _load(base_path, seen + (path.resolve(),))
        if base.model != model:
            check.fail("extends", f"{base_name} is a {base.model} plant, not {model}")
        parameters.update(base.parameters)
    parameters.update(check.numbers(top.get("parameters", {}), "parameters"))
    check.done()
    return PlantSet(path.stem, path, model, str(description), Frozen(parameters))


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
    period = check.number(top.get("period", 1.0), "period", positive=True)
    substeps = check.number(top.get("substeps", 10), "substeps", minimum=1, integer=True)
    identifier = top.get("identifier") or "".join(p.capitalize() for p in re.split(r"[^A-Za-z0-9]+", path.stem))
    if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", str(identifier)):
        check.fail("identifier", f"must be a C identifier, got {identifier!r}")
    if inputs and outputs and states and len(set(inputs + outputs + states)) != nu + ny + n:
        check.fail("inputs/outputs/states", "names must differ from each other")
    if time == "continuous" and "period" in top:
        check.fail("period", "only a discrete plant has a sample period")
    unit = check.string(top["time_unit"], "time_unit") if "time_unit" in top else "s"
    check.done()
    return LinearSpec(str(identifier), str(top.get("description", "")), time == "discrete",
                      period, substeps, A, B, C, D, inputs, outputs, states, x0, unit or "s")
