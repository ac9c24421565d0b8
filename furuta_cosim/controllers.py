"""Controller files (YAML) <-> :class:`~furuta_cosim.design.GeneralizedController`.

    name: lqr-paper
    type: static                  # or generalized
    time: discrete                # or continuous
    period: 0.002                 # the control period (a continuous design is sampled at it)
    K: [-0.3105, -5.2621, 70.7488, 8.9224, 0.1772]      # static
    # Ac: [[-100]]  Bc: [[0, 0, 0, 0, 0]]  Cc: [[-0.5]]  Dc: [[...]]   # generalized
    model: paper-printed          # the model it was designed on (analyze's default)
    prefilter: {output: y, F: -0.3105}        # F is computed on the model when left out
    provenance: {method: ..., Q: ..., R: ...}  # free-form: how it was made
"""

from __future__ import annotations

import os

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from furuta_cosim import __version__, paths
from furuta_cosim.config import Checker, load_yaml, resolve_file
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.design.controller import GeneralizedController
from furuta_cosim.design.linear import LinearModel
from furuta_cosim.design.prefilter import prefilter
from furuta_cosim.errors import ConfigError, DesignError
from furuta_cosim.files import output_file, write_text

KEYS = ("name", "type", "time", "period", "K", "Ac", "Bc", "Cc", "Dc", "model", "prefilter",
        "provenance", "description")
SWINGUP_KEYS = ("name", "type", "balance", "plant", "swingup", "provenance", "description")


@dataclass(frozen=True)
class ControllerFile:
    """A controller with what the file says about its use."""

    controller: GeneralizedController
    period: float
    model: str | None = None
    tracked_output: str | None = None
    F: float | None = None
    description: str = ""
    path: Path | None = None
    provenance: dict = field(default_factory=dict, compare=False)
    # a swing-up-and-balance file: ``controller`` is its balance controller, these its swing-up
    swingup: "SwingUp | None" = None
    balance: Path | None = None          # the balance controller's file
    plant: str | None = None             # the plant the swing-up's energy is computed on
    own_name: str | None = None          # a swing-up file's own name (the balance keeps its)

    @property
    def name(self) -> str:
        return self.own_name or self.controller.name

    @property
    def source(self) -> str:
        return str(self.path) if self.path else self.name


def controller_path(name: str | Path, beside: Path | None = None) -> Path:
    """A controller name of ``scenarios/controllers``, or a file (relative: to ``beside``)."""
    return resolve_file(name, paths.scenarios() / "controllers", "controller", beside=beside)


def load_controller(name: str | Path, beside: Path | None = None) -> ControllerFile:
    """Read and validate a controller file; every problem is reported at once.

    Parameters
    ----------
    name : str or path
        A shipped controller's name (``lqr-paper``) or a file.
    beside : path, optional
        The folder of the file that names it, where a relative path or a name is looked up
        first.

    Returns
    -------
    ControllerFile
        The controller and its file's metadata (model, prefilter, provenance)."""
    path = controller_path(name, beside)
    data = load_yaml(path)
    check = Checker(path)
    if isinstance(data, dict) and data.get("type") == "swingup":
        return _load_swingup(path, data, check)
    top = check.mapping(data, "", required=("type", "time"), optional=KEYS)
    if top is None:
        check.done()
    kind = check.string(top.get("type"), "type", ("static", "generalized", "swingup")) if "type" in top else None
    time = check.string(top.get("time"), "time", ("discrete", "continuous")) if "time" in top else None
    period = None
    if "period" in top:
        period = check.period(top["period"], "period")
    elif time == "discrete":
        check.fail("period", "missing (a discrete controller needs its sample period)")
    matrices = {}
    if kind == "static":
        for key in ("Ac", "Bc", "Cc", "Dc"):
            if key in top:
                check.fail(key, "a static controller has only K (use type: generalized)")
        if "K" not in top:
            check.fail("K", "missing (a static controller needs its gain)")
        else:
            matrices["K"] = check.matrix(top["K"], "K")
    elif kind == "generalized":
        if "K" in top:
            check.fail("K", "a generalized controller has Ac, Bc, Cc, Dc, not K")
        for key in ("Ac", "Bc", "Cc", "Dc"):
            if key not in top:
                check.fail(key, "missing")
            else:
                matrices[key] = check.matrix(top[key], key)
    if kind == "generalized" and all(matrices.get(k) is not None for k in ("Ac", "Bc", "Cc", "Dc")):
        _check_shapes(check, *(np.array(matrices[k]) for k in ("Ac", "Bc", "Cc", "Dc")))
    model = check.string(top["model"], "model") if "model" in top else None
    tracked, F = None, None
    if "prefilter" in top:
        section = check.mapping(top["prefilter"], "prefilter", required=("output",), optional=("F",))
        if section:
            tracked = check.string(section.get("output"), "prefilter.output") if "output" in section else None
            if "F" in section:
                F = check.number(section["F"], "prefilter.F")
                if F is not None and abs(F) > MAX_MAGNITUDE:
                    check.fail("prefilter.F", f"must be within +-{MAX_MAGNITUDE:g}, got {F:g}")
    provenance = top.get("provenance", {})
    if not isinstance(provenance, dict):
        check.fail("provenance", "expected a mapping")
    name = (check.file_name(top["name"], "name") if "name" in top
            else check.file_name(path.stem, "name (taken from the file name)"))
    description = check.text(top["description"], "description") if "description" in top else ""
    check.done()
    try:
        if kind == "static":
            controller = GeneralizedController.static(
                matrices["K"], period if time == "discrete" else 0.0, name, provenance)
        else:
            controller = GeneralizedController(*(matrices[k] for k in ("Ac", "Bc", "Cc", "Dc")),
                                               period if time == "discrete" else 0.0, name, provenance)
    except DesignError as error:
        raise ConfigError([f"{path}: {error}"]) from None
    return ControllerFile(controller, period or 0.0, model, tracked, F, description, path,
                          provenance)


def _load_swingup(path: Path, top: dict, check: Checker) -> ControllerFile:
    """A swing-up-and-balance file (:mod:`furuta_cosim.swingup`): its balance controller file
    (beside it, or a name), the plant its energy is computed on, its settings."""
    from furuta_cosim.swingup import SETTINGS, SwingUp, pendulum

    check.mapping(top, "", required=("type", "balance"), optional=SWINGUP_KEYS)
    balance_name = check.string(top.get("balance"), "balance")
    settings = {}
    section = top.get("swingup", {})
    if check.mapping(section, "swingup", optional=tuple(SETTINGS)) is not None:
        for key, value in section.items():
            if key in SETTINGS:
                _, low, high, _ = SETTINGS[key]
                number = check.number(value, f"swingup.{key}", minimum=low, maximum=high)
                if number is not None:
                    settings[key] = number
    if settings.get("direction", 1.0) not in (1.0, -1.0):
        check.fail("swingup.direction", f"expected 1 or -1, got {settings['direction']:g}")
    if settings.get("fall_angle", SETTINGS["fall_angle"][0]) <= settings.get("catch_angle", SETTINGS["catch_angle"][0]):
        check.fail("swingup.fall_angle", "must be larger than catch_angle: a pendulum just caught "
                                         "would count as fallen")
    name = (check.file_name(top["name"], "name") if "name" in top
            else check.file_name(path.stem, "name (taken from the file name)"))
    description = check.text(top["description"], "description") if "description" in top else ""
    provenance = top.get("provenance", {})
    if not isinstance(provenance, dict):
        check.fail("provenance", "expected a mapping")
    plant_name = check.string(top["plant"], "plant") if "plant" in top else None
    check.done()
    try:
        balance = load_controller(balance_name, path.parent)
    except ConfigError as error:
        raise error.within(f"{path}: balance") from None
    if balance.swingup is not None:
        raise ConfigError([f"{path}: balance: {balance.source} is a swing-up file itself; name a "
                           "balance controller"])
    plant_name = plant_name or _plant_of(balance.model)
    if plant_name is None:
        raise ConfigError([f"{path}: plant: missing (the pendulum whose energy the swing-up "
                           f"computes; {balance.source} names no plant model to take it from)"])
    from furuta_cosim.fmu.plants import load_plant

    try:
        plant = load_plant(plant_name, beside=path.parent)
        inertia, mgl = pendulum(plant.parameters)
    except ConfigError as error:
        raise error.within(f"{path}: plant") from None
    except KeyError as error:
        raise ConfigError([f"{path}: plant: {plant_name} has no {error.args[0]} (a Furuta plant's "
                           "pendulum: m_p, l_p, I_p, g)"]) from None
    return replace(balance, swingup=SwingUp(inertia, mgl, **settings), balance=balance.path,
                   plant=str(plant.path), own_name=name, description=description or balance.description,
                   path=path, provenance=provenance)


def _plant_of(model: str | None) -> str | None:
    """The plant file of a model name ``derived:PLANT``, if it is one."""
    if model and model.startswith("derived:") and len(model) > len("derived:"):
        return model.partition(":")[2]
    return None


def _check_shapes(check: Checker, Ac, Bc, Cc, Dc) -> None:
    n_xc = Ac.shape[0]
    if Ac.shape[0] != Ac.shape[1]:
        check.fail("Ac", f"must be square, got {Ac.shape[0]}x{Ac.shape[1]}")
    if Bc.shape[0] != n_xc:
        check.fail("Bc", f"expected {n_xc} row(s) (as Ac), got {Bc.shape[0]}")
    if Cc.shape[1] != n_xc:
        check.fail("Cc", f"expected {n_xc} column(s) (as Ac), got {Cc.shape[1]}")
    if Dc.shape[1] != Bc.shape[1]:
        check.fail("Dc", f"expected {Bc.shape[1]} values per row (as Bc's columns), got {Dc.shape[1]}")
    if Dc.shape[0] != Cc.shape[0]:
        check.fail("Dc", f"expected {Cc.shape[0]} row(s) (as Cc), got {Dc.shape[0]}")


def fit(cfile: ControllerFile, *, plant: str, states: int, inputs: int = 1,
        period: float | None = None, discrete_plant: bool = False, tracked: str | None = None,
        model=None) -> ControllerFile:
    """The one check of a controller against where it is used; the prefilter F computed on
    ``model`` where the file leaves it out.

    Parameters
    ----------
    plant : str
        How messages name the plant or model (``model paper-printed``, ``plant Furuta``).
    states, inputs : int
        What the controller must feed back and drive.
    period : float, optional
        The period a discrete controller must run at (the control period, or a discrete
        model's sample period); None accepts any.
    discrete_plant : bool
        A continuous controller cannot run on a discrete plant.
    tracked : str, optional
        The output the run tracks; the file's prefilter must be for it.
    model : LinearModel or callable returning one, optional
        For a prefilter without F; called only then.

    Problems are ConfigErrors naming the controller file and the key.
    """
    c = cfile.controller
    key = "K" if c.n_xc == 0 else "Dc"

    def fail(where: str, message: str) -> ConfigError:
        return ConfigError([f"{cfile.source}: {where}: {message}"])

    if c.Dc.shape[1] != states:
        raise fail(key, f"expected {states} values per row ({plant} has {states} states), "
                        f"got {c.Dc.shape[1]}")
    if c.Dc.shape[0] != inputs:
        raise fail(key, f"expected {inputs} row(s) ({plant} has {inputs} control input(s)), "
                        f"got {c.Dc.shape[0]}")
    if c.discrete and period and abs(c.period - period) > 1e-12 * period:
        raise fail("period", f"the controller runs at {c.period:g} but {plant} is sampled at "
                             f"{period:g}")
    if not c.discrete and discrete_plant:
        raise fail("time", f"a continuous controller cannot run on the discrete {plant}")
    if tracked and cfile.tracked_output and cfile.tracked_output != tracked:
        raise fail("prefilter.output", f"{cfile.tracked_output} differs from the tracked output "
                                       f"{tracked}")
    if cfile.tracked_output and cfile.F is None:
        if model is None:
            raise fail("prefilter.F", "missing, and no model to compute it on (give F, or "
                                      "name the model the controller was designed on)")
        try:
            linear = model() if callable(model) else model
            return replace(cfile, F=prefilter(linear, c, cfile.tracked_output))
        except DesignError as error:
            raise fail("prefilter.output", str(error)) from None
    return cfile


def check_fits(cfile: ControllerFile, model: LinearModel) -> ControllerFile:
    """:func:`fit` against a linear model (as ``analyze`` uses it)."""
    return fit(cfile, plant=f"model {model.name}", states=model.n, inputs=model.B.shape[1],
               period=model.period if model.discrete else None, discrete_plant=model.discrete,
               model=model)


def default_output(model: LinearModel) -> str:
    """The default tracked output: the model's first state when its first output measures that
    state alone (a sensor on it: the first row of C a unit vector on it), else its first output."""
    import numpy as np

    row = np.asarray(model.C, dtype=float)[0]
    unit = np.zeros_like(row)
    unit[0] = 1.0
    return model.states[0] if model.states and np.array_equal(row, unit) else model.outputs[0]


def controller_document(cfile: ControllerFile, folder: Path | None = None) -> dict:
    """The file's content; a swing-up file names its balance controller and plant by paths
    relative to ``folder`` (where it is written)."""
    if cfile.swingup is not None:
        from furuta_cosim.fmu.plants import plant_path

        document = {"name": cfile.name, "description": cfile.description or None, "type": "swingup",
                    "balance": _shipped_or_relative(cfile.balance, folder, controller_path),
                    "plant": _shipped_or_relative(cfile.plant, folder, plant_path),
                    "swingup": cfile.swingup.settings(),
                    "provenance": {**cfile.provenance, "tool": f"furuta-cosim {__version__}"}}
        # no `description: null` (a swing-up file without one was written so, and refused when read)
        return {k: v for k, v in document.items() if v is not None}
    c = cfile.controller
    document = {"name": c.name, "description": cfile.description or None,
                "type": "static" if c.n_xc == 0 else "generalized",
                "time": "discrete" if c.discrete else "continuous"}
    if cfile.period:
        document["period"] = cfile.period
    if c.n_xc == 0:
        document["K"] = c.Dc[0].tolist() if c.Dc.shape[0] == 1 else c.Dc.tolist()
    else:
        document.update(Ac=c.Ac.tolist(), Bc=c.Bc.tolist(), Cc=c.Cc.tolist(), Dc=c.Dc.tolist())
    if cfile.model:
        document["model"] = cfile.model
    if cfile.tracked_output:
        document["prefilter"] = {"output": cfile.tracked_output, "F": cfile.F}
    document["provenance"] = {**cfile.provenance, "tool": f"furuta-cosim {__version__}"}
    return {k: v for k, v in document.items() if v is not None}


def save_controller(cfile: ControllerFile, path: str | Path) -> Path:
    """Write a controller file that :func:`load_controller` reads back unchanged."""
    text = yaml.safe_dump(controller_document(cfile, Path(path).parent), sort_keys=False,
                          default_flow_style=None, width=100)
    return write_text(output_file(path),
                      f"# Written by furuta-cosim; see provenance for how it was designed.\n{text}")


def recorded_model(model_name: str, folder: Path | None = None) -> str:
    """The model as a controller file in ``folder`` records it: a name as it is, a file by its
    path relative to ``folder`` (absolute without one: ``derived:variant.yaml`` given from
    another folder could not be found again otherwise)."""
    fmu, hash_, mapping = str(model_name).partition("#")
    if fmu.endswith(".fmu"):
        return _relative(fmu, folder) + (f"#{_relative(mapping, folder)}" if hash_ else "")
    kind, colon, rest = str(model_name).partition(":")
    if kind == "derived" and colon:
        return f"derived:{recorded_model(rest, folder)}"
    path = Path(model_name)
    if path.suffix in (".yaml", ".yml") or len(path.parts) > 1:
        return _relative(path, folder)
    return str(model_name)


def _shipped_or_relative(path, folder: Path | None, shipped) -> str | None:
    """A shipped file by its name (``shipped(name)`` finds it), any other by its path relative
    to ``folder``."""
    if not path:
        return None
    try:
        if shipped(Path(path).stem).resolve() == Path(path).resolve():
            return Path(path).stem
    except ConfigError:
        pass
    return _relative(path, folder)


def _relative(path: str | Path, folder: Path | None) -> str:
    resolved = Path(path).resolve()
    return os.path.relpath(resolved, Path(folder).resolve()) if folder is not None else str(resolved)
