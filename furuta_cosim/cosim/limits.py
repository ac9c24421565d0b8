"""Bounds on metrics that only grow along a run, watched while it runs.

``error.ISE``, ``error.IAE``, ``error.ITAE`` and ``u.energy`` are sums of non-negative terms,
and ``u.peak_abs`` and ``<output>.max_abs`` are maxima: their value over the samples run so
far is a lower bound of their value over the whole run. A run whose running value is past its
bound has failed whatever comes after, so :func:`~furuta_cosim.cosim.evaluation.evaluate`
stops it there (``RunResult.stopped`` says where and why) instead of simulating the rest.

The running values are sums over the same samples, the same terms and the same ``dt`` as
:func:`furuta_cosim.metrics.compute`, so a stopped run's value is the full run's up to the
samples it did not run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# metrics of e = r - y that are sums of non-negative terms, and of the applied input
SUMS = ("error.ISE", "error.IAE", "error.ITAE", "u.energy")
# the running values are checked after every this many seconds of plant time
EVERY = 0.5


def monotone(metric: str, outputs) -> bool:
    """Whether ``metric`` only grows along a run, and can be watched (``outputs``: the
    prepared scenario's plant outputs, whose ``max_abs`` can)."""
    if metric in SUMS or metric == "u.peak_abs":
        return True
    signal, _, name = metric.rpartition(".")
    return name == "max_abs" and signal in outputs


@dataclass
class Watch:
    """The running values of the bounded metrics of one run (``bounds``: metric -> value past
    which the run has failed), updated a chunk of samples at a time."""

    bounds: dict
    signals: list          # the prepared scenario's signal columns, in order
    tracked: str
    dt: float

    def __post_init__(self):
        self.values = {metric: 0.0 for metric in self.bounds}
        self._y = self.signals.index(self.tracked)

    def update(self, t, r, rows, us) -> str | None:
        """Add samples (times, references, output rows, applied inputs) to the running values;
        the first metric past its bound, or None."""
        if not len(us):
            return None
        table = np.asarray(rows, dtype=float).reshape(len(us), len(self.signals))
        u = np.asarray(us, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            e = np.asarray(r, dtype=float) - table[:, self._y]
            for metric in self.bounds:
                self.values[metric] = self._grow(metric, self.values[metric], t, e, u, table)
        for metric, bound in self.bounds.items():
            if self.values[metric] > bound:
                return metric
        return None

    def _grow(self, metric, value, t, e, u, table) -> float:
        if metric == "error.ISE":
            return value + float(np.sum(e ** 2)) * self.dt
        if metric == "error.IAE":
            return value + float(np.sum(np.abs(e))) * self.dt
        if metric == "error.ITAE":
            return value + float(np.sum(np.asarray(t) * np.abs(e))) * self.dt
        if metric == "u.energy":
            return value + float(np.sum(u ** 2)) * self.dt
        column = u if metric == "u.peak_abs" else table[:, self.signals.index(metric.rpartition(".")[0])]
        peak = float(np.max(np.abs(column)))
        # NaN is left to the run's own check of its outputs (a failure, not a bound)
        return value if math.isnan(peak) else max(value, peak)
