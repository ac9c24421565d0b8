"""identify as a pipeline of stages, each a function of one record to the next, in the order
they run::

    load        spec, logs, plant target, identity        -> Loaded
    precheck    names, ranges, the notes about each log    -> Checked
    fit         the run directory claimed, the fit         -> Fitted
    intervals   profiles, bootstrap, intervals read        -> Fitted
    verdict     the judge's verdict and its notes          -> Fitted
    write       plant.yaml, fit.json, figures, report      -> fit.json's document

``judge`` (identify/verdict.py's rule) is read by ``intervals`` and ``verdict``. The command
line and :func:`~furuta_cosim.identify.run.identify` run :class:`Pipeline`'s defaults; any
stage is replaced alone (``Pipeline(judge=mine).run(spec, folder)``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence


from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import output_folder, write_text
from furuta_cosim.identify.estimate import balancing
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.fit import FitResult, check_ranges, fit, physical_ranges
from furuta_cosim.identify.replay import SimulationFailed, Target, check_names, compare, open_session, simulate, target_for
from furuta_cosim.identify.rundir import CHECKPOINT, claim, fitted_digest, identity_of
from furuta_cosim.identify.spec import load_identify_spec
from furuta_cosim.identify.split import parts_of
from furuta_cosim.identify.verdict import judge as judge_fit
from furuta_cosim.identify.verdict import read_intervals
from furuta_cosim.identify.written import draw_figures, per_log, plant_text, report_page


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


# -- the records each stage hands the next -------------------------------------------------------

def _no_progress(stage, simulations, cost) -> None:
    """No progress is shown."""


def _no_log(line: str) -> None:
    """No line is printed."""


@dataclass(frozen=True)
class Options:
    """How a fit runs: :func:`~furuta_cosim.identify.run.identify`'s keyword arguments, each
    meaning what it means there.

    Parameters
    ----------
    workers : int
        Local processes for the simulations of the Jacobian and the profiles.
    dask : str, optional
        A Dask scheduler address, or ``"local"``, instead of local processes.
    fmi_version : str
        The plant FMU's FMI version: ``"2.0"`` or ``"3.0"``.
    resume : bool
        Go on with the stopped run in the output folder.
    starts : int
        Fit from this many starts and keep the lowest cost.
    profiles : bool
        Profile each free plant parameter.
    bootstrap : int
        Replicates of a block bootstrap of the residuals (0: none).
    seed : int
        The multi-start's design and the bootstrap's draws.
    holdout : float, optional
        The last fraction of each fitted log held out (the spec's when None).
    validation : sequence of paths
        More experiment files to validate on.
    accept : bool
        Write the fitted plant even when the judge does not trust it.
    force : bool
        Fit even when the logs cannot separate some free unknowns.
    progress : callable
        ``progress(stage, simulations, cost)``, called as the fit goes.
    log : callable
        Takes a line about the fit.
    """

    workers: int = 1
    dask: str | None = None
    fmi_version: str = "2.0"
    resume: bool = False
    starts: int = 1
    profiles: bool = True
    bootstrap: int = 0
    seed: int = 0
    holdout: float | None = None
    validation: Sequence = ()
    accept: bool = False
    force: bool = False
    progress: Callable = field(default_factory=lambda: _no_progress)
    log: Callable[[str], None] = field(default_factory=lambda: _no_log)


@dataclass
class Loaded:
    """What load reads: the spec cut into its fitted and held-out parts, the logs fitted in
    segments as wholes (replayed whole after the fit), the plant target, the run directory (not
    yet claimed) and the run's identity (what a resume must match)."""

    spec: object
    whole: list
    target: Target
    out: Path
    identity: dict
    options: Options


@dataclass
class Checked:
    """What precheck adds: the notes about each log the fit will print (a loop closed or not,
    a start read from data)."""

    loaded: Loaded
    notes: list


@dataclass
class Fitted:
    """What the fit gives: its result, the fit.json document so far, the physical ranges the
    judge reads, the checkpoint's profiles (a resume's), and the checkpoint writer."""

    loaded: Loaded
    result: FitResult
    document: dict
    ranges: dict
    saved: dict
    checkpoint: Callable[[], None]


# -- the stages ------------------------------------------------------------------------------------

def load(spec_name: str | Path, output: str | Path, options: Options) -> Loaded:
    """The spec, its logs (held-out parts cut), the plant target and the run's identity; every
    option checked. Nothing is written.

    Parameters
    ----------
    spec_name : str or path
        An identify spec: a shipped name or a file.
    output : path
        The run folder (claimed later, by the fit stage).
    options : Options
        How the fit runs.
    """
    for name, value, low, high in (("starts", options.starts, 1, 1000),
                                   ("bootstrap", options.bootstrap, 0, 100_000),
                                   ("seed", options.seed, 0, 2**32 - 1)):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ConfigError([f"{name}: expected a whole number from {low} to {high}, got {value!r}"])
    spec = load_identify_spec(spec_name)
    holdout = options.holdout
    if holdout is not None and (isinstance(holdout, bool) or not isinstance(holdout, (int, float))
                                or not 0.0 <= holdout <= 0.9):
        raise ConfigError([f"holdout: expected a fraction from 0 to 0.9, got {holdout!r}"])
    fraction = spec.holdout if holdout is None else float(holdout)
    extra = [load_experiment(Path(v)) for v in options.validation]
    whole = parts_of(spec, fraction, extra, segmented=False)
    whole = [e for e in whole.experiments + whole.validation if e.segments]
    spec = parts_of(spec, fraction, extra)
    names = [e.name for e in spec.experiments + spec.validation]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError([f"validation: two experiments are named {', '.join(twice)}: names must differ"])
    out = output_folder(output)
    try:
        target = target_for(plant=spec.plant, fmi_version=options.fmi_version)
    except ConfigError as error:
        raise error.within(f"{spec.path}: plant") from None
    identity = identity_of(spec, target, options.fmi_version)
    identity["options"] = {"starts": options.starts, "profiles": bool(options.profiles),
                           "bootstrap": options.bootstrap, "seed": options.seed, "holdout": fraction}
    return Loaded(spec, whole, target, out, identity, options)


def precheck(loaded: Loaded) -> Checked:
    """What can be checked before the run directory is touched: every column names a variable
    of the plant, every free parameter's range lies within the plant's physical one; and the
    notes the fit prints about each log. (The checks that need simulations, the loop's rebuilt
    command and whether the logs separate the unknowns, run at the fit's start.)

    Parameters
    ----------
    loaded : Loaded
        What :func:`load` read.
    """
    spec, target = loaded.spec, loaded.target
    check_names(target, spec.experiments + spec.validation, tuple(p.name for p in spec.free), str(spec.path))
    check_ranges(spec, target)
    notes = []
    for e in spec.experiments + spec.validation:
        if e.loop is not None and balancing(e) and target.mapping is None:
            notes.append(f"note: {e.name}: replayed with its loop closed ({e.loop.describe()}), the angles "
                         "the encoders rounded estimated by a smoother")
        elif e.loop is not None:
            notes.append(f"note: {e.name}: not a balancing log (the pendulum leaves upright): fitted on its "
                         "logged voltage, open loop")
    for e in spec.experiments + spec.validation:
        for state_name, how in e.start_from.items():
            notes.append(f"note: {e.name}: starts with {state_name} = {how} (start: data)")
    return Checked(loaded, notes)


def fit_stage(checked: Checked) -> Fitted:
    """The run directory claimed (an earlier run's files removed, or a stopped run resumed),
    the fit from its starts, each finished stage checkpointed; the fitted logs replayed whole
    and the stated start rates read by their smoothers."""
    loaded = checked.loaded
    spec, target, out, options = loaded.spec, loaded.target, loaded.out, loaded.options
    state = claim(out, spec, loaded.identity, options.resume)
    options.log(f"identify {spec.name}: {len(spec.free)} parameters of {target.label} on "
                f"{_names(spec.experiments)}" + (f"; validation {_names(spec.validation)}" if spec.validation else "")
                + (f"; {options.starts} starts" if options.starts > 1 else "")
                + (f"; resumed after stage {state['stage']}" if state else ""))
    for note in checked.notes:
        options.log(note)
    saved = {"fit": state, "profiles": (state or {}).get("profiles", {})}

    def checkpoint() -> None:
        write_text(out / CHECKPOINT, dumps({"identity": loaded.identity, **(saved["fit"] or {}),
                                            "profiles": saved["profiles"]}, indent=1) + "\n")

    def fitted(progress_state: dict) -> None:
        saved["fit"] = progress_state
        checkpoint()

    result = fit(spec, target, workers=options.workers, dask=options.dask, progress=options.progress,
                 log=options.log, resume=state, on_stage=fitted, starts=options.starts, seed=options.seed,
                 force=options.force)
    document = result.document()
    if loaded.whole:
        document["whole"] = _whole_replays(loaded.whole, target, result.values)
    stated = _stated_starts(result.spec.experiments, target, result.values)
    if stated:
        document["stated_starts"] = stated
    return Fitted(loaded, result, document, physical_ranges(target), saved, checkpoint)


def intervals(fitted: Fitted, judge: Callable = judge_fit) -> Fitted:
    """Each parameter's interval beyond the sandwich: profiles (skipped, saying why, when the fit
    stopped at its budget or ``judge`` finds it does not reproduce its data: a profile from a
    point that is not the optimum bounds nothing), the bootstrap when asked, then every interval
    read against the ranges."""
    loaded, result, document = fitted.loaded, fitted.result, fitted.document
    options, spec, target = loaded.options, loaded.spec, loaded.target
    converged = not result.message.startswith("stopped")
    replays = [r for r in judge(document, fitted.ranges, spec.tolerance)["reasons"]
               if "replay" in r or "stated start" in r]
    skipped = None
    if options.profiles and not converged:
        skipped = "not profiled: the fit did not converge"
        options.log("  profiles skipped: the fit stopped at its budget, and a profile from a point that is not "
                    "the optimum bounds nothing")
    elif options.profiles and replays:
        skipped = "not profiled: the fit does not reproduce its data"
        options.log(f"  profiles skipped: the fit is not trusted whatever its intervals ({replays[0]})")
    if options.profiles and skipped is None:
        from furuta_cosim.identify.profile import profile_all

        def profiled(name: str, found: dict) -> None:
            fitted.saved["profiles"][name] = found
            fitted.checkpoint()

        clock = time.perf_counter()
        found = profile_all(result.spec, target, result, workers=options.workers, dask=options.dask,
                            done=fitted.saved["profiles"], progress=options.progress, log=options.log,
                            on_profile=profiled)
        _with_profiles(document, found)
        document["profiles"] = {"simulations": sum(p.get("simulations", 0) for p in found.values()),
                                "seconds": time.perf_counter() - clock}
    if options.bootstrap:
        from furuta_cosim.identify.bootstrap import bootstrap_all

        clock = time.perf_counter()
        resampled = bootstrap_all(result.spec, target, result, replicates=options.bootstrap, seed=options.seed,
                                  workers=options.workers, dask=options.dask, progress=options.progress,
                                  log=options.log)
        _with_bootstrap(document, resampled)
        document["bootstrap"]["seconds"] = time.perf_counter() - clock
    document["spec_sha256"] = loaded.identity["spec_sha256"]
    document["options"] = loaded.identity["options"]
    read_intervals(document, fitted.ranges, "not profiled" if not options.profiles
                   else skipped or "its profile did not finish")
    if skipped:
        document["profiles_skipped"] = skipped
    return fitted


def verdict(fitted: Fitted, judge: Callable = judge_fit) -> Fitted:
    """The verdict on the whole fit (``judge``: identify/verdict.py), with the notes on what
    every interval rests on, and whether a fit not trusted is written all the same (``accept``)."""
    result, document = fitted.result, fitted.document
    document["loops"] = {e.name: "closed" if e.loop is not None else
                         "segments" if e.alias and "@" in e.name else "open"
                         for e in result.spec.experiments + result.spec.validation}
    document["verdict"] = found = judge(document, fitted.ranges, fitted.loaded.spec.tolerance)
    widest = []
    if result.reach:
        widest = sorted(((r / abs(result.values[n]), n) for n, r in result.reach.items()
                         if "." not in n and result.values[n]), reverse=True)[:3]
    if widest:   # a plant parameter's reach (an initial state's alone is in fit.json)
        found["notes"].append(
            "every interval is widened by the reach of the start state the logs give (each counted angle "
            "anywhere within half a count, each freed rate of a balancing log within what its smoother "
            "knows, a balancing log's smoother within its own error): " + ", ".join(f"{n} +-{100 * r:.2g} %" for r, n in widest)
            + " (docs: Your own rig, What the data can tell)")
    for e in result.spec.experiments:
        if e.loop is not None and e.loop.lead_in is not None:   # a window cut from a run
            found["notes"].append(
                f"{e.name}: its window starts mid-run (t = {e.t[0]:g} s of its log), its start state read or "
                "fitted there: on synthetic balancing logs such windows' intervals held the truth less often "
                "than whole logs' did; check the fit against one of the whole log (docs: Your own rig, What is "
                "not yet right)")
    document["accepted"] = bool(fitted.loaded.options.accept) and not found["trusted"]
    return fitted


def write(fitted: Fitted) -> dict:
    """The run directory: plant.yaml and fit.json first (a full disk or a kill while drawing
    keeps the fit), the checkpoint removed, then the figures and report.html. Returns fit.json's
    document."""
    result, document, out = fitted.result, fitted.document, fitted.loaded.out
    found = document["verdict"]
    figures_of = per_log([(e, {"start": result.simulated[e.name]["start"], "fitted": result.simulated[e.name]["fit"]})
                          for e in result.spec.experiments + result.spec.validation])
    document["figures"] = [f"{name}-{kind}.png" for name in figures_of for kind in ("overlay", "residuals")]
    profiled = any("profile" in p for p in document["parameters"].values())
    if profiled:
        document["figures"].append("profiles.png")
    document["files"] = sorted(["plant.yaml", "fit.json", "report.html"] + document["figures"]
                               + [str(Path(p).with_suffix(".svg")) for p in document["figures"]])
    rejected = None if found["trusted"] or fitted.loaded.options.accept else found["reasons"][0]
    write_text(out / "plant.yaml", plant_text(result, out, rejected, found))
    document["fitted_plant"] = ({"file": "plant.yaml", "rejected": True} if rejected else
                                {"file": "plant.yaml", "sha256": fitted_digest(out / "plant.yaml")})
    write_text(out / "fit.json", dumps(document, indent=2) + "\n")
    (out / CHECKPOINT).unlink(missing_ok=True)
    for name, members in figures_of.items():
        draw_figures(out, name, members)
    if profiled:
        from furuta_cosim.report.rig import plot_profiles

        plot_profiles(document["parameters"], out / "profiles")
    write_text(out / "report.html", report_page(document, out))
    return document


@dataclass(frozen=True)
class Pipeline:
    """identify's stages, each replaceable alone (``Pipeline(judge=mine).run(...)``).

    Parameters
    ----------
    load : callable
        ``(spec_name, output, options) -> Loaded`` (:func:`load`).
    precheck : callable
        ``Loaded -> Checked`` (:func:`precheck`).
    fit : callable
        ``Checked -> Fitted`` (:func:`fit_stage`).
    judge : callable
        The verdict's rule: ``(document, ranges, tolerance) -> verdict dict``
        (identify/verdict.py judge), read by ``intervals`` (whether to profile) and ``verdict``.
    intervals : callable
        ``(Fitted, judge) -> Fitted`` (:func:`intervals`).
    verdict : callable
        ``(Fitted, judge) -> Fitted`` (:func:`verdict`).
    write : callable
        ``Fitted -> dict``, fit.json's document (:func:`write`).
    """

    # factories: a function as a plain default would read as a method of the class
    load: Callable = field(default_factory=lambda: load)
    precheck: Callable = field(default_factory=lambda: precheck)
    fit: Callable = field(default_factory=lambda: fit_stage)
    judge: Callable = field(default_factory=lambda: judge_fit)
    intervals: Callable = field(default_factory=lambda: intervals)
    verdict: Callable = field(default_factory=lambda: verdict)
    write: Callable = field(default_factory=lambda: write)

    def run(self, spec_name: str | Path, output: str | Path, **options) -> dict:
        """The whole fit of ``spec_name`` into ``output``: fit.json's document.

        Parameters
        ----------
        spec_name : str or path
            An identify spec: a shipped name or a file.
        output : path
            The run folder.
        options
            :class:`Options`' fields by name (``profiles=False``, ``workers=2``, ...).
        """
        loaded = self.load(spec_name, output, Options(**options))
        fitted = self.fit(self.precheck(loaded))
        return self.write(self.verdict(self.intervals(fitted, self.judge), self.judge))
