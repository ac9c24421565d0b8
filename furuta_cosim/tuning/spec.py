"""Tuning specs (``scenarios/tuning/*.yaml``): YAML -> frozen dataclasses, validated as
strictly as scenarios (every problem at once, with file and key; unknown keys rejected).

    name: paper-spectral
    controller: {n_xc: 1, time: continuous, period: 0.002, model: paper-printed}
    parameters:
      Ac: {log: [-1, 2], sign: -1}       # Ac = -10^a
      Bc: {box: [-1, 1]}
      Cc: {box: [-1, 1]}
      Dc: {lqr: [-2, 3], R: 10}          # Dc = lqr(A, B, diag(10^q), R)
    objective: {type: spectral}
    constraints: {stability_margin: 0.01}
    optimizer: {method: bo, n_calls: 150, n_initial_points: 10, xi: 0.01, seed: 0}
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from furuta_cosim import paths
from furuta_cosim.config import Checker, load_yaml, resolve_file
from furuta_cosim.defaults import PAPER_PERIOD
from furuta_cosim.errors import ConfigError
from furuta_cosim.metrics import checked
from furuta_cosim.scenario import scenario_path
from furuta_cosim.tuning.space import KINDS, Block

OBJECTIVES = ("spectral", "scenarios", "tradeoff")
AGGREGATES = ("worst", "mean")


@dataclass(frozen=True)
class Term:
    metric: str
    weight: float
    relative_to: str | None = None     # a controller file: the metric divided by its value there


@dataclass(frozen=True)
class Criterion:
    """One number of a candidate: its weighted terms on each run, aggregated over the runs."""

    name: str
    terms: tuple[Term, ...]
    aggregate: str


@dataclass(frozen=True)
class Objective:
    type: str
    scenarios: tuple[str, ...] = ()    # resolved scenario files
    terms: tuple[Term, ...] = ()
    aggregate: str = "worst"
    criteria_: tuple[Criterion, ...] = ()  # tradeoff: two or more, each minimized

    @property
    def criteria(self) -> tuple[Criterion, ...]:
        """What a candidate is scored by: a scenarios objective is the one criterion
        ``objective``; a tradeoff has its own."""
        if self.type == "scenarios":
            return (Criterion("objective", self.terms, self.aggregate),)
        return self.criteria_

    @property
    def all_terms(self) -> tuple[Term, ...]:
        return tuple(term for criterion in self.criteria for term in criterion.terms)


@dataclass(frozen=True)
class Constraints:
    stability_margin: float = 0.0      # on Abar (and the sampled loop): abscissa <= -margin
    controller_stable: bool = False    # eig(Ac) stable
    max_abs: tuple[tuple[str, float], ...] = ()   # signal -> bound in co-simulation
    requirements: bool = True          # the scenarios' own requirements
    penalty: float = 1.0e3             # objective of an infeasible candidate (plus its violation)
    baseline: str | None = None        # no_worse_than: this controller's metrics, per run,
    no_worse_than: tuple[tuple[str, float], ...] = ()   # times these factors bound the candidate's
    # a candidate's run stops once a constraint on a metric that only grows is broken by this
    # slack (tuning/objective.py, Evaluator.limits); None: every run goes to its end
    stop_early: float | None = None  # off; a slack >= 0 turns early stopping on


# log and lqr bounds are exponents of 10, at most this large in magnitude
MAX_DECADES = 12
MAX_BOX = 1e6  # a box's bounds: beyond, the search's scaling of the box overflows
# limits that keep a spec from taking the machine (each refused with one line, documented)
MAX_STATES = 20            # controller states n_xc
MAX_CALLS = 100_000        # evaluations of one run
MAX_SEED = 2**32 - 1       # numpy's and scipy's seeds
MAX_VARIANTS = 65          # plant variants of a spec (as from_fit's 64 samples and the point estimate)
MAX_PENALTY = 1.0e9        # an infeasible score stays finite (penalty * 2 plus violations)
MAX_STOP = 1.0e6           # constraints.stop_early: a slack, at most this


@dataclass(frozen=True)
class OptimizerSettings:
    method: str = "bo"
    n_calls: int = 150
    n_initial_points: int = 10
    xi: float = 0.01
    seed: int = 0
    batch: int = 1
    gp_restarts: int = 0
    region: str = "trust"               # bo's candidates: a trust region, or the whole space
    start: str = "auto"                 # bo's start: around the first baseline, or the whole space
    front: str = "auto"                 # a tradeoff's search: ehvi (two criteria) or parego
    initial: tuple[str, ...] = ()       # controller files entering the initial design
    warm_start: bool = True             # the spec's baselines enter the initial design too


# rig trials of one tuning at most (`rig.n_trials`, `tune --n-trials`)
MAX_TRIALS = 1000


@dataclass(frozen=True)
class RigSettings:
    """How a tuning runs on a rig (``rig:``; tuning/rig.py): the budget in rig trials, the
    swing-up-and-balance file that resets the rig and holds the pendulum between scenarios,
    how far from upright a candidate's pendulum may fall before the trial counts it failed,
    the width of the safe method's confidence bounds, and the simulated fidelity's budget."""

    n_trials: int = 30
    reset: str | None = None       # a swing-up file (a name or a path, as the spec names controllers)
    fall: float = 0.5              # rad from upright
    beta: float = 2.0              # the safe set: mean + beta std of the constraint <= 0
    simulations: int | None = None  # the simulated fidelity's evaluations (default optimizer.n_calls)


@dataclass(frozen=True)
class TuningSpec:
    name: str
    description: str
    path: Path | None
    n_xc: int
    discrete: bool
    period: float
    model: str
    blocks: tuple[Block, ...]
    objective: Objective
    constraints: Constraints
    optimizer: OptimizerSettings
    variants: tuple[tuple[tuple[str, float], ...], ...] = ((),)
    baselines: tuple[str, ...] = ()    # controllers scored alike, for the summary
    plant: str | None = None           # every scenario runs on this plant (a name or a file)
    notes: tuple[str, ...] = ()        # what running on ``plant`` changed, in words
    fit: "FitSource | None" = None     # where the variants were drawn from, when from a fit
    swingup: str | None = None         # a swing-up file whose settings are tuned (``blocks``)
    rig: RigSettings = RigSettings()   # tuning with a rig in the loop (``tune --board``)

    @property
    def source(self) -> str:
        return str(self.path) if self.path else self.name


@dataclass(frozen=True)
class FitSource:
    """The identify run that plant variants were drawn from: its fit.json (path and sha256 of
    its content), how many variants and the seed of their design."""

    path: str
    sha256: str
    samples: int
    seed: int
    held: tuple = ()          # (name, value): not identifiable from the fit's data, not drawn
    plant_sha256: str = ""    # the fitted plant's values (plant.yaml beside the fit)


@dataclass(frozen=True)
class _Objective:
    """What a method's refusal looks at before the spec is whole: its objective."""

    objective: object


def spec_path(name: str | Path) -> Path:
    return resolve_file(name, paths.scenarios() / "tuning", "tuning spec")


def load_spec(name: str | Path, plant: str | Path | None = None,
              from_fit: tuple[str | Path, int, int] | None = None) -> TuningSpec:
    """Read and validate a tuning spec; the model named is loaded to size the matrices.

    Parameters
    ----------
    name : str or path
        A shipped spec's name (``effort``) or a file.
    plant : str or path, optional
        Tune for this plant (a name or file) instead of the spec's ``plant`` key: every
        scenario runs on it, the controller is designed on its linearization
        (``derived:PLANT``, whatever ``controller.model`` says), and every LQR the spec names
        (baselines, relative terms, constraints, initial points) is designed again for it with
        its own recipe (the same Q, R and period).
    from_fit : tuple, optional
        ``(fit_json, samples, seed)``: draw the spec's plant variants from that identify run,
        as ``variants: {from_fit: ...}`` does.

    Returns
    -------
    TuningSpec

    Raises
    ------
    ConfigError
        Naming the file and key of every problem.
    """
    from furuta_cosim.models import load_model

    path = spec_path(name)
    check = Checker(path)
    top = check.mapping(load_yaml(path), "", required=("controller", "parameters", "objective"),
                        optional=("name", "description", "constraints", "optimizer", "variants",
                                  "baselines", "plant", "rig"))
    if top is None:
        check.done()
    given_controller = top.get("controller", {})
    swingup = None
    if isinstance(given_controller, dict) and given_controller.get("type") == "swingup":
        swingup, n_xc, time, period, model_name = _swingup_base(check, given_controller, path)
    else:
        controller = check.mapping(given_controller, "controller", required=("n_xc", "model"),
                                   optional=("time", "period")) or {}
        n_xc = check.number(controller.get("n_xc"), "controller.n_xc", integer=True, minimum=0,
                            maximum=MAX_STATES) if "n_xc" in controller else None
        time = check.string(controller.get("time", "continuous"), "controller.time", ("continuous", "discrete"))
        period = check.period(controller.get("period", PAPER_PERIOD), "controller.period")
        model_name = check.string(controller.get("model"), "controller.model") if "model" in controller else None
    where = "plant=" if plant is not None else "plant"
    if plant is None and "plant" in top:
        plant = check.string(top["plant"], "plant")
    if from_fit is not None:
        from furuta_cosim.identify.variants import MAX_SAMPLES

        fit, samples, seed = from_fit
        flags = Checker("from_fit")
        for flag, value, low, high in (("samples", samples, 1, MAX_SAMPLES),
                                       ("seed", seed, 0, MAX_SEED)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ConfigError([f"{flag}: expected a whole number from {low} to {high}, got {value}"])
        variants, fitted, source = _variants(flags, {"from_fit": str(Path(fit).resolve()),
                                                     "samples": samples, "seed": seed}, Path.cwd())
        flags.done()
    else:
        variants, fitted, source = _variants(check, top.get("variants", [{}]), path.parent)
    check.done()
    if plant is None and fitted is not None:
        plant, where = str(fitted), "variants.from_fit"
    if plant is not None:
        from furuta_cosim.fmu.plants import content_sha256, load_plant

        try:
            given = load_plant(plant, beside=path.parent if where == "plant" else None)
        except ConfigError as error:
            raise error.within("plant" if where == "plant=" else f"{path}: {where}") from None
        if source is not None and content_sha256(given) != source.plant_sha256:
            named = "plant" if where == "plant=" else f"{path}: plant"
            raise ConfigError([f"{named}: {given.path} is not the plant {source.path} was fitted to "
                               f"({fitted}): tune on that plant, or draw variants from a fit of this one"])
        low, high = given.control_period
        if period is not None and ((low is not None and period < low * (1 - 1e-12))
                                   or (high is not None and period > high * (1 + 1e-12))):
            bounds = " and ".join(f"{name} {v:g}" for name, v in (("min", low), ("max", high)) if v is not None)
            raise ConfigError([f"{path}: controller.period: {period:g} s is outside what the "
                               f"{given.name} plant allows ({given.path.name}: limits.control_period: {bounds})"])
        plant = _portable_model(str(given.path.resolve()), path.parent) if where != "plant=" else str(given.path.resolve())
        plant = given.name if _is_shipped(given) else plant
        model_name = f"derived:{plant}"
    try:
        model = load_model(model_name, beside=path.parent)
        model_name = _portable_model(model_name, path.parent)
    except ConfigError as error:
        raise error.within(f"{path}: controller.model" if plant is None else f"{path}: {where}") from None
    notes = [f"{name} is not identifiable from the fit's data: held at {value:g} in every variant"
             for name, value in (source.held if source is not None else ())]
    n_x, n_u = model.n, model.B.shape[1]
    shapes = {"Ac": (n_xc, n_xc), "Bc": (n_xc, n_x), "Cc": (n_u, n_xc), "Dc": (n_u, n_x)}
    # a matrix the spec leaves out is zero (Dc excepted: the plant needs feedback)
    resolve = lambda name, key: _for_plant(_controller_file(check, name, key, model), plant, model,  # noqa: E731
                                           model_name, notes)
    if swingup is not None:
        blocks = _swingup_blocks(check, top.get("parameters"))
    else:
        parameters = check.mapping(top.get("parameters"), "parameters", optional=tuple(shapes)) or {}
        blocks = tuple(_block(check, parameters[key], key, shape, resolve) if key in parameters
                       else (Block(key, "fixed", shape) if key != "Dc" else _block(check, None, key, shape))
                       for key, shape in shapes.items())
    objective = _objective(check, top.get("objective"), resolve)
    constraints = _constraints(check, top.get("constraints", {}))
    optimizer = _optimizer(check, top.get("optimizer", {}))
    rig = _rig(check, top.get("rig", {}))
    baselines = ()
    if "baselines" in top:
        baselines = tuple(resolve(name, f"baselines[{k}]")
                          for k, name in enumerate(check.names(top["baselines"], "baselines") or ()))
    initial = (top.get("optimizer") or {}).get("initial", []) if isinstance(top.get("optimizer"), dict) else []
    if optimizer and initial:
        optimizer = replace(optimizer, initial=tuple(
            resolve(name, f"optimizer.initial[{k}]")
            for k, name in enumerate(check.names(initial, "optimizer.initial") or ())))
    if constraints.baseline:
        constraints = replace(constraints, baseline=resolve(
            constraints.baseline, "constraints.no_worse_than.controller"))
    if objective and objective.type == "spectral":
        given = top.get("constraints")
        for key in ("max_abs", "no_worse_than", "requirements"):
            if isinstance(given, dict) and key in given:
                check.fail(f"constraints.{key}", "the spectral objective runs no co-simulation: "
                                                 "this constraint would never be checked")
        if "variants" in top or from_fit is not None:
            check.fail("variants", "the spectral objective is computed on the linear model: plant "
                                   "variants would be ignored (use a scenarios objective)")
    if objective and optimizer and objective.type != "tradeoff" and optimizer.front != "auto":
        check.fail("optimizer.front", f"chooses how a tradeoff searches its front; this objective is "
                                      f"{objective.type} (one number)")
    name = (check.file_name(top["name"], "name") if "name" in top
            else check.file_name(path.stem, "name (taken from the file name)"))
    description = check.text(top["description"], "description") if "description" in top else ""
    if objective and optimizer:
        from furuta_cosim.tuning.methods import METHODS

        refusal = METHODS[optimizer.method].refusal(_Objective(objective))
        if refusal:
            check.fail("optimizer.method", refusal)
    if objective and objective.type == "tradeoff" and optimizer and optimizer.front == "ehvi" \
            and len(objective.criteria) != 2:
        check.fail("optimizer.front", f"ehvi computes the hypervolume of two criteria, this objective "
                                      f"has {len(objective.criteria)}: use parego (or auto)")
    if optimizer and optimizer.batch > optimizer.n_calls:
        check.fail("optimizer.batch", f"larger than the budget optimizer.n_calls ({optimizer.n_calls})")
    if optimizer and optimizer.method == "bo" and optimizer.n_initial_points > optimizer.n_calls:
        check.fail("optimizer.n_initial_points", f"larger than optimizer.n_calls ({optimizer.n_calls})")
    if all(b is not None and b.kind == "fixed" for b in blocks):
        check.fail("parameters", "every matrix is fixed: nothing to tune")
    if swingup is not None and objective and objective.type == "spectral":
        check.fail("objective.type", "a swing-up is judged in co-simulation: use a scenarios objective")
    check.done()
    return TuningSpec(name, description, path, n_xc, time == "discrete", period, model_name, blocks,
                      objective, constraints, optimizer, variants, baselines, plant,
                      tuple(dict.fromkeys(notes)), source, swingup, rig)


def _swingup_base(check: Checker, section: dict, path: Path):
    """``controller: {type: swingup, base: FILE}``: the swing-up-and-balance file whose settings
    are tuned; its balance controller's period and model are the search's."""
    from furuta_cosim.controllers import load_controller

    check.mapping(section, "controller", required=("type", "base"))
    name = check.string(section.get("base"), "controller.base")
    if name is None:
        check.done()
    try:
        base = load_controller(name, path.parent)
    except ConfigError as error:
        raise error.within(f"{path}: controller.base") from None
    if base.swingup is None:
        raise ConfigError([f"{path}: controller.base: {base.source} is not a swing-up file (type: swingup)"])
    if not base.controller.discrete:
        raise ConfigError([f"{path}: controller.base: its balance controller {base.balance} is continuous; "
                           "a swing-up is tuned around a discrete one"])
    if not base.model:
        raise ConfigError([f"{path}: controller.base: its balance controller names no model"])
    return str(base.path.resolve()), 0, "discrete", base.controller.period, base.model


def _swingup_blocks(check: Checker, value) -> tuple:
    """``parameters: {SETTING: {box: [lo, hi]} or {log: [lo, hi]}}`` of a swing-up's settings:
    each a scalar block, inside the setting's own range."""
    from furuta_cosim.swingup import SETTINGS

    tunable = tuple(k for k in SETTINGS if k != "direction")
    section = check.mapping(value, "parameters", optional=tunable) or {}
    if not section:
        check.fail("parameters", f"names no setting to tune (settings: {', '.join(tunable)})")
    blocks = []
    for key, entry in section.items():
        where = f"parameters.{key}"
        item = check.mapping(entry, where, optional=("box", "log"))
        if not item or len(item) != 1:
            if item is not None:
                check.fail(where, "expected {box: [low, high]} or {log: [low, high]} (powers of 10)")
            continue
        kind = next(iter(item))
        bounds = check.vector(item[kind], f"{where}.{kind}", 2)
        if bounds is None:
            continue
        low, high = bounds
        _, least, most, _ = SETTINGS[key]
        values = (10.0 ** low, 10.0 ** high) if kind == "log" and max(abs(low), abs(high)) < 300 else (low, high)
        if not low < high:
            check.fail(f"{where}.{kind}", f"expected [low, high] with low < high, got {bounds}")
        elif values[0] < least or values[1] > most:
            check.fail(f"{where}.{kind}", f"{key} ranges over [{least:g}, {most:g}]; this range gives "
                                          f"[{values[0]:g}, {values[1]:g}]")
        else:
            blocks.append(Block(key, kind, (1, 1), low, high))
    return tuple(blocks)


def _is_shipped(plant) -> bool:
    from furuta_cosim.fmu.plants import plant_path

    try:
        return plant_path(plant.name).resolve() == Path(plant.path).resolve()
    except ConfigError:
        return False


def _for_plant(path: str, plant: str | None, model, model_name: str, notes: list) -> str:
    """The controller file ``path``, or with a plant the same LQR recipe designed on the
    plant's linearization (written once to the cache, named ``<name>-on-<plant>``)."""
    if plant is None or not Path(path).is_file():
        return path
    import hashlib

    from furuta_cosim.controllers import load_controller
    from furuta_cosim.lqr_file import design_lqr_file

    cfile = load_controller(path)
    recipe = cfile.controller.provenance or {}
    method = str(recipe.get("method", ""))
    label = Path(str(plant)).stem
    if not (method.startswith(("dlqr", "lqr")) and "Q" in recipe and "R" in recipe):
        notes.append(f"{cfile.name} is not an LQR design: it is compared on {label} as it is")
        return path
    continuous = not method.startswith("dlqr")
    period = float(recipe.get("period") or cfile.period or PAPER_PERIOD)
    key = hashlib.sha256(Path(path).read_bytes() + model.A.tobytes() + model.B.tobytes()
                         + repr((method, period)).encode()).hexdigest()[:16]
    target = paths.cache() / "designs" / key / f"{cfile.name}-on-{label}.yaml"
    if not target.is_file():
        design_lqr_file(model_name, Q=list(np.ravel(recipe["Q"])), R=list(np.ravel(recipe["R"])),
                        period=period, continuous=continuous, name=target.stem,
                        track=cfile.tracked_output,
                        description=f"{cfile.name}'s recipe (the same Q, R and period) on {label}",
                        output=target)
    notes.append(f"{cfile.name} is designed again for {label} with its own Q, R and period "
                 f"({target.stem})")
    return str(target)


def _portable_model(name: str, folder: Path) -> str:
    """The spec's model as the run's files record it: a shipped name as it is, anything else
    (a file, a name of the spec's own tree) as the absolute path it resolved to, so that
    best.yaml in a run directory names the same model."""
    from furuta_cosim.fmu.plants import plant_path

    kind, _, parameter_set = name.partition(":")
    if kind == "derived":
        if not parameter_set:
            return name
        return f"derived:{_portable_model(parameter_set, folder)}"
    path = plant_path(name, beside=folder).resolve()
    try:
        shipped = plant_path(name).resolve()
    except ConfigError:  # a name of the spec's own tree only
        shipped = None
    return name if path == shipped else str(path)


def _controller_file(check: Checker, name: str, key: str, model) -> str:
    """A controller the spec names (resolved beside the spec; kept as an absolute path), checked
    to be one of this plant's: a controller of another plant is refused here, not scored as a
    failed evaluation after the run."""
    from furuta_cosim.controllers import load_controller

    folder = Path(check.source).parent
    try:
        cfile = load_controller(name, folder)
    except ConfigError as error:
        check.fail(key, "; ".join(error.problems))
        return name
    controller = cfile.controller
    n_u = model.B.shape[1]
    if controller.Dc.shape != (n_u, model.n):
        check.fail(key, f"{cfile.source} is a controller of {controller.Dc.shape[1]} states and "
                        f"{controller.Dc.shape[0]} inputs; the model {model.name} has {model.n} and {n_u}")
    return str(cfile.path.resolve())


def _block(check: Checker, value, key: str, shape: tuple[int, int], controller=None) -> Block | None:
    """``controller(name, key)``: a controller file the spec names, resolved and checked."""
    where = f"parameters.{key}"
    if value is None:
        check.fail(where, "missing (Dc has no default: give fixed, box, log or lqr)")
        return None
    if not isinstance(value, dict) or not set(value) & set(KINDS):
        check.fail(where, f"expected a mapping with one of {', '.join(KINDS)}")
        return None
    kinds = [k for k in KINDS if k in value]
    if len(kinds) > 1 and not (set(kinds) == {"fixed", "box"} or set(kinds) == {"fixed", "log"}):
        check.fail(where, f"one of {', '.join(KINDS)} (fixed only beside box or log, for the "
                          f"entries that are not free), got {', '.join(kinds)}")
        return None
    kind = next(k for k in ("lqr", "box", "log", "fixed") if k in value)
    optional = {"fixed": ("fixed",), "box": ("box", "fixed", "entries", "around"),
                "log": ("log", "sign", "fixed", "entries"), "lqr": ("lqr", "R")}[kind]
    section = check.mapping(value, where, optional=optional)
    if section is None:
        return None
    rows, cols = shape
    if rows * cols == 0:
        check.fail(where, f"{key} is empty with n_xc = 0: leave it out")
        return None
    fixed = ()
    if "fixed" in section:
        matrix = check.matrix(section["fixed"], f"{where}.fixed", rows=rows, cols=cols)
        fixed = tuple(v for row in (matrix or []) for v in row)
    if kind == "fixed":
        return Block(key, "fixed", shape, fixed=fixed)
    if kind == "lqr" and key != "Dc":
        check.fail(where, "lqr makes Dc only")
        return None
    if "entries" in section:
        entries = _entries(check, section["entries"], f"{where}.entries", shape)
    else:
        entries = None
    ranges, around = (), ()
    if kind == "box" and isinstance(section["box"], list) and len(section["box"]) == 2 \
            and all(isinstance(side, list) for side in section["box"]):
        # a range per free entry: [[lows], [highs]]
        count = len(entries) if entries is not None else rows * cols
        lows = check.vector(section["box"][0], f"{where}.box[0]", count)
        highs = check.vector(section["box"][1], f"{where}.box[1]", count)
        if lows is None or highs is None:
            return None
        bad = [k for k, (a, b) in enumerate(zip(lows, highs)) if not a < b]
        if bad:
            check.fail(f"{where}.box", f"expected low < high for every entry; not for entries {bad}")
            return None
        ranges = tuple(zip(lows, highs))
        bounds = [min(lows), max(highs)]
    else:
        bounds = check.vector(section[kind], f"{where}.{kind}", 2)
    if bounds is None:
        return None
    if "around" in section:
        name = check.string(section["around"], f"{where}.around")
        if name and controller is not None:
            known = len(check.problems)
            path = controller(name, f"{where}.around")
            if len(check.problems) > known:
                return None  # said: not a controller of this plant
            around = _matrix_of(check, path, key, shape, f"{where}.around")
            if around is None:
                return None
        if "fixed" in section:
            check.fail(f"{where}.fixed", "around gives the entries that are not free")
    low, high = bounds
    if not low < high:
        check.fail(f"{where}.{kind}", f"expected [low, high] with low < high, got {bounds}")
        return None
    if kind == "box" and max(abs(low), abs(high)) > MAX_BOX:
        check.fail(f"{where}.box", f"expected bounds within +-{MAX_BOX:g} (a gain or a relative "
                                   f"change; the search scales the box), got {bounds}")
        return None
    if kind in ("log", "lqr") and max(abs(low), abs(high)) > MAX_DECADES:
        # the bounds are exponents: [-50, 50] is most likely a range of values through 0
        hint = ("a range of values through 0 has no log scale: use box" if kind == "log"
                else "the state weights are 10^q")
        check.fail(f"{where}.{kind}", f"expected exponents of 10 within +-{MAX_DECADES} ([-1, 2]: "
                                      f"0.1 to 100), got {bounds}; {hint}")
        return None
    sign, R, entries = 1.0, 1.0, None
    if kind == "log":
        sign = check.number(section.get("sign", 1), f"{where}.sign")
        if sign is not None and sign not in (-1.0, 1.0):
            check.fail(f"{where}.sign", f"expected 1 or -1, got {sign:g}")
        sign = sign or 1.0
    if kind == "lqr":
        R = check.number(section.get("R", 1.0), f"{where}.R", positive=True) or 1.0
    return Block(key, kind, shape, low, high, sign, R, entries, fixed, ranges, around)


def _matrix_of(check: Checker, path: str, key: str, shape, where: str) -> tuple | None:
    """The matrix ``key`` of a controller file, row by row, when it has the block's shape."""
    from furuta_cosim.controllers import load_controller

    try:
        matrix = np.asarray(getattr(load_controller(path).controller, key), dtype=float)
    except ConfigError:
        return None  # said already by the controller check
    if matrix.shape != tuple(shape):
        check.fail(where, f"{Path(path).stem}'s {key} is {matrix.shape[0]} x {matrix.shape[1]}; "
                          f"the search's is {shape[0]} x {shape[1]}")
        return None
    return tuple(float(v) for v in matrix.reshape(-1))


def _entries(check: Checker, value, key: str, shape) -> tuple | None:
    pairs = check.matrix(value, key, cols=2) if isinstance(value, list) and value else None
    if pairs is None:
        check.fail(key, "expected a list of [row, column] pairs")
        return None
    result = []
    for i, j in pairs:
        if not (i == int(i) and j == int(j) and 0 <= i < shape[0] and 0 <= j < shape[1]):
            check.fail(key, f"[{i:g}, {j:g}] is not an entry of a {shape[0]}x{shape[1]} matrix")
            return None
        result.append((int(i), int(j)))
    if len(set(result)) != len(result):
        check.fail(key, "an entry is named twice")
        return None
    return tuple(result)


def _objective(check: Checker, value, controller) -> Objective | None:
    """``controller(name, key)``: a controller file the spec names, resolved and checked."""
    section = check.mapping(value, "objective", required=("type",),
                            optional=("scenarios", "terms", "aggregate", "criteria"))
    if not section or "type" not in section:
        return None
    kind = check.string(section["type"], "objective.type", OBJECTIVES)
    if kind == "spectral":
        for key in ("scenarios", "terms", "criteria"):
            if key in section:
                check.fail(f"objective.{key}", "the spectral objective uses no scenarios")
        return Objective("spectral")
    if kind is None:
        return None
    wrong = "criteria" if kind == "scenarios" else "terms"
    if wrong in section:
        check.fail(f"objective.{wrong}", f"a {kind} objective has "
                   + ("terms (one number)" if kind == "scenarios" else "criteria (two or more numbers), each with its terms"))
    scenarios = check.names(section.get("scenarios"), "objective.scenarios") if "scenarios" in section else None
    if not scenarios:
        check.fail("objective.scenarios", "expected at least one scenario name or file")
    terms, aggregate, criteria = (), Objective.aggregate, ()
    if kind == "scenarios":
        terms = _terms(check, section.get("terms"), "objective.terms", controller)
        aggregate = check.string(section.get("aggregate", Objective.aggregate), "objective.aggregate",
                                 AGGREGATES) or Objective.aggregate
    else:
        if "aggregate" in section:
            check.fail("objective.aggregate", "a tradeoff objective aggregates per criterion "
                                              "(objective.criteria[k].aggregate)")
        criteria = _criteria(check, section.get("criteria"), controller)
    # resolved once, here: a file beside the spec, or a name in scenarios/
    resolved = []
    for k, name in enumerate(scenarios or []):
        try:
            path = scenario_path(name, Path(check.source).parent)
        except ConfigError as error:
            check.fail(f"objective.scenarios[{k}]", str(error))
            continue
        if not path.is_file():
            check.fail(f"objective.scenarios[{k}]", f"{name}: no such scenario file")
            continue
        resolved.append(str(path))
    return Objective(kind, tuple(resolved), terms, aggregate, criteria)


def _terms(check: Checker, raw, key: str, controller) -> tuple[Term, ...]:
    terms = []
    if not isinstance(raw, list) or not raw:
        check.fail(key, "expected a list of {metric, weight, relative_to}")
        return ()
    for k, item in enumerate(raw):
        where = f"{key}[{k}]"
        term = check.mapping(item, where, required=("metric",), optional=("weight", "relative_to"))
        if not term or "metric" not in term:
            continue
        metric = checked(check, term["metric"], f"{where}.metric")
        weight = check.number(term.get("weight", 1.0), f"{where}.weight", minimum=0.0)
        relative = None
        if "relative_to" in term:
            name = check.string(term["relative_to"], f"{where}.relative_to")
            relative = controller(name, f"{where}.relative_to") if name else None
        if metric and weight is not None:
            terms.append(Term(metric, weight, relative))
    if terms and len(terms) == len(raw) and not any(t.weight > 0 for t in terms):
        check.fail(key, "every weight is 0: nothing to minimize")
    return tuple(terms)


def _criteria(check: Checker, raw, controller) -> tuple[Criterion, ...]:
    if not isinstance(raw, list) or len(raw) < 2:
        check.fail("objective.criteria", "expected a list of two or more {name, terms, aggregate}: "
                                         "a trade-off needs at least two numbers")
        return ()
    criteria, names = [], set()
    for k, item in enumerate(raw):
        where = f"objective.criteria[{k}]"
        section = check.mapping(item, where, required=("name", "terms"), optional=("aggregate",))
        if not section or "name" not in section:
            continue
        name = check.file_name(section["name"], f"{where}.name")
        if name in names:
            check.fail(f"{where}.name", f"{name!r} names an earlier criterion too")
        names.add(name)
        terms = _terms(check, section.get("terms"), f"{where}.terms", controller)
        aggregate = check.string(section.get("aggregate", "mean"), f"{where}.aggregate", AGGREGATES)
        if name and terms and aggregate:
            criteria.append(Criterion(name, terms, aggregate))
    return tuple(criteria)


def _constraints(check: Checker, value) -> Constraints:
    section = check.mapping(value, "constraints", optional=("stability_margin", "controller_stable",
                                                            "max_abs", "requirements", "penalty",
                                                            "no_worse_than", "stop_early"))
    if section is None:
        return Constraints()
    margin = check.number(section.get("stability_margin", 0.0), "constraints.stability_margin", minimum=0.0)
    flags = {}
    for key in ("controller_stable", "requirements"):
        if key in section and not isinstance(section[key], bool):
            check.fail(f"constraints.{key}", f"expected true or false, got {section[key]!r}")
        flags[key] = bool(section.get(key, key == "requirements"))
    bounds = check.numbers(section.get("max_abs", {}), "constraints.max_abs", positive=True)
    penalty = check.number(section.get("penalty", Constraints.penalty), "constraints.penalty", positive=True,
                           maximum=MAX_PENALTY)
    baseline, factors = None, ()
    if "no_worse_than" in section:
        relative = check.mapping(section["no_worse_than"], "constraints.no_worse_than",
                                 required=("controller", "metrics")) or {}
        if "controller" in relative:
            baseline = check.string(relative["controller"], "constraints.no_worse_than.controller")
        if "metrics" in relative:
            ratios = check.numbers(relative["metrics"], "constraints.no_worse_than.metrics", positive=True)
            factors = tuple((metric, ratio) for metric, ratio in ratios.items()
                            if checked(check, metric, f"constraints.no_worse_than.metrics.{metric}"))
    stop = section.get("stop_early", Constraints.stop_early)
    if stop is False or stop is None:
        stop = None
    elif stop is True or not isinstance(stop, (int, float)):
        check.fail("constraints.stop_early", f"expected false or a slack >= 0 (how far past a "
                                             f"constraint a run stops), got {stop!r}")
        stop = None
    else:
        stop = check.number(stop, "constraints.stop_early", minimum=0.0, maximum=MAX_STOP)
    return Constraints(margin or 0.0, flags["controller_stable"], tuple(bounds.items()),
                       flags["requirements"], penalty or Constraints.penalty, baseline, factors, stop)


def _rig(check: Checker, value) -> RigSettings:
    """``rig:``: the settings of a tuning with a rig in the loop (RigSettings)."""
    section = check.mapping(value, "rig", optional=("n_trials", "reset", "fall", "beta", "simulations"))
    if section is None:
        return RigSettings()
    defaults = RigSettings()
    values = {"n_trials": check.number(section.get("n_trials", defaults.n_trials), "rig.n_trials",
                                       integer=True, minimum=2, maximum=MAX_TRIALS),
              "fall": check.number(section.get("fall", defaults.fall), "rig.fall", positive=True, maximum=3.0),
              "beta": check.number(section.get("beta", defaults.beta), "rig.beta", minimum=0.0, maximum=10.0)}
    if "simulations" in section:
        values["simulations"] = check.number(section["simulations"], "rig.simulations", integer=True,
                                             minimum=1, maximum=MAX_CALLS)
    if "reset" in section:
        name = check.string(section["reset"], "rig.reset")
        values["reset"] = _reset_file(check, name) if name else None
    if None in (values["n_trials"], values["fall"], values["beta"]):
        return defaults
    return RigSettings(**values)


def _reset_file(check: Checker, name: str) -> str | None:
    """The swing-up file of ``rig.reset``, resolved as the spec's other controller files are."""
    from furuta_cosim.controllers import load_controller

    try:
        cfile = load_controller(name, Path(check.source).parent)
    except ConfigError as error:
        check.fail("rig.reset", "; ".join(error.problems))
        return None
    if cfile.swingup is None:
        check.fail("rig.reset", f"{cfile.source} is not a swing-up file (type: swingup): a rig trial "
                                "resets the rig by swinging the pendulum up and catching it")
        return None
    return str(cfile.path.resolve())


# the optimizer's numeric settings and their checks (the defaults: OptimizerSettings)
_OPTIMIZER_NUMBERS = {"n_calls": dict(integer=True, minimum=1, maximum=MAX_CALLS),
                      "n_initial_points": dict(integer=True, minimum=1),
                      "xi": dict(minimum=0.0),
                      "seed": dict(integer=True, minimum=0, maximum=MAX_SEED),
                      "batch": dict(integer=True, minimum=1, maximum=1000),
                      "gp_restarts": dict(integer=True, minimum=0, maximum=20)}


def _optimizer(check: Checker, value) -> OptimizerSettings | None:
    from furuta_cosim.tuning.bayesopt import FRONTS, REGIONS, STARTS

    defaults = OptimizerSettings()
    section = check.mapping(value, "optimizer", optional=("method", "region", "front", "initial", "start",
                                                          "warm_start", *_OPTIMIZER_NUMBERS))
    if section is None:
        return None
    from furuta_cosim.tuning.methods import METHODS

    values = {"method": check.string(section.get("method", defaults.method), "optimizer.method", tuple(METHODS)),
              "region": check.string(section.get("region", defaults.region), "optimizer.region", REGIONS),
              "front": check.string(section.get("front", defaults.front), "optimizer.front", FRONTS),
              "start": check.string(section.get("start", defaults.start), "optimizer.start", STARTS)}
    for key, rules in _OPTIMIZER_NUMBERS.items():
        values[key] = check.number(section.get(key, getattr(defaults, key)), f"optimizer.{key}", **rules)
    values["warm_start"] = section.get("warm_start", defaults.warm_start)
    if not isinstance(values["warm_start"], bool):
        check.fail("optimizer.warm_start", f"expected true or false, got {values['warm_start']!r}")
        values["warm_start"] = None
    if None in values.values():
        return None
    return OptimizerSettings(**values)


def _variants(check: Checker, value, folder: Path) -> tuple[tuple, Path | None, FitSource | None]:
    """The plant variants, and with ``{from_fit: FILE, samples, seed}`` the fitted plant
    (``plant.yaml`` beside the fit) they vary and where they came from."""
    if isinstance(value, dict):
        from furuta_cosim.identify.variants import MAX_SAMPLES, draw, load_fit

        section = check.mapping(value, "variants", required=("from_fit",), optional=("samples", "seed"))
        text = check.string(section.get("from_fit"), "variants.from_fit") if section else None
        samples = check.number(section.get("samples", 8), "variants.samples", integer=True, minimum=1,
                               maximum=MAX_SAMPLES) if section else None
        seed = check.number(section.get("seed", 0), "variants.seed", integer=True, minimum=0,
                            maximum=MAX_SEED) if section else None
        if text is None or samples is None or seed is None:
            return ((),), None, None
        fit = Path(text) if Path(text).is_absolute() else folder / text
        plant = fit.parent / "plant.yaml"
        if not fit.is_file() or not plant.is_file():
            check.fail("variants.from_fit", f"{fit}: expected the fit.json of an identify run, with "
                                            "its plant.yaml beside it")
            return ((),), None, None
        try:
            loaded = load_fit(fit)
            found = draw(loaded, samples, seed)
            digest = hashlib.sha256(fit.read_bytes()).hexdigest()
        except ConfigError as error:
            check.problems.extend(error.within(f"{check.source}: variants.from_fit").problems)
            return ((),), None, None
        except OSError as error:
            check.fail("variants.from_fit", f"{fit}: cannot be read ({error.__class__.__name__})")
            return ((),), None, None
        return (tuple(tuple(v.items()) for v in found), plant,
                FitSource(str(fit), digest, int(samples), int(seed), tuple(loaded.held.items()),
                          loaded.plant_sha256))
    if not isinstance(value, list) or not value:
        check.fail("variants", "expected a list of parameter overrides ({} is the plant as it is), "
                               "or {from_fit: FILE, samples: N, seed: S}")
        return ((),), None, None
    if len(value) > MAX_VARIANTS:
        check.fail("variants", f"{len(value)} variants; at most {MAX_VARIANTS} (every candidate "
                               "runs on each)")
        return ((),), None, None
    result = []
    for k, item in enumerate(value):
        overrides = check.numbers(item, f"variants[{k}]")
        result.append(tuple(overrides.items()))
    return tuple(result), None, None
