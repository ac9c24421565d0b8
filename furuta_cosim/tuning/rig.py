"""Tuning with the rig in the loop: each evaluation a rig trial, the simulation the cheap fidelity.

    run-dir/
      spec.yaml, run.json    as a tuning's (run.json also records the rig: evaluator, board, plant)
      simulation/            the simulated fidelity: a tuning run of the spec in simulation
      history.jsonl          one line per rig trial: its scores, the trial, the same candidate simulated
      trials/NNNN/           trial NNNN (the history's index): candidate.yaml, trial.json, and the
                             rig run's folder run/ (log.csv, experiment.yaml, summary.json) or
                             external/ (the request and what the rig sent back); home/ when the rig
                             was brought to rest first
      trials/baseline-NAME/  the baseline's trial: the reference of the spec's relative terms and
                             constraints on this rig, and the safe method's first point
      best.yaml, summary.json, summary.md, convergence.png

A trial scores a candidate as a simulation does, from the logged signals of each scenario
(rig/trial.py): the same metrics, terms and constraints, every relative term and tracking
constraint measured against the baseline's trial on the same rig. A trial the supervisor
stopped, or in which the candidate let the pendulum fall, is a failed evaluation with the data
it collected (its scenarios' metrics as far as they ran, the log in its folder).

Before the first trial the spec is tuned in simulation (``simulation/``, ``rig.simulations``
evaluations): the prior of the safe method (tuning/safe.py), which also simulates every
candidate it considers for the rig. A killed tuning resumes after its last finished trial: the
history says which trials finished, a trial cut short keeps its folder (renamed
``NNNN.interrupted``) and runs again.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Callable

from furuta_cosim.documents import dumps, json_safe
from furuta_cosim.errors import ConfigError, RunStopped
from furuta_cosim.files import folder as make_folder, output_folder, write_text
from furuta_cosim.tuning.objective import Evaluator, Outcome
from furuta_cosim.tuning.trials import STATUSES, TrialResult, TrialScenario

HELD_OFF = 0.01  # rad: a reset's integral this far from 0 is said in the trial's log line


class Fidelity:
    """The simulated fidelity: the spec's plant (its variants too) in simulation, the history of
    the spec tuned there, and every candidate the rig tuning simulates (each once)."""

    def __init__(self, spec, records: list[dict], folder: Path | None = None):
        self.evaluator = Evaluator(spec)
        self.records = records
        self.folder = folder
        self._exact: dict[tuple, dict] = {}

    def exact(self, x) -> dict:
        """The candidate at ``x`` simulated, every run to its end: ``value``, ``margin``,
        ``feasible`` (``known``: refused by the loop's exact checks)."""
        key = tuple(float(v) for v in x)
        if key not in self._exact:
            evaluator = self.evaluator
            try:
                outcome = evaluator.score(evaluator.space.controller(list(key)))
            except Exception as error:  # noqa: BLE001 - no controller there: not a candidate
                outcome = Outcome(evaluator.spec.constraints.penalty * 2, False, error=str(error), known=True)
            self._exact[key] = json_safe({"value": outcome.value, "margin": outcome.margin,
                                          "feasible": outcome.feasible, "known": outcome.known,
                                          "slacks": outcome.slacks or {}})
        return self._exact[key]


class RigEvaluator(Evaluator):
    """Scores candidates by rig trials (module docstring): the spec's scenarios on the rig's
    one plant, the metrics from the logs, the references from the baseline's trial."""

    def __init__(self, spec, trials, folder: Path, fidelity: Fidelity,
                 log: Callable[[str], None] | None = None):
        super().__init__(spec)
        self.trials, self.folder, self.fidelity = trials, Path(folder), fidelity
        self.log = log or (lambda line: None)
        self.index = 0           # the history index of the next trial (set by RigExecutor)
        self._trials: dict = {}  # reference controller -> (TrialResult, metrics, info)

    def variants(self) -> tuple:
        return ((),)  # the rig is one plant

    def __call__(self, x, order=None) -> Outcome:
        outcome = super().__call__(x, order)
        if not outcome.known:
            outcome.simulation = self.fidelity.exact(x)
        return outcome

    # -- a candidate's trial -------------------------------------------------------------------
    def _scenarios(self, controller, constraints: dict, slacks: list, _order=None,
                   _early: bool = False) -> Outcome:
        # a trial runs every scenario, in the spec's order: one reset, one damp-down
        from furuta_cosim.cosim import compile_controller
        from furuta_cosim.errors import DesignError

        spec, scenarios = self.spec, []
        for label, prepared, _ in self.runs():
            try:
                cfile = _candidate_file(self, controller, prepared)
            except DesignError as error:
                return Outcome(spec.constraints.penalty * 2, False, constraints, {},
                               f"{label}: no prefilter: {error}", known=True)
            compiled = compile_controller(prepared, cfile)
            scenarios.append(TrialScenario(label, prepared, compiled.cfile, compiled.runtime))
        result, metrics, info = self.run_trial(f"{self.index:04d}", scenarios)
        return self._judged(result, metrics, info, constraints, list(slacks))

    def run_trial(self, name: str, scenarios: list[TrialScenario]) -> tuple[TrialResult, dict, dict]:
        """Run trial ``name`` into ``trials/NAME`` (a folder left by a trial cut short is kept,
        renamed): the result, each scenario's metrics, and what the history records of it."""
        from furuta_cosim.controllers import save_controller
        from furuta_cosim.metrics import compute

        folder = self.folder / "trials" / name
        if folder.exists():
            aside = _aside(folder)
            folder.rename(aside)
            self.log(f"trial {name}: the folder of a trial cut short is kept as {aside.name}; it runs again")
        make_folder(folder)
        save_controller(scenarios[0].cfile, folder / "candidate.yaml")
        self.log(f"trial {name}: {self.trials.where}")
        result = self.trials.run(folder, name, scenarios, self.log)
        metrics = dict(result.metrics)
        failures = dict(result.failures)
        for s in scenarios:
            trace = result.traces.get(s.label)
            if trace is not None:
                scenario = s.prepared.scenario
                metrics[s.label] = compute(trace, scenario.reference.settles, scenario.error_window)
                if trace.failure and s.label not in failures:
                    failures[s.label] = trace.failure
            elif s.label not in metrics and s.label not in failures:
                failures[s.label] = "not run: " + (result.reason if result.status != "finished" else "no data")
        _believable(folder, metrics, scenarios, result.traces,
                    {s.label for s in scenarios if result.status == "finished" and s.label not in failures})
        info = {"folder": f"trials/{name}", "status": result.status, "reason": result.reason,
                "failures": failures, "seconds": result.seconds}
        if result.hold_offset is not None:
            info["hold_offset"] = result.hold_offset
        write_text(folder / "trial.json", dumps(json_safe({**info, "metrics": metrics}), indent=2) + "\n")
        self.log(f"trial {name}: {result.status}: {result.reason}"
                 + ("" if not failures else "; failed: " + "; ".join(f"{k}: {v}" for k, v in failures.items()))
                 + held_home(result.hold_offset))
        if "reset" in failures and not any(s.label in metrics for s in scenarios):
            raise RunStopped(f"trial {name}: the reset failed before the candidate ran ({failures['reset']}; "
                             f"{folder}): the safe controller must swing up and hold this rig; check it "
                             "(and rig.reset), then resume")
        return TrialResult(result.status, result.reason, failures, {}, metrics, result.seconds,
                           result.at_rest, result.hold_offset), metrics, info

    def _judged(self, result: TrialResult, metrics: dict, info: dict, constraints: dict,
                slacks: list) -> Outcome:
        """The outcome of a trial: each scenario's metrics against the spec's constraints and
        terms, as a simulation's are; a scenario that failed (a fall, a trip, not run) breaks a
        constraint by as much as a diverged simulation."""
        from furuta_cosim.metrics import verdicts

        from furuta_cosim.tuning.objective import MARGIN_CAP

        spec = self.spec
        scores, shown, violation, violated = [], {}, 0.0, []
        self._named = {}
        for label, prepared, _ in self.runs():
            values = metrics.get(label)
            if values is not None:
                shown[label] = json_safe(values)
            failure = result.failures.get(label)
            if values is None or failure:
                self._named.update(dict.fromkeys(self.constraint_names(label), MARGIN_CAP))
                violation += 1.0
                constraints[f"{label}.failed"] = failure or "no data"
                slacks.append(math.inf)
                violated.append(label)
                scores.append([math.inf] * len(spec.objective.criteria))
                continue
            found = self._constraint_slacks(label, values, constraints)
            if spec.constraints.requirements:
                checks = verdicts(values, prepared.scenario.requirements, "candidate")
                failed = [k for k, v in checks.items() if not v["pass"]]
                if failed:
                    constraints[f"{label}.requirements"] = failed
                    found.append(0.1 * len(failed))
            violation += sum(max(0.0, slack) for slack in found)
            slacks += found
            if any(slack > 0 for slack in found):
                violated.append(label)
            scores.append([self._criterion(c, label, values) for c in spec.objective.criteria])
        if result.status != "finished" and not violated:   # a tripped trial is never feasible
            violation += 1.0
            constraints["trial"] = f"{result.status}: {result.reason}"
            slacks.append(math.inf)
            violated.append("trial")
        outcome = self._outcome(scores, violation, constraints, shown, slacks, violated)
        outcome.trial = json_safe(info)
        if result.status != "finished":
            outcome.error = f"{result.status}: {result.reason}"
        return outcome

    # -- the baselines' trials -------------------------------------------------------------
    def _reference_runs(self, controller: str, key: str) -> dict:
        return self.reference_trial(controller, key)[1]

    def reference_trial(self, controller: str, key: str = "baselines") -> tuple:
        """The trial of a controller file the spec names (a baseline: the reference of its
        relative terms and constraints), run once per run directory (``trials/baseline-NAME``;
        a resumed run reads it back); (result, metrics, info)."""
        if controller not in self._trials:
            from furuta_cosim.cosim import compile_controller

            name = f"baseline-{Path(controller).stem}"
            found = self._recorded(name)
            if found is None:
                scenarios = []
                for label, prepared, _ in self.runs():
                    try:
                        compiled = compile_controller(prepared, controller)
                    except ConfigError as error:
                        raise error.within(f"{self.spec.source}: {key}") from None
                    scenarios.append(TrialScenario(label, prepared, compiled.cfile, compiled.runtime))
                found = self.run_trial(name, scenarios)
            result = found[0]
            if result.status != "finished" or result.failures:
                raise RunStopped(f"the baseline {Path(controller).stem} did not run the spec's scenarios on "
                                 f"the rig ({result.status}: {result.reason}; "
                                 + "; ".join(f"{k}: {v}" for k, v in result.failures.items())
                                 + f"; {self.folder / 'trials' / name}): a tuning on the rig is measured "
                                 "against a baseline that runs them")
            self._trials[controller] = found
        return self._trials[controller]

    def baseline_outcome(self, controller: str) -> Outcome:
        """A baseline's outcome from its trial, scored as a candidate's."""
        from furuta_cosim.controllers import load_controller

        result, metrics, info = self.reference_trial(controller)
        cfile = load_controller(controller)
        constraints, violation, slacks = self._loop_checks(cfile.controller)
        return self._judged(result, metrics, info, constraints, slacks)

    def _recorded(self, name: str) -> tuple | None:
        """A finished trial's result as its trial.json records it (a resumed run), or None."""
        path = self.folder / "trials" / name / "trial.json"
        try:
            document = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        labels = [label for label, _, _ in self.runs()]
        if not _trial_document(document, labels):
            return None
        metrics = {label: {m: (math.inf if v is None else float(v)) for m, v in values.items()}
                   for label, values in document["metrics"].items()}
        info = {k: document[k] for k in ("folder", "status", "reason", "failures", "seconds")}
        return (TrialResult(document["status"], document["reason"], dict(document["failures"]), {}, metrics,
                            float(document["seconds"])), metrics, info)


def held_home(offset: float | None) -> str:
    """What a trial's log line says of the reset's integral (trial.py's ``hold_offset``): where
    the rig's own equilibrium under the safe controller is off home, the reference that held
    the arm home instead."""
    if offset is None or abs(offset) < HELD_OFF:
        return ""
    return (f"; the reset held the arm home with its reference {offset:+.3f} rad off (the rig's "
            "equilibrium under the safe controller is off home: a cable's pull, friction)")


def _trial_document(document, labels) -> bool:
    """Whether a trial.json read back is whole: its keys, a known status, metrics by the runs'
    labels (numbers, or null where not finite)."""
    if not isinstance(document, dict):
        return False
    if document.get("status") not in STATUSES or not isinstance(document.get("reason"), str):
        return False
    if not isinstance(document.get("failures"), dict) or not isinstance(document.get("folder"), str):
        return False
    seconds = document.get("seconds")
    if not isinstance(seconds, (int, float)) or isinstance(seconds, bool) or not math.isfinite(seconds):
        return False
    metrics = document.get("metrics")
    if not isinstance(metrics, dict) or not set(metrics) <= set(labels):
        return False
    return all(isinstance(values, dict) and all(
        isinstance(m, str) and (v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)
                                              and math.isfinite(v))) for m, v in values.items())
        for values in metrics.values())


def _aside(folder: Path) -> Path:
    for k in range(1, 1000):
        aside = folder.with_name(f"{folder.name}.interrupted" + (f"-{k}" if k > 1 else ""))
        if not aside.exists():
            return aside
    raise ConfigError([f"{folder}: too many interrupted trials kept beside it"])


class RigExecutor:
    """Rig trials one after the other in this process: a trial's number is its history index.
    A stop that is not the candidate's fault (the rig not at rest, no answer from an external
    rig, a result it cannot read) ends the run, resumable; any other error fails the candidate."""

    name = "rig"

    def __init__(self, spec, evaluator: RigEvaluator, history):
        self.spec, self.evaluator, self.history = spec, evaluator, history
        self.where = evaluator.trials.where

    def submit(self, x, order=None):
        return x, order

    def gather(self, pending) -> list[Outcome]:
        from furuta_cosim.tuning.executors import _describe, failed

        outcomes = []
        for k, (x, order) in enumerate(pending):
            self.evaluator.index = len(self.history.records) + k
            try:
                outcomes.append(self.evaluator(x, order))
            except (RunStopped, ConfigError):
                raise
            except Exception as error:  # noqa: BLE001 - the candidate's fault, recorded
                outcomes.append(failed(self.spec, _describe(error)))
        return outcomes

    def map(self, xs, order=None) -> list[Outcome]:
        return self.gather([self.submit(x, order) for x in xs])

    def close(self) -> None:
        pass


def tune_on_rig(spec, run_dir: str | Path, trials, *, method: str | None = None,
                n_trials: int | None = None, seed: int | None = None, resume: bool = False,
                progress: Callable | None = None, log: Callable[[str], None] | None = None) -> dict:
    """Tune ``spec`` with each evaluation a rig trial on ``trials`` (tuning/trials.py: a board or
    an external rig), into ``run_dir`` (module docstring); returns the summary document.

    Parameters
    ----------
    spec : TuningSpec
        A ``scenarios`` objective with ``rig.reset`` (the swing-up file that resets the rig).
    run_dir : path
        New (or empty), or a run to ``resume``.
    trials : BoardTrials or ExternalTrials
        Where the trials run.
    method : str, optional
        ``safe`` (default; tuning/safe.py), or ``bo``, ``random``, ``de``: every candidate they
        propose runs on the rig, the supervisor the only guard.
    n_trials : int, optional
        Rig trials in all, the baseline's included (default ``rig.n_trials``; a resume keeps the
        run's).
    seed : int, optional
        Default ``optimizer.seed``.
    resume : bool
        Go on after the last finished trial; refused when the spec, method, seed, plant or rig
        differ from the run's.
    progress : callable, optional
        ``progress(done, total, best, feasible)`` after every trial (and for the simulated
        fidelity's tuning, before them).
    log : callable, optional
        Takes a line about each trial and the run.

    Returns
    -------
    dict
        The summary document (summary.json).
    """
    from threadpoolctl import threadpool_limits

    from furuta_cosim.tuning.history import History
    from furuta_cosim.tuning.methods import METHODS, Run, method_for
    from furuta_cosim.tuning.rundir import Clock, identity_of, locked, recorded, same_run
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import MAX_SEED, MAX_TRIALS

    log = log or (lambda line: None)
    method = method or "safe"
    folder = output_folder(run_dir)
    if n_trials is None and resume:
        started = recorded(folder).get("n_calls")
        if isinstance(started, int) and not isinstance(started, bool) and 2 <= started <= MAX_TRIALS:
            n_trials = started
    n_trials = spec.rig.n_trials if n_trials is None else n_trials
    seed = spec.optimizer.seed if seed is None else seed
    if method not in METHODS:
        raise ConfigError([f"method: expected one of {', '.join(METHODS)}, got {method!r}"])
    if isinstance(n_trials, bool) or not isinstance(n_trials, int) or not 2 <= n_trials <= MAX_TRIALS:
        raise ConfigError([f"n_trials: expected a whole number from 2 to {MAX_TRIALS}, got {n_trials}"])
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError([f"seed: expected a whole number from 0 to 2^32 - 1, got {seed}"])
    if spec.objective.type != "scenarios":
        raise ConfigError([f"{spec.source}: objective.type: a rig trial scores scenarios; this spec's "
                           f"objective is {spec.objective.type}"])
    if spec.swingup is not None:
        raise ConfigError([f"{spec.source}: controller: a rig trial is reset by a swing-up; tune the "
                           "swing-up itself in simulation (its catch is what resets the rig)"])
    if spec.rig.reset is None:
        raise ConfigError([f"{spec.source}: rig.reset: missing: a rig trial resets the rig with a "
                           "swing-up-and-balance file (e.g. reset: swingup-qube)"])
    refusal = METHODS[method].refusal(spec)
    if refusal:
        raise ConfigError([f"method: {refusal}"])
    if method == "safe" and not spec.baselines:
        raise ConfigError([f"{spec.source}: baselines: the safe method starts from a controller known "
                           "to be safe on the rig: name it as the first baseline"])
    # a run stopped in its simulated fidelity, before its first trial, has its run.json and no
    # history of trials yet: --resume continues it (the simulation resumes where it stopped)
    if resume and not (folder / "history.jsonl").is_file() and not (folder / "run.json").is_file():
        raise ConfigError([f"resume: {folder} holds no tuning run (no history.jsonl)"])
    if not resume and (folder / "history.jsonl").exists():
        raise ConfigError([f"run_dir {folder}: holds a tuning run already; choose another folder or "
                           "`resume` it"])
    # what the run is, and on which rig (its board or exchange folder, its plant file's content)
    mine = {**identity_of(spec, method, seed, n_trials), "rig": rig_identity(trials)}
    if resume:
        same_run(folder, mine)
        theirs = recorded(folder).get("rig")
        if theirs is not None and theirs != mine["rig"]:
            raise ConfigError([f"resume: the rig differs from the one the run was started on "
                               f"({json.dumps(theirs, sort_keys=True)} in {folder / 'run.json'}; now "
                               f"{json.dumps(mine['rig'], sort_keys=True)})"])
    evaluator = lock = history = None
    try:
        make_folder(folder)
        lock = locked(folder)
        if not resume:
            if spec.path:
                write_text(folder / "spec.yaml", mine["spec"])
            write_text(folder / "run.json", json.dumps({k: v for k, v in mine.items() if k != "spec"}) + "\n")
        # the simulated fidelity: the spec tuned in simulation first (resumed where it stopped)
        simulation = folder / "simulation"
        calls = spec.rig.simulations or spec.optimizer.n_calls
        if not (simulation / "summary.json").is_file():
            log(f"the simulated fidelity: tuning {spec.name} in simulation ({calls} evaluations) into {simulation}")
            tune(spec, simulation, method="bo", n_calls=calls, seed=seed,
                 resume=(simulation / "history.jsonl").is_file(), progress=progress, log=log)
        sim_history = History(simulation / "history.jsonl", True, Evaluator(spec).space.bounds)
        sim_history.close()
        fidelity = Fidelity(spec, sim_history.records, simulation)
        evaluator = RigEvaluator(spec, trials, folder, fidelity, log)
        evaluator.runs()
        history = History(folder / "history.jsonl", resume and (folder / "history.jsonl").is_file(),
                          evaluator.space.bounds, log)
        if len(history.records) > n_trials:
            raise ConfigError([f"resume: the run holds {len(history.records)} trials, more than the "
                               f"{n_trials} of `n_trials`"])
        log(f"tuning {spec.name} on the rig into {folder}, {trials.where} ({method}, {n_trials} trials)")
        clock = Clock(folder / "run.json")
        clock.identity["n_calls"] = n_trials
        clock.identity["rig"] = mine["rig"]
        executor = RigExecutor(spec, evaluator, history)
        run = Run(spec, folder, evaluator, executor, history, n_trials, seed, clock, progress, log, prior=fidelity)
        with threadpool_limits(1):
            # the baselines' trials first: every relative term and constraint is measured against them
            evaluator.check_references()
            method_for(method).search(run)
        return finish_rig(spec, folder, evaluator, history.records, n_trials, method, seed, clock)
    finally:
        if history is not None:
            history.close()
        if lock is not None:
            os.close(lock)


def finish_rig(spec, folder: Path, evaluator: RigEvaluator, records: list[dict], n_trials: int,
               method: str, seed: int, clock) -> dict:
    """The run's summary: best.yaml (the best feasible trial's controller), the baselines as
    their trials scored them, every trial that broke a constraint or was stopped, the rig time;
    summary.json, summary.md and the convergence figure."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.report.figures import plot_convergence
    from furuta_cosim.tuning.saved import save_scored

    feasible = [r for r in records if r["feasible"]]
    best = min(feasible, key=lambda r: (r["objective"], r["index"])) if feasible else None
    baselines = {}
    for name in spec.baselines:
        outcome = evaluator.baseline_outcome(name)
        baselines[load_controller(name).name] = json_safe({
            "objective": outcome.objective, "feasible": outcome.feasible,
            "constraints": outcome.constraints, "metrics": outcome.metrics, "trial": outcome.trial})
    ran = [r for r in records if r.get("trial")]
    unsafe = [{"index": r["index"], "folder": r["trial"]["folder"], "status": r["trial"]["status"],
               "violated": r.get("violated") or [], "error": r.get("error"),
               "failures": r["trial"].get("failures") or {}}
              for r in ran if not r["feasible"]]
    tripped = [u for u in unsafe if u["status"] == "tripped"]
    sim = _simulation_summary(evaluator.fidelity.folder)
    document = {"spec": spec.name, "method": method, "seed": seed, "n_trials": n_trials,
                "evaluator": evaluator.trials.kind, "where": evaluator.trials.where,
                "trials": len(ran), "evaluations": len(records), "feasible": len(feasible),
                "unsafe": unsafe, "violations": len(unsafe), "trips": len(tripped),
                "refused": sum(1 for r in records if r.get("known")),
                "rig_seconds": float(sum(r["trial"].get("seconds") or 0.0 for r in ran)),
                "optimizer_seconds": clock["optimizer"], "evaluation_seconds": clock["evaluation"],
                "simulation": sim, "best": None, "baselines": baselines}
    if best is not None:
        prefilter = save_scored(evaluator, best, folder / "best.yaml", f"{spec.name}-rig-best",
                                f"best of tuning {spec.name} on the rig ({method}, seed {seed})", method, seed)
        document["best"] = {"index": best["index"], "objective": best["objective"],
                            "origin": best.get("origin") or "", "parameters": best["parameters"],
                            "metrics": best["metrics"], "file": "best.yaml", "prefilter": prefilter,
                            "trial": best.get("trial"), "simulation": best.get("simulation")}
    document["gap"] = _gap(ran, best)
    levels = {name: b["objective"] for name, b in baselines.items() if b["feasible"]}
    plot_convergence(records, folder / "convergence", levels)
    if best is not None:
        document["figures"] = _figures(evaluator, folder, best, baselines)
    write_text(folder / "summary.json", dumps(document, indent=2) + "\n")
    write_text(folder / "summary.md", rig_summary_text(spec, document))
    return document


def _gap(ran: list[dict], best: dict | None) -> dict | None:
    """The rig against the simulation of the same controllers: per trial with both values the
    objective on the rig minus the simulated one (what the safe method's gap models), their
    median and range, and the best trial's; None without such a trial."""
    import math

    import numpy as np

    def one(r):
        sim = (r.get("simulation") or {}).get("value") if isinstance(r.get("simulation"), dict) else None
        value = r.get("value", r.get("objective"))
        ok = all(isinstance(v, (int, float)) and math.isfinite(v) for v in (sim, value))
        return float(value) - float(sim) if ok else None

    gaps = [g for g in (one(r) for r in ran) if g is not None]
    if not gaps:
        return None
    return {"trials": len(gaps), "median": float(np.median(gaps)), "min": min(gaps), "max": max(gaps),
            "best": one(best) if best is not None else None}


def _figures(evaluator: RigEvaluator, folder: Path, best: dict, baselines: dict) -> list[str]:
    """Per scenario, ``best-<scenario>.png`` (and .svg): the best trial on the rig beside the
    same controller simulated and the first baseline's trial, from their logs (board trials)."""
    from furuta_cosim.cosim import evaluate
    from furuta_cosim.report.figures import plot_runs
    from furuta_cosim.rig.trial import Segment, segment_traces

    runs = evaluator.runs()
    segments = [Segment(label, None, prepared.rbar) for label, prepared, _ in runs]
    found = {}
    trial = folder / (best.get("trial") or {}).get("folder", "-") / "run"
    if not (trial / "log.csv").is_file():
        return []  # an external rig's trial: its files are in external/, as it sent them
    found["the best trial"] = segment_traces(trial, segments)
    first = next(iter(baselines.values()), None)
    base = folder / ((first or {}).get("trial") or {}).get("folder", "-") / "run"
    if (base / "log.csv").is_file():
        found[f"{next(iter(baselines))}'s trial"] = segment_traces(base, segments)
    simulated = {}
    sim = evaluator.fidelity.evaluator
    controller = evaluator.space.controller(best["x"])
    for label, prepared, _ in sim.runs():
        name = label.split("[", 1)[0]  # the first plant variant's run (the point estimate's)
        if name in simulated:
            continue
        try:
            cfile = _candidate_file(evaluator, controller, prepared)
            simulated[name] = evaluate(prepared, sim._session(prepared), cfile).trace
        except Exception:  # noqa: BLE001 - a figure is not worth failing the summary for
            continue
    found["the best, simulated"] = simulated
    written = []
    for label, _, _ in runs:
        traces = {name: by_run[label] for name, by_run in found.items() if label in by_run}
        if traces:
            paths = plot_runs(traces, folder / f"best-{label}", f"{label}: on the rig and in simulation",
                              ["theta0", "theta1", "u"])
            written += [p.name for p in paths]
    return written


def _candidate_file(evaluator, controller, prepared):
    """The controller file a candidate's run scores (its prefilter for the run's output)."""
    from furuta_cosim.controllers import ControllerFile
    from furuta_cosim.design.prefilter import prefilter

    if isinstance(controller, ControllerFile):
        return controller
    spec = evaluator.spec
    return ControllerFile(controller, spec.period, spec.model, prepared.tracked,
                          prefilter(evaluator.model, controller, prepared.tracked))


def _simulation_summary(folder: Path | None) -> dict | None:
    """The simulated fidelity's best, as its summary.json says."""
    try:
        found = json.loads((Path(folder) / "summary.json").read_text())
    except (OSError, ValueError, TypeError):
        return None
    best = found.get("best") if isinstance(found, dict) else None
    return {"folder": "simulation", "evaluations": found.get("evaluations"),
            "best_objective": best.get("objective") if isinstance(best, dict) else None,
            "best_file": "simulation/best.yaml" if isinstance(best, dict) else None}


def rig_summary_text(spec, document: dict) -> str:
    """summary.md of a tuning on the rig: what ran where, the best trial against the
    baselines' trials, and every trial that broke a constraint or was stopped."""
    lines = [f"# Tuning {spec.name} on the rig", "", spec.description, "",
             f"- method: {document['method']}, seed {document['seed']}, {document['where']}",
             f"- trials: {document['trials']} of {document['n_trials']} "
             f"({document['rig_seconds']:.1f} s of rig time), {document['feasible']} feasible, "
             f"{document['violations']} broke a constraint or failed, {document['trips']} stopped by "
             f"the supervisor; {document['refused']} candidates refused by the loop's exact checks "
             "without a trial",
             f"- time: optimizer {document['optimizer_seconds']:.1f} s, trials "
             f"{document['evaluation_seconds']:.1f} s", ""]
    sim = document.get("simulation")
    if sim and sim.get("best_objective") is not None:
        lines += [f"The simulated fidelity ({sim['folder']}/, {sim['evaluations']} evaluations): best "
                  f"{sim['best_objective']:.6g} in simulation ({sim['best_file']}).", ""]
    best = document["best"]
    if best:
        simulated = (best.get("simulation") or {}).get("value")
        lines.append(f"Best on the rig: objective {best['objective']:.6g} at trial {best['index']} "
                     f"({best['trial']['folder'] if best.get('trial') else 'a baseline trial'}), from "
                     f"{best['origin'] or 'the search'} (best.yaml)"
                     + (f"; the same controller scores {simulated:.6g} in simulation." if simulated is not None
                        else "."))
        lines.append("A rig's score is one trial's: running best.yaml again scores within the rig's "
                     "trial-to-trial spread, not to the digit.")
        gap = document.get("gap")
        if gap and gap.get("best") is not None:
            lines.append(
                f"Why the two differ: the rig is not the model. Over the {gap['trials']} trials with both "
                f"scores, the rig's objective minus the same controller's in simulation was "
                f"{gap['median']:+.4g} (median; from {gap['min']:+.4g} to {gap['max']:+.4g}), "
                f"{gap['best']:+.4g} for best.yaml"
                + ("; the safe method models this gap as it goes (a GP over the trials' differences) and "
                   "proposes only what the simulation plus the gap says is safe." if document["method"] == "safe"
                   else "."))
    else:
        lines.append("No feasible controller was found on the rig.")
    from furuta_cosim.tuning.summary import baseline_line

    lines += [baseline_line(name, baseline, best, "its trial on the rig")
              for name, baseline in document["baselines"].items()]
    lines += ["", "Trials that broke a constraint or failed:" if document["unsafe"] else
              "No trial broke a constraint or failed."]
    for u in document["unsafe"]:
        why = u["error"] or ", ".join(f"{k}: {v}" for k, v in u["failures"].items()) or \
            "broke " + ", ".join(u["violated"])
        lines.append(f"- trial {u['index']} ({u['folder']}, {u['status']}): {why}")
    return "\n".join(lines) + "\n"


def rig_identity(trials) -> dict:
    """What identifies the rig of a run (run.json, checked by a resume): the evaluator, the board
    and its options or the exchange folder, the rig's plant file and its content's hash."""
    from furuta_cosim.fmu.plants import content_sha256

    plant = getattr(trials, "plant", None)
    found = {"evaluator": trials.kind}
    if trials.kind == "board":
        found["board"] = trials.board
        found["options"] = {k: v for k, v in sorted(trials.options.items()) if isinstance(v, (int, float, str))}
    else:
        found["folder"] = str(trials.folder)
    if plant is not None:
        found["plant"] = plant.path.name  # the hash says which; a moved run folder stays whole
        found["plant_sha256"] = content_sha256(plant)
    return found


def _believable(folder: Path, metrics: dict, scenarios, traces: dict, finished: set) -> None:
    """Stop the tuning (RunStopped) on a trial whose metrics cannot be what a rig measured
    (tuning/plausible.py), naming the file and the field: it learns nothing from them."""
    from furuta_cosim.tuning.plausible import implausible

    for s in scenarios:
        values = metrics.get(s.label)
        if values is None:
            continue
        problems = implausible(values, s.prepared, s.label in finished)
        if problems:
            where = (f"{folder / 'result.json'}: scenarios.{s.label}.metrics" if s.label not in traces
                     else f"{folder}: {s.label}'s log")
            raise RunStopped(f"{where}: {problems[0]}" + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else "")
                             + ": a rig's result that cannot be true is not learned from; check the rig side, "
                             "then resume")

