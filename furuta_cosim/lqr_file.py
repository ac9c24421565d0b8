"""Controller files designed and analyzed: the one place that turns a model, weights and a
period into a checked, provenanced LQR controller file (``furuta-cosim design lqr`` and
``tools/regenerate_controllers.py`` both call :func:`design_lqr_file`), and the one that
analyzes a controller file on the model it names (:func:`analyze_file`, ``analyze``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from furuta_cosim.controllers import (ControllerFile, check_fits, default_output, load_controller,
                                      recorded_model, save_controller)
from furuta_cosim.defaults import PAPER_PERIOD
from furuta_cosim.design import analyze, lqr, prefilter
from furuta_cosim.design.analysis import Analysis
from furuta_cosim.design.linear import LinearModel
from furuta_cosim.errors import ConfigError, DesignError
from furuta_cosim.files import output_file
from furuta_cosim.fmu.plants import plant_path
from furuta_cosim.models import load_model


@dataclass
class Design:
    cfile: ControllerFile
    model: LinearModel
    analysis: Analysis
    path: Path | None          # where the file was written, if it was

    def as_dict(self) -> dict:
        """What ``design lqr --json`` prints."""
        controller, K = self.cfile.controller, self.cfile.controller.K
        return {"K": K[0].tolist() if K.shape[0] == 1 else K.tolist(),
                "closed_loop_eigenvalues": [[float(z.real), float(z.imag)]
                                            for z in self.analysis.eigenvalues],
                "time": "discrete" if controller.discrete else "continuous",
                "period": controller.period, "model": self.model.name,
                "stable": self.analysis.stable,
                "prefilter": {"output": self.cfile.tracked_output, "F": self.cfile.F},
                "method": controller.provenance["method"],
                "notes": [self.model.provenance["note"]] if self.model.provenance.get("note") else []}


def analyze_file(controller: str | Path, model: str | None = None) -> Design:
    """A controller file analyzed on ``model`` (given: resolved from here), or on the model
    the file names (resolved beside the file)."""
    cfile = load_controller(controller)
    name = model or cfile.model
    if not name:
        raise ConfigError([f"{cfile.source}: model: missing; name one with `model`"])
    linear = load_model(name, None if model or not cfile.path else cfile.path.parent)
    cfile = check_fits(cfile, linear)
    c = cfile.controller
    sampling = cfile.period if not c.discrete and cfile.period else None
    analysis = analyze(linear, c, margins=True, sampling_period=sampling,
                       tracked_output=cfile.tracked_output or default_output(linear))
    return Design(cfile, linear, analysis, cfile.path)


def design_lqr_file(model_name: str, *, Q: Sequence[float] | None = None,
                    R: Sequence[float] | None = None, period: float = PAPER_PERIOD,
                    continuous: bool = False, name: str | None = None, track: str | None = None,
                    description: str = "", output: str | Path | None = None) -> Design:
    """An LQR on ``model_name`` (dlqr at ``period``, or the continuous ARE), its prefilter for
    ``track`` and its analysis, written to ``output`` when given.

    ``Q`` and ``R`` are weights as on the command line: one value (times the identity), n
    diagonal values or n*n entries (None: python-control's defaults of :func:`lqr`, the paper's
    for the pendulum). The controller is named ``name``, else after the output file, else
    ``lqr``; the file records the model as it was given, a path relative to the file's own
    folder (so that the file travels with what it names, and ``analyze`` finds it again). Problems name the parameter or file at fault (ConfigError,
    DesignError).
    """
    if not continuous and not (isinstance(period, (int, float)) and period > 0):
        raise DesignError(f"period: must be > 0, got {period}")
    if output:
        output_file(output)
    model = load_model(model_name)
    weights = (_weights(Q, model.n, "Q"), _weights(R, model.B.shape[1], "R"))
    try:
        controller = lqr(model, *weights, None if (continuous or model.discrete) else period)
    except DesignError as error:
        if error.key == "A, B":
            raise ConfigError([f"{_model_source(model_name)}: A, B: {error}"]) from None
        if error.key:
            raise DesignError(f"{error.key}: {error}") from None
        raise
    name = name or (Path(output).stem if output else "lqr")
    controller = dataclasses.replace(controller, name=name)
    tracked = track or default_output(model)
    try:
        F = prefilter(model, controller, tracked)
    except DesignError as error:
        raise DesignError(f"track {tracked}: {error}") from None
    cfile = ControllerFile(controller, controller.period or (0.0 if continuous else period),
                           recorded_model(model_name, Path(output).parent if output else None),
                           tracked, F, description,
                           provenance=controller.provenance)
    path = save_controller(cfile, output) if output else None
    return Design(cfile, model, analyze(model, controller), path)


def _model_source(model_name: str) -> str:
    """Where a model comes from, for messages: its plant file, or its name."""
    if str(model_name).startswith("derived"):
        return str(model_name)
    try:
        return str(plant_path(model_name))
    except ConfigError:
        return str(model_name)


def _weights(values, n: int, flag: str):
    """A weight from the command line: one value (times the identity), n diagonal values or n*n
    entries; None when not given."""
    if not values:
        return None
    if len(values) == 1:
        return values[0] * np.eye(n)
    if len(values) == n:
        return np.diag(values)
    if len(values) == n * n:
        return np.reshape(values, (n, n))
    expected = "1 value" if n == 1 else f"{n} diagonal values or {n * n} entries"
    raise DesignError(f"{flag}: expected {expected}, got {len(values)}")
