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
             fmi_version: str = "2.0", resume: bool = False, progress=lambda stage, n, cost: None,
             log: Callable[[str], None] = lambda line: None) -> dict:
    """Fit the plant parameters of an identify spec to its experiments and write the run
    directory: ``plant.yaml`` (the fitted plant) and ``fit.json`` first, then ``report.html``
    and the figures.

    Parameters
    ----------
    spec_name : str or path
        An identify spec: a shipped name (``qube-servo-3``) or a file.
    output : path
        The run directory: new, empty, or an earlier run of this spec (whose files are then
        replaced: none of them stays beside the new fit). Anything else is refused.
    workers : int
        Local processes that run the simulations of the Jacobian.
    dask : str, optional
        A Dask scheduler address, or ``"local"``, instead of local processes.
    fmi_version : str
        The FMI version of the plant FMU the fit simulates: ``"2.0"`` or ``"3.0"``.
    resume : bool
        Go on with the run in ``output`` that was stopped (killed, interrupted) from its last
        finished stage: the same fit as an uninterrupted run. Refused when the spec, its data,
        the plant or the FMU differ from the run's.
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

    from furuta_cosim.errors import ConfigError

    spec = load_identify_spec(spec_name)
    out = output_folder(output)
    try:
        target = target_for(plant=spec.plant, fmi_version=fmi_version)
    except ConfigError as error:
        raise error.within(f"{spec.path}: plant") from None
    from furuta_cosim.identify.fit import check_ranges

    check_names(target, spec.experiments + spec.validation, tuple(p.name for p in spec.free), str(spec.path))
    check_ranges(spec, target)
    identity = _identity(spec, target, fmi_version)
    state = _claim(out, spec, identity, resume)
    log(f"identify {spec.name}: {len(spec.free)} parameters of {target.label} on "
        f"{', '.join(e.name for e in spec.experiments)}"
        + (f"; validation {', '.join(e.name for e in spec.validation)}" if spec.validation else "")
        + (f"; resumed after stage {state['stage']}" if state else ""))

    def checkpoint(progress_state: dict) -> None:
        write_text(out / CHECKPOINT, dumps({"identity": identity, **progress_state}, indent=1) + "\n")

    result = fit(spec, target, workers=workers, dask=dask, progress=progress, log=log,
                 resume=state, on_stage=checkpoint)
    document = result.document()
    document["spec_sha256"] = identity["spec_sha256"]
    figures_of = [(e, result.simulated[e.name]) for e in spec.experiments + spec.validation]
    document["figures"] = [f"{e.name}-{kind}.png" for e, _ in figures_of for kind in ("overlay", "residuals")]
    document["files"] = sorted(["plant.yaml", "fit.json", "report.html"] + document["figures"]
                               + [str(Path(p).with_suffix(".svg")) for p in document["figures"]])
    # the fit first, so that a full disk or a kill while drawing keeps it
    plant = plant_text(result, out)
    write_text(out / "plant.yaml", plant)
    document["fitted_plant"] = {"file": "plant.yaml", "sha256": _fitted_digest(out / "plant.yaml")}
    write_text(out / "fit.json", dumps(document, indent=2) + "\n")
    (out / CHECKPOINT).unlink(missing_ok=True)
    for experiment, pair in figures_of:
        _figures(out, experiment, {"start": pair["start"], "fitted": pair["fit"]})
    write_text(out / "report.html", report_page(document, out))
    return document


CHECKPOINT = "identify-checkpoint.json"  # the finished stages of a run that has not ended


def _identity(spec, target, fmi_version: str) -> dict:
    """What a run is: the spec's content, its data, the plant's values and the FMU."""
    import hashlib

    from furuta_cosim.fmu.plants import content_sha256

    return {"spec": spec.name, "spec_sha256": hashlib.sha256(Path(spec.path).read_bytes()).hexdigest(),
            "data": {e.name: e.sha256 for e in spec.experiments + spec.validation},
            "plant_sha256": content_sha256(target.plant) if target.plant is not None else None,
            "fmu_sha256": hashlib.sha256(Path(target.fmu).read_bytes()).hexdigest(),
            "fmi_version": fmi_version}


def _fitted_digest(path: Path) -> str:
    from furuta_cosim.fmu.plants import content_sha256, load_plant

    return content_sha256(load_plant(path))


def _claim(out: Path, spec, identity: dict, resume: bool) -> dict | None:
    """The run directory made ours: refused when it holds anything but an earlier run of this
    spec; an earlier run's files and any half-written file removed (a new run) or its last
    finished stage returned (``resume``)."""
    import json

    from furuta_cosim.errors import ConfigError

    entries = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    earlier = None
    for name in ("fit.json", CHECKPOINT):
        if name in entries:
            try:
                earlier = json.loads((out / name).read_text())
            except (OSError, ValueError, RecursionError):
                earlier = None
            if isinstance(earlier, dict):
                earlier = earlier.get("identity", earlier) if name == CHECKPOINT else earlier
                break
    ours = isinstance(earlier, dict) and earlier.get("spec", earlier.get("name")) == spec.name
    if resume:
        if CHECKPOINT not in entries:
            what = "a finished fit" if "fit.json" in entries else "no stopped identify run"
            raise ConfigError([f"resume: {out} holds {what}: nothing to resume (run identify "
                               "without `resume`)"])
        try:
            saved = json.loads((out / CHECKPOINT).read_text()) if ours else None
        except (OSError, ValueError, RecursionError):
            saved = None
        if not isinstance(saved, dict):
            raise ConfigError([f"resume: {out / CHECKPOINT} is not a checkpoint of identify {spec.name}"])
        _same(out / CHECKPOINT, saved.get("identity"), identity)
        try:
            state = {"stage": int(saved["stage"]), "x": [float(v) for v in saved["x"]],
                     "record": list(saved["record"]), "simulations": int(saved["simulations"]),
                     "message": str(saved.get("message", ""))}
        except (KeyError, TypeError, ValueError):
            raise ConfigError([f"resume: {out / CHECKPOINT}: damaged (stage, x, record, "
                               "simulations expected)"]) from None
        if len(state["x"]) != len(spec.free) + sum(len(e.free_starts()) for e in spec.experiments):
            raise ConfigError([f"resume: {out / CHECKPOINT}: holds {len(state['x'])} values, the "
                               "spec has another number of free unknowns"])
        return state
    if entries and not ours:
        raise ConfigError([f"output {out}: holds files that are not a run of identify {spec.name} "
                           f"({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''}); "
                           "choose a new or empty folder"])
    # a new run of this spec: what the earlier one wrote goes, so nothing stale stays beside it
    listed = earlier.get("files", []) if isinstance(earlier, dict) else []
    for name in entries:
        if name in listed or name == CHECKPOINT or name.endswith(".partial") \
                or name.endswith(("-overlay.png", "-overlay.svg", "-residuals.png", "-residuals.svg")):
            (out / name).unlink(missing_ok=True)
    return None


def _same(where: Path, saved, identity: dict) -> None:
    from furuta_cosim.errors import ConfigError

    if not isinstance(saved, dict):
        raise ConfigError([f"resume: {where}: records no identity of its run"])
    words = {"spec_sha256": "the spec's content", "data": "the logs (their sha256)",
             "plant_sha256": "the plant's values", "fmu_sha256": "the plant FMU",
             "fmi_version": "the FMI version"}
    for key, what in words.items():
        if saved.get(key) != identity.get(key):
            raise ConfigError([f"resume: {what} differ from the stopped run's ({where}); run "
                               "identify anew without `resume`"])


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
        if p["interval"] is None:
            rows.append(f"| {name} | {p['start']:.5g} | {p['value']:.5g} | none: {p['verdict']} | | |")
            continue
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
