"""A tuning run: the ask/evaluate/record loop over a spec, written to a run directory.

    run-dir/
      spec.yaml        a copy of the spec
      run.json         the method, seed and plant it was started with (checked by --resume)
      history.jsonl    one line per evaluation, appended and flushed to disk (fsync) at once
      best.yaml        the best feasible controller, a controller file simulate/analyze accept
      convergence.png  (and .svg) best objective against evaluations
      summary.json     best, baselines scored alike, counts; summary.md the same in words

Candidates come in synchronous batches of ``optimizer.batch`` (``bo``: constrained Bayesian
optimization, tuning/optimizers.py; ``random``: the same space drawn at random; ``de``: scipy's
differential evolution), each point of a batch sent to an executor (tuning/executors.py) as
soon as it is known. Workers change only the speed: a history depends on the spec, the seed
and the batch size, and a resumed run goes on exactly as the uninterrupted one would have.
``bo`` starts from an initial design holding the spec's baselines and ``optimizer.initial``
controllers that its search space can represent, filled up by a Latin hypercube.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.documents import dumps, json_safe
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import output_folder, write_text
from furuta_cosim.report.figures import plot_convergence
from furuta_cosim.tuning.objective import Evaluator, Outcome
from furuta_cosim.tuning.spec import METHODS, TuningSpec


def _record(index: int, x, names, outcome: Outcome, origin: str = "", surrogate=None) -> dict:
    return json_safe({"index": index, "x": [float(v) for v in x],
                       "parameters": dict(zip(names, map(float, x))),
                       "objective": outcome.objective, "feasible": outcome.feasible,
                       "value": outcome.value, "margin": outcome.margin,
                       **({"criteria": outcome.criteria} if outcome.criteria is not None else {}),
                       "constraints": outcome.constraints, "metrics": outcome.metrics,
                       "origin": origin, "surrogate": surrogate,
                       "wall_time": outcome.wall_time, "worker": outcome.worker, "error": outcome.error})


def _append(handle, record: dict) -> None:
    handle.write(dumps(record) + "\n")
    handle.flush()
    os.fsync(handle.fileno())


class _Spent(Exception):
    """The budget is spent: ends scipy's differential evolution from inside."""


class _History:
    """history.jsonl: the records so far, and each new one appended and forced to disk before
    the run goes on.

    On --resume every line is checked (its index, x inside the search space, a finite
    objective): a damaged line is one error naming it, and nothing is dropped or changed. Only
    a last line without its newline that does not parse is what a crash while writing leaves:
    it is dropped, saying so. The file is never followed through a symbolic link."""

    def __init__(self, path: Path, resume: bool, bounds, log=None):
        self.path = path
        self.records: list[dict] = []
        flags = os.O_RDWR | os.O_CREAT | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0)
        if path.is_symlink():
            raise ConfigError([f"{path}: is a symbolic link; a run's history is a file of its own"])
        if resume:
            self._read(bounds, log)
        try:
            handle = os.open(path, flags, 0o644)
        except OSError as error:
            raise ConfigError([f"{path}: cannot be opened ({error.strerror})"]) from None
        self._handle = os.fdopen(handle, "a")

    def _read(self, bounds, log) -> None:
        raw = self.path.read_bytes()
        if not raw:
            return
        lines = raw.split(b"\n")
        complete = raw.endswith(b"\n")
        if complete:
            lines.pop()
        for number, line in enumerate(lines, start=1):
            last = number == len(lines)
            problem = None
            try:
                record = json.loads(line)
            except ValueError:
                record, problem = None, "not JSON"
            if problem and last and not complete:
                # a crash while writing: the evaluation is not in the history, it runs again
                with self.path.open("r+b") as handle:
                    handle.truncate(len(raw) - len(line))
                if log:
                    log(f"{self.path}: line {number} was cut short by a crash: dropped, its "
                        "evaluation runs again")
                return
            problem = problem or _damage(record, len(self.records), bounds)
            if problem:
                raise ConfigError([f"--resume: {self.path}: line {number}: {problem}; nothing was "
                                   "changed: repair or remove that line (and the ones after it), "
                                   "then --resume again"])
            self.records.append(record)
        if raw and not complete:
            with self.path.open("ab") as handle:  # the last record lacked its newline
                handle.write(b"\n")

    def append(self, record: dict) -> None:
        _append(self._handle, record)
        self.records.append(record)

    def close(self) -> None:
        self._handle.close()


def _damage(record, index: int, bounds) -> str | None:
    """What is wrong with one history record, or None."""
    if not isinstance(record, dict):
        return "not a record"
    if record.get("index") != index or isinstance(record.get("index"), bool):
        return f"expected index {index}, got {record.get('index')!r}"
    x = record.get("x")
    if (not isinstance(x, list) or len(x) != len(bounds)
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       for v in x)):
        return f"x: expected {len(bounds)} finite numbers"
    for k, (value, (low, high)) in enumerate(zip(x, bounds)):
        slack = 1e-9 * (high - low)
        if not low - slack <= value <= high + slack:
            return f"x[{k}] = {value!r} is outside the search space [{low:g}, {high:g}]"
    objective = record.get("objective")
    if isinstance(objective, bool) or not isinstance(objective, (int, float)) or not math.isfinite(objective):
        return f"objective: expected a finite number, got {objective!r}"
    if not isinstance(record.get("feasible"), bool):
        return f"feasible: expected true or false, got {record.get('feasible')!r}"
    return None


def _locked(folder: Path):
    """An exclusive lock on the run directory (``.lock``), held for the whole run: a second
    ``tune`` on the same folder is refused at once. The lock ends with the process, a killed
    one too."""
    import fcntl

    try:
        handle = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    except OSError as error:
        raise ConfigError([f"-o {folder}: cannot be locked ({error.strerror})"]) from None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(handle)
        raise ConfigError([f"-o {folder}: another tune is running in this folder; wait for it "
                           "or choose another folder"]) from None
    return handle


def _same_run(folder: Path, identity: dict) -> None:
    """A resumed run goes on with the spec, method and seed it started with, or not at all:
    its history would otherwise mix two searches."""
    try:
        started = json.loads((folder / "run.json").read_text())
        spec_text = (folder / "spec.yaml").read_text() if (folder / "spec.yaml").exists() else None
    except (OSError, ValueError) as error:
        raise ConfigError([f"--resume: {folder / 'run.json'} cannot be read ({error})"]) from None
    if spec_text is not None and spec_text != identity["spec"]:
        raise ConfigError([f"--resume: the spec differs from the one {folder} was started with "
                           f"({folder / 'spec.yaml'})"])
    for key, flag in (("method", "--optimizer"), ("seed", "--seed"), ("plant", "--plant")):
        if started.get(key) != identity.get(key):
            mine, theirs = identity.get(key, "(none)"), started.get(key, "(none)")
            raise ConfigError([f"--resume: {flag} {mine} differs from the run's {theirs} "
                               f"({folder / 'run.json'})"])


def _executor(spec, evaluator, workers: int, dask: str | None):
    from furuta_cosim.tuning.executors import Dask, Processes, Serial

    if dask:
        return Dask(spec, dask, max(workers, 1))
    if workers > 1:
        return Processes(spec, workers)
    return Serial(spec, evaluator)


def tune(spec: TuningSpec, run_dir: str | Path, *, method: str | None = None,
         n_calls: int | None = None, seed: int | None = None, workers: int = 1,
         dask: str | None = None, resume: bool = False,
         progress: Callable[[int, int, float | None, int], None] | None = None,
         log: Callable[[str], None] | None = None) -> dict:
    """Run the spec's optimization into ``run_dir`` and return the summary document.

    Candidates are asked in synchronous batches of ``optimizer.batch`` (the initial design at
    once), so that workers change the speed and never the history. One run per directory at
    a time (a lock).

    Parameters
    ----------
    spec : TuningSpec
        From :func:`furuta_cosim.tuning.spec.load_spec`.
    run_dir : path
        The run directory: ``history.jsonl``, ``summary.md``, ``summary.json``, ``best.yaml``
        and the figures. A new one must not exist (or be empty) unless ``resume``.
    method : str, optional
        The optimizer (``bo``, ``random``, ``de``, ...); default the spec's ``optimizer.method``.
    n_calls : int, optional
        Evaluations in all; default the spec's ``optimizer.n_calls``.
    seed : int, optional
        The optimizer's seed; default the spec's ``optimizer.seed``.
    workers : int
        Local processes that evaluate candidates (1: in this process).
    dask : str, optional
        A Dask scheduler address, or ``"local"``, to evaluate on a Dask cluster instead.
    resume : bool
        Continue ``run_dir`` after a crash: its history is replayed into the optimizer and the
        run goes on until it holds exactly ``n_calls`` evaluations.
    progress : callable, optional
        ``progress(done, total, best, feasible)``, called after every batch.
    log : callable, optional
        Takes a line about the run (a baseline left out of the initial design, a history line
        dropped after a crash).

    Returns
    -------
    dict
        The summary document (what ``summary.json`` holds).

    Raises
    ------
    ConfigError
        For a bad option or run directory, before anything is written.
    RunStopped
        When a Dask scheduler is lost or no worker comes for a minute; the history is kept.
    """
    from furuta_cosim.cosim.worker import check_workers
    from furuta_cosim.tuning.spec import MAX_CALLS, MAX_SEED

    method = method or spec.optimizer.method
    n_calls = spec.optimizer.n_calls if n_calls is None else n_calls
    seed = spec.optimizer.seed if seed is None else seed
    # every option is checked before anything is made: a refused option leaves no folder
    if method not in METHODS:
        raise ConfigError([f"--optimizer: expected one of {', '.join(METHODS)}, got {method!r}"])
    if isinstance(n_calls, bool) or not isinstance(n_calls, int) or not 1 <= n_calls <= MAX_CALLS:
        raise ConfigError([f"--n-calls: expected a whole number from 1 to {MAX_CALLS}, got {n_calls}"])
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError([f"--seed: expected a whole number from 0 to 2^32 - 1, got {seed}"])
    if method == "de" and spec.objective.type == "tradeoff":
        raise ConfigError(["--optimizer de: differential evolution minimizes one number; a "
                           "tradeoff objective is searched by bo or random"])
    check_workers(workers)
    if dask is not None:
        from furuta_cosim.tuning.executors import check_address

        check_address(dask)
    folder = output_folder(run_dir)
    if resume and not (folder / "history.jsonl").is_file():
        raise ConfigError([f"--resume: {folder} holds no tuning run (no history.jsonl)"])
    if not resume and (folder / "history.jsonl").exists():
        raise ConfigError([f"-o {folder}: holds a tuning run already; choose another folder "
                           "or --resume it"])
    evaluator = Evaluator(spec)
    if spec.objective.type != "spectral":
        evaluator.runs()  # every scenario and variant prepared (and checked) before any file
        evaluator.check_references()
        if log:
            for line in evaluator.vacuous():
                log(f"warning: {spec.source}: {line}")
    identity = {"spec": Path(spec.path).read_text() if spec.path else spec.name,
                "method": method, "seed": seed}
    if spec.plant is not None:
        identity["plant"] = spec.plant
    if resume:
        _same_run(folder, identity)
    executor = _executor(spec, evaluator, workers, dask)  # a Dask scheduler is reached here
    lock = history = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = _locked(folder)
        if not resume and (folder / "history.jsonl").exists():  # one that finished meanwhile
            raise ConfigError([f"-o {folder}: holds a tuning run already; choose another "
                               "folder or --resume it"])
        if not resume:
            if spec.path:
                write_text(folder / "spec.yaml", identity["spec"])
            write_text(folder / "run.json", json.dumps({k: v for k, v in identity.items() if k != "spec"}) + "\n")
        history = _History(folder / "history.jsonl", resume, evaluator.space.bounds, log)
        if log:
            log(f"tuning {spec.name} into {folder}, {executor.where}")
        if len(history.records) > n_calls:
            raise ConfigError([f"--resume: the run holds {len(history.records)} evaluations, "
                               f"more than --n-calls {n_calls}"])
        return _search(spec, folder, evaluator, executor, history, n_calls, seed, method,
                       workers, dask, progress, log)
    finally:
        executor.close()
        if history is not None:
            history.close()
        if lock is not None:
            os.close(lock)


def _search(spec, folder, evaluator, executor, history, n_calls, seed, method, workers, dask,
            progress, log) -> dict:
    from threadpoolctl import threadpool_limits

    batch = spec.optimizer.batch
    clock = _Clock(folder / "run.json")
    # one BLAS thread for the optimizer, serial too: with workers they use the other cores;
    # alone, at a GP's sizes (150 points), a second thread made each iteration twice as
    # slow (tools/bench_tune.py, paper-spectral), and splitting BLAS reductions over
    # threads rounds differently, so a seed's history would depend on the core count
    with threadpool_limits(1):
        if method == "de":
            _differential_evolution(spec, evaluator, executor, history, n_calls, seed, batch,
                                    clock, progress)
        elif method == "random":
            _random(evaluator, executor, history, n_calls, seed, batch, clock, progress)
        else:
            _bayes(spec, evaluator, executor, history, n_calls, seed, batch, clock, progress, log)
    return _finish(spec, folder, evaluator, history.records, n_calls, method, seed, clock)


class _Clock(dict):
    """Seconds spent in the optimizer and waiting for evaluations, kept in run.json after every
    batch, so that a resumed run (a finished one too) goes on counting from there."""

    def __init__(self, path: Path):
        try:
            saved = json.loads(path.read_text())
        except (OSError, ValueError):
            saved = {}
        saved = saved if isinstance(saved, dict) else {}
        super().__init__({key: _seconds(saved.get(f"{key}_seconds")) for key in ("optimizer", "evaluation")})
        self.path, self.identity = path, {k: saved.get(k) for k in ("method", "seed", "plant") if k in saved}

    def save(self) -> None:
        write_text(self.path, json.dumps({**self.identity, "optimizer_seconds": self["optimizer"],
                                          "evaluation_seconds": self["evaluation"]}) + "\n")


def _seconds(value) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok and value >= 0 else 0.0


def _report(progress, history: _History, n_calls: int, clock: _Clock) -> None:
    clock.save()
    if progress:
        feasible = [r["objective"] for r in history.records if r["feasible"]]
        progress(len(history.records), n_calls, min(feasible) if feasible else None, len(feasible))


def _evaluate(executor, evaluator, history: _History, xs, clock, origins=None) -> list[float]:
    return _collect(executor, evaluator, history, xs, [executor.submit(x) for x in xs], clock,
                    origins)


def _collect(executor, evaluator, history: _History, xs, pending, clock, origins=None,
             surrogate=None) -> list[float]:
    """Wait for a batch's outcomes (the evaluation clock: time spent waiting), record them."""
    started = time.perf_counter()
    outcomes = executor.gather(pending) if pending else []
    clock["evaluation"] += time.perf_counter() - started
    names = evaluator.space.names
    for k, (x, outcome) in enumerate(zip(xs, outcomes)):
        history.append(_record(len(history.records), x, names, outcome,
                               origins[k] if origins else "", surrogate))
    return [outcome.objective for outcome in outcomes]


def _random(evaluator, executor, history, n_calls, seed, batch, clock, progress):
    from furuta_cosim.tuning.optimizers import RandomSearch

    sampler = RandomSearch(evaluator.space.bounds, seed)
    while len(history.records) < n_calls:
        first = len(history.records)
        xs = [sampler.point(k) for k in range(first, min(first + batch, n_calls))]
        _evaluate(executor, evaluator, history, xs, clock, ["random"] * len(xs))
        _report(progress, history, n_calls, clock)


def initial_design(spec, evaluator, seed: int, log=None) -> list[tuple[list[float], str]]:
    """The initial design of ``bo``: the spec's baselines (unless ``optimizer.warm_start`` is
    false) and ``optimizer.initial`` controllers the space can represent (each said in one line, or why not), then a Latin hypercube up to
    ``optimizer.n_initial_points``."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.tuning.optimizers import latin_hypercube

    design, seen = [], set()
    baselines = spec.baselines if spec.optimizer.warm_start else ()
    for kind, names in (("baseline", baselines), ("initial", spec.optimizer.initial)):
        for name in names:
            cfile = load_controller(name)
            if cfile.name in seen:
                continue
            seen.add(cfile.name)
            x, how = evaluator.space.point_of(cfile)
            if log:
                log(f"{kind} {cfile.name}: " + (f"in the initial design, {how}" if x is not None
                                                 else f"not in the initial design: {how}"))
            if x is not None:
                design.append((x, f"{kind} {cfile.name}"))
    fill = latin_hypercube(spec.optimizer.n_initial_points - len(design), evaluator.space.bounds, seed)
    return design + [(x, "initial design") for x in fill]


def _bayes(spec, evaluator, executor, history, n_calls, seed, batch, clock, progress, log):
    from furuta_cosim.tuning import pareto
    from furuta_cosim.tuning.mobo import HypervolumeBO
    from furuta_cosim.tuning.optimizers import ConstrainedBO, batches

    settings, records = spec.optimizer, history.records
    if len(records) >= n_calls:
        return  # a finished run resumed: nothing to propose, no time to count
    started = time.perf_counter()
    design = initial_design(spec, evaluator, seed, log)[:n_calls]
    _replayed(records, [x for x, _ in design], 0)
    todo = design[len(records):]
    clock["optimizer"] += time.perf_counter() - started
    if todo:  # every point is known: all at once, whatever the workers
        _evaluate(executor, evaluator, history, [x for x, _ in todo], clock, [o for _, o in todo])
        _report(progress, history, n_calls, clock)
    names = [c.name for c in spec.objective.criteria]
    parego = spec.objective.type == "tradeoff" and front_search(spec) == "parego"
    kind = HypervolumeBO if spec.objective.type == "tradeoff" and not parego else ConstrainedBO
    optimizer = kind(evaluator.space.bounds, seed, xi=settings.xi, n_initial_points=len(design),
                     batch=batch, gp_restarts=settings.gp_restarts, region=settings.region,
                     screen=_stable(evaluator), **({"names": names} if kind is HypervolumeBO else {}))
    for number, first, count in batches(len(design), batch, n_calls):
        if first + count <= len(records):
            continue  # evaluated before a resume
        started = time.perf_counter()
        seen = records[:first]
        if parego:  # this batch's scalarization
            seen = pareto.scalarized(seen, names, seed, number)
        proposal = optimizer.propose(seen, len(design), number)
        points = proposal.points(count)
        xs, pending = [], []
        done = len(records) - first  # a resume in the middle of this batch: proposed again
        while True:  # each point goes out while the next one is computed
            started = started or time.perf_counter()
            x = next(points, None)
            clock["optimizer"] += time.perf_counter() - started
            started = None
            if x is None:
                break
            if len(xs) < done:
                _replayed(records[first:], [x], len(xs))
                xs.append(None)
                continue
            xs.append(x)
            pending.append(executor.submit(x))
        fresh = [x for x in xs if x is not None]
        _collect(executor, evaluator, history, fresh, pending, clock,
                 [proposal.origin] * len(fresh), proposal.surrogate)
        _report(progress, history, n_calls, clock)


def front_search(spec) -> str:
    """How ``bo`` searches a tradeoff: ``optimizer.front``, auto meaning ehvi for two criteria
    and parego for more."""
    if spec.optimizer.front != "auto":
        return spec.optimizer.front
    return "ehvi" if len(spec.objective.criteria) == 2 else "parego"


def _stable(evaluator):
    """The exact check of the loop's stability at a point (microseconds to a millisecond,
    against a co-simulation's tenths of a second): candidates that fail it are not proposed."""
    def screen(x) -> bool:
        try:
            return evaluator.loop_checks(evaluator.space.controller(x))[1] == 0
        except Exception:  # noqa: BLE001 - no controller there: not a candidate
            return False
    return screen


def _replayed(records, xs, offset: int) -> None:
    """A resumed run proposes again what the history holds: the same points, or the history
    is not this run's (a changed kernel library can do that; say so, change nothing)."""
    for k, x in enumerate(xs[:max(0, len(records) - offset)]):
        recorded = records[offset + k]
        if not np.allclose(recorded["x"], x, rtol=0, atol=1e-9 * (1 + np.max(np.abs(x)))):
            raise ConfigError([f"--resume: evaluation {recorded['index']} of the history is not "
                               "the point this run proposes there (were the spec's controllers "
                               "or a library changed?); nothing was changed"])


def _differential_evolution(spec, evaluator, executor, history, n_calls, seed, batch, clock,
                            progress):
    """scipy's differential evolution on the same space and budget; a resumed run replays the
    recorded evaluations (same seed, same proposals) and evaluates only what is new."""
    from scipy.optimize import differential_evolution

    replay = list(history.records)

    def evaluate_all(function, points):
        xs = [list(map(float, x)) for x in points]
        ys = []
        while xs and replay and np.allclose(xs[0], replay[0]["x"], rtol=0, atol=1e-12):
            ys.append(replay.pop(0)["objective"])
            xs.pop(0)
        remaining = n_calls - len(history.records)
        if xs and remaining <= 0:
            raise _Spent()
        ys += _evaluate(executor, evaluator, history, xs[:remaining], clock,
                        ["differential evolution"] * len(xs[:remaining]))
        _report(progress, history, n_calls, clock)
        if len(xs) > remaining:
            raise _Spent()
        return ys

    dimensions = len(evaluator.space.bounds)
    budget = spec.optimizer.n_calls  # the spec's, not --n-calls: a longer run extends a shorter one
    started, waited = time.perf_counter(), clock["evaluation"]
    try:
        differential_evolution(lambda x: 0.0, evaluator.space.bounds, seed=seed, maxiter=10**9,
                               popsize=max(5, min(15, budget // (4 * dimensions) or 1)),
                               polish=False, updating="deferred", workers=evaluate_all, tol=0,
                               init="latinhypercube")
    except _Spent:
        pass
    clock["optimizer"] += time.perf_counter() - started - (clock["evaluation"] - waited)


def _variant_spread(evaluator, document) -> dict:
    """Per controller (the tuned one, each baseline): its objective on each plant variant
    alone, the worst of them and their spread."""
    found = {}
    candidates = ([("tuned", document["best"]["metrics"])] if document["best"] else []) + [
        (name, b.get("metrics") or {}) for name, b in document["baselines"].items()]
    for name, metrics in candidates:
        scores = evaluator.by_variant(metrics)
        known = [v for v in scores if v is not None]
        found[name] = {"scores": scores,
                       "worst": max(known) if len(known) == len(scores) else None,
                       "best": min(known) if known else None}
    return found


def _finish(spec, folder, evaluator, records, n_calls, method, seed, clock) -> dict:
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.tuning.saved import save_scored

    feasible = [r for r in records if r["feasible"]]
    best = min(feasible, key=lambda r: (r["objective"], r["index"])) if feasible else None
    baselines = {}
    for name in spec.baselines:
        cfile = load_controller(name)
        outcome = evaluator.score(cfile.controller)
        baselines[cfile.name] = json_safe({"objective": outcome.objective,
                                            "feasible": outcome.feasible,
                                            **({"criteria": outcome.criteria}
                                               if outcome.criteria is not None else {}),
                                            "constraints": outcome.constraints,
                                            "metrics": outcome.metrics})
    failures = sum(1 for r in records if r["error"])
    warnings = evaluator.vacuous() if spec.objective.type != "spectral" else []
    document = {"spec": spec.name, "method": method, "seed": seed, "n_calls": n_calls,
                "evaluations": len(records), "feasible": len(feasible), "failed": failures,
                "objective": spec.objective.type, "optimizer_seconds": clock["optimizer"],
                "evaluation_seconds": clock["evaluation"], "best": None, "baselines": baselines,
                "warnings": warnings}
    if method == "bo" and spec.objective.type == "tradeoff":
        document["search"] = {"ehvi": "expected hypervolume improvement",
                              "parego": "ParEGO scalarizations"}[front_search(spec)]
    if best is not None:
        prefilter = save_scored(evaluator, best, folder / "best.yaml", f"{spec.name}-best",
                                f"best of tuning {spec.name} ({method}, seed {seed})", method, seed)
        document["best"] = {"index": best["index"], "objective": best["objective"],
                            "origin": best.get("origin") or "", "parameters": best["parameters"],
                            "metrics": best["metrics"], "file": "best.yaml",
                            "prefilter": prefilter}
    if len(spec.variants) > 1 and spec.objective.type == "scenarios":
        document["variants"] = _variant_spread(evaluator, document)
    if spec.objective.type == "tradeoff":
        from furuta_cosim.tuning.front import write_front

        document["front"] = write_front(evaluator, folder, records, baselines, method, seed)
    levels = {name: b["objective"] for name, b in baselines.items() if b["feasible"]}
    plot_convergence(records, folder / "convergence", levels)
    write_text(folder / "summary.json", dumps(document, indent=2) + "\n")
    write_text(folder / "summary.md", summary_text(spec, document))
    return document


def summary_text(spec: TuningSpec, document: dict) -> str:
    """summary.md: the run's summary document in words (what ``tune`` prints)."""
    lines = [f"# Tuning {spec.name}", "", spec.description, "",
             f"- method: {document['method']}" + (f" ({document['search']})" if document.get("search") else "")
             + f", seed {document['seed']}, {document['evaluations']} "
             f"evaluations, {document['feasible']} feasible, {document['failed']} failed",
             f"- objective: {document['objective']}" + _described(spec.objective),
             f"- time: optimizer {document['optimizer_seconds']:.1f} s, waiting for evaluations "
             f"{document['evaluation_seconds']:.1f} s", ""]
    if spec.plant is not None:
        lines += [f"On plant {spec.plant}: the controller is designed on its linearization."]
        lines += [f"- {note}." for note in spec.notes] + [""]
    lines += [f"Warning: {line}." for line in document.get("warnings") or []]
    lines += [""] if document.get("warnings") else []
    best = document["best"]
    if best:
        origin, F = best.get("origin") or "the search", best.get("prefilter") or {}
        lines.append(f"Best: objective {best['objective']:.6g} at evaluation {best['index']}, "
                     f"from {origin} (best.yaml" + (f", prefilter F = {F['F']:.6g} for {F['output']}"
                                                    if F else "") + ").")
    else:
        lines.append("No feasible controller was found.")
    if document.get("variants"):
        lines.append(f"Over the {len(spec.variants)} plant variants, each scored alone (the "
                     "objective on that variant's scenarios):")
        for name, v in document["variants"].items():
            worst = "a run without a finite value" if v["worst"] is None else f"{v['worst']:.6g}"
            spread = "" if v["best"] is None else f", best {v['best']:.6g}"
            lines.append(f"- {name}: worst {worst}{spread}")
        lines.append("")
    if document.get("front") is not None:
        from furuta_cosim.tuning.front import summary_lines

        lines += summary_lines(spec, document["front"]) + [""]
    for name, baseline in document["baselines"].items():
        verdict = f"{baseline['objective']:.6g}" if baseline["feasible"] else \
            f"infeasible (score {baseline['objective']:.6g})"
        better = ""
        if best and baseline["feasible"]:
            better = (" - the tuned controller scores better" if best["objective"] < baseline["objective"]
                      else f" - the tuned controller does NOT beat it (worse by "
                           f"{(best['objective'] / baseline['objective'] - 1) * 100:.1f} %)")
        lines.append(f"- {name}, scored alike: {verdict}{better}")
        if best and baseline["feasible"] and best.get("metrics") and baseline.get("metrics") \
                and spec.objective.type == "scenarios":
            lines += _run_by_run(spec, best["metrics"], baseline["metrics"], name)
    if best and best.get("metrics"):
        lines += ["", "Metric by metric, on every scenario and plant variant:", ""]
        keys = list(dict.fromkeys([t.metric for t in spec.objective.all_terms]
                                  + [m for m, _ in spec.constraints.no_worse_than]
                                  + ["error.ISE", "u.rms", "u.peak_abs"]
                                  + [f"{name}.max_abs" for name, _ in spec.constraints.max_abs]))
        names = [n for n, b in document["baselines"].items() if b.get("metrics")]
        lines.append("| run | metric | tuned | " + " | ".join(names) + " | tuned / " +
                     (names[0] if names else "-") + " |")
        lines.append("| --- " * (4 + len(names)) + "|")
        same = []
        for label, values in best["metrics"].items():
            for key in keys:
                value = values.get(key)
                others = [document["baselines"][n]["metrics"].get(label, {}).get(key) for n in names]
                if others and all(other == value for other in others):
                    same.append(f"{label} {key}")  # equal everywhere: no information in a row
                    continue
                ratio = (f"{value / others[0]:.3f}" if names and value is not None and others[0]
                         else "")
                shown = [_cell(v) for v in [value] + others]
                lines.append(f"| {label} | {key} | " + " | ".join(shown) + f" | {ratio} |")
        if same:
            lines += ["", "The same for the tuned controller and every baseline (left out of the "
                          "table): " + ", ".join(same) + "."]
    return "\n".join(lines) + "\n"


def _described(objective) -> str:
    """The objective in words, after its type."""
    if objective.type == "spectral":
        return (" (the paper's max |Re eig(Abar)| as stated: it measures the fastest mode, not the "
                "slowest, so it rewards poles near the imaginary axis; docs/pages/paper-readings.md §3)")

    def terms(criterion) -> str:
        return " + ".join(f"{t.weight:g} {t.metric}" + (f" / {Path(t.relative_to).stem}'s"
                                                        if t.relative_to else "")
                          for t in criterion.terms) + f", {criterion.aggregate} over scenarios and plant variants"

    if objective.type == "scenarios":
        return " = " + terms(objective.criteria[0])
    return (" of " + "; ".join(f"{c.name} = {terms(c)}" for c in objective.criteria)
            + " (each minimized; best.yaml is the point of the lowest mean of the criteria)")


def _run_by_run(spec: TuningSpec, tuned: dict, baseline: dict, name: str) -> list[str]:
    """Where the tuned controller is lower and where higher than a baseline, run by run, in the
    objective's own metrics: a lower mean can hide runs on which it is worse."""
    lower, higher = [], []
    for label, values in tuned.items():
        changes = []
        for term in spec.objective.terms:
            ours, theirs = values.get(term.metric), baseline.get(label, {}).get(term.metric)
            if ours is not None and theirs:
                changes.append((term.metric, (ours / theirs - 1) * 100))
        if changes:
            text = f"{label} (" + ", ".join(f"{metric} {change:+.1f} %" for metric, change in changes) + ")"
            (lower if all(change < 0 for _, change in changes) else higher).append(text)
    return [f"  - lower than {name} in every objective metric on: " + ("; ".join(lower) or "no run"),
            "  - not lower on: " + ("; ".join(higher) or "no run")]


def _cell(value) -> str:
    return "never" if value is None else format(value, ".4g")
