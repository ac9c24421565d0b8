"""``simulate``: a scenario's controllers run in turn, each result saved as soon as it exists,
then the figure and ``metrics.json``, which lists exactly the files of the run.

The command-line interface only formats what :func:`simulate_scenario` returns.
"""

from __future__ import annotations

import math

import json

import numpy as np
from pathlib import Path
from typing import Callable, Sequence

from furuta_cosim.cosim.evaluation import runs, scenario_controllers
from furuta_cosim.cosim.master import prepare
from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import folder, output_folder, write_text
from furuta_cosim.scenario import Scenario


def controller_names(scenario: Scenario) -> list[str]:
    """The names of the scenario's own controllers (what requirements scope to)."""
    from furuta_cosim.controllers import load_controller

    folder = scenario.path.parent if scenario.path else None
    names = []
    for name in scenario.controllers:
        try:
            names.append(load_controller(name, folder).name)
        except ConfigError:
            names.append(Path(str(name)).stem)
    return names


def unchecked_requirements(scenario: Scenario, compiled: Sequence) -> list[str]:
    """Requirements that name no controller of this run (``compiled``: the controllers about
    to run): a line each saying so.

    A scope naming a controller that is neither the scenario's nor running, or a requirement on
    a controller state (``xc3``) that a controller it applies to does not have, is a
    ConfigError before anything runs (the one would skip its requirement without a word, the
    other fail it for a value that cannot exist)."""
    from furuta_cosim.signals import is_controller_state

    running = [c.name for c in compiled]
    known = set(controller_names(scenario)) | set(running)
    problems, notes = [], []
    for k, requirement in enumerate(scenario.requirements):
        for name in requirement.controllers:
            if name not in known:
                problems.append(f"{scenario.source}: requirements[{k}].controllers: no controller "
                                f"{name!r} in this scenario (controllers: {', '.join(sorted(known))})")
        signal = requirement.metric.rpartition(".")[0]
        if is_controller_state(signal):
            for c in compiled:
                states = getattr(c.runtime, "n_xc", 0)
                if requirement.applies_to(c.name) and int(signal[2:]) > states:
                    problems.append(f"{scenario.source}: requirements[{k}].metric: {c.name} has "
                                    f"{states or 'no'} controller state{'s' if states != 1 else ''}"
                                    f" ({', '.join(f'xc{j + 1}' for j in range(states)) or 'a static gain'}): "
                                    f"no {signal}")
        if requirement.controllers and not set(requirement.controllers) & set(running):
            notes.append(f"{requirement.describe()} applies to {', '.join(requirement.controllers)}, "
                         "which did not run: not checked")
    if problems:
        raise ConfigError(problems)
    return notes


def plant_names(prepared) -> str:
    """The plant's own variables behind the view's names, with their conversions
    (``angle = pend_angle x 0.0174533``); empty when the view uses the FMU's names as they are."""
    pairs = list(zip(prepared.signals, prepared.outputs)) + [(prepared.control_input, prepared.control_input)] \
        + list(zip(prepared.disturbances, prepared.disturbance_inputs))
    parts = []
    for view, own in pairs:
        scale, offset = prepared.conversions.get(own, (1.0, 0.0))
        if view == own and (scale, offset) == (1.0, 0.0):
            continue
        parts.append(f"{view} = {own}" + (f" x {scale:g}" if scale != 1.0 else "")
                     + (f" + {offset:g}" if offset else ""))
    return ", ".join(parts)


def simulate_scenario(scenario: Scenario, output: str | Path, *,
                      controllers: Sequence | None = None, fmu: str | Path | None = None,
                      every: int = 1, traces: bool = True,
                      progress: Callable[[str, int, int], None] | None = None,
                      log: Callable[[str], None] = lambda line: None) -> tuple[dict, dict]:
    """Run the scenario's controllers and write their files to ``output``.

    Each trace is written as soon as its run ends, so nothing is lost if a later run fails.

    Parameters
    ----------
    scenario : Scenario
        From :func:`furuta_cosim.scenario.load_scenario`.
    output : path
        The folder for the traces (CSV), ``metrics.json`` and the figures.
    controllers : sequence, optional
        Controller names or files to run instead of the scenario's own.
    fmu : path, optional
        Run on this FMU instead of the scenario's plant.
    every : int
        Write every ``every``-th sample of the traces (metrics always use every sample).
    traces : bool
        Write the traces at all.
    progress : callable, optional
        ``progress(controller, step, steps)`` while a run goes.
    log : callable
        Takes a line per finished run.

    Returns
    -------
    tuple
        ``(document, results)``: the ``metrics.json`` document and ``{name: RunResult}``.
    """
    from furuta_cosim.report.figures import plot_runs

    if every < 1:
        raise ConfigError([f"every: must be a whole number >= 1, got {every}"])
    out = output_folder(output)
    earlier = _files_of_earlier_run(out)
    prepared = prepare(scenario, fmu=fmu)
    compiled = scenario_controllers(prepared, controllers)
    notes = unchecked_requirements(scenario, compiled)
    log(f"simulating {scenario.name}: {prepared.steps} control steps each for "
        f"{', '.join(c.name for c in compiled)}")
    named = plant_names(prepared)
    if named:
        log(f"  on {prepared.fmu.name}: {named}")
    for c in compiled:
        other = design_mismatch(getattr(c, "cfile", None), prepared)
        if other:
            log(f"warning: {c.name}: {other}")
    folder(out)
    results, entries, written = {}, {}, []
    for result in runs(prepared, compiled, progress=progress):
        entry = result.save(out, every=every, trace=traces)
        entry["warnings"] = concerns(result.metrics)
        entry["diverged"] = None if result.failure else diverged(result.trace, prepared)
        if entry["trace"]:
            written.append(Path(entry["trace"]).name)
        results[result.controller], entries[result.controller] = result, entry
        log(f"  {result.controller}: done in {result.wall_time:.2f} s"
            + (f" ({result.failure.split(':')[0]})" if result.failure else ""))
    if prepared.steps > 100_000:
        log("drawing the figure")
    figures = plot_runs({n: r.trace for n, r in results.items()}, out / scenario.name,
                        f"{scenario.name}: {scenario.description}", scenario.plot or None,
                        prepared.time_unit)
    written += [f.name for f in figures]
    document = {"scenario": scenario.name, "description": scenario.description,
                "plant": prepared.plant_name, "fmu": Path(prepared.fmu).name,
                "fmu_sha256": _sha256(prepared.fmu),
                "control_period": prepared.control_period, "time_unit": prepared.time_unit,
                "steps": prepared.steps, "trace_every": every, "controllers": entries,
                "unchecked": notes, "figures": [f.name for f in figures],
                "files": sorted(written + ["metrics.json"]),
                "passed": all(r.passed for r in results.values())
                and not any(e["diverged"] for e in entries.values())}
    write_text(out / "metrics.json", dumps(document, indent=2) + "\n")
    for name in earlier - set(document["files"]):
        (out / name).unlink(missing_ok=True)  # an earlier run's file this run did not write
    return document, results


def design_mismatch(cfile, prepared) -> str | None:
    """A line when a controller file was designed on a plant's linearization (``model:
    derived:PLANT``) and the scenario runs another plant (by content), else None. A linear
    model file names no plant, and is not compared."""
    model = str(getattr(cfile, "model", "") or "")
    if prepared.plant is None or not (model == "derived" or model.startswith("derived:")):
        return None
    from furuta_cosim.fmu.plants import content_sha256, load_plant

    name = model.partition(":")[2] or "paper-calibrated"
    try:
        designed = load_plant(name, beside=cfile.path.parent if getattr(cfile, "path", None) else None)
    except ConfigError:
        return None
    if content_sha256(designed) == content_sha256(prepared.plant):
        return None
    return (f"designed on {designed.name} (model {model}), run here on {prepared.plant.name}: its gains "
            "are not this plant's, so expect it to do worse or to fail")


def diverged(trace, prepared) -> str | None:
    """Why a run left what its plant allows, else None: the pendulum fell (from within pi/2 of
    upright to beyond it), or the arm or the current went past the plant file's ``limits``
    (what a rig's supervisor would have stopped)."""
    from furuta_cosim.swingup import wrap

    signals = trace.signals
    for name in getattr(prepared, "upright", ()):   # the declaration's pendulum angles
        if name not in signals or not len(signals[name]):
            continue
        pendulum = np.array([abs(wrap(float(v))) for v in signals[name] if math.isfinite(v)])
        if len(pendulum) and pendulum[0] < math.pi / 2 and pendulum.max() > math.pi / 2:
            return f"the pendulum fell: {pendulum.max():.3g} rad from upright"
    from furuta_cosim.fmu.plants import LIMITED_SIGNALS

    limits = dict(prepared.plant.limits) if prepared.plant is not None else {}
    for key, (signal, unit) in LIMITED_SIGNALS.items():
        bound = limits.get(key)
        if bound and signal in signals and len(signals[signal]):
            peak = float(np.nanmax(np.abs(signals[signal])))
            if peak > bound:
                return (f"|{signal}| reached {peak:.4g} {unit}, beyond the plant's limits.{key} of {bound:g} {unit} "
                        "(a rig's supervisor stops there)")
    return None


def concerns(metrics: dict) -> list[str]:
    """What a run that went to its end did wrong without breaking a requirement: an output
    that never settles (the loop oscillates, or drifts off), with its size and the input's."""
    found = []
    for key, value in metrics.items():
        signal, _, name = key.rpartition(".")
        if ".step" in signal:
            continue  # one step of several: the table shows each
        wrapped = metrics.get(f"{signal}.WrappedSettlingTime")
        if name == "SettlingTime" and isinstance(wrapped, float) and math.isfinite(wrapped):
            continue  # swung up the other way round (to 2 pi): upright, as the wrapped angle says
        if name in ("SettlingTime", "WrappedSettlingTime") and (value is None or not math.isfinite(value)):
            peak, u = metrics.get(f"{signal}.max_abs"), metrics.get("u.peak_abs")
            found.append(f"{signal} does not settle by the end of the run (peak |{signal}| {peak:.4g}"
                         + (f", peak |u| {u:.4g}" if u is not None else "") + ")"
                         if peak is not None else f"{signal} does not settle by the end of the run")
    return found


# what simulate writes besides metrics.json: a CSV trace per controller (header ``t,...``), a
# figure as PNG and SVG; only such files are ever removed
_OURS = {".csv": (b"t,",), ".png": (b"\x89PNG\r\n\x1a\n",), ".svg": (b"<?xml", b"<svg")}


def _files_of_earlier_run(folder: Path) -> set[str]:
    """The files an earlier run's metrics.json lists in ``folder`` that this command can have
    written (a trace or a figure, by name and by content): a user's own files there are never
    touched, even when a metrics.json names them."""
    from furuta_cosim.config import plain_name

    try:
        listed = json.loads((folder / "metrics.json").read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):
        return set()
    ours = set()
    for name in listed if isinstance(listed, list) else []:
        if not isinstance(name, str) or Path(name).suffix not in _OURS or not plain_name(Path(name).stem):
            continue
        path = folder / name
        try:
            if path.is_symlink() or not path.is_file():
                continue
            with path.open("rb") as handle:
                head = handle.read(16)
        except OSError:
            continue
        if head.startswith(_OURS[path.suffix]):
            ours.add(name)
    return ours



def _sha256(path) -> str:
    """The FMU by its content: the file itself stays in the cache of the machine that ran."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
