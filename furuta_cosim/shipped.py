"""What the project ships, by kind and name, with the line each file gives about itself
(``furuta-cosim list``). Cheap: reads the YAML files, imports nothing heavy."""

from __future__ import annotations

from furuta_cosim import paths
from furuta_cosim.config import load_yaml
from furuta_cosim.errors import ConfigError


def _descriptions(folder) -> dict[str, dict]:
    found = {}
    for path in sorted(folder.glob("*.yaml")):
        try:
            data = load_yaml(path)
        except ConfigError:
            data = None
        found[path.stem] = data if isinstance(data, dict) else {}
    return found


def listing() -> dict[str, dict[str, str]]:
    """``{kind: {name: description}}`` for plants, models, controllers and scenarios: every
    name the commands accept besides file paths."""
    from furuta_cosim.fmu.plants import model_names

    plant_files = _descriptions(paths.scenarios() / "plants")
    plants = {name: f"the {name} model with its default parameter set" for name in model_names()}
    plants.update({name: str(data.get("description", "")) for name, data in plant_files.items()})
    models = {name: str(data.get("description", "")) for name, data in plant_files.items()
              if data.get("model") == "linear"}
    nonlinear = [name for name, data in plant_files.items() if data.get("model") not in (None, "linear")]
    models["derived"] = "the plant FMU linearized at the upright equilibrium (paper-calibrated)"
    for name in nonlinear:
        models[f"derived:{name}"] = f"the plant FMU with {name}, linearized"
    return {
        "plants": plants,
        "models": models,
        "controllers": {n: str(d.get("description", ""))
                        for n, d in _descriptions(paths.scenarios() / "controllers").items()},
        "scenarios": {n: str(d.get("description", "")) for n, d in _descriptions(paths.scenarios()).items()},
        "tuning": {n: str(d.get("description", ""))
                   for n, d in _descriptions(paths.scenarios() / "tuning").items()},
        "identify": {n: str(d.get("description", ""))
                     for n, d in _descriptions(paths.scenarios() / "identify").items()},
    }
