"""A run's time series: t, the reference, the applied input and every recorded signal."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from furuta_cosim.files import atomic


@dataclass
class Trace:
    """Samples at the control instants t[k]: the values read before u[k] was applied."""

    controller: str
    t: np.ndarray
    r: np.ndarray                 # the reference rbar, in the tracked output's units
    u: np.ndarray                 # the input applied over [t[k], t[k+1])
    signals: dict[str, np.ndarray]
    tracked: str
    input_name: str = "u"
    failure: str | None = None  # why the run stopped early; the trace holds what came before
    units: dict[str, str] = field(default_factory=dict)  # signal -> unit its FMU declares

    def watched(self) -> list[str]:
        """The plant outputs besides the tracked one measured in its unit (for a pendulum on
        an arm: the pendulum angle beside the arm's): what a figure or table shows first."""
        unit = self.units.get(self.tracked)
        return [name for name in self.signals if name != self.tracked and unit
                and self.units.get(name) == unit]

    def label(self, name: str) -> str:
        """``name [unit]``, or the name when its FMU declares no unit."""
        name = self.input_name if name == "u" else name
        unit = self.units.get(name)
        return f"{name} [{unit}]" if unit else name

    def __getitem__(self, name: str) -> np.ndarray:
        if name in ("t", "r", "u"):
            return getattr(self, name)
        if name == "error":
            return self.r - self.signals[self.tracked]
        return self.signals[name]

    def columns(self) -> list[str]:
        return ["t", "r", "u", *self.signals]

    def to_csv(self, path: str | Path, every: int = 1) -> Path:
        """Write every ``every``-th sample (the first included) to ``path``, atomically: the
        file appears under its name only once it is complete."""
        with atomic(path) as partial:
            with partial.open("w", newline="") as handle:
                writer = csv.writer(handle)
                writer.writerow(self.columns())
                writer.writerows(np.column_stack([self[c][::every] for c in self.columns()]).tolist())
        return path

    @classmethod
    def from_csv(cls, path: str | Path, controller: str, tracked: str, input_name: str = "u") -> "Trace":
        data = np.atleast_1d(np.genfromtxt(path, delimiter=",", names=True, deletechars=""))
        names = data.dtype.names
        signals = {n: np.asarray(data[n]) for n in names if n not in ("t", "r", "u")}
        return cls(controller, np.asarray(data["t"]), np.asarray(data["r"]), np.asarray(data["u"]),
                   signals, tracked, input_name)
