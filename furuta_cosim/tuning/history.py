"""history.jsonl: one line per evaluation, appended and forced to disk before the run goes
on; read back strictly on --resume."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from furuta_cosim.documents import dumps, json_safe
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import named

if TYPE_CHECKING:
    from furuta_cosim.tuning.objective import Outcome


def record(index: int, x, names, outcome: Outcome, origin: str = "", surrogate=None) -> dict:
    return json_safe({"index": index, "x": [float(v) for v in x],
                       "parameters": dict(zip(names, map(float, x))),
                       "objective": outcome.objective, "feasible": outcome.feasible,
                       "value": outcome.value, "margin": outcome.margin,
                       **({"criteria": outcome.criteria} if outcome.criteria is not None else {}),
                       "constraints": outcome.constraints, "metrics": outcome.metrics,
                       # which runs broke a constraint (the next batches run them first), and
                       # a run stopped early with the runs it left out
                       "violated": outcome.violated, "stopped": outcome.stopped,
                       "skipped": outcome.skipped,
                       # refused by the loop's exact checks (bo checks them, not learns them)
                       "known": outcome.known,
                       "origin": origin, "surrogate": surrogate,
                       "wall_time": outcome.wall_time, "worker": outcome.worker, "error": outcome.error,
                       # a rig trial (tuning/rig.py): its run folder and status, and the same
                       # candidate in simulation (the residual the safe method learns)
                       # each co-simulated constraint's slack by name (the safe method models each)
                       **({"slacks": outcome.slacks} if outcome.slacks is not None else {}),
                       **({"trial": outcome.trial} if outcome.trial is not None else {}),
                       **({"simulation": outcome.simulation} if outcome.simulation is not None else {})})


def _append(handle, record: dict) -> None:
    handle.write(dumps(record) + "\n")
    handle.flush()
    os.fsync(handle.fileno())


class History:
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
                raise ConfigError([f"resume: {self.path}: line {number}: {problem}; nothing was "
                                   "changed: repair or remove that line (and the ones after it), "
                                   "then `resume` again"])
            self.records.append(record)
        if raw and not complete:
            with self.path.open("ab") as handle:  # the last record lacked its newline
                handle.write(b"\n")

    def append(self, record: dict) -> None:
        try:
            _append(self._handle, record)
        except OSError as error:  # a full disk: say which file
            raise named(error, self.path) from None
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




def failing_first(records, labels) -> list[str]:
    """The run labels, the one broken most often in ``records`` first (ties: as given): the
    order a candidate's runs go in, so that one that fails is likely to fail, and stop, first."""
    counts = dict.fromkeys(labels, 0)
    for r in records:
        violated = r.get("violated")
        for label in violated if isinstance(violated, list) else ():
            if label in counts:
                counts[label] += 1
    position = {label: k for k, label in enumerate(labels)}
    return sorted(labels, key=lambda label: (-counts[label], position[label]))


def replayed(records, xs, offset: int) -> None:
    """A resumed run proposes again what the history holds: the same points, or the history
    is not this run's (a changed kernel library can do that; say so, change nothing)."""
    for k, x in enumerate(xs[:max(0, len(records) - offset)]):
        recorded = records[offset + k]
        if not np.allclose(recorded["x"], x, rtol=0, atol=1e-9 * (1 + np.max(np.abs(x)))):
            raise ConfigError([f"resume: evaluation {recorded['index']} of the history is not "
                               "the point this run proposes there (were the spec's controllers "
                               "or a library changed?); nothing was changed"])
