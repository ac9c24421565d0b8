"""An identify run directory's claim and checkpoint: what a run is (its identity: the spec's
content, its data, the plant, the FMU, the options), the folder made ours (refused when it holds
anything else; an earlier run's files removed) or a stopped run's finished stages read back for
``resume``."""

from __future__ import annotations

from pathlib import Path




CHECKPOINT = "identify-checkpoint.json"  # the finished stages of a run that has not ended


def identity_of(spec, target, fmi_version: str) -> dict:
    """What a run is: the spec's content, its data, the plant's values and the FMU."""
    import hashlib

    from furuta_cosim.fmu.plants import content_sha256

    return {"spec": spec.name, "spec_sha256": hashlib.sha256(Path(spec.path).read_bytes()).hexdigest(),
            "data": {e.name: e.sha256 for e in spec.experiments + spec.validation},
            "plant_sha256": content_sha256(target.plant) if target.plant is not None else None,
            "fmu_sha256": hashlib.sha256(Path(target.fmu).read_bytes()).hexdigest(),
            "fmi_version": fmi_version}


def fitted_digest(path: Path) -> str:
    from furuta_cosim.fmu.plants import content_sha256, load_plant

    return content_sha256(load_plant(path))


def claim(out: Path, spec, identity: dict, resume: bool) -> dict | None:
    """The run directory made ours: refused when it holds anything but an earlier run of this
    spec; an earlier run's files and any half-written file removed (a new run) or its last
    finished stage returned (``resume``)."""
    import json

    from furuta_cosim.errors import ConfigError

    entries = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    earlier = None
    for name in ("fit.json", CHECKPOINT):
        if name in entries:
            try:
                earlier = json.loads((out / name).read_text())
            except (OSError, ValueError, RecursionError):
                earlier = None
            if isinstance(earlier, dict):
                earlier = earlier.get("identity", earlier) if name == CHECKPOINT else earlier
                break
    ours = isinstance(earlier, dict) and earlier.get("spec", earlier.get("name")) == spec.name
    if resume:
        if CHECKPOINT not in entries:
            what = "a finished fit" if "fit.json" in entries else "no stopped identify run"
            raise ConfigError([f"resume: {out} holds {what}: nothing to resume (run identify "
                               "without `resume`)"])
        try:
            saved = json.loads((out / CHECKPOINT).read_text()) if ours else None
        except (OSError, ValueError, RecursionError):
            saved = None
        if not isinstance(saved, dict):
            raise ConfigError([f"resume: {out / CHECKPOINT} is not a checkpoint of identify {spec.name}"])
        _same(out / CHECKPOINT, saved.get("identity"), identity)
        count = len(spec.free) + sum(len(e.free_starts()) for e in spec.experiments)
        try:
            state = {"start": int(saved.get("start", 0)), "stage": int(saved["stage"]),
                     "x": None if saved["x"] is None else [float(v) for v in saved["x"]],
                     "record": list(saved["record"]), "simulations": int(saved["simulations"]),
                     "message": str(saved.get("message", "")),
                     "budget_from": int(saved.get("budget_from", 0)),
                     "optima": [{"x": [float(v) for v in o["x"]], "cost": float(o["cost"]),
                                 "message": str(o.get("message", "")), "record": list(o["record"])}
                                for o in saved.get("optima", [])],
                     "profiles": _profiles_read(saved.get("profiles")),
                     "precheck": saved.get("precheck") if isinstance(saved.get("precheck"), dict) else None}
        except (KeyError, TypeError, ValueError):
            raise ConfigError([f"resume: {out / CHECKPOINT}: damaged (stage, x, record, "
                               "simulations expected)"]) from None
        lengths = [len(state["x"])] if state["x"] is not None else []
        lengths += [len(o["x"]) for o in state["optima"]]
        if any(n != count for n in lengths):
            raise ConfigError([f"resume: {out / CHECKPOINT}: holds values of another number of "
                               f"unknowns than the spec's {count}"])
        return state
    if entries and not ours:
        raise ConfigError([f"output {out}: holds files that are not a run of identify {spec.name} "
                           f"({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''}); "
                           "choose a new or empty folder"])
    # a new run of this spec: what the earlier one wrote goes, so nothing stale stays beside it
    listed = earlier.get("files", []) if isinstance(earlier, dict) else []
    for name in entries:
        if name in listed or name == CHECKPOINT or name.endswith(".partial") \
                or name in ("profiles.png", "profiles.svg") \
                or name.endswith(("-overlay.png", "-overlay.svg", "-residuals.png", "-residuals.svg")):
            (out / name).unlink(missing_ok=True)
    return None


def _profiles_read(saved) -> dict:
    """Profiles a checkpoint holds, each only if whole (a damaged one is computed again)."""
    import math

    from furuta_cosim.identify.profile import VERDICTS

    found = {}
    for name, p in (saved or {}).items() if isinstance(saved, dict) else ():
        try:
            numbers = [float(v) for v in p["values"] + p["rise"]]
            interval = p["interval"]
            whole = (p["verdict"] in VERDICTS and len(p["values"]) == len(p["rise"]) >= 1
                     and all(math.isfinite(v) for v in numbers)
                     and (interval is None or (len(interval) == 2 and all(
                         v is None or math.isfinite(float(v)) for v in interval))))
        except (KeyError, TypeError, ValueError):
            whole = False
        if whole and isinstance(name, str):
            found[name] = p
    return found


def _same(where: Path, saved, identity: dict) -> None:
    from furuta_cosim.errors import ConfigError

    if not isinstance(saved, dict):
        raise ConfigError([f"resume: {where}: records no identity of its run"])
    words = {"spec_sha256": "the spec's content", "data": "the logs (their sha256)",
             "plant_sha256": "the plant's values", "fmu_sha256": "the plant FMU",
             "fmi_version": "the FMI version", "options": "the options (starts, profiles, bootstrap, seed)"}
    for key, what in words.items():
        if saved.get(key) != identity.get(key):
            raise ConfigError([f"resume: {what} differ from the stopped run's ({where}); run "
                               "identify anew without `resume`"])
