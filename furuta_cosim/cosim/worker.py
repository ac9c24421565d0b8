"""Evaluation in worker processes (a process pool, a Dask worker).

A worker keeps one open plant session per FMU and one copy of each prepared scenario it has
received, and evaluates candidate after candidate on them::

    with ProcessPoolExecutor() as pool:
        results = list(pool.map(evaluate_here, [prepared] * 2, ["lqr-paper", "bo-paper"]))

Sessions are closed when the worker process exits.
"""

from __future__ import annotations

import atexit
from pathlib import Path

from furuta_cosim.cosim.evaluation import evaluate
from furuta_cosim.cosim.master import Prepared
from furuta_cosim.cosim.result import RunResult

# one BLAS thread per worker: several threads on busy cores slow everything down
SINGLE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

_SESSIONS: dict = {}
_PREPARED: dict[str, Prepared] = {}


def start_pool(workers: int):
    """A pool of ``workers`` local processes, each with one BLAS thread."""
    import os
    from concurrent.futures import ProcessPoolExecutor

    saved = {k: os.environ.get(k) for k in SINGLE_THREAD}
    os.environ.update(SINGLE_THREAD)  # inherited by the workers
    try:
        return ProcessPoolExecutor(workers)
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def session_for(prepared: Prepared):
    """This process's open session on the prepared scenario's FMU (opened on first use).

    An FMU that is not at its path here (another machine) is built again from the plant
    file when the scenario has one."""
    from furuta_cosim.fmu.session import PlantSession

    fmu = Path(prepared.fmu)
    if not fmu.is_file() and prepared.plant is not None:
        from furuta_cosim.fmu.exporter import build_fmu

        fmu = build_fmu(prepared.plant)
    key = str(fmu)
    if key not in _SESSIONS:
        _SESSIONS[key] = PlantSession.open(fmu)
    return _SESSIONS[key]


def evaluate_here(prepared: Prepared, controller) -> RunResult:
    """:func:`~furuta_cosim.cosim.evaluation.evaluate` on this process's session, keeping the
    first copy of each prepared scenario (so its estimator is compiled once)."""
    prepared = _PREPARED.setdefault(prepared.key, prepared)
    return evaluate(prepared, session_for(prepared), controller)


@atexit.register
def close_all() -> None:
    """Close every session this process opened."""
    while _SESSIONS:
        _, session = _SESSIONS.popitem()
        session.close()
    _PREPARED.clear()
