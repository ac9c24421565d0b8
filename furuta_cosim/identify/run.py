"""The commands' logic: ``replay`` (a plant against logs) and ``identify`` (a fit and its run
directory). The CLI only formats what these return.

An identify run directory holds ``plant.yaml`` (a plant file every command takes: it
``extends`` the spec's plant with the fitted values, and records where they come from),
``fit.json`` (values, intervals, correlations, residuals), ``report.html`` and the figures.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import yaml

from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import folder, output_folder, write_text
from furuta_cosim.identify.experiment import Experiment, load_experiment
from furuta_cosim.identify.fit import FitResult, fit, with_values
from furuta_cosim.identify.replay import (SimulationFailed, Target, chatter, check_names, compare,
                                          open_session, simulate)
from furuta_cosim.identify.spec import load_identify_spec
from furuta_cosim.identify.split import parts_of
from furuta_cosim.identify.verdict import line as verdict_line


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
                entry["figures"] = [p.name for p in _figures(out, experiment.name, [(experiment, {target.label: simulated})])]
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


def _whole_replays(logs, target: Target, values: dict) -> dict:
    """Each log fitted in segments replayed whole at the fitted ``values``, as ``replay`` runs
    it: per output its comparison, or the failure. Segments each restart from the measured
    state, so they can all fit while the log, run through, does not."""
    from furuta_cosim.identify.estimate import with_estimate

    found = {}
    with open_session(target) as session:
        for experiment in logs:
            experiment = with_estimate(experiment, target)
            try:
                simulated = simulate(session, target, experiment, values)
            except SimulationFailed as error:
                found[experiment.name] = {"failure": str(error)}
                continue
            found[experiment.name] = compare(experiment, experiment.corrected(simulated, values))
    return found


def _per_log(pairs) -> dict:
    """``{log: [(experiment, its simulations), ...]}``: a log's segments (``log@k``) together."""
    found: dict = {}
    for experiment, simulated in pairs:
        name = experiment.alias if experiment.alias and "@" in experiment.name else experiment.name
        found.setdefault(name, []).append((experiment, simulated))
    return found


def _figures(out: Path, name: str, members) -> list[Path]:
    """A log's overlay and residuals: ``members`` its (experiment, {label: simulated outputs})
    pairs, its segments (each from its own start) drawn one after the other on the log's time
    axis, the line broken between them."""
    from furuta_cosim.report.rig import plot_overlay, plot_residuals

    first = members[0][0]
    gap = [np.array([np.nan])] if len(members) > 1 else []

    def joined(pieces):
        parts = []
        for k, piece in enumerate(pieces):
            parts += ([] if k == 0 else gap) + [np.asarray(piece, dtype=float)]
        return np.concatenate(parts)

    t = joined([e.t for e, _ in members])
    measured = {n: joined([e.outputs[n].values for e, _ in members]) for n in first.outputs}
    labels = list(members[0][1])
    simulated = {label: {n: joined([runs[label][n] for _, runs in members]) for n in first.outputs}
                 for label in labels}
    quantum = {n: 2 * 3 ** 0.5 * m.sigma for n, m in first.outputs.items() if m.sigma_from == "quantum"}
    segments = f" ({len(members)} segments, each from its measured state)" if len(members) > 1 else ""
    written = plot_overlay(t, measured, simulated, out / f"{name}-overlay", f"{name}: measured and simulated{segments}")
    written += plot_residuals(t, measured, simulated, out / f"{name}-residuals",
                              f"{name}: simulated - measured{segments}", quantum)
    return [p for p in written if p.suffix == ".png"]


def _stated_starts(experiments, target, values: dict) -> dict:
    """Per fitted balancing log (its angles estimated) whose start rates are stated (a number, or the
    slope of its first counts), what its smoother at the fitted ``values`` puts them at:
    {log: {rate: {stated, estimate, sigma}}} (identify/estimate.py start_estimate; judged in
    identify/verdict.py)."""
    from furuta_cosim.identify.estimate import start_estimate
    from furuta_cosim.identify.experiment import Free

    found = {}
    plant = {k: v for k, v in values.items() if "." not in k}
    for e in experiments:
        if e.loop is None or not e.loop.estimate:
            continue
        rates = {r: float(v) for r, v in e.start.items() if r in ("dtheta0", "dtheta1") and not isinstance(v, Free)}
        if not rates:
            continue
        estimate = start_estimate(e, target, {**e.parameters, **plant})
        found[e.name] = {r: {"stated": v, "estimate": estimate[r][0], "sigma": estimate[r][1],
                             "at": float(e.t[0])} for r, v in rates.items() if r in estimate}
    return found


def identify(spec_name: str | Path, output: str | Path, *, workers: int = 1, dask: str | None = None,
             fmi_version: str = "2.0", resume: bool = False, starts: int = 1, profiles: bool = True,
             bootstrap: int = 0, seed: int = 0, holdout: float | None = None,
             validation: Sequence[str | Path] = (), accept: bool = False, force: bool = False,
             progress=lambda stage, n, cost: None, log: Callable[[str], None] = lambda line: None) -> dict:
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
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.identify.replay import target_for

    for name, value, low, high in (("starts", starts, 1, 1000), ("bootstrap", bootstrap, 0, 100_000),
                                   ("seed", seed, 0, 2**32 - 1)):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ConfigError([f"{name}: expected a whole number from {low} to {high}, got {value!r}"])
    spec = load_identify_spec(spec_name)
    if holdout is not None and (isinstance(holdout, bool) or not isinstance(holdout, (int, float))
                                or not 0.0 <= holdout <= 0.9):
        raise ConfigError([f"holdout: expected a fraction from 0 to 0.9, got {holdout!r}"])
    extra = [load_experiment(Path(v)) for v in validation]
    whole = parts_of(spec, spec.holdout if holdout is None else float(holdout), extra, segmented=False)
    whole = [e for e in whole.experiments + whole.validation if e.segments]
    spec = parts_of(spec, spec.holdout if holdout is None else float(holdout), extra)
    names = [e.name for e in spec.experiments + spec.validation]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError([f"validation: two experiments are named {', '.join(twice)}: names must differ"])
    out = output_folder(output)
    try:
        target = target_for(plant=spec.plant, fmi_version=fmi_version)
    except ConfigError as error:
        raise error.within(f"{spec.path}: plant") from None
    from furuta_cosim.identify.fit import check_ranges

    check_names(target, spec.experiments + spec.validation, tuple(p.name for p in spec.free), str(spec.path))
    check_ranges(spec, target)
    identity = _identity(spec, target, fmi_version)
    identity["options"] = {"starts": starts, "profiles": bool(profiles), "bootstrap": bootstrap, "seed": seed,
                           "holdout": spec.holdout if holdout is None else float(holdout)}
    state = _claim(out, spec, identity, resume)
    log(f"identify {spec.name}: {len(spec.free)} parameters of {target.label} on "
        f"{_names(spec.experiments)}" + (f"; validation {_names(spec.validation)}" if spec.validation else "")
        + (f"; {starts} starts" if starts > 1 else "")
        + (f"; resumed after stage {state['stage']}" if state else ""))
    from furuta_cosim.identify.estimate import balancing

    for e in spec.experiments + spec.validation:
        if e.loop is not None and balancing(e) and target.mapping is None:
            log(f"note: {e.name}: replayed with its loop closed ({e.loop.describe()}), the angles the "
                "encoders rounded estimated by a smoother")
        elif e.loop is not None:
            log(f"note: {e.name}: not a balancing log (the pendulum leaves upright): fitted on its "
                "logged voltage, open loop")
    for e in spec.experiments + spec.validation:
        for state_name, how in e.start_from.items():
            log(f"note: {e.name}: starts with {state_name} = {how} (start: data)")
    saved = {"fit": state, "profiles": (state or {}).get("profiles", {})}

    def checkpoint() -> None:
        write_text(out / CHECKPOINT, dumps({"identity": identity, **(saved["fit"] or {}),
                                            "profiles": saved["profiles"]}, indent=1) + "\n")

    def fitted(progress_state: dict) -> None:
        saved["fit"] = progress_state
        checkpoint()

    def profiled(name: str, found: dict) -> None:
        saved["profiles"][name] = found
        checkpoint()

    result = fit(spec, target, workers=workers, dask=dask, progress=progress, log=log,
                 resume=state, on_stage=fitted, starts=starts, seed=seed, force=force)
    document = result.document()
    from furuta_cosim.identify.fit import physical_ranges
    from furuta_cosim.identify.verdict import judge, read_intervals

    ranges = physical_ranges(target)
    if whole:
        document["whole"] = _whole_replays(whole, target, result.values)
    stated = _stated_starts(result.spec.experiments, target, result.values)
    if stated:
        document["stated_starts"] = stated
    converged = not result.message.startswith("stopped")
    # the verdict on the replays alone, before the profiles spend anything: a fit that does not
    # reproduce its data, or is worse than its start, is not trusted whatever its intervals
    replays = [r for r in judge(document, ranges, spec.tolerance)["reasons"] if "replay" in r or "stated start" in r]
    skipped = None
    if profiles and not converged:
        skipped = "not profiled: the fit did not converge"
        log("  profiles skipped: the fit stopped at its budget, and a profile from a point that is not "
            "the optimum bounds nothing")
    elif profiles and replays:
        skipped = "not profiled: the fit does not reproduce its data"
        log(f"  profiles skipped: the fit is not trusted whatever its intervals ({replays[0]})")
    if profiles and skipped is None:
        from furuta_cosim.identify.profile import profile_all

        clock = time.perf_counter()
        found = profile_all(result.spec, target, result, workers=workers, dask=dask, done=saved["profiles"],
                            progress=progress, log=log, on_profile=profiled)
        _with_profiles(document, found)
        document["profiles"] = {"simulations": sum(p.get("simulations", 0) for p in found.values()),
                                "seconds": time.perf_counter() - clock}
    if bootstrap:
        from furuta_cosim.identify.bootstrap import bootstrap_all

        clock = time.perf_counter()
        resampled = bootstrap_all(result.spec, target, result, replicates=bootstrap, seed=seed, workers=workers,
                                  dask=dask, progress=progress, log=log)
        _with_bootstrap(document, resampled)
        document["bootstrap"]["seconds"] = time.perf_counter() - clock
    document["spec_sha256"] = identity["spec_sha256"]
    document["options"] = identity["options"]
    read_intervals(document, ranges, "not profiled" if not profiles else skipped or "its profile did not finish")

    document["loops"] = {e.name: "closed" if e.loop is not None else
                         "segments" if e.alias and "@" in e.name else "open"
                         for e in result.spec.experiments + result.spec.validation}
    document["verdict"] = verdict = judge(document, ranges, spec.tolerance)
    widest = []
    if result.reach:
        widest = sorted(((r / abs(result.values[n]), n) for n, r in result.reach.items()
                         if "." not in n and result.values[n]), reverse=True)[:3]
    if widest:   # a plant parameter's reach (an initial state's alone is in fit.json)
        verdict["notes"].append(
            "every interval is widened by the reach of the start state the logs give (each counted angle "
            "anywhere within half a count, each freed rate of a balancing log within what its smoother "
            "knows, a balancing log's smoother within its own error): " + ", ".join(f"{n} +-{100 * r:.2g} %" for r, n in widest)
            + " (docs: Your own rig, What the data can tell)")
    for e in result.spec.experiments:
        if e.loop is not None and e.loop.lead_in is not None:   # a window cut from a run
            verdict["notes"].append(
                f"{e.name}: its window starts mid-run (t = {e.t[0]:g} s of its log), its start state read or "
                "fitted there: on synthetic balancing logs such windows' intervals held the truth less often "
                "than whole logs' did; check the fit against one of the whole log (docs: Your own rig, What is "
                "not yet right)")
    document["accepted"] = bool(accept) and not verdict["trusted"]
    figures_of = _per_log([(e, {"start": result.simulated[e.name]["start"], "fitted": result.simulated[e.name]["fit"]})
                           for e in result.spec.experiments + result.spec.validation])
    document["figures"] = [f"{name}-{kind}.png" for name in figures_of for kind in ("overlay", "residuals")]
    profiled = any("profile" in p for p in document["parameters"].values())
    if profiled:
        document["figures"].append("profiles.png")
    if skipped:
        document["profiles_skipped"] = skipped
    document["files"] = sorted(["plant.yaml", "fit.json", "report.html"] + document["figures"]
                               + [str(Path(p).with_suffix(".svg")) for p in document["figures"]])
    # the fit first, so that a full disk or a kill while drawing keeps it
    rejected = None if verdict["trusted"] or accept else verdict["reasons"][0]
    plant = plant_text(result, out, rejected, verdict)
    write_text(out / "plant.yaml", plant)
    document["fitted_plant"] = ({"file": "plant.yaml", "rejected": True} if rejected else
                                {"file": "plant.yaml", "sha256": _fitted_digest(out / "plant.yaml")})
    write_text(out / "fit.json", dumps(document, indent=2) + "\n")
    (out / CHECKPOINT).unlink(missing_ok=True)
    for name, members in figures_of.items():
        _figures(out, name, members)
    if profiled:
        from furuta_cosim.report.rig import plot_profiles

        plot_profiles(document["parameters"], out / "profiles")
    write_text(out / "report.html", report_page(document, out))
    return document


def _names(experiments) -> str:
    """The logs' names, a log cut into segments once with their count."""
    counts: dict = {}
    for e in experiments:
        whole = e.alias if e.alias and "@" in e.name else e.name
        counts[whole] = counts.get(whole, 0) + 1
    return ", ".join(name if n == 1 else f"{name} ({n} segments)" for name, n in counts.items())


def _with_profiles(document: dict, found: dict) -> None:
    """fit.json with each profiled parameter's profile, its likelihood-ratio interval and its
    verdict; a parameter that is not identifiable in the profile's sense is marked so
    (``identifiable: false``: tune --from-fit holds it at its value). The interval is the
    profile's widened by its reach (identify/reach.py); one that then
    reaches 0 or a bound is not identifiable."""
    from furuta_cosim.identify.reach import widened

    for name, profile in found.items():
        entry = document["parameters"][name]
        entry["profile"] = {k: profile[k] for k in ("values", "rise", "threshold", "simulations")}
        entry["interval_profile"] = widened(profile["interval"], entry.get("reach"))
        if profile["verdict"] == "not profiled":   # its sandwich interval says it (identify/verdict.py)
            entry["profile_why"] = profile.get("why", "")
            continue
        verdict, why = profile["verdict"], profile.get("why", "")
        lo, hi = entry["interval_profile"]
        if verdict == "identifiable" and (lo <= max(0.0, entry["bounds"][0]) or hi >= entry["bounds"][1]):
            verdict = "practically not identifiable"
            why = (f"its profile interval widened by its reach (+-{entry['reach']:.3g}) "
                   f"is [{lo:.4g}, {hi:.4g}], reaching 0 or a bound")
        entry["verdict"] = verdict + (f": {why}" if why else "")
        entry["identifiable"] = verdict == "identifiable"
        entry["rests_on"] = "its profile" + (", widened by its reach" if entry.get("reach") else "")
    document["interval_profile_method"] = (
        "profile likelihood: the cost with the parameter held and every other unknown fitted again; "
        "95 % where it rises less than chi2(1, 0.95) / 2 times the residual variance, scaled by the "
        "parameter's sandwich-to-textbook variance ratio (Chandler and Bate 2007)"
        + ("; widened on each side by each value's reach (the start state the logs give, a balancing log's "
           "smoother: identify/reach.py)" if document.get("reach") else ""))


def _with_bootstrap(document: dict, resampled: dict) -> None:
    from furuta_cosim.identify.reach import widened

    for name, entry in resampled["parameters"].items():
        document["parameters"][name]["interval_bootstrap"] = widened(entry["interval"],
                                                                     document["parameters"][name].get("reach"))
        document["parameters"][name]["stderr_bootstrap"] = entry["stderr"]
    document["bootstrap"] = {k: resampled[k] for k in ("replicates", "seed", "blocks", "method")}


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
        count = len(spec.free) + sum(len(e.free_starts()) for e in spec.experiments)
        try:
            state = {"start": int(saved.get("start", 0)), "stage": int(saved["stage"]),
                     "x": None if saved["x"] is None else [float(v) for v in saved["x"]],
                     "record": list(saved["record"]), "simulations": int(saved["simulations"]),
                     "message": str(saved.get("message", "")),
                     "budget_from": int(saved.get("budget_from", 0)),
                     "optima": [{"x": [float(v) for v in o["x"]], "cost": float(o["cost"]),
                                 "message": str(o.get("message", "")), "record": list(o["record"])}
                                for o in saved.get("optima", [])],
                     "profiles": _profiles_read(saved.get("profiles")),
                     "precheck": saved.get("precheck") if isinstance(saved.get("precheck"), dict) else None}
        except (KeyError, TypeError, ValueError):
            raise ConfigError([f"resume: {out / CHECKPOINT}: damaged (stage, x, record, "
                               "simulations expected)"]) from None
        lengths = [len(state["x"])] if state["x"] is not None else []
        lengths += [len(o["x"]) for o in state["optima"]]
        if any(n != count for n in lengths):
            raise ConfigError([f"resume: {out / CHECKPOINT}: holds values of another number of "
                               f"unknowns than the spec's {count}"])
        return state
    if entries and not ours:
        raise ConfigError([f"output {out}: holds files that are not a run of identify {spec.name} "
                           f"({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''}); "
                           "choose a new or empty folder"])
    # a new run of this spec: what the earlier one wrote goes, so nothing stale stays beside it
    listed = earlier.get("files", []) if isinstance(earlier, dict) else []
    for name in entries:
        if name in listed or name == CHECKPOINT or name.endswith(".partial") \
                or name in ("profiles.png", "profiles.svg") \
                or name.endswith(("-overlay.png", "-overlay.svg", "-residuals.png", "-residuals.svg")):
            (out / name).unlink(missing_ok=True)
    return None


def _profiles_read(saved) -> dict:
    """Profiles a checkpoint holds, each only if whole (a damaged one is computed again)."""
    import math

    from furuta_cosim.identify.profile import VERDICTS

    found = {}
    for name, p in (saved or {}).items() if isinstance(saved, dict) else ():
        try:
            numbers = [float(v) for v in p["values"] + p["rise"]]
            interval = p["interval"]
            whole = (p["verdict"] in VERDICTS and len(p["values"]) == len(p["rise"]) >= 1
                     and all(math.isfinite(v) for v in numbers)
                     and (interval is None or (len(interval) == 2 and all(
                         v is None or math.isfinite(float(v)) for v in interval))))
        except (KeyError, TypeError, ValueError):
            whole = False
        if whole and isinstance(name, str):
            found[name] = p
    return found


def _same(where: Path, saved, identity: dict) -> None:
    from furuta_cosim.errors import ConfigError

    if not isinstance(saved, dict):
        raise ConfigError([f"resume: {where}: records no identity of its run"])
    words = {"spec_sha256": "the spec's content", "data": "the logs (their sha256)",
             "plant_sha256": "the plant's values", "fmu_sha256": "the plant FMU",
             "fmi_version": "the FMI version", "options": "the options (starts, profiles, bootstrap, seed)"}
    for key, what in words.items():
        if saved.get(key) != identity.get(key):
            raise ConfigError([f"resume: {what} differ from the stopped run's ({where}); run "
                               "identify anew without `resume`"])


def plant_text(result: FitResult, out: Path, rejected: str | None = None, verdict: dict | None = None) -> str:
    """The fitted plant file: the spec's plant extended with the fitted values (a name stays a
    name; a file is named by its path relative to ``out``, so the folder travels). A fit the
    verdict does not trust carries ``rejected: <why>``, which load_plant refuses."""
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
    if verdict is not None:
        document["provenance"]["verdict"] = ("trusted" if verdict["trusted"] else
                                             "not trusted, written with --accept: " + "; ".join(verdict["reasons"]))
    if rejected is not None:
        document = {"rejected": rejected, **document}
    head = (f"# Written by furuta-cosim identify {spec.name}: the fitted parameters on top of "
            f"{base}.\n# Their intervals and correlations are in fit.json beside this file.\n")
    return head + yaml.safe_dump(document, sort_keys=False)


def _bounds_text(interval) -> str:
    """``[lo, hi]``, a side the profile never crossed said so."""
    if interval is None:
        return "none"
    lo, hi = interval
    return (f"[{'to its bound' if lo is None else format(lo, '.4g')}, "
            f"{'to its bound' if hi is None else format(hi, '.4g')}]")


def parameter_rows(document: dict) -> list[list[str]]:
    """Per unknown: name, start, fitted, each interval fit.json has, the verdict (text cells)."""
    bootstrap = any("interval_bootstrap" in p for p in document["parameters"].values())
    rows = [["parameter", "start", "fitted", "sandwich 95 %", "profile 95 %"]
            + (["bootstrap 95 %"] if bootstrap else []) + ["verdict"]]
    for name, p in document["parameters"].items():
        fitted = f"{p['value']:.5g}" + (" (at a bound)" if p.get("at_bound") else "")
        row = [name, f"{p['start']:.5g}", fitted, _bounds_text(p["interval"]),
               _bounds_text(p["interval_profile"]) if "interval_profile" in p else "not profiled"]
        if bootstrap:
            row.append(_bounds_text(p.get("interval_bootstrap")) if "interval_bootstrap" in p else "")
        rows.append(row + [p["verdict"]])
    return rows


def summary_text(document: dict, out: Path) -> str:
    """What ``identify`` prints: the values and intervals, the verdicts, the optima of a
    multi-start, the pairs not separable, the residuals."""
    rows = parameter_rows(document)
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]) - 1)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r[:-1], widths)) + "  " + r[-1] for r in rows]
    optima = (document.get("starts") or {}).get("optima") or []
    if len(optima) > 1:
        lines.append(f"{document['starts']['count']} starts, {len(optima)} distinct optima: "
                     + "; ".join(f"cost {o['cost']:.6g} ({len(o['starts'])} start(s))" for o in optima)
                     + "; the lowest is kept")
    elif document.get("starts", {}).get("count", 1) > 1:
        lines.append(f"{document['starts']['count']} starts, all at the same optimum")
    for a, b, r in document["not_separable"]:
        lines.append(f"not separable: {a} and {b} (correlation {r:+.3f})")
    for kind, name, output, start, c in _replays(document):
        period = c.get("period", {}).get("error")
        segments = c.get("segments")
        lines.append(f"{'validation ' if kind == 'validation' else ''}{name} {output}: RMS {start:.4g} -> "
                     f"{c['rms']:.4g}" + (f" ({c['rms'] * 57.29577951308232:.4g} deg)"
                                          if output.startswith("theta") else "")
                     + ("" if period is None else f", period {100 * period:+.3f} %")
                     + (f" over {segments['count']} segments (median segment {segments['median']:.4g}, worst "
                        f"{segments['worst']:.4g}: {segments['worst_of'][0]})" if segments else ""))
    lines.append(f"{document['simulations']} simulations in {document['seconds']:.1f} s; "
                 f"plant.yaml, fit.json and report.html in {out}")
    if document.get("profiles"):
        lines.append(f"profiles: {document['profiles']['simulations']} simulations in "
                     f"{document['profiles']['seconds']:.1f} s")
    if document.get("bootstrap"):
        lines.append(f"bootstrap: {document['bootstrap']['replicates']} replicates in "
                     f"{document['bootstrap']['seconds']:.1f} s")
    if document["message"].startswith("stopped"):
        lines.append(f"note: {document['message']}: the fit is the best point found within the budget")
    verdict = document.get("verdict")
    if verdict:
        lines += [f"note: {n}" for n in verdict["notes"]]
        lines.append(verdict_line(verdict) + (" (plant.yaml written all the same: --accept)"
                                              if document.get("accepted") else
                                              "" if verdict["trusted"] else " (plant.yaml is marked rejected)"))
    return "\n".join(lines) + "\n"


def _replays(document: dict) -> list[tuple]:
    """(kind, log, output, RMS at the start values, the fitted comparison) per log and output,
    the segments of a log fitted by multiple shooting as one log (identify/verdict.py by_log)."""
    from furuta_cosim.identify.verdict import by_log

    found = []
    for kind in ("experiments", "validation"):
        start = by_log({kind: {name: document["at_start"][name] for name in document[kind]},
                        "data": document.get("data", {})}, kind)
        for (name, output), c in by_log(document, kind).items():
            found.append((kind, name, output, start[(name, output)]["rms"], c))
    return found


def report_page(document: dict, out: Path) -> str:
    from furuta_cosim.report.html import figure, markdown_to_html, page

    table = parameter_rows(document)
    rows = ["| " + " | ".join(table[0]) + " |", "|" + "---|" * len(table[0])]
    rows += ["| " + " | ".join(r) + " |" for r in table[1:]]
    fits = ["| experiment | output | RMS at start | RMS fitted | period error fitted |", "|---|---|---|---|---|"]
    for kind, name, output, start, c in _replays(document):
        period = c.get("period", {}).get("error")
        segments = c.get("segments")
        shown = name + (f" ({segments['count']} segments, the worst {', '.join(segments['worst_of'])})"
                        if segments else "")
        fits.append(f"| {shown}{' (validation)' if kind == 'validation' else ''} | {output} | "
                    f"{start:.4g} | {c['rms']:.4g} | {'' if period is None else f'{100 * period:+.3f} %'} |")
    pairs = "".join(f"- {a} and {b}: correlation {r:+.3f}, not separable on these data\n"
                    for a, b, r in document["not_separable"]) or "- none above 0.95\n"
    methods = f"Intervals: sandwich, {document['interval_method']}."
    if document.get("interval_profile_method"):
        methods += f" Profile, {document['interval_profile_method']}."
    if document.get("bootstrap"):
        methods += f" Bootstrap, {document['bootstrap']['method']} ({document['bootstrap']['replicates']} replicates)."
    optima = (document.get("starts") or {}).get("optima") or []
    starts = ""
    if document.get("starts", {}).get("count", 1) > 1:
        starts = (f"\n## Starts\n\n{document['starts']['count']} starts reached {len(optima)} distinct "
                  "optima (the lowest kept):\n\n" + "".join(
                      f"- cost {o['cost']:.6g} from {len(o['starts'])} start(s)\n" for o in optima))
    text = (f"# identify {document['name']}\n\n"
            f"Plant {document['plant']}; {document['simulations']} simulations in "
            f"{document['seconds']:.1f} s; {document['message']}\n\n" + "\n".join(rows) + "\n\n"
            + methods + " The textbook s^2 (J^T J)^-1, which assumes independent residuals, is in "
            "fit.json (stderr_plain).\n" + starts + "\n## Correlated pairs\n\n" + pairs
            + "\n## Residuals (SI units: rad, A)\n\n" + "\n".join(fits) + "\n")
    data = ["| experiment | file | samples | window [s] | sha256 |", "|---|---|---|---|---|"]
    data += [f"| {name} | {d['file']} | {d['samples']} | {d['window'][0]:g} to {d['window'][1]:g} | {d['sha256'][:16]} |"
             for name, d in document["data"].items()]
    text += "\n## Data\n\n" + "\n".join(data) + f"\n\nPlant FMU sha256 {document['fmu_sha256'][:16]}.\n"
    body = markdown_to_html(text) + "".join(
        figure(out / Path(name).with_suffix(".svg"), Path(name).stem) for name in document["figures"])
    return page(f"identify {document['name']}", body)
