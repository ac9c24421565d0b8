"""``simulate``: a scenario's controllers run in turn, each result saved as soon as it exists,
then the figure and ``metrics.json``, which lists exactly the files of the run.

The command-line interface only formats what :func:`simulate_scenario` returns.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable, Sequence

from furuta_cosim.cosim.evaluation import evaluate, scenario_controllers
from furuta_cosim.cosim.master import prepare
from furuta_cosim.errors import ConfigError, FmuError
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


def unchecked_requirements(scenario: Scenario, running: Sequence[str]) -> list[str]:
    """Requirements that name no controller of this run: a line each saying so.

    A scope naming a controller that is neither the scenario's nor running is a ConfigError
    (a misspelt name would otherwise skip its requirement without a word)."""
    known = set(controller_names(scenario)) | set(running)
    problems, notes = [], []
    for k, requirement in enumerate(scenario.requirements):
        for name in requirement.controllers:
            if name not in known:
                problems.append(f"{scenario.source}: requirements[{k}].controllers: no controller "
                                f"{name!r} in this scenario (controllers: {', '.join(sorted(known))})")
        if requirement.controllers and not set(requirement.controllers) & set(running):
            notes.append(f"{requirement.describe()} applies to {', '.join(requirement.controllers)}, "
                         "which did not run: not checked")
    if problems:
        raise ConfigError(problems)
    return notes


def check_output_folder(folder: Path) -> None:
    """Fail before any run when the output folder cannot be used."""
    if folder.exists() and not folder.is_dir():
        raise ConfigError([f"-o {folder}: exists and is not a folder"])
    probe = folder
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError([f"-o {folder}: {probe} is not writable"])


def simulate_scenario(scenario: Scenario, output: str | Path, *,
                      controllers: Sequence | None = None, fmu: str | Path | None = None,
                      every: int = 1, traces: bool = True,
                      progress: Callable[[str, int, int], None] | None = None,
                      log: Callable[[str], None] = lambda line: None) -> tuple[dict, dict]:
    """Run the scenario's controllers (or ``controllers``) and write their files to ``output``.

    Returns ``(document, results)``: the ``metrics.json`` document and ``{name: RunResult}``.
    Each trace is written as soon as its run ends, so nothing is lost if a later run fails;
    ``every`` thins the written traces (metrics always use every sample), ``traces=False``
    writes none.
    """
    from furuta_cosim.fmu.session import PlantSession
    from furuta_cosim.report.figures import plot_runs

    if every < 1:
        raise ConfigError([f"--every: must be a whole number >= 1, got {every}"])
    out = Path(output)
    check_output_folder(out)
    prepared = prepare(scenario, fmu=fmu)
    compiled = scenario_controllers(prepared, controllers)
    notes = unchecked_requirements(scenario, [c.name for c in compiled])
    log(f"simulating {scenario.name}: {prepared.steps} control steps each for "
        f"{', '.join(c.name for c in compiled)}")
    out.mkdir(parents=True, exist_ok=True)
    results, entries, written = {}, {}, []
    with PlantSession.open(prepared.fmu) as session:
        for c in compiled:
            report = (lambda k, n, name=c.name: progress(name, k, n)) if progress else None
            try:
                result = evaluate(prepared, session, c, progress=report)
            except FmuError as error:
                raise FmuError(f"{prepared.source}: controller {c.name}: {error}") from None
            entry = result.save(out, every=every, trace=traces)
            if entry["trace"]:
                written.append(Path(entry["trace"]).name)
            results[c.name], entries[c.name] = result, entry
            log(f"  {c.name}: done in {result.wall_time:.2f} s"
                + (f" ({result.failure.split(':')[0]})" if result.failure else ""))
    if prepared.steps > 100_000:
        log("drawing the figure")
    figures = plot_runs({n: r.trace for n, r in results.items()}, out / scenario.name,
                        f"{scenario.name}: {scenario.description}", scenario.plot or None,
                        prepared.time_unit)
    written += [f.name for f in figures]
    document = {"scenario": scenario.name, "description": scenario.description,
                "plant": prepared.plant_name, "fmu": str(prepared.fmu),
                "control_period": prepared.control_period, "time_unit": prepared.time_unit,
                "steps": prepared.steps, "trace_every": every, "controllers": entries,
                "unchecked": notes, "figures": [str(f) for f in figures],
                "files": sorted(written + ["metrics.json"]),
                "passed": all(r.passed for r in results.values())}
    _write_json(out / "metrics.json", document)
    return document, results


def _write_json(path: Path, document: dict) -> None:
    partial = path.with_name(f".{path.name}.partial")
    try:
        partial.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n")
        partial.replace(path)
    finally:
        partial.unlink(missing_ok=True)

