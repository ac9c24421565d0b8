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


def identity_of(spec, method: str, seed: int, n_calls: int) -> dict:
    """What a run is, recorded in run.json and checked by a resume: the spec's text (and its
    sha256), the method, the seed, the budget, and what its plant variants are made of (the
    plant file's content, the fit's content, the variants themselves), so that a resume can
    never continue a history on other plants."""
    import hashlib

    text = Path(spec.path).read_text() if spec.path else spec.name
    identity = {"spec": text, "method": method, "seed": seed, "n_calls": n_calls,
                "spec_sha256": hashlib.sha256(text.encode()).hexdigest()}
    if spec.plant is not None:
        from furuta_cosim.fmu.plants import content_sha256, load_plant

        identity["plant"] = spec.plant
        identity["plant_sha256"] = content_sha256(load_plant(spec.plant))
    identity["variants_sha256"] = _digest([dict(v) for v in spec.variants])
    if spec.fit is not None:
        identity["fit"] = {"path": spec.fit.path, "sha256": spec.fit.sha256,
                           "samples": spec.fit.samples, "seed": spec.fit.seed}
    return identity


def _digest(value) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()


# what run.json records besides the times, and a resume checks (run.json of older runs may
# lack the later ones: a key the run did not record is not checked)
IDENTITY = ("method", "seed", "plant", "spec_sha256", "n_calls", "plant_sha256",
            "variants_sha256", "fit")


def recorded(folder: Path) -> dict:
    """The identity run.json records ({} when it cannot be read)."""
    try:
        started = json.loads((folder / "run.json").read_text())
    except (OSError, ValueError):
        return {}
    return started if isinstance(started, dict) else {}


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
    where = folder / "run.json"
    fit, theirs = identity.get("fit") or {}, started.get("fit") or {}
    if ("fit" in started or "variants_sha256" in started) and bool(fit) != bool(theirs):
        raise ConfigError([f"resume: the run was started {'with' if theirs else 'without'} plant "
                           f"variants from a fit ({theirs.get('path', 'none')}), this one "
                           f"{'with' if fit else 'without'} ({fit.get('path', 'none')}) ({where})"])
    if fit and theirs:
        for key, flag in (("samples", "from_fit: samples"), ("seed", "from_fit: seed")):
            if fit.get(key) != theirs.get(key):
                raise ConfigError([f"{flag} {fit.get(key)} differs from the run's {theirs.get(key)}: "
                                   f"its plant variants would differ ({where})"])
        if fit.get("sha256") != theirs.get("sha256"):
            raise ConfigError([f"resume: the fit {fit.get('path')} is not the one the run drew its "
                               f"variants from ({theirs.get('path')}): its content differs (sha256 "
                               f"in {where})"])
    if "plant_sha256" in started and started["plant_sha256"] != identity.get("plant_sha256"):
        raise ConfigError([f"resume: the plant file {identity.get('plant')} has changed since the run "
                           f"started: its parameters differ (sha256 in {where})"])
    if "variants_sha256" in started and started["variants_sha256"] != identity.get("variants_sha256"):
        raise ConfigError([f"resume: the spec's plant variants differ from those the run was started "
                           f"with (sha256 in {where})"])


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
        self.path, self.identity = path, {k: saved.get(k) for k in IDENTITY if k in saved}

    def save(self) -> None:
        write_text(self.path, json.dumps({**self.identity, "optimizer_seconds": self["optimizer"],
                                          "evaluation_seconds": self["evaluation"]}) + "\n")


def _seconds(value) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok and value >= 0 else 0.0
