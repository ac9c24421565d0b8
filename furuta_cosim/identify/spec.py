"""Identify specs (``scenarios/identify/*.yaml``): which plant, which experiments, which
parameters are free, within which bounds.

    name: qube-servo-3
    plant: qube-servo-3              # start values and every fixed parameter
    experiments: [../rigs/qube-servo-3/free-swing.yaml]
    validation: []                   # held out: scored, never fitted
    free:
      I_p: {start: 3.3e-5, bounds: [1.0e-6, 1.0e-3]}
    horizon: [2.0, 8.0]              # seconds fitted first, in stages, before the whole windows
    tolerance: 20                    # a trusted fit replays within this many noise floors RMS
    holdout: 0.25                    # the last quarter of each log held out, validated on
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from furuta_cosim import paths
from furuta_cosim.config import Checker, excerpt, load_yaml, resolve_file
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import Experiment, load_experiment

_KEYS = ("name", "description", "plant", "experiments", "validation", "free", "horizon",
         "max_simulations", "tolerance", "holdout")
MAX_FREE = 40


@dataclass(frozen=True)
class Parameter:
    """A free parameter: its first guess and its bounds (the fit never leaves them)."""

    name: str
    start: float | None          # None: the plant's own value
    bounds: tuple[float, float]


@dataclass(frozen=True)
class IdentifySpec:
    name: str
    description: str
    path: Path
    plant: str                   # a plant name, or a path (resolved beside the spec)
    experiments: tuple[Experiment, ...]
    validation: tuple[Experiment, ...]
    free: tuple[Parameter, ...]
    horizon: tuple[float, ...] | None   # None: doubling from 2 s
    max_simulations: int = 2000
    tolerance: float = 20.0      # noise floors of replay RMS a trusted fit stays within
    holdout: float = 0.0         # the last fraction of each fitted log, held out for validation


def spec_path(name: str | Path) -> Path:
    return resolve_file(name, paths.scenarios() / "identify", "identify spec")


def load_identify_spec(name: str | Path) -> IdentifySpec:
    """Read and check an identify spec and its experiment files; one ConfigError lists every
    problem, each with its file and key."""
    path = spec_path(name)
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", required=("plant", "experiments", "free"), optional=_KEYS)
    check.done()
    spec_name = check.file_name(top.get("name", path.stem), "name")
    description = check.text(top.get("description", ""), "description")
    plant = check.string(top["plant"], "plant")
    if plant is not None and (plant.endswith((".yaml", ".yml")) or "/" in plant):
        plant = str(path.parent / plant) if not Path(plant).is_absolute() else plant
    free = _free(check, top["free"])
    horizon = None
    if "horizon" in top:
        values = check.vector(top["horizon"], "horizon")
        if values is not None:
            if not all(v > 0 for v in values) or sorted(values) != values or len(set(values)) != len(values):
                check.fail("horizon", f"expected increasing durations > 0 (seconds), got {values}")
            else:
                horizon = tuple(values)
    budget = check.number(top.get("max_simulations", 2000), "max_simulations", minimum=1,
                          maximum=1_000_000, integer=True)
    from furuta_cosim.identify.verdict import TOLERANCE

    tolerance = check.number(top.get("tolerance", TOLERANCE), "tolerance", positive=True, maximum=1e6)
    holdout = check.number(top.get("holdout", 0.0), "holdout", minimum=0.0, maximum=0.9)
    experiments = _experiments(check, top["experiments"], "experiments", path, required=True)
    validation = _experiments(check, top.get("validation", []), "validation", path)
    check.done()
    names = [e.name for e in experiments + validation]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        check.fail("experiments", f"two experiments are named {', '.join(twice)}: names must differ "
                                  "(they name the free initial states and the figures)")
    fitted_values = sum(e.samples * len(e.outputs) for e in experiments)
    unknowns = len(free) + sum(len(e.free_starts()) for e in experiments)
    if fitted_values <= unknowns:
        check.fail("experiments", f"{fitted_values} measured values for {unknowns} free unknowns: "
                                  "a fit needs more samples than free parameters")
    check.done()
    return IdentifySpec(spec_name, description, path, plant, tuple(experiments), tuple(validation),
                        tuple(free), horizon, int(budget), float(tolerance), float(holdout))


def _free(check: Checker, value) -> list[Parameter]:
    section = check.mapping(value, "free", optional=tuple(value) if isinstance(value, dict) else ())
    if section is not None and not section:
        check.fail("free", "names no parameter: nothing to fit")
    if section and len(section) > MAX_FREE:
        check.fail("free", f"{len(section)} parameters; at most {MAX_FREE}")
        return []
    found = []
    for name, entry in (section or {}).items():
        key = f"free.{name}"
        if "." in str(name):
            check.fail(key, "a plant parameter's name has no '.'")
            continue
        item = check.mapping(entry, key, required=("bounds",), optional=("start",))
        if not item or "bounds" not in item:
            continue
        bounds = check.vector(item["bounds"], f"{key}.bounds", 2)
        start = check.number(item["start"], f"{key}.start") if "start" in item else None
        if bounds is None or ("start" in item and start is None):
            continue
        lo, hi = bounds
        if max(abs(lo), abs(hi)) > MAX_MAGNITUDE:
            check.fail(f"{key}.bounds", f"expected magnitudes of at most {MAX_MAGNITUDE:g}, got [{lo:g}, {hi:g}]")
            continue
        if not lo < hi:
            check.fail(f"{key}.bounds", f"expected [lo, hi] with lo < hi, got [{lo:g}, {hi:g}]")
            continue
        if start is not None and not lo <= start <= hi:
            check.fail(f"{key}.start", f"{start:g} is outside its bounds [{lo:g}, {hi:g}]")
            continue
        found.append(Parameter(str(name), start, (lo, hi)))
    return found


def _experiments(check: Checker, value, key: str, path: Path, required: bool = False) -> list[Experiment]:
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        check.fail(key, f"expected a list of experiment files, got {excerpt(repr(value))}")
        return []
    if required and not value:
        check.fail(key, "names no experiment")
    found = []
    for k, name in enumerate(value):
        file = Path(name)
        file = file if file.is_absolute() else path.parent / file
        if file.suffix not in (".yaml", ".yml"):
            file = file.with_name(file.name + ".yaml")
        try:
            found.append(load_experiment(file))
        except ConfigError as error:
            check.problems.extend(error.within(f"{path}: {key}[{k}]").problems)
    return found

