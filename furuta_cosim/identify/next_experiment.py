"""The next experiment: excitations a rig can play, ranked by what they would add to a fit.

Each candidate (a PRBS, a chirp, a multisine, a square wave, played open loop on the hanging
pendulum; a free swing for comparison) is scaled to the largest amplitude whose simulation at the
current estimate keeps the voltage and the arm inside the rig's limits (with a margin for the
model's error), and scored by the expected Fisher information at the estimate (Walter and
Pronzato, "Identification of Parametric Models from Experimental Data", 1997; what Pyomo.DoE
computes): F = J^T J of the sensitivities of its outputs, each weighted by its sensor's noise
(the encoders' quantum / sqrt(12), the current sensor's stated noise). Added to the information
of the experiments already fitted (the same sum over their samples), it predicts the covariance
after the new experiment, and so the interval widths and correlations the next fit would give.

The prediction assumes independent residuals, as the textbook covariance does; the fit's own
(sandwich) intervals are wider where the residuals are correlated. So the predicted width of an
interval is the fit's interval times the predicted textbook width over today's textbook width:
the factor by which the new data would shrink it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.config import Frozen
from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import Experiment, Measured

ARM_MARGIN = 0.6      # a candidate's simulated arm stays within this fraction of the arm limit
PERIOD = 0.002        # the table's period: the QUBE's loop
CORRELATED = 0.9      # a pair above this is reported as still hard to separate


@dataclass(frozen=True)
class Candidate:
    name: str
    description: str
    volts: np.ndarray            # per sample, at PERIOD
    release: float = 0.0         # the pendulum held this far from hanging, then let go (rad)


def shapes(duration: float, seed: int = 0) -> list[Candidate]:
    """The candidate excitations at unit amplitude (module docstring), ``duration`` long."""
    n = int(round(duration / PERIOD)) + 1
    t = np.arange(n) * PERIOD
    rng = np.random.default_rng([seed, 7])
    found = []
    for hold in (0.02, 0.05, 0.1):
        levels = rng.choice([-1.0, 1.0], size=int(math.ceil(n * PERIOD / hold)) + 1)
        found.append(Candidate(f"prbs-{int(hold * 1000)}ms", f"PRBS, a level held {hold * 1000:g} ms at least",
                               levels[(t / hold).astype(int)]))
    for low, high in ((0.5, 10.0), (2.0, 20.0)):
        phase = 2 * math.pi * (low * t + 0.5 * (high - low) / duration * t ** 2)
        found.append(Candidate(f"chirp-{low:g}-{high:g}Hz", f"linear chirp from {low:g} to {high:g} Hz",
                               np.sin(phase)))
    lines = np.arange(1, 21) * 0.5  # 0.5 to 10 Hz, Schroeder's phases (a low crest factor)
    phases = -math.pi * np.arange(1, 21) * np.arange(0, 20) / 20
    multisine = np.sin(2 * math.pi * np.outer(t, lines) + phases).sum(axis=1)
    found.append(Candidate("multisine-0.5-10Hz", "multisine, 20 lines from 0.5 to 10 Hz, Schroeder phases",
                           multisine / np.max(np.abs(multisine))))
    for frequency in (1.0, 4.0):
        found.append(Candidate(f"square-{frequency:g}Hz", f"steps up and down, {frequency:g} Hz",
                               np.where(np.sin(2 * math.pi * frequency * t) >= 0, 1.0, -1.0)))
    found.append(Candidate("free-swing", "no voltage; the pendulum let go 1 rad from hanging (for comparison)",
                           np.zeros(n), release=1.0))
    return found


def _experiment(candidate: Candidate, volts: np.ndarray, sensors: dict) -> Experiment:
    """A candidate as an experiment the fit's machinery simulates (its measured values unused)."""
    n = len(volts)
    quantum = 2 * math.pi / float(sensors.get("encoder_counts", 2048))
    angle = quantum / math.sqrt(12.0)
    noise = float(sensors.get("current_noise", 0.004)) or 0.004
    zeros = np.zeros(n)
    outputs = {"theta0": Measured("theta0", zeros, angle, "quantum"),
               "theta1": Measured("theta1", zeros, angle, "quantum"),
               "i": Measured("i", zeros, noise, "noise")}
    start = {"theta0": 0.0, "dtheta0": 0.0, "theta1": math.pi + candidate.release, "dtheta1": 0.0, "i": 0.0}
    return Experiment(candidate.name, candidate.description, Path(candidate.name), Path(candidate.name), "",
                      np.arange(n) * PERIOD, PERIOD, Frozen({"V": volts}), Frozen(outputs), Frozen(start))


def design(spec_name, fit_folder, *, duration: float = 10.0, seed: int = 0, voltage: float | None = None,
           arm: float | None = None, focus=None,
           log: Callable[[str], None] = lambda line: None) -> dict:
    """Rank the candidate excitations for the fit in ``fit_folder`` (identify's run folder of
    ``spec_name``): a dict with the current widths and correlations and, per candidate (best
    first), its amplitude, peaks and predicted widths and correlations.

    ``focus`` names the free parameters the ranking is about (all by default): the candidates
    are ranked by the widest predicted interval among them, then by their largest correlation."""
    import json

    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.identify.problem import Problem, Runner, unknowns
    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.identify.spec import load_identify_spec
    from furuta_cosim.rig.supervisor import Limits

    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and 1.0 <= duration <= 120.0):
        raise ConfigError([f"duration: expected seconds from 1 to 120, got {duration}"])
    spec = load_identify_spec(spec_name)
    folder = Path(fit_folder)
    try:
        document = json.loads((folder / "fit.json").read_text())
        values = {name: float(p["value"]) for name, p in document["parameters"].items()}
        plant = load_plant(folder / "plant.yaml")
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ConfigError([f"{folder}: not a run folder of identify (fit.json and plant.yaml expected: "
                           f"{type(error).__name__}: {error})"]) from None
    if document.get("spec_sha256") and document.get("name") != spec.name:
        raise ConfigError([f"{folder}: a fit of identify {document.get('name')}, not of {spec.name}"])
    items = unknowns(spec, plant.parameters)
    missing = [u.name for u in items if u.name not in values]
    if missing:
        raise ConfigError([f"{folder / 'fit.json'}: has no value of {', '.join(missing)} (a fit of another spec?)"])
    limits = Limits.of(plant)
    voltage = float(voltage if voltage is not None else limits.voltage or 10.0)
    arm = float(arm if arm is not None else limits.theta0 or 2.0)
    for name, value, high in (("voltage", voltage, 50.0), ("arm", arm, 10.0)):
        if not (math.isfinite(value) and 0 < value <= high):
            raise ConfigError([f"{name}: expected a number in (0, {high:g}], got {value}"])
    x = np.array([values[u.name] / u.scale for u in items])
    plant_names = [p.name for p in spec.free]
    focus = list(plant_names if not focus else focus)
    unknown = [name for name in focus if name not in plant_names]
    if unknown:
        raise ConfigError([f"focus: {', '.join(unknown)} not a free parameter of {spec.name} "
                           f"(those are {', '.join(plant_names)})"])
    index = [k for k, u in enumerate(items) if u.name in focus]
    target = target_for(plant=folder / "plant.yaml")
    candidates = shapes(duration, seed)
    sensors = dict(plant.sensors)
    runner = Runner(target, spec.experiments, 1, None)
    try:
        now = Problem(runner, spec.experiments, items, None, math.inf, lambda n, c: None).jac(x)
    finally:
        runner.close()
    info_now = now.T @ now
    cov_now = _inverse(info_now)
    plain_now = np.sqrt(np.maximum(np.diag(cov_now), 0.0))
    fitted = {name: document["parameters"][name] for name in focus}
    half_now = {}
    for k in index:  # today's half-width of the fit's own interval, relative to the value
        p, name = fitted[items[k].name], items[k].name
        interval = p.get("interval")
        half_now[name] = (math.inf if not interval or not p["value"] else
                          (interval[1] - interval[0]) / 2 / abs(p["value"]))
    ranked = []
    for candidate in candidates:
        scaled = _scaled(candidate, target, sensors, voltage, arm, items, x)
        if scaled is None:
            log(f"  {candidate.name}: no amplitude keeps the arm within {ARM_MARGIN * arm:.2f} rad")
            continue
        volts, peaks, J = scaled
        cov = _inverse(info_now + J.T @ J)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        factor = {items[k].name: float(sd[k] / plain_now[k]) if plain_now[k] > 0 else 1.0 for k in index}
        half = {name: half_now[name] * factor[name] for name in factor}
        corr = _correlation(cov, index, focus)
        largest, pair = _largest(corr)
        ranked.append({"name": candidate.name, "description": candidate.description,
                       "amplitude": float(np.max(np.abs(volts))), "release": candidate.release, "peaks": peaks,
                       "factor": factor, "half_width": half, "widest": max(half.values()),
                       "correlation": corr, "largest_correlation": largest, "pair": pair,
                       "log_det": float(np.linalg.slogdet(cov[np.ix_(index, index)])[1]),
                       "volts": volts})
        log(f"  {candidate.name}: amplitude {ranked[-1]['amplitude']:.2f} V, arm {peaks['theta0']:.2f} rad, "
            f"widest interval +-{100 * ranked[-1]['widest']:.3g} %")
    if not ranked:
        raise ConfigError([f"no candidate keeps the arm within {ARM_MARGIN * arm:.2f} rad at {voltage:g} V"])
    ranked.sort(key=lambda c: (c["widest"], c["largest_correlation"]))
    today = _correlation(cov_now, index, focus)
    largest, pair = _largest(today)
    return {"spec": spec.name, "fit": str(folder), "duration": duration, "period": PERIOD, "seed": seed,
            "focus": focus, "limits": {"voltage": voltage, "arm": arm, "arm_margin": ARM_MARGIN},
            "now": {"half_width": half_now, "correlation": today, "largest_correlation": largest, "pair": pair},
            "candidates": ranked}


def _inverse(information: np.ndarray) -> np.ndarray:
    """A covariance from an information matrix; a direction with no information gets an infinite
    variance (the pseudo-inverse would call it zero)."""
    scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        normalized = information / np.outer(scale, scale)
        cov = np.linalg.pinv(normalized, rcond=1e-12, hermitian=True) / np.outer(scale, scale)
    blind = np.diag(information) <= 0
    cov[blind, :] = cov[:, blind] = 0.0
    cov[blind, blind] = math.inf
    return cov


def _correlation(cov: np.ndarray, index: list[int], names: list[str]) -> dict:
    sub = cov[np.ix_(index, index)]
    sd = np.sqrt(np.maximum(np.diag(sub), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.nan_to_num(sub / np.outer(sd, sd))
    return {"names": names, "matrix": corr.tolist()}


def _largest(corr: dict) -> tuple[float, list[str]]:
    """The largest correlation in magnitude between two different parameters, and the pair."""
    matrix = np.abs(np.array(corr["matrix"]))
    np.fill_diagonal(matrix, 0.0)
    if matrix.size < 4:
        return 0.0, []
    i, j = np.unravel_index(int(np.argmax(matrix)), matrix.shape)
    return float(matrix[i, j]), [corr["names"][i], corr["names"][j]]


def _scaled(candidate: Candidate, target, sensors: dict, voltage: float, arm: float, items, x):
    """(volts, peaks, weighted sensitivities) of the candidate at the largest amplitude up to
    ``voltage`` whose simulation keeps the arm within ARM_MARGIN of ``arm``; None if none does."""
    from furuta_cosim.identify.problem import Problem, Runner

    amplitude = voltage if np.any(candidate.volts) else 0.0
    for _ in range(12):
        volts = candidate.volts * amplitude
        experiment = _experiment(candidate, volts, sensors)
        runner = Runner(target, [experiment], 1, None)
        try:
            problem = Problem(runner, [experiment], items, None, math.inf, lambda n, c: None)
            outputs, failure = runner.map([(0, None, problem.values(x))])[0]
            if outputs is None:
                return None
            peak = float(np.max(np.abs(outputs["theta0"])))
            if peak <= ARM_MARGIN * arm:
                J = problem.jac(x)
                peaks = {"V": float(np.max(np.abs(volts))), "theta0": peak,
                         "i": float(np.max(np.abs(outputs["i"])))}
                return volts, peaks, J
        finally:
            runner.close()
        if amplitude == 0.0:
            return None
        # the arm's travel grows about linearly with the amplitude: aim inside the margin
        amplitude *= min(0.8, 0.95 * ARM_MARGIN * arm / peak)
    return None


def write_design(found: dict, spec_name, out: str | Path, rig_folder: str = "rig") -> dict:
    """The chosen (best) candidate as ``input.csv`` (t,V: ``rig run --input`` plays it), the
    next identify spec ``next.yaml`` (the spec's experiments and the rig run's log in
    ``out/rig_folder``, its free parameters starting at the fit), ``design.json`` and
    ``design.md`` (the ranking); paths in them relative to ``out``."""
    import yaml

    from furuta_cosim.files import folder as make_folder, output_folder, write_text
    from furuta_cosim.identify.spec import load_identify_spec
    from furuta_cosim.documents import dumps

    spec = load_identify_spec(spec_name)
    out = make_folder(output_folder(out), root=True)
    best = found["candidates"][0]
    t = np.arange(len(best["volts"])) * found["period"]
    write_text(out / "input.csv", "t,V\n" + "".join(f"{a:.6f},{v:.6f}\n" for a, v in zip(t, best["volts"])))
    values = {}
    try:
        import json

        values = {n: p["value"] for n, p in json.loads((Path(found["fit"]) / "fit.json").read_text())["parameters"].items()}
    except (OSError, ValueError, KeyError):
        pass
    here = out.resolve()
    experiments = [os.path.relpath(Path(e.path).resolve(), here) for e in spec.experiments]
    experiments.append(f"{rig_folder}/experiment.yaml")
    free = {p.name: {"start": float(values.get(p.name, p.start or 0.0)), "bounds": list(p.bounds)} for p in spec.free}
    next_spec = {"name": f"{spec.name}-next", "description": f"{spec.name} with the designed {best['name']}",
                 "plant": os.path.relpath(Path(found["fit"]).resolve() / "plant.yaml", here),
                 "experiments": experiments, "free": free}
    write_text(out / "next.yaml", "# Written by furuta-cosim design-experiment: the fit's experiments and "
               "the designed one, once `rig run --input input.csv` has recorded it in "
               f"{rig_folder}/.\n" + yaml.safe_dump(next_spec, sort_keys=False))
    kept = {k: v for k, v in found.items() if k != "candidates"}
    kept["fit"] = os.path.relpath(Path(found["fit"]).resolve(), here)
    kept["candidates"] = [{k: v for k, v in c.items() if k != "volts"} for c in found["candidates"]]
    kept["chosen"] = best["name"]
    write_text(out / "design.json", dumps(kept, indent=1) + "\n")
    write_text(out / "design.md", design_text(found))
    return kept


def design_text(found: dict) -> str:
    """The ranking as text: each candidate's amplitude, arm travel, widest interval and largest
    correlation predicted after it, against today's."""
    now = found["now"]
    names = list(now["half_width"])
    lines = [f"next experiment for {found['spec']}: {found['duration']:g} s within {found['limits']['voltage']:g} V "
             f"and {found['limits']['arm_margin'] * found['limits']['arm']:.2f} rad of arm travel",
             "today (the fit's 95 % intervals, +- relative): "
             + ", ".join(f"{n} +-{100 * now['half_width'][n]:.3g} %" for n in names)
             + f"; largest correlation {now['largest_correlation']:.3f} ({' and '.join(now['pair'])}, textbook)",
             "predicted after adding each (the expected Fisher information at the fit):",
             f"{'candidate':22s} {'volts':>6s} {'arm rad':>7s} {'widest':>9s}  {'largest correlation'}"]
    for c in found["candidates"]:
        widest = max(c["half_width"], key=c["half_width"].get)
        lines.append(f"{c['name']:22s} {c['amplitude']:6.2f} {c['peaks']['theta0']:7.2f} "
                     f"{100 * c['widest']:8.3g}% ({widest})  {c['largest_correlation']:.3f} ({' and '.join(c['pair'])})")
    best = found["candidates"][0]
    lines += ["", f"chosen: {best['name']} ({best['description']}): "
              + ", ".join(f"{n} +-{100 * best['half_width'][n]:.3g} %" for n in names)]
    return "\n".join(lines) + "\n"
