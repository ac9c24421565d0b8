"""A scored point of a tuning as a controller file: everything the scoring used (the controller
at the recorded point and the prefilter its runs computed), so that ``simulate`` and
``analyze`` of the file reproduce what the history recorded."""

from __future__ import annotations

from pathlib import Path

from furuta_cosim.tuning.objective import Evaluator


def save_scored(evaluator: Evaluator, record: dict, path: Path, name: str, description: str,
                method: str, seed: int) -> dict:
    """Write the controller of history ``record`` to ``path``; its prefilter (output and F)."""
    from furuta_cosim.controllers import ControllerFile, recorded_model, save_controller

    spec = evaluator.spec
    controller = evaluator.space.controller(record["x"], name=name)
    tracked, F = prefilter_of(evaluator, controller)
    provenance = {"method": f"furuta-cosim tune ({method})", "spec": spec.name, "seed": seed,
                  "evaluation": record["index"], "objective": record["objective"],
                  "origin": record.get("origin") or ""}
    if record.get("criteria"):
        provenance["criteria"] = record["criteria"]
    if isinstance(controller, ControllerFile):  # a swing-up file with the tuned settings
        from dataclasses import replace

        save_controller(replace(controller, description=description, provenance=provenance), path)
        return {"output": tracked, "F": F}
    # the model by a path relative to the file: a run directory travels with its plant
    model = recorded_model(spec.model, Path(path).parent)
    save_controller(ControllerFile(controller, spec.period, model, tracked, F, description,
                                   provenance=provenance), path)
    return {"output": tracked, "F": F}


def prefilter_of(evaluator: Evaluator, controller) -> tuple[str, float]:
    """The tracked output and prefilter F the scoring used (the first run's, when runs track
    different outputs; the model's default output for the spectral objective)."""
    from furuta_cosim.controllers import default_output
    from furuta_cosim.design.prefilter import prefilter

    prefilters = evaluator.prefilters(controller) if evaluator.spec.objective.type != "spectral" else {}
    if prefilters:
        tracked = next(iter(prefilters))
        return tracked, float(prefilters[tracked])
    tracked = default_output(evaluator.model)
    return tracked, float(prefilter(evaluator.model, getattr(controller, "controller", controller), tracked))
