"""The commands' logic: ``replay`` (a plant against logs) and ``identify`` (a fit and its run
directory: the stages of identify/pipeline.py). The CLI only formats what these return.

An identify run directory holds ``plant.yaml`` (a plant file every command takes: it
``extends`` the spec's plant with the fitted values, and records where they come from),
``fit.json`` (values, intervals, correlations, residuals), ``report.html`` and the figures.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import output_folder, write_text
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.replay import (SimulationFailed, Target, chatter, check_names, compare,
                                          open_session, simulate)
from furuta_cosim.identify.written import draw_figures


def replay(experiments: Sequence[str | Path], target: Target, output: str | Path | None = None,
           tolerance: float | None = None) -> dict:
    """Each experiment's logged inputs run open loop on ``target`` (or, for a log with a
    ``loop:``, the controller that ran closing the loop again): per output its RMS error (SI
    units) and, where it oscillates, its period.

    Parameters
    ----------
    experiments : sequence of str or path
        Experiment files (their logs, inputs and outputs).
    target : Target
        The plant to run them on, from :func:`furuta_cosim.identify.replay.target_for`.
    output : path, optional
        A folder for an overlay and a residual figure per experiment (PNG and SVG) and
        ``replay.json``.
    tolerance : float, optional
        Noise floors of RMS an output may replay within (identify/verdict.py; default 20).

    Returns
    -------
    dict
        Per experiment and output: the RMS error, its noise floors and, where it oscillates,
        the period; ``reproduced``: every experiment ran and every output is within
        ``tolerance`` noise floors, else ``far`` lists those that are not.
    """
    from furuta_cosim.identify.verdict import TOLERANCE, floor_of

    tolerance = TOLERANCE if tolerance is None else tolerance
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not 0 < tolerance <= 1e6:
        raise ConfigError([f"tolerance: expected a number of noise floors in (0, 1e6], got {tolerance!r}"])
    from furuta_cosim.identify.estimate import with_estimate

    loaded = [load_experiment(path) for path in experiments]
    named: dict = {}
    for experiment in loaded:   # replay.json and the report are keyed by the log's name
        if experiment.name in named:
            raise ConfigError([f"{experiment.path}: name: {experiment.name} is the name of {named[experiment.name]} "
                               "too: give one of them another name: key"])
        named[experiment.name] = experiment.path
    check_names(target, loaded)
    delays, said = fitted_delays(target, loaded)
    from furuta_cosim.identify.precheck import wrong_loop

    # a loop that does not rebuild its logged command replays another loop than the one that ran
    said += [line for e in loaded if e.loop is not None for line in [wrong_loop(e)] if line]
    # a balancing log closes its loop as a fit does (identify/estimate.py): the RMS replay
    # reports is the one identify reports for the same plant
    loaded = [with_estimate(e, target) for e in loaded]
    out = output_folder(output) if output is not None else None
    document = {"plant": target.label, "tolerance": tolerance, "experiments": {}, "far": [],
                "notes": [f"{e.name}: segments: {e.segments:g} s is how identify fits it (multiple shooting, each "
                          "segment from its measured state); replay runs its whole window as the log ran ("
                          + ("its loop closed" if e.loop is not None else "open loop on its logged input") + ")"
                          for e in loaded if e.segments] + said,
                "values": delays}
    with open_session(target) as session:
        for experiment in loaded:
            record: dict = {}
            try:
                simulated = simulate(session, target, experiment, delays, record=record)
            except SimulationFailed as error:
                document["experiments"][experiment.name] = {"failure": str(error)}
                continue
            entry = {"file": experiment.path.name, "data": experiment.data.name,
                     "sha256": experiment.sha256, "samples": experiment.samples,
                     "loop": "closed" if experiment.loop is not None else "open",
                     "outputs": compare(experiment, simulated)}
            if experiment.loop is not None and experiment.loop.mode is not None:
                entry["mode"] = modes(experiment, record.get("switches", []), record.get("own"))
            try:
                for output_name, rms in chatter(session, target, experiment, simulated, delays).items():
                    entry["outputs"][output_name]["chatter"] = rms
            except SimulationFailed:
                pass  # the shifted replay failed: the output is judged on its stated noise alone
            for output_name, c in entry["outputs"].items():
                floor, what = floor_of(c)
                c["floors"] = c["rms"] / floor if floor > 0 else None
                c["floor_is"] = what
                if not (c["floors"] is not None and c["floors"] <= tolerance):
                    document["far"].append(f"{experiment.name} {output_name}")
            if out is not None:
                entry["figures"] = [p.name for p in draw_figures(out, experiment.name, [(experiment, {target.label: simulated})])]
            document["experiments"][experiment.name] = entry
    document["reproduced"] = not document["far"] and not any("failure" in e for e in document["experiments"].values())
    if out is not None:
        write_text(out / "replay.json", dumps(document, indent=2) + "\n")
    return document


def modes(experiment, replayed: list, own: list | None = None) -> dict:
    """The controller's mode switches as the log has them (its ``loop.mode`` column) and as the
    replay's controller made them: each as [time (s), new mode]; ``agree`` when they are the
    same switches at the same samples, else ``first_apart``, the time of the first that is not.
    ``own``: the replay followed the logged mode (``followed``), and these are the samples where
    the controller's own rule gave another mode (sample, its mode); its switches (``replayed``)
    are then the rule's: at the first sample of each such stretch, the rule's mode, and where a
    stretch ends before the log switches back, the logged mode again."""
    logged_mode = np.asarray(experiment.loop.mode, dtype=float)
    changes = np.nonzero(np.diff(logged_mode) != 0)[0] + 1
    logged = [(int(k), float(logged_mode[k])) for k in changes]
    t = experiment.t
    if own is not None:   # the rule's mode at each sample: the logged one where it agreed
        rule = logged_mode.copy()
        for k, m in own:
            if 0 <= k < len(rule):
                rule[k] = m
        changed = np.nonzero(np.diff(rule) != 0)[0] + 1
        replayed = [(int(k), float(rule[k])) for k in changed]
    ours = [(int(k), float(m)) for k, m in replayed if 0 <= k < experiment.samples]
    apart = next((min(a[0], b[0]) for a, b in zip(logged, ours) if a != b), None)
    if apart is None and len(logged) != len(ours):
        apart = (logged + ours)[min(len(logged), len(ours))][0]
    return {"logged": [[float(t[k]), m] for k, m in logged], "replayed": [[float(t[k]), m] for k, m in ours],
            "followed": own is not None,
            "agree": apart is None, "first_apart": None if apart is None else float(t[apart])}


def fitted_delays(target: Target, experiments) -> tuple[dict, list[str]]:
    """(values, notes): each free delay of ``experiments`` at its fitted value where ``target``
    is a plant that identify wrote (its ``provenance.fit``, the fit.json beside it): a log the
    fit fitted at its own value, another at the fitted logs' mean of the same delay (an input's
    or the loop's: the rig's, fit.shared_values); a note per delay says which. Without such a
    fit, ({}, []): each free delay at its start (the low bound)."""
    from furuta_cosim.config import load_yaml
    from furuta_cosim.identify.variants import _load_json

    plant = target.plant
    free = {(e.alias or e.name, suffix) for e in experiments for suffix in e.free_starts() if suffix.endswith(".delay")}
    if plant is None or not free:
        return {}, []
    data = load_yaml(plant.path)
    provenance = data.get("provenance") if isinstance(data, dict) else None
    name = provenance.get("fit") if isinstance(provenance, dict) else None
    if not isinstance(name, str) or Path(name).name != name or not (Path(plant.path).parent / name).is_file():
        return {}, [f"{owner}: its {suffix} at its start, {_start_of(experiments, owner, suffix) * 1000:g} ms (the "
                    f"plant {plant.name} is not a fit with a fit.json beside it)" for owner, suffix in sorted(free)]
    path = Path(plant.path).parent / name
    document = _load_json(path)
    parameters = document.get("parameters") if isinstance(document, dict) else None
    if not isinstance(parameters, dict):
        raise ConfigError([f"{path}: parameters: missing: not a fit.json of identify"])
    fitted = {}
    for key, entry in parameters.items():
        value = entry.get("value") if isinstance(entry, dict) else None
        if isinstance(key, str) and key.endswith(".delay") and isinstance(value, (int, float)) \
                and not isinstance(value, bool) and 0.0 <= value <= 1.0:
            fitted[key] = float(value)
    values, notes = {}, []
    for owner, suffix in sorted(free):
        own = f"{owner}.{suffix}"
        same = sorted(k for k in fitted if k.split(".", 1)[1] == suffix)
        if own in fitted:
            values[own] = fitted[own]
            notes.append(f"{owner}: its {suffix} at {fitted[own] * 1000:.4g} ms, its value in {path.name}")
        elif same:
            values[own] = float(np.mean([fitted[k] for k in same]))
            notes.append(f"{owner}: its {suffix} at {values[own] * 1000:.4g} ms, fitted on {', '.join(same)} "
                         f"({path.name}; a delay is the rig's, shared by its logs)")
        else:
            notes.append(f"{owner}: its {suffix} at its start, {_start_of(experiments, owner, suffix) * 1000:g} ms "
                         f"({path.name} fitted no {suffix})")
    return values, notes


def _start_of(experiments, owner: str, suffix: str) -> float:
    for e in experiments:
        if (e.alias or e.name) == owner and suffix in e.free_starts():
            return e.free_starts()[suffix].start
    return 0.0


def identify(spec_name: str | Path, output: str | Path, *, workers: int = 1, dask: str | None = None,
             fmi_version: str = "2.0", resume: bool = False, starts: int = 1, profiles: bool = True,
             bootstrap: int = 0, seed: int = 0, holdout: float | None = None,
             validation: Sequence[str | Path] = (), accept: bool = False, force: bool = False,
             progress=lambda stage, n, cost: None, log: Callable[[str], None] = lambda line: None) -> dict:
    """Fit the plant parameters of an identify spec to its experiments and write the run
    directory: ``plant.yaml`` (the fitted plant) and ``fit.json`` first, then ``report.html``
    and the figures; the stages of identify/pipeline.py with their defaults.

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
        finished stage (or profile): the same fit as an uninterrupted run. Refused when the
        spec, its data, the plant, the FMU or these options differ from the run's.
    starts : int
        Fit from this many starts (the spec's, then a Latin hypercube around it) and keep the
        lowest cost; the distinct optima found are reported.
    profiles : bool
        Profile each free plant parameter (identify/profile.py): a likelihood-ratio interval
        and a verdict (identifiable, practically or structurally not identifiable).
    bootstrap : int
        Replicates of a block bootstrap of the residuals (identify/bootstrap.py; 0: none).
    seed : int
        The multi-start's design and the bootstrap's draws.
    holdout : float, optional
        The last fraction of each fitted log held out and validated on (the spec's ``holdout``
        when None).
    validation : sequence of paths
        More experiment files to validate on, beside the spec's ``validation``.
    accept : bool
        Write the fitted plant even when the verdict (identify/verdict.py) does not trust it;
        otherwise such a fit's plant file carries ``rejected`` and no ``--plant`` reads it.
    force : bool
        Fit even when the Jacobian at the start values says the experiments cannot separate
        some free unknowns (identify/precheck.py); otherwise the fit stops before it begins
        with a NotSeparable error (a ConfigError) that names them and the next step.
    progress : callable
        ``progress(stage, simulations, cost)``, called as the fit goes.
    log : callable
        Takes a line about the fit (its stages, pairs that are not separable).

    Returns
    -------
    dict
        The ``fit.json`` document: values, intervals, verdicts, correlations, residuals.
    """
    from furuta_cosim.identify.pipeline import Pipeline

    return Pipeline().run(spec_name, output, workers=workers, dask=dask, fmi_version=fmi_version, resume=resume,
                          starts=starts, profiles=profiles, bootstrap=bootstrap, seed=seed, holdout=holdout,
                          validation=validation, accept=accept, force=force, progress=progress, log=log)
