"""The run directory of a tuning: its lock, the identity a --resume must match (run.json),
the time accounting kept there, and where candidates are evaluated."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from furuta_cosim.errors import ConfigError
from furuta_cosim.files import write_text


def locked(folder: Path):
    """An exclusive lock on the run directory (``.lock``), held for the whole run: a second
    ``tune`` on the same folder is refused at once. The lock ends with the process, a killed
    one too."""
    import fcntl

    try:
        handle = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    except OSError as error:
        raise ConfigError([f"run_dir {folder}: cannot be locked ({error.strerror})"]) from None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(handle)
        raise ConfigError([f"run_dir {folder}: another tune is running in this folder; wait for it "
                           "or choose another folder"]) from None
    return handle


def same_run(folder: Path, identity: dict) -> None:
    """A resumed run goes on with the spec, method and seed it started with, or not at all:
    its history would otherwise mix two searches."""
    try:
        started = json.loads((folder / "run.json").read_text())
        spec_text = (folder / "spec.yaml").read_text() if (folder / "spec.yaml").exists() else None
    except (OSError, ValueError) as error:
        raise ConfigError([f"resume: {folder / 'run.json'} cannot be read ({error})"]) from None
    if not isinstance(started, dict):
        raise ConfigError([f"resume: {folder / 'run.json'} is not a run's identity"])
    recorded = started.get("spec_sha256")
    if (spec_text is not None and spec_text != identity["spec"]) or \
            (recorded is not None and recorded != identity["spec_sha256"]):
        raise ConfigError([f"resume: the spec differs from the one {folder} was started with "
                           f"({folder / 'spec.yaml'}, sha256 in {folder / 'run.json'})"])
    if spec_text is None and recorded is None:
        raise ConfigError([f"resume: {folder / 'spec.yaml'} is missing and run.json records no "
                           "spec hash: nothing tells that this spec is the one the run started with"])
    for key in ("method", "seed", "plant"):
        if started.get(key) != identity.get(key):
            mine, theirs = identity.get(key, "(none)"), started.get(key, "(none)")
            raise ConfigError([f"resume: `{key}` {mine} differs from the run's {theirs} "
                               f"({folder / 'run.json'})"])


def executor_for(spec, evaluator, workers: int, dask: str | None):
    """Where candidates are evaluated: a Dask cluster, local processes, or this process."""
    from furuta_cosim.tuning.executors import Dask, Processes, Serial

    if dask:
        return Dask(spec, dask, max(workers, 1))
    if workers > 1:
        return Processes(spec, workers)
    return Serial(spec, evaluator)


class Clock(dict):
    """Seconds spent in the optimizer and waiting for evaluations, kept in run.json after every
    batch, so that a resumed run (a finished one too) goes on counting from there."""

    def __init__(self, path: Path):
        try:
            saved = json.loads(path.read_text())
        except (OSError, ValueError):
            saved = {}
        saved = saved if isinstance(saved, dict) else {}
        super().__init__({key: _seconds(saved.get(f"{key}_seconds")) for key in ("optimizer", "evaluation")})
        self.path, self.identity = path, {k: saved.get(k) for k in ("method", "seed", "plant", "spec_sha256")
                                    if k in saved}

    def save(self) -> None:
        write_text(self.path, json.dumps({**self.identity, "optimizer_seconds": self["optimizer"],
                                          "evaluation_seconds": self["evaluation"]}) + "\n")


def _seconds(value) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok and value >= 0 else 0.0
