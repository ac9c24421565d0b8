"""A rig log held as a baseline: does the model still predict the rig?

A rig-check file names a logged experiment (a ``rig run``'s ``experiment.yaml``, or any
experiment file) and a plant, and states how far the plant FMU, replayed on the logged inputs,
may be from the log: the RMS of simulated minus measured per output, in SI units. ``regress``
takes such files beside scenario files::

    rig_check: swingup-on-the-bench     # the check's name
    experiment: ../rig/runs/swingup/experiment.yaml
    plant: ../rig/fit/plant.yaml        # the model under test (a name or a file)
    seconds: 0.6                        # optional: the first seconds of the log only
    tolerances: {theta0: 0.05, theta1: 0.1}

Its tolerances are set by hand, from what the model should do: ``regress --update`` leaves the
file as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from furuta_cosim.config import Checker, load_yaml
from furuta_cosim.errors import ConfigError

KEYS = ("rig_check", "description", "experiment", "plant", "seconds", "tolerances")


@dataclass(frozen=True)
class RigCheck:
    name: str
    path: Path
    experiment: Path
    plant: str
    seconds: float | None
    tolerances: dict


def is_rig_check(path: str | Path) -> bool:
    """Whether a YAML file is a rig check (its top level names ``rig_check``)."""
    try:
        data = load_yaml(path)
    except ConfigError:
        return False
    return isinstance(data, dict) and "rig_check" in data


def load_rig_check(path: str | Path) -> RigCheck:
    path = Path(path)
    check = Checker(path)
    top = check.mapping(load_yaml(path), "", required=("rig_check", "experiment", "plant", "tolerances"),
                        optional=KEYS)
    check.done()
    name = check.file_name(top["rig_check"], "rig_check")
    check.text(top.get("description", ""), "description")
    experiment = check.string(top["experiment"], "experiment")
    plant = check.string(top["plant"], "plant")
    seconds = check.number(top["seconds"], "seconds", positive=True) if "seconds" in top else None
    tolerances = check.numbers(top["tolerances"], "tolerances", positive=True)
    if isinstance(top.get("tolerances"), dict) and not top["tolerances"]:
        check.fail("tolerances", "names no output: a check needs at least one")
    check.done()
    experiment_path = Path(experiment) if Path(experiment).is_absolute() else path.parent / experiment
    if plant.endswith((".yaml", ".yml")) or "/" in plant:
        plant = str(Path(plant) if Path(plant).is_absolute() else path.parent / plant)
    return RigCheck(name, path, experiment_path, plant, seconds, dict(tolerances))


def run_rig_check(path: str | Path) -> tuple[str, str, list[tuple[str, float, float]], int, list[str]]:
    """(its name, status ``pass`` or ``fail``, [(output, tolerance, RMS)] of the outputs beyond
    their tolerance, outputs checked, notes) of one rig check."""
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import SimulationFailed, check_names, compare, open_session, simulate, target_for

    check = load_rig_check(path)
    try:
        experiment = load_experiment(check.experiment)
        target = target_for(plant=check.plant)
        check_names(target, [experiment])
    except ConfigError as error:
        raise error.within(f"{check.path}") from None
    unknown = [name for name in check.tolerances if name not in experiment.outputs]
    if unknown:
        raise ConfigError([f"{check.path}: tolerances.{unknown[0]}: the experiment measures no {unknown[0]} "
                           f"(outputs: {', '.join(experiment.outputs)})"])
    if check.seconds is not None:
        experiment = experiment.truncated(check.seconds)
    with open_session(target) as session:
        try:
            simulated = simulate(session, target, experiment)
        except SimulationFailed as error:
            return check.name, "fail", [(name, tol, math.inf) for name, tol in check.tolerances.items()], len(check.tolerances), \
                [f"the replay did not reach the log's end: {error}"]
    found = compare(experiment, simulated)
    beyond = [(name, tol, found[name]["rms"]) for name, tol in check.tolerances.items()
              if not found[name]["rms"] <= tol]
    notes = [f"{name}: RMS {found[name]['rms']:.4g} (tolerance {tol:g})" for name, tol in check.tolerances.items()]
    return check.name, ("fail" if beyond else "pass"), beyond, len(check.tolerances), notes
