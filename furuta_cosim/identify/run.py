"""The commands' logic: ``replay`` (a plant against logs) and ``identify`` (a fit and its run
directory). The CLI only formats what these return.

An identify run directory holds ``plant.yaml`` (a plant file every command takes: it
``extends`` the spec's plant with the fitted values, and records where they come from),
``fit.json`` (values, intervals, correlations, residuals), ``report.html`` and the figures.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Sequence

import yaml

from furuta_cosim.documents import dumps
from furuta_cosim.files import folder, output_folder, write_text
from furuta_cosim.identify.experiment import Experiment, load_experiment
from furuta_cosim.identify.fit import FitResult, fit, with_values
from furuta_cosim.identify.replay import (SimulationFailed, Target, check_names, compare,
                                          open_session, simulate)
from furuta_cosim.identify.spec import load_identify_spec


def replay(experiments: Sequence[str | Path], target: Target, output: str | Path | None = None) -> dict:
    """Each experiment's logged inputs run open loop on ``target``: per output its RMS error
    (SI units) and, where it oscillates, its period.

    Parameters
    ----------
    experiments : sequence of str or path
        Experiment files (their logs, inputs and outputs).
    target : Target
        The plant to run them on, from :func:`furuta_cosim.identify.replay.target_for`.
    output : path, optional
        A folder for an overlay and a residual figure per experiment (PNG and SVG) and
        ``replay.json``.

    Returns
    -------
    dict
        Per experiment and output: the RMS error and, where it oscillates, the period.
    """
    loaded = [load_experiment(path) for path in experiments]
    check_names(target, loaded)
    out = output_folder(output) if output is not None else None
    document = {"plant": target.label, "experiments": {}}
    with open_session(target) as session:
        for experiment in loaded:
            try:
                simulated = simulate(session, target, experiment)
            except SimulationFailed as error:
                document["experiments"][experiment.name] = {"failure": str(error)}
                continue
            entry = {"file": str(experiment.path), "samples": experiment.samples,
                     "outputs": compare(experiment, simulated)}
            if out is not None:
                entry["figures"] = [p.name for p in _figures(out, experiment, {target.label: simulated})]
            document["experiments"][experiment.name] = entry
    if out is not None:
        write_text(out / "replay.json", dumps(document, indent=2) + "\n")
    return document


def _figures(out: Path, experiment: Experiment, simulated: dict) -> list[Path]:
    from furuta_cosim.report.rig import plot_overlay, plot_residuals

    measured = {n: m.values for n, m in experiment.outputs.items()}
    quantum = {n: 2 * 3 ** 0.5 * m.sigma for n, m in experiment.outputs.items() if m.sigma_from == "quantum"}
    written = plot_overlay(experiment.t, measured, simulated, out / f"{experiment.name}-overlay",
                           f"{experiment.name}: measured and simulated")
    written += plot_residuals(experiment.t, measured, simulated, out / f"{experiment.name}-residuals",
                              f"{experiment.name}: simulated - measured", quantum)
    return [p for p in written if p.suffix == ".png"]


def identify(spec_name: str | Path, output: str | Path, *, workers: int = 1, dask: str | None = None,
             fmi_version: str = "2.0", progress=lambda stage, n, cost: None,
             log: Callable[[str], None] = lambda line: None) -> dict:
    """Fit the plant parameters of an identify spec to its experiments and write the run
    directory: ``plant.yaml`` (the fitted plant), ``fit.json``, ``report.html`` and figures.

    Parameters
    ----------
    spec_name : str or path
        An identify spec: a shipped name (``qube-servo-3``) or a file.
    output : path
        The run directory (created; an existing non-empty one is refused).
    workers : int
        Local processes that run the simulations of the Jacobian.
    dask : str, optional
        A Dask scheduler address, or ``"local"``, instead of local processes.
    fmi_version : str
        The FMI version of the plant FMU the fit simulates: ``"2.0"`` or ``"3.0"``.
    progress : callable
        ``progress(stage, simulations, cost)``, called as the fit goes.
    log : callable
        Takes a line about the fit (its stages, pairs that are not separable).

    Returns
    -------
    dict
        The ``fit.json`` document: values, intervals, correlations, residuals.
    """
    from furuta_cosim.identify.replay import target_for

    spec = load_identify_spec(spec_name)
    out = output_folder(output)
    target = target_for(plant=spec.plant, fmi_version=fmi_version)
    log(f"identify {spec.name}: {len(spec.free)} parameters of {target.label} on "
        f"{', '.join(e.name for e in spec.experiments)}"
        + (f"; validation {', '.join(e.name for e in spec.validation)}" if spec.validation else ""))
    result = fit(spec, target, workers=workers, dask=dask, progress=progress, log=log)
    document = result.document()
    folder(out)
    figures = []
    for experiment in spec.experiments + spec.validation:
        pair = result.simulated[experiment.name]
        figures += _figures(out, experiment, {"start": pair["start"], "fitted": pair["fit"]})
    document["figures"] = [p.name for p in figures]
    document["files"] = sorted(["plant.yaml", "fit.json", "report.html"] + document["figures"]
                               + [p.with_suffix(".svg").name for p in figures])
    write_text(out / "plant.yaml", plant_text(result, out))
    write_text(out / "fit.json", dumps(document, indent=2) + "\n")
    write_text(out / "report.html", report_page(document, out))
    return document


def plant_text(result: FitResult, out: Path) -> str:
    """The fitted plant file: the spec's plant extended with the fitted values (a name stays a
    name; a file is named by its path relative to ``out``, so the folder travels)."""
    spec, plant = result.spec, result.target.plant
    base = spec.plant
    if "/" in base or base.endswith((".yaml", ".yml")):
        base = os.path.relpath(Path(plant.path).resolve(), out.resolve())
    document = {
        "model": plant.model,
        "extends": base,
        "description": f"{plant.name} fitted to {', '.join(e.name for e in spec.experiments)} "
                       f"(identify {spec.name})",
        "parameters": {name: float(value) for name, value in with_values(result).items()},
        "provenance": {
            "identify": spec.name,
            "data": {e.name: {"file": e.data.name, "sha256": e.sha256} for e in spec.experiments},
            "rms": {name: {o: c["rms"] for o, c in outputs.items()}
                    for name, outputs in result.experiments.items()},
            "fit": "fit.json",
        },
    }
    head = (f"# Written by furuta-cosim identify {spec.name}: the fitted parameters on top of "
            f"{base}.\n# Their intervals and correlations are in fit.json beside this file.\n")
    return head + yaml.safe_dump(document, sort_keys=False)


def report_page(document: dict, out: Path) -> str:
    from furuta_cosim.report.html import figure, markdown_to_html, page

    rows = ["| parameter | start | fitted | 95 % interval | stderr | plain stderr |", "|---|---|---|---|---|---|"]
    for name, p in document["parameters"].items():
        lo, hi = p["interval"]
        rows.append(f"| {name} | {p['start']:.5g} | {p['value']:.5g}{' (at a bound)' if p['at_bound'] else ''} "
                    f"| [{lo:.4g}, {hi:.4g}] | {p['stderr']:.3g} | {p['stderr_plain']:.3g} |")
    fits = ["| experiment | output | RMS at start | RMS fitted | period error fitted |", "|---|---|---|---|---|"]
    for kind in ("experiments", "validation"):
        for name, outputs in document[kind].items():
            for output, c in outputs.items():
                start = document["at_start"][name][output]["rms"]
                period = c.get("period", {}).get("error")
                fits.append(f"| {name}{' (validation)' if kind == 'validation' else ''} | {output} | "
                            f"{start:.4g} | {c['rms']:.4g} | {'' if period is None else f'{100 * period:+.3f} %'} |")
    pairs = "".join(f"- {a} and {b}: correlation {r:+.3f}, not separable on these data\n"
                    for a, b, r in document["not_separable"]) or "- none above 0.95\n"
    text = (f"# identify {document['name']}\n\n"
            f"Plant {document['plant']}; {document['simulations']} simulations in "
            f"{document['seconds']:.1f} s; {document['message']}\n\n" + "\n".join(rows) + "\n\n"
            f"Intervals: {document['interval_method']}. The plain column is the textbook "
            "s^2 (J^T J)^-1, which assumes independent residuals.\n\n## Correlated pairs\n\n" + pairs
            + "\n## Residuals (SI units: rad, A)\n\n" + "\n".join(fits) + "\n")
    data = ["| experiment | file | samples | window [s] | sha256 |", "|---|---|---|---|---|"]
    data += [f"| {name} | {d['file']} | {d['samples']} | {d['window'][0]:g} to {d['window'][1]:g} | {d['sha256'][:16]} |"
             for name, d in document["data"].items()]
    text += "\n## Data\n\n" + "\n".join(data) + f"\n\nPlant FMU sha256 {document['fmu_sha256'][:16]}.\n"
    body = markdown_to_html(text) + "".join(
        figure(out / Path(name).with_suffix(".svg"), Path(name).stem) for name in document["figures"])
    return page(f"identify {document['name']}", body)
