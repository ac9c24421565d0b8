"""Bounds on metrics that only grow along a run, watched while it runs.

A metric registered as growing (furuta_cosim/metrics.py: a :class:`~furuta_cosim.metrics.Sum`
of non-negative terms or a :class:`~furuta_cosim.metrics.Peak`) has a value over the samples run
so far that is a lower bound of its value over the whole run. A run whose running value is past its
bound has failed whatever comes after, so :func:`~furuta_cosim.cosim.evaluation.evaluate`
stops it there (``RunResult.stopped`` says where and why) instead of simulating the rest.

The running values are the metric's own running form (the same terms and the same ``dt`` as
:func:`furuta_cosim.metrics.compute`: one implementation), so a stopped run's value is the full
run's up to the samples it did not run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_cosim.metrics import Samples, entry

# the running values are checked after every this many seconds of plant time
EVERY = 0.5


def monotone(metric: str, outputs) -> bool:
    """Whether ``metric`` only grows along a run (its registered metric ``grows``) and can be
    watched: one of the input's or the error's, or of a plant output (``outputs``: the
    prepared scenario's, whose samples the loop hands over)."""
    found = entry(metric)
    signal = metric.rpartition(".")[0]
    return bool(found and found.grows and (signal in ("u", "error") or (found.of == "signal" and signal in outputs)))


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
        self._metrics = {metric: entry(metric) for metric in self.bounds}

    def update(self, t, r, rows, us) -> str | None:
        """Add samples (times, references, output rows, applied inputs) to the running values;
        the first metric past its bound, or None."""
        if not len(us):
            return None
        table = np.asarray(rows, dtype=float).reshape(len(us), len(self.signals))
        u = np.asarray(us, dtype=float)
        t = np.asarray(t, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            e = np.asarray(r, dtype=float) - table[:, self._y]
            for metric, found in self._metrics.items():
                signal = metric.rpartition(".")[0]
                x = e if signal == "error" else u if signal == "u" else table[:, self.signals.index(signal)]
                self.values[metric] = found.running(self.values[metric], Samples(t, x, self.dt))
        for metric, bound in self.bounds.items():
            if self.values[metric] > bound:
                return metric
        return None
