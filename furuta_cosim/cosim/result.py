"""The result of one controller on one prepared scenario, and its files.

A result is written as an entry of a ``metrics.json`` (what ``simulate`` writes) plus the CSV
of its trace, and read back from the two. Non-finite metric values (a response that never
settles) are ``null`` in JSON and read back as infinity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from furuta_cosim.cosim.trace import Trace
from furuta_cosim.documents import json_safe


@dataclass
class RunResult:
    """Trace, metrics, requirement verdicts, why the run stopped early (if it did), wall time."""

    scenario: str
    controller: str
    trace: Trace
    metrics: dict[str, float]
    requirements: dict[str, dict]
    failure: str | None
    wall_time: float
    time_unit: str = "s"
    # a watched metric past its bound ended the run here: {"t", "metric", "value", "bound"}
    stopped: dict | None = None

    @property
    def passed(self) -> bool:
        """The run went to the end and met every requirement that applies to it."""
        return not self.failure and not self.stopped and all(v["pass"] for v in self.requirements.values())

    def to_dict(self, trace_file: str | Path | None = None) -> dict:
        """The JSON entry (``trace_file``: where its CSV is, when it was written)."""
        return {"scenario": self.scenario, "controller": self.controller, "failure": self.failure,
                "passed": self.passed, "wall_time": self.wall_time, "time_unit": self.time_unit,
                "tracked": self.trace.tracked, "input": self.trace.input_name,
                "units": dict(self.trace.units), "metrics": json_safe(self.metrics),
                "requirements": json_safe(self.requirements),
                "trace": str(trace_file) if trace_file else None}

    def save(self, folder: str | Path, *, every: int = 1, trace: bool = True) -> dict:
        """Write the trace to ``<folder>/<controller>.csv`` (every ``every``-th sample; none
        with ``trace=False``) and return the JSON entry that points to it."""
        path = self.trace.to_csv(Path(folder) / f"{self.controller}.csv", every=every) if trace else None
        # named relative to the folder: a folder moved or shared stays whole
        return self.to_dict(Path(path).name if path else None)

    @classmethod
    def from_dict(cls, data: dict, base: str | Path | None = None) -> "RunResult":
        """Read a result back from its JSON entry and its CSV (relative to ``base``, the JSON's
        folder)."""
        path = Path(data["trace"]) if data.get("trace") else None
        if path is not None and base is not None and (not path.is_absolute() or not path.exists()):
            path = Path(base) / path.name  # beside the JSON (an older file's absolute path: moved)
        if path is not None:
            trace = Trace.from_csv(path, data["controller"], data["tracked"], data.get("input", "u"))
        else:
            import numpy as np

            trace = Trace(data["controller"], np.zeros(0), np.zeros(0), np.zeros(0), {},
                          data["tracked"], data.get("input", "u"))
        trace.failure = data.get("failure")
        units = data.get("units")
        if isinstance(units, dict):
            trace.units = {str(k): str(v) for k, v in units.items() if isinstance(v, str)}
        metrics = {k: math.inf if v is None else float(v) for k, v in data["metrics"].items()}
        requirements = {k: {**v, "value": math.inf if v["value"] is None else v["value"]}
                        for k, v in data["requirements"].items()}
        return cls(data["scenario"], data["controller"], trace, metrics, requirements,
                   data.get("failure"), float(data.get("wall_time", 0.0)), data.get("time_unit", "s"))
