"""Evaluation in worker processes (a process pool, a Dask worker).

A worker keeps one open plant session per FMU and one copy of each prepared scenario it has
received, and evaluates candidate after candidate on them::

    with ProcessPoolExecutor() as pool:
        results = list(pool.map(evaluate_here, [prepared] * 2, ["lqr-paper", "bo-paper"]))

Sessions are closed when the worker process exits.
"""

from __future__ import annotations

import atexit
import os
import re
import signal
from pathlib import Path

from furuta_cosim.cosim.evaluation import evaluate
from furuta_cosim.cosim.master import Prepared
from furuta_cosim.cosim.result import RunResult

# one BLAS thread per worker: several threads on busy cores slow everything down
SINGLE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

_SESSIONS: dict = {}
_PREPARED: dict[str, Prepared] = {}


def default_workers() -> int:
    """One worker per core: the default of every command that runs workers."""
    return os.cpu_count() or 1


def max_workers() -> int:
    """At most four worker processes per core: more only cost memory and start-up."""
    return 4 * default_workers()


def check_workers(workers: int, flag: str = "workers") -> int:
    """``workers`` when it is a usable count of worker processes; ConfigError otherwise."""
    from furuta_cosim.errors import ConfigError

    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= max_workers():
        raise ConfigError([f"{flag}: expected a whole number from 1 to {max_workers()} (four per "
                           f"core), got {workers}"])
    return workers


def _watch_parent(parent: int) -> None:
    """In a worker: end this process when the one that started it is gone (killed with -9,
    say), instead of living on as an orphan."""
    import threading
    import time

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


def _start_worker(parent: int, setup, setup_args) -> None:
    import multiprocessing.util
    import signal

    # a signal is the main process's to decide on: a terminal's Ctrl-C and a scheduler's SIGTERM
    # reach the whole group, and a worker that died of one inside the pool's queue lock (the
    # handler it inherited at the fork) left the main process waiting for ever
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _HELD)   # blocked from the fork until now (start_pool)
    _watch_parent(parent)
    # a pool's worker ends by os._exit, without atexit handlers; multiprocessing's own exit
    # finalizers do run there. They remove the extracted FMUs and nothing more: unloading a
    # library (dlclose) in a forked worker at exit can deadlock on a lock the fork copied
    multiprocessing.util.Finalize(None, _remove_extracted, exitpriority=10)
    if setup is not None:
        setup(*setup_args)


def _ready() -> None:
    """A task that does nothing: the first one, which makes the pool start its workers."""


_HELD = {signal.SIGINT, signal.SIGTERM}


def start_pool(workers: int, setup=None, setup_args: tuple = ()):
    """A pool of ``workers`` local processes, each with one BLAS thread, each ending when
    this process ends; ``setup(*setup_args)`` runs first in each (what every task shares, sent
    once per worker).

    The workers are started here, with SIGINT and SIGTERM blocked from the fork until each has
    set them to be ignored: a group's Ctrl-C that landed in that window killed the worker with
    the handler it inherited (a BrokenProcessPool traceback instead of the interrupt, 1 run in
    20 of tools/bench_signals.py). A signal held back meanwhile reaches this process as the
    mask is lifted, and the pool is ended before it goes on."""
    from concurrent.futures import ProcessPoolExecutor

    saved = {k: os.environ.get(k) for k in SINGLE_THREAD}
    os.environ.update(SINGLE_THREAD)  # inherited by the workers, forked below
    try:
        pool = ProcessPoolExecutor(workers, initializer=_start_worker, initargs=(os.getpid(), setup, setup_args))
        try:
            previous = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
            try:
                pool.submit(_ready).result()   # every worker forked now (3.11: all at the first task)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        except BaseException:
            stop_pool(pool)
            raise
        return pool
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


_STOPPED: list[tuple[int, int, float]] = []


def stop_pool(pool, grace: float = 5.0) -> int:
    """End ``pool`` within ``grace`` seconds: its pending tasks cancelled, its workers given
    the grace to finish the task in hand, then killed (a worker blocked writing a result that
    nobody will read never ends by itself). Returns how many had to be killed. A pool ended
    while an exception (an interrupt, a failure) is on its way out is remembered for
    :func:`stopped_pools`, so that the command can say what it ended."""
    import sys
    import time
    from multiprocessing.connection import wait

    stopping = sys.exc_info()[0] is not None
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)   # shutdown forgets it
    start = time.monotonic()
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = start + grace
    # a worker has ended when its sentinel is ready: asked by poll() instead, a worker that
    # something else in the process reaped reads as alive for ever (waitpid fails, poll says None)
    running = {process.sentinel: process for process in processes}
    while running and deadline > time.monotonic():
        for sentinel in wait(list(running), deadline - time.monotonic()):
            running.pop(sentinel)
    for process in running.values():
        process.kill()
        process.join(1.0)
    killed = len(running)
    # its manager thread ends once it sees the workers gone; a later fork while it still holds
    # a queue's lock would hand that lock, held, to the next pool's worker (which then hangs)
    if manager is not None:
        manager.join(max(1.0, deadline - time.monotonic()))
    if stopping and processes:
        _STOPPED.append((len(processes), killed, time.monotonic() - start))
    return killed


def stopped_pools() -> list[str]:
    """One line per pool ended by an interrupt or a failure since the last call: how many
    worker processes, how long they took, how many had to be killed."""
    lines = []
    for count, killed, seconds in _STOPPED:
        how = (f"{killed} killed after the {seconds:.1f} s grace" if killed
               else "each finished or dropped its task")
        lines.append(f"ended the {count} worker process{'es' if count != 1 else ''} "
                     f"in {seconds:.2f} s ({how})")
    _STOPPED.clear()
    return lines


_ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx)://)?[A-Za-z0-9.\-\[\]:]+:\d{1,5}")


def check_address(address: str) -> str:
    """``local`` or a Dask scheduler address (``tcp://host:8786``, ``host:8786``)."""
    from furuta_cosim.errors import ConfigError

    if address != "local" and not _ADDRESS.fullmatch(str(address)):
        raise ConfigError([f"dask: expected 'local' or a scheduler address such as "
                           f"tcp://host:8786, got {address!r}"])
    return address


def connect_dask(address: str, workers: int):
    """(client, cluster or None): a LocalCluster of ``workers`` one-thread processes for
    ``local``, else a client of the scheduler at ``address``; one line when neither can be had."""
    from furuta_cosim.errors import ConfigError

    check_address(address)
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError(["dask: Dask is not installed (pip install -e '.[dask]')"]) from None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, env=SINGLE_THREAD)
        return Client(cluster), cluster
    try:
        return Client(address, timeout="30s"), None
    except (OSError, TimeoutError) as error:
        raise ConfigError([f"dask {address}: no Dask scheduler answers there ({error})"]) from None


def session_on(fmu: str | Path):
    """This process's open session on ``fmu``, opened on first use and kept; a new one (on a
    new copy of the FMU) after a fatal error. A pool's worker removes the extracted copies
    when it ends, whichever job opened them (a tuning's or a fit's)."""
    from furuta_cosim.fmu.session import PlantSession

    key = str(fmu)
    session = _SESSIONS.get(key)
    if session is not None and not session.usable:  # the FMU failed fatally: a new instance
        session.close()
        session = None
    if session is None:
        session = _SESSIONS[key] = PlantSession.open(fmu)
    return session


def close_session(fmu: str | Path) -> None:
    """Close this process's session on ``fmu``, if it has one (its extracted copy removed)."""
    session = _SESSIONS.pop(str(fmu), None)
    if session is not None:
        session.close()


def session_for(prepared: Prepared):
    """This process's open session on the prepared scenario's FMU (opened on first use).

    An FMU that is not at its path here (another machine) is built again from the plant
    file when the scenario has one."""
    fmu = Path(prepared.fmu)
    if not fmu.is_file() and prepared.plant is not None:
        from furuta_cosim.fmu.exporter import build_fmu

        fmu = build_fmu(prepared.plant)
    return session_on(fmu)


def evaluate_here(prepared: Prepared, controller) -> RunResult:
    """:func:`~furuta_cosim.cosim.evaluation.evaluate` on this process's session, keeping the
    first copy of each prepared scenario (so its estimator is compiled once).

    Parameters
    ----------
    prepared : Prepared
        The scenario; a copy with the same key seen before in this process is used instead.
    controller : Compiled, ControllerFile, GeneralizedController, str or path
        Anything :func:`~furuta_cosim.cosim.evaluation.compile_controller` takes.

    Returns
    -------
    RunResult
    """
    prepared = _PREPARED.setdefault(prepared.key, prepared)
    return evaluate(prepared, session_for(prepared), controller)


def _remove_extracted() -> None:
    """The extracted FMUs of this process's sessions, removed; the libraries stay loaded
    until the process is gone a moment later."""
    import shutil

    for session in list(_SESSIONS.values()):
        shutil.rmtree(session.binary.directory, ignore_errors=True)


@atexit.register
def close_all() -> None:
    """Close every session this process opened."""
    while _SESSIONS:
        _, session = _SESSIONS.popitem()
        session.close()
    _PREPARED.clear()
