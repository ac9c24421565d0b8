"""A tuning run: the ask/evaluate/record loop over a spec, written to a run directory.

    run-dir/
      spec.yaml        a copy of the spec
      run.json         the method, seed and plant it was started with (checked by --resume)
      history.jsonl    one line per evaluation, appended and flushed to disk (fsync) at once
      best.yaml        the best feasible controller, a controller file simulate/analyze accept
      convergence.png  (and .svg) best objective against evaluations
      summary.json     best, baselines scored alike, counts; summary.md the same in words

Candidates come in synchronous batches of ``optimizer.batch`` from the spec's method
(tuning/methods.py: ``bo``, ``random``, ``de``), each point of a batch sent to an executor
(tuning/executors.py) as soon as it is known. Workers change only the speed: a history
depends on the spec, the seed and the batch size, and a resumed run goes on exactly as the
uninterrupted one would have. The jobs around it have modules of their own: the history file
(tuning/history.py), the run directory's lock, identity and clocks (tuning/rundir.py), and
the summary (tuning/summary.py).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable

from furuta_cosim.errors import ConfigError
from furuta_cosim.files import folder as make_folder, output_folder, write_text
from furuta_cosim.tuning.history import History
from furuta_cosim.tuning.methods import METHODS, Run, method_for
from furuta_cosim.tuning.objective import Evaluator
from furuta_cosim.tuning.rundir import Clock, executor_for, identity_of, locked, recorded, same_run
from furuta_cosim.tuning.spec import TuningSpec
from furuta_cosim.tuning.summary import finish, summary_text

__all__ = ["tune", "summary_text"]


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
        run goes on until it holds exactly ``n_calls`` evaluations (default: the budget the
        run was started with). Refused when the spec, method, seed, plant file or plant
        variants (the fit's content, its samples and seed) differ from the run's.
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
    from threadpoolctl import threadpool_limits

    from furuta_cosim.cosim.worker import check_workers
    from furuta_cosim.tuning.spec import MAX_CALLS, MAX_SEED

    method = method or spec.optimizer.method
    if n_calls is None and resume:  # the budget the run was started with, not the spec's
        started = recorded(output_folder(run_dir)).get("n_calls")
        if isinstance(started, int) and not isinstance(started, bool) and 1 <= started <= MAX_CALLS:
            n_calls = started
    n_calls = spec.optimizer.n_calls if n_calls is None else n_calls
    seed = spec.optimizer.seed if seed is None else seed
    # every option is checked before anything is made: a refused option leaves no folder
    if method not in METHODS:
        raise ConfigError([f"method: expected one of {', '.join(METHODS)}, got {method!r}"])
    if isinstance(n_calls, bool) or not isinstance(n_calls, int) or not 1 <= n_calls <= MAX_CALLS:
        raise ConfigError([f"n_calls: expected a whole number from 1 to {MAX_CALLS}, got {n_calls}"])
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError([f"seed: expected a whole number from 0 to 2^32 - 1, got {seed}"])
    refusal = METHODS[method].refusal(spec)
    if refusal:
        raise ConfigError([f"method: {refusal}"])
    if METHODS[method].rig_only:
        raise ConfigError([f"method: {method} ({METHODS[method].description}) tunes on a rig: give a "
                           "`board`, or an external rig (`evaluator`) with the folder its trials are exchanged in"])
    check_workers(workers)
    if dask is not None:
        from furuta_cosim.tuning.executors import check_address

        check_address(dask)
    folder = output_folder(run_dir)
    if resume and not (folder / "history.jsonl").is_file():
        raise ConfigError([f"resume: {folder} holds no tuning run (no history.jsonl)"])
    if not resume and (folder / "history.jsonl").exists():
        raise ConfigError([f"run_dir {folder}: holds a tuning run already; choose another folder "
                           "or `resume` it"])
    evaluator = Evaluator(spec)
    if spec.objective.type != "spectral":
        evaluator.runs()  # every scenario and variant prepared (and checked) before any file
        evaluator.check_references()
        if log:
            for line in evaluator.vacuous():
                log(f"warning: {spec.source}: {line}")
    identity = identity_of(spec, method, seed, n_calls)
    if resume:
        same_run(folder, identity)
    executor = executor_for(spec, evaluator, workers, dask)  # a Dask scheduler is reached here
    lock = history = None
    try:
        make_folder(folder)
        lock = locked(folder)
        if not resume and (folder / "history.jsonl").exists():  # one that finished meanwhile
            raise ConfigError([f"run_dir {folder}: holds a tuning run already; choose another "
                               "folder or `resume` it"])
        if not resume:
            if spec.path:
                write_text(folder / "spec.yaml", identity["spec"])
            write_text(folder / "run.json", json.dumps({k: v for k, v in identity.items() if k != "spec"}) + "\n")
        history = History(folder / "history.jsonl", resume, evaluator.space.bounds, log)
        if log:
            log(f"tuning {spec.name} into {folder}, {executor.where}")
        if len(history.records) > n_calls:
            raise ConfigError([f"resume: the run holds {len(history.records)} evaluations, "
                               f"more than the {n_calls} of `n_calls`"])
        clock = Clock(folder / "run.json")
        clock.identity["n_calls"] = n_calls  # a resume that extends the run records its new budget
        run = Run(spec, folder, evaluator, executor, history, n_calls, seed, clock, progress, log)
        # one BLAS thread for the optimizer, serial too: with workers they use the other
        # cores; alone, at a GP's sizes (150 points), a second thread made each iteration
        # twice as slow (tools/bench_tune.py, paper-spectral), and splitting BLAS reductions
        # over threads rounds differently, so a seed's history would depend on the core count
        with threadpool_limits(1):
            method_for(method).search(run)
        return finish(spec, folder, evaluator, history.records, n_calls, method, seed, run.clock)
    finally:
        executor.close()
        if history is not None:
            history.close()
        if lock is not None:
            os.close(lock)
