"""Where candidates are evaluated: in this process, in local worker processes, or on Dask.

Every executor takes the candidates of a batch one by one (``submit``: a worker starts on it
at once) and hands back one outcome per candidate, in order (``gather``); ``map`` does both. A worker keeps one :class:`~furuta_cosim.tuning.objective.Evaluator` per spec (its
prepared scenarios and one FMU session per plant variant) for its whole life. A candidate
whose evaluation raises, or whose worker dies, gets a failed outcome with the error; the run
goes on (a dead local worker pool is started again).
"""

from __future__ import annotations

import os
import traceback

from furuta_cosim.cosim.worker import check_address, connect_dask, start_pool
from furuta_cosim.tuning.objective import Evaluator, Outcome
from furuta_cosim.tuning.spec import TuningSpec

_EVALUATORS: dict[str, Evaluator] = {}


def dask_wait() -> float:
    """Seconds a Dask run waits with no worker before it stops (resumable):
    ``FURUTA_COSIM_DASK_WAIT``, default 60."""
    try:
        value = float(os.environ.get("FURUTA_COSIM_DASK_WAIT", "60"))
    except ValueError:
        value = 60.0
    return value if value > 0 else 60.0


def failed(spec: TuningSpec, error: str) -> Outcome:
    return Outcome(spec.constraints.penalty * 2, False, {}, {}, error)


def evaluate_in_worker(spec: TuningSpec, x, order=None) -> Outcome:
    """The worker's side: this process's evaluator for the spec, built on first use."""
    key = repr(spec)
    evaluator = _EVALUATORS.get(key)
    if evaluator is None:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
        evaluator = _EVALUATORS[key] = Evaluator(spec)
    return evaluator(x, order)


class _Executor:
    def map(self, xs, order=None) -> list[Outcome]:
        return self.gather([self.submit(x, order) for x in xs])


class Serial(_Executor):
    """In this process, one after the other (when gathered)."""

    name = "serial"

    def __init__(self, spec: TuningSpec, evaluator: Evaluator):
        self.spec, self.evaluator = spec, evaluator
        self.where = "in this process"

    def submit(self, x, order=None):
        return x, order

    def gather(self, pending) -> list[Outcome]:
        outcomes = []
        for x, order in pending:
            try:
                outcomes.append(self.evaluator(x, order))
            except Exception as error:  # noqa: BLE001 (a candidate's fault is recorded, not fatal)
                outcomes.append(failed(self.spec, _describe(error)))
        return outcomes

    def close(self) -> None:
        pass


class Processes(_Executor):
    """Local worker processes (default: one per core)."""

    name = "processes"

    def __init__(self, spec: TuningSpec, workers: int):
        self.spec, self.workers = spec, workers
        self.where = f"{workers} worker processes"
        self._pool = None

    def _start(self):
        self._pool = start_pool(self.workers)

    def submit(self, x, order=None):
        from concurrent.futures.process import BrokenProcessPool

        if self._pool is None:
            self._start()
        try:
            return x, order, self._pool.submit(evaluate_in_worker, self.spec, x, order)
        except BrokenProcessPool:  # a worker died on an earlier point of the batch: run it later
            return x, order, None

    def gather(self, pending) -> list[Outcome]:
        from concurrent.futures.process import BrokenProcessPool

        outcomes, broken = [], []
        for k, (_, _, future) in enumerate(pending):
            try:
                if future is None:
                    raise BrokenProcessPool("not started: the pool was broken")
                outcomes.append(future.result())
            except BrokenProcessPool:
                broken.append(k)
                outcomes.append(None)
            except Exception as error:  # noqa: BLE001
                outcomes.append(failed(self.spec, _describe(error)))
        if broken:
            # which candidate killed its worker is unknown: each one that was in flight runs
            # again alone, in a fresh pool, so only the culprit fails
            self._restart()
            for k in broken:
                x, order, _ = pending[k]
                try:
                    outcomes[k] = self._pool.submit(evaluate_in_worker, self.spec, x, order).result()
                except BrokenProcessPool:
                    outcomes[k] = failed(self.spec, "the worker process died during this evaluation")
                    self._restart()
                except Exception as error:  # noqa: BLE001
                    outcomes[k] = failed(self.spec, _describe(error))
        return outcomes

    def _restart(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._start()

    def close(self) -> None:
        if self._pool is not None:
            from furuta_cosim.cosim.worker import stop_pool

            stop_pool(self._pool)
            self._pool = None


class Dask(_Executor):
    """A Dask cluster: an existing scheduler's address, or ``local`` for a LocalCluster."""

    name = "dask"

    def __init__(self, spec: TuningSpec, address: str, workers: int):
        self.spec, self.address = spec, check_address(address)
        self.where = f"on Dask ({address})"
        self._client, self._cluster = connect_dask(address, workers)

    def submit(self, x, order=None):
        return self._client.submit(evaluate_in_worker, self.spec, list(x), order, pure=False)

    def gather(self, pending) -> list[Outcome]:
        return [self._result(future) for future in pending]

    def _result(self, future) -> Outcome:
        """One outcome; a lost scheduler, or no worker for dask_wait() seconds, stops the run
        (RunStopped: the history so far is kept) instead of failing points or waiting forever."""
        from concurrent.futures import CancelledError
        from concurrent.futures import TimeoutError as Pending

        from furuta_cosim.errors import RunStopped

        idle, poll = 0.0, min(2.0, dask_wait())
        while True:
            try:
                return future.result(timeout=poll)
            except Pending:
                pass
            except CancelledError:
                raise RunStopped(f"the Dask scheduler {self.address} was lost; what was evaluated "
                                 "is kept: `resume` continues the run") from None
            except Exception as error:  # noqa: BLE001 (KilledWorker included: the point failed)
                if self._client.status not in ("running", "connecting", "newly-created"):
                    raise RunStopped(f"the Dask scheduler {self.address} was lost ({error}); "
                                     "`resume` continues the run") from None
                return failed(self.spec, _describe(error))
            if self._client.status != "running":
                idle += poll
                reason = f"the Dask scheduler {self.address} does not answer"
            else:
                try:
                    workers = len(self._client.scheduler_info().get("workers", {}))
                except Exception:  # noqa: BLE001
                    workers = 0
                idle = idle + poll if workers == 0 else 0.0
                reason = f"the Dask cluster {self.address} has no worker"
            if idle >= dask_wait():
                raise RunStopped(f"{reason} (waited {idle:.0f} s, FURUTA_COSIM_DASK_WAIT); what "
                                 "was evaluated is kept: `resume` continues the run")

    def close(self) -> None:
        try:
            self._client.close(timeout=10)
            if self._cluster is not None:
                self._cluster.close(timeout=10)
        except Exception:  # noqa: BLE001 (a lost scheduler: nothing left to close cleanly)
            pass


def _describe(error: BaseException) -> str:
    last = traceback.extract_tb(error.__traceback__)[-1:] if error.__traceback__ else []
    where = f" ({last[0].filename}:{last[0].lineno})" if last else ""
    return f"{type(error).__name__}: {error}{where}"
