"""Scenario files: YAML -> frozen dataclasses, validated strictly.

Every problem is reported at once with its place (``file: timing.control_period: must be
> 0, got -1``); unknown keys are problems. Names that only the plant FMU knows (variables,
inputs) and the controllers' fit to the plant are checked when the run is prepared
(:func:`furuta_cosim.cosim.master.prepare`), also with file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from furuta_cosim import paths
from furuta_cosim.config import Checker, Frozen, load_yaml, resolve_file
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.variables import MAX_FACTOR, MAX_OFFSET, MIN_FACTOR
from furuta_cosim.metrics import checked, entry
from furuta_cosim.references import KINDS, PLAIN

METRIC_BOUNDS = ("max", "min")


@dataclass(frozen=True)
class Signal:
    """One reference component; a reference is the sum of its components."""

    kind: str
    params: Mapping[str, object]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return KINDS[self.kind].value(self.params, t)


@dataclass(frozen=True)
class Reference:
    output: str | None  # None: the plant's default (its first measured output, else its first state)
    signals: tuple[Signal, ...]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        total = np.zeros_like(t)
        for signal in self.signals:
            total = total + signal(t)
        return total

    @property
    def settles(self) -> bool:
        """True when it ends constant (steps, tables, constants): step metrics apply."""
        return all(KINDS[s.kind].settles for s in self.signals)


@dataclass(frozen=True)
class Noise:
    seed: int
    process: Mapping[str, float]      # FMU disturbance input -> standard deviation
    measurement: Mapping[str, float]  # fed-back signal -> standard deviation


@dataclass(frozen=True)
class Pulse:
    input: str
    start: float
    duration: float
    value: float


@dataclass(frozen=True)
class Requirement:
    metric: str
    max: float | None = None
    min: float | None = None
    controllers: tuple[str, ...] = ()  # empty: every controller

    def applies_to(self, controller: str) -> bool:
        return not self.controllers or controller in self.controllers

    def check(self, value: float | None) -> bool:
        if value is None or not math.isfinite(value):
            return False
        return (self.max is None or value <= self.max) and (self.min is None or value >= self.min)

    def describe(self) -> str:
        bounds = [f"<= {self.max:g}" if self.max is not None else "",
                  f">= {self.min:g}" if self.min is not None else ""]
        return f"{self.metric} {' and '.join(b for b in bounds if b)}"


@dataclass(frozen=True)
class Estimator:
    kind: str
    measured: tuple[str, ...]


@dataclass(frozen=True)
class PlantMapping:
    """How an FMU's variables appear to the controller (``plant.mapping``): view name -> FMU
    variable. ``states`` is in the controller's order."""

    states: Mapping[str, str]          # fed-back state -> FMU output
    disturbances: Mapping[str, str]    # disturbance name -> FMU input
    initial: Mapping[str, str]         # state -> FMU parameter that sets its start value
    source: str | None = None          # a mapping file (regress --mapping), else the scenario's
    control_input: str | None = None   # the file's control_input
    # FMU variable -> (scale, offset) given in the mapping: view value = scale * FMU value + offset
    conversions: Mapping[str, tuple] = field(default_factory=dict)
    outputs: Mapping[str, str] = field(default_factory=dict)  # recorded output (not fed back) -> FMU output
    ignore: tuple[str, ...] = ()       # FMU outputs not read at all


@dataclass(frozen=True)
class Regression:
    """How ``regress`` compares a run with its baseline: a metric passes when
    ``|got - expected| <= atol + rtol * |expected|``; a trace passes when every sample lies in
    a band around the baseline's (fmpy.util.validate_signal: ``dy`` of the signal's range
    above and below, widened over ``dx`` baseline points on either side)."""

    rtol: float = 1e-6
    atol: float = 1e-9
    metrics: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: Frozen({}))
    dy: float = 1e-3
    dx: int = 3
    points: int = 200           # baseline trace points (the run is downsampled to about this)
    # a run that stops early (a diverging loop) is compared on what is reproducible across
    # machines: that it stops, when (within ``divergence_time``; None: 5 % of the duration),
    # and its trace while every signal stays within +-``divergence_bound``; past that, the
    # last bits of BLAS decide where it goes
    divergence_bound: float = 100.0
    divergence_time: float | None = None

    def tolerance(self, metric: str) -> tuple[float, float]:
        """(rtol, atol) of ``metric``: the scenario's own for it, else the larger of the
        scenario's default and the least the metric itself needs (its registry entry)."""
        own, registered = self.metrics.get(metric, {}), entry(metric)
        least = (registered.rtol, registered.atol) if registered else (0.0, 0.0)
        return own.get("rtol", max(self.rtol, least[0])), own.get("atol", max(self.atol, least[1]))


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    path: Path | None
    plant: str
    overrides: Mapping[str, float]
    initial: Mapping[str, float]
    control_input: str | None
    duration: float
    control_period: float | None    # None: the plant's sample period, or 2 ms
    communication_step: float | None  # None: the control period
    reference: Reference
    noise: Noise | None
    disturbances: tuple[Pulse, ...]
    actuator_limit: float | None
    controllers: tuple[str, ...]
    estimator: Estimator | None
    requirements: tuple[Requirement, ...]
    error_window: tuple[float, float] | None
    plot: tuple[str, ...]
    fmu: Path | None = None             # an FMU to run instead of building plant.model
    mapping: PlantMapping | None = None
    regression: Regression = field(default_factory=Regression)
    delay: int = 0                      # control samples between a measurement and its command

    @property
    def source(self) -> str:
        return str(self.path) if self.path else self.name

    @property
    def folder(self) -> Path | None:
        """Where the files it names are looked up first (None: a scenario made in code)."""
        return self.path.parent if self.path else None


def scenario_path(name: str | Path, beside: Path | None = None) -> Path:
    """A scenario name of ``scenarios/``, or a file (relative: to ``beside`` when given)."""
    return resolve_file(name, paths.scenarios(), "scenario", beside=beside)


def load_scenario(name: str | Path) -> Scenario:
    """Read and validate a scenario file (the Scenarios page lists every key).

    Parameters
    ----------
    name : str or path
        A shipped scenario's name (``paper-step``) or a file.

    Returns
    -------
    Scenario

    Raises
    ------
    ConfigError
        Naming the file and key of every problem at once.
    """
    path = scenario_path(name)
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", required=("plant", "timing", "controllers"),
                        optional=("name", "description", "reference", "noise", "disturbances",
                                  "actuator", "estimator", "requirements", "metrics", "plot",
                                  "regression"))
    if top is None:
        check.done()
    plant, overrides, initial, control_input, fmu, mapping = (
        _plant(check, top["plant"], path.parent) if "plant" in top
        else ("", Frozen({}), Frozen({}), None, None, None))
    *timing, delay = _timing(check, top["timing"]) if "timing" in top else (0.0, None, None, 0)
    reference = _reference(check, top.get("reference", {"signal": {"type": "constant", "value": 0.0}}))
    noise = _noise(check, top["noise"]) if "noise" in top else None
    disturbances = _disturbances(check, top.get("disturbances", []))
    limit = None
    if "actuator" in top:
        actuator = check.mapping(top["actuator"], "actuator", required=("limit",))
        if actuator and "limit" in actuator:
            limit = check.number(actuator["limit"], "actuator.limit", positive=True)
    controllers = _controllers(check, top["controllers"]) if "controllers" in top else ()
    estimator = _estimator(check, top["estimator"]) if "estimator" in top else None
    requirements = _requirements(check, top.get("requirements", []))
    window = None
    if "metrics" in top:
        metrics = check.mapping(top["metrics"], "metrics", optional=("error_window",))
        if metrics and "error_window" in metrics:
            pair = check.vector(metrics["error_window"], "metrics.error_window", 2)
            if pair and not pair[0] < pair[1]:
                check.fail("metrics.error_window", f"expected [start, end] with start < end, got {pair}")
            window = tuple(pair) if pair else None
    plot = ()
    if "plot" in top:
        plot = tuple(check.names(top["plot"], "plot") or ())
    regression = _regression(check, top["regression"]) if "regression" in top else Regression()
    name = (check.file_name(top["name"], "name") if "name" in top
            else check.file_name(path.stem, "name (taken from the file name)"))
    description = check.text(top["description"], "description") if "description" in top else ""
    check.done()
    return Scenario(name, description, path,
                    plant, overrides, initial, control_input, *timing, reference, noise,
                    disturbances, limit, controllers, estimator, requirements, window, plot,
                    fmu, mapping, regression, delay)


def load_mapping(path: str | Path) -> PlantMapping:
    """A plant-mapping file (``regress --fmu FMU --mapping FILE``): ``control_input`` and the
    ``states``, ``disturbances`` and ``initial`` of a scenario's ``plant.mapping``. Problems
    found later against the FMU name this file and its keys."""
    from dataclasses import replace

    path = Path(path)
    if not path.is_file():
        raise ConfigError([f"mapping {path}: no such file"])
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", optional=("control_input",) + MAPPING_KEYS)
    control_input = None
    if top and "control_input" in top:
        control_input = check.string(top["control_input"], "control_input")
    parts = {k: v for k, v in (top or {}).items() if k in MAPPING_KEYS}
    mapping = _mapping(check, parts, prefix="")
    check.done()
    return replace(mapping, source=str(path), control_input=control_input)


def _regression(check: Checker, value) -> Regression:
    section = check.mapping(value, "regression", optional=("rtol", "atol", "metrics", "band", "points",
                                                            "divergence"))
    if not section:
        return Regression()
    found = {}
    for key in ("rtol", "atol"):
        if key in section:
            found[key] = check.number(section[key], f"regression.{key}", minimum=0.0)
    metrics = {}
    raw = section.get("metrics", {})
    entries = check.mapping(raw, "regression.metrics", optional=tuple(raw) if isinstance(raw, dict) else ())
    for metric, tolerance in (entries or {}).items():
        key = f"regression.metrics.{metric}"
        if checked(check, metric, key) is None:
            continue
        own = check.mapping(tolerance, key, optional=("rtol", "atol"))
        if own:
            metrics[str(metric)] = Frozen({k: check.number(v, f"{key}.{k}", minimum=0.0)
                                           for k, v in own.items()})
    found["metrics"] = Frozen(metrics)
    if "band" in section:
        band = check.mapping(section["band"], "regression.band", optional=("dy", "dx"))
        if band and "dy" in band:
            found["dy"] = check.number(band["dy"], "regression.band.dy", minimum=0.0)
        if band and "dx" in band:
            found["dx"] = check.number(band["dx"], "regression.band.dx", minimum=1, integer=True)
    if "points" in section:
        points = check.number(section["points"], "regression.points", minimum=10, integer=True)
        if points is not None and points > 100_000:
            check.fail("regression.points", f"at most 100000 (a baseline is meant to stay small), got {points}")
            points = None
        found["points"] = points
    if "divergence" in section:
        diverged = check.mapping(section["divergence"], "regression.divergence", optional=("bound", "time"))
        if diverged and "bound" in diverged:
            found["divergence_bound"] = check.number(diverged["bound"], "regression.divergence.bound",
                                                     positive=True)
        if diverged and "time" in diverged:
            found["divergence_time"] = check.number(diverged["time"], "regression.divergence.time",
                                                    positive=True)
    return Regression(**{k: v for k, v in found.items() if v is not None})


def _plant(check: Checker, value, folder: Path):
    section = check.mapping(value, "plant", optional=("model", "fmu", "overrides", "initial",
                                                       "control_input", "mapping"))
    if section is None:
        return "", Frozen({}), Frozen({}), None, None, None
    if "model" not in section and "fmu" not in section:
        check.fail("plant", "expected model (a plant name or file) or fmu (an FMU file)")
    elif "model" in section and "fmu" in section:
        check.fail("plant", "model and fmu both given: model builds the plant's FMU, fmu runs "
                            "another one; give one of them")
    model = check.string(section.get("model"), "plant.model") if "model" in section else ""
    fmu = None
    if "fmu" in section:
        text = check.string(section["fmu"], "plant.fmu")
        if text:
            fmu = Path(text) if Path(text).is_absolute() else folder / text
    overrides = check.numbers(section.get("overrides", {}), "plant.overrides")
    given = section.get("initial", {})
    if isinstance(given, dict):  # a pendulum hanging down starts at pi: `<angle>: pi` says so
        given = {k: ({"pi": math.pi, "-pi": -math.pi}.get(v.strip(), v) if isinstance(v, str) else v)
                 for k, v in given.items()}
    initial = check.numbers(given, "plant.initial")
    control_input = None
    if "control_input" in section:
        control_input = check.string(section["control_input"], "plant.control_input")
    mapping = _mapping(check, section["mapping"]) if "mapping" in section else None
    return model or "", overrides, initial, control_input, fmu, mapping


def _mapping(check: Checker, value, prefix: str = "plant.mapping.") -> PlantMapping | None:
    section = check.mapping(value, prefix.rstrip(".") or "", optional=MAPPING_KEYS)
    if section is None:
        return None
    parts, conversions = {}, {}
    for part in ("states", "outputs", "disturbances", "initial"):
        key = f"{prefix}{part}"
        raw = section.get(part, {})
        entries = check.mapping(raw, key, optional=tuple(raw) if isinstance(raw, dict) else ())
        names = {}
        for name, target in (entries or {}).items():
            where = f"{key}.{name}"
            if isinstance(target, dict) and part != "initial":
                # {variable: NAME, scale: S, offset: O}: the view's value is S * FMU value + O
                entry = check.mapping(target, where, required=("variable",), optional=("scale", "offset"))
                if not entry or "variable" not in entry:
                    continue
                text = check.string(entry["variable"], f"{where}.variable")
                scale = check.number(entry.get("scale", 1.0), f"{where}.scale")
                offset = check.number(entry.get("offset", 0.0), f"{where}.offset")
                if scale is not None and not MIN_FACTOR <= abs(scale) <= MAX_FACTOR:
                    check.fail(f"{where}.scale", f"expected a magnitude in [{MIN_FACTOR:g}, {MAX_FACTOR:g}] "
                               f"(the view's value is scale * FMU value + offset), got {scale:g}")
                elif offset is not None and abs(offset) > MAX_OFFSET:
                    check.fail(f"{where}.offset", f"expected a magnitude of at most {MAX_OFFSET:g}, got {offset:g}")
                elif text and scale is not None and offset is not None:
                    conversions[text] = (float(scale), float(offset))
            else:
                text = check.string(target, where)
            if text:
                names[str(name)] = text
        parts[part] = Frozen(names)
    ignore = []
    if "ignore" in section:
        raw = section["ignore"]
        if not isinstance(raw, list) or not all(isinstance(n, str) and n for n in raw):
            check.fail(f"{prefix}ignore", f"expected a list of FMU output names, got {raw!r}")
        else:
            ignore = list(raw)
    mapped = list(parts["states"].values()) + list(parts["outputs"].values())
    if len(set(mapped)) != len(mapped):
        check.fail(f"{prefix}states", "two names map to the same FMU output")
    pushed = list(parts["disturbances"].values())
    if len(set(pushed)) != len(pushed):
        twice = sorted({n for n in pushed if pushed.count(n) > 1})
        check.fail(f"{prefix}disturbances", f"two disturbances act on the same FMU input ({', '.join(twice)})")
    for name in ignore:
        if name in mapped:
            check.fail(f"{prefix}ignore", f"{name} is mapped: it cannot be ignored as well")
    for name in parts["initial"]:
        if parts["states"] and name not in parts["states"]:
            check.fail(f"{prefix}initial.{name}", f"not a mapped state "
                       f"(states: {', '.join(parts['states'])})")
    return PlantMapping(parts["states"], parts["disturbances"], parts["initial"],
                        conversions=Frozen(conversions), outputs=parts["outputs"], ignore=tuple(ignore))


# the keys of plant.mapping and of a mapping file (which adds control_input)
MAPPING_KEYS = ("states", "outputs", "ignore", "disturbances", "initial")


def _timing(check: Checker, value):
    section = check.mapping(value, "timing", required=("duration",),
                            optional=("control_period", "communication_step", "delay"))
    if not section:
        return 0.0, None, None, 0
    duration = check.number(section.get("duration"), "timing.duration", positive=True) if "duration" in section else None
    period = step = None
    if "control_period" in section:
        period = check.number(section["control_period"], "timing.control_period", positive=True)
    if "communication_step" in section:
        step = check.number(section["communication_step"], "timing.communication_step", positive=True)
    if duration and period and duration < period:
        check.fail("timing.duration", f"must be at least one control period ({period:g}), got {duration:g}")
    delay = 0
    if "delay" in section:
        if section["delay"] not in (0, 1) or isinstance(section["delay"], bool):
            check.fail("timing.delay", f"expected 0 or 1 (control samples), got {section['delay']!r}")
        else:
            delay = int(section["delay"])
    return duration or 0.0, period, step, delay


def _signal(check: Checker, value, key: str) -> Signal | None:
    if not isinstance(value, dict) or "type" not in value:
        check.fail(key, f"expected a mapping with a type ({', '.join(KINDS)})")
        return None
    name = check.string(value["type"], f"{key}.type", tuple(KINDS))
    if name is None:
        return None
    kind = KINDS[name]
    section = check.mapping(value, key, required=kind.required + ("type",), optional=kind.optional)
    if section is None:
        return None
    params = {}
    for name in kind.required + kind.optional:
        if name not in section:
            continue
        read = kind.read(check, section, key, name)
        if read is PLAIN:
            # a reference is a physical signal: within +-1e12 like every matrix entry
            minimum = 0.0 if name in kind.times else None
            read = check.number(section[name], f"{key}.{name}", positive=name in kind.positive,
                                minimum=minimum, maximum=MAX_MAGNITUDE)
            if read is not None and minimum is None and read < -MAX_MAGNITUDE:
                check.fail(f"{key}.{name}", f"must be >= {-MAX_MAGNITUDE:g}, got {read:g}")
                read = None
        params[name] = read
    return Signal(kind.name, Frozen(params))


def _reference(check: Checker, value) -> Reference:
    section = check.mapping(value, "reference", required=("signal",), optional=("output",))
    if not section:
        return Reference(None, ())
    output = check.string(section["output"], "reference.output") if "output" in section else None
    raw = section.get("signal")
    items = raw if isinstance(raw, list) else [raw]
    if isinstance(raw, list) and not raw:
        check.fail("reference.signal", "expected at least one signal")
    signals = []
    for k, item in enumerate(items):
        key = f"reference.signal[{k}]" if isinstance(raw, list) else "reference.signal"
        signal = _signal(check, item, key)
        if signal:
            signals.append(signal)
    return Reference(output, tuple(signals))


def _noise(check: Checker, value) -> Noise | None:
    section = check.mapping(value, "noise", required=("seed",), optional=("process", "measurement"))
    if not section:
        return None
    seed = check.number(section.get("seed"), "noise.seed", integer=True, minimum=0) if "seed" in section else 0
    process = check.numbers(section.get("process", {}), "noise.process", minimum=0.0)
    measurement = check.numbers(section.get("measurement", {}), "noise.measurement", minimum=0.0)
    return Noise(seed or 0, process, measurement)


def _disturbances(check: Checker, value) -> tuple[Pulse, ...]:
    if not isinstance(value, list):
        check.fail("disturbances", "expected a list of pulses")
        return ()
    pulses = []
    for k, item in enumerate(value):
        key = f"disturbances[{k}]"
        section = check.mapping(item, key, required=("input", "start", "duration", "value"))
        if not section or len(section) < 4:
            continue
        name = check.string(section["input"], f"{key}.input")
        start = check.number(section["start"], f"{key}.start", minimum=0.0)
        duration = check.number(section["duration"], f"{key}.duration", positive=True)
        amount = check.number(section["value"], f"{key}.value")
        if None not in (name, start, duration, amount):
            pulses.append(Pulse(name, start, duration, amount))
    return tuple(pulses)


def _controllers(check: Checker, value) -> tuple[str, ...]:
    names = check.names(value, "controllers")
    if names == []:
        check.fail("controllers", "expected at least one controller")
    return tuple(names or ())


def _estimator(check: Checker, value) -> Estimator | None:
    section = check.mapping(value, "estimator", required=("type", "measured"))
    if not section or len(section) < 2:
        return None
    kind = check.string(section["type"], "estimator.type", ("kalman",))
    measured = check.names(section["measured"], "estimator.measured")
    if kind and measured:
        return Estimator(kind, tuple(measured))
    return None


def _requirements(check: Checker, value) -> tuple[Requirement, ...]:
    if not isinstance(value, list):
        check.fail("requirements", "expected a list of {metric, max and/or min}")
        return ()
    result = []
    for k, item in enumerate(value):
        key = f"requirements[{k}]"
        section = check.mapping(item, key, required=("metric",), optional=METRIC_BOUNDS + ("controllers",))
        if not section or "metric" not in section:
            continue
        metric = checked(check, section["metric"], f"{key}.metric")
        bounds = {b: check.number(section[b], f"{key}.{b}") for b in METRIC_BOUNDS if b in section}
        if not bounds:
            check.fail(key, "expected a bound: max and/or min")
        elif None not in bounds.values() and len(bounds) == 2 and bounds["min"] > bounds["max"]:
            check.fail(key, f"min {bounds['min']:g} is above max {bounds['max']:g}: no value meets both")
        scope = tuple(check.names(section["controllers"], f"{key}.controllers") or ()) if "controllers" in section else ()
        if metric and bounds and None not in bounds.values():
            result.append(Requirement(metric, bounds.get("max"), bounds.get("min"), scope))
    return tuple(result)
