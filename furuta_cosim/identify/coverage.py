"""What a 95 % interval is worth: the coverage of each kind of interval identify gives, measured
on synthetic logs with coloured noise and a known truth.

Each replicate is the same 2 s PRBS run of the QUBE model (the truth: the plant's own values),
logged as a 2048-count arm encoder (the arm disturbed by an AR(1) series of one count's
standard deviation before it is counted) and a current whose noise is an AR(1) series
(coefficient ``phi``, standard deviation ``noise``): the correlated residuals of a real log,
which the textbook interval ignores. R_a and M_f are fitted from 10 % off; each kind of interval (the
textbook s^2 (J^T J)^-1, the sandwich, the profile likelihood's, the block bootstrap's) either
holds the truth or not. The coverage is the fraction of replicates whose interval holds it; a
95 % interval should reach about 0.95 (binomial spread over 50 replicates: +-0.03).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

FREE = ("R_a", "M_f")
KINDS = ("textbook", "sandwich", "profile", "bootstrap")
PERIOD, SAMPLES = 0.002, 1001


def _clean(plant: str, seed: int):
    """The PRBS input and the model's outputs at its own values (the truth)."""
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.fmu.session import PlantSession
    from furuta_cosim.identify.replay import target_for

    rng = np.random.default_rng([seed, 11])
    volts = np.repeat(rng.choice([-3.0, 3.0], size=SAMPLES // 25 + 1), 25)[:SAMPLES]
    target = target_for(plant=plant)
    truth = {name: float(load_plant(plant).parameters[name]) for name in FREE}
    with PlantSession.open(target.fmu) as session:
        session.reset(parameters={**truth, "theta1_start": math.pi})
        session.set_io(inputs=["V"], outputs=["theta0", "i"])
        rows = [session.get(["theta0", "i"])] + [session.step([v], PERIOD) for v in volts[:-1]]
    return volts, np.array(rows), truth


def _ar1(rng, n: int, phi: float, sd: float) -> np.ndarray:
    white = rng.normal(0.0, sd * math.sqrt(1.0 - phi * phi), n)
    series = np.empty(n)
    series[0] = rng.normal(0.0, sd)
    for k in range(1, n):
        series[k] = phi * series[k - 1] + white[k]
    return series


def coverage_study(replicates: int = 50, *, plant: str = "qube-servo-3", phi: float = 0.9,
                   noise: float = 0.01, bootstrap: int = 0, seed: int = 0,
                   log: Callable[[str], None] = lambda line: None) -> dict:
    """The coverage of each kind of interval (module docstring) over ``replicates`` logs;
    ``bootstrap`` replicates per log for the bootstrap's interval (0: not measured).

    Returns {"coverage": {kind: {parameter: fraction}}, "width": {kind: {parameter: mean
    relative width}}, "replicates", "truth", the settings}."""
    from furuta_cosim.identify.bootstrap import bootstrap_all
    from furuta_cosim.identify.fit import fit
    from furuta_cosim.identify.profile import profile_all
    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.identify.spec import load_identify_spec

    volts, clean, truth = _clean(plant, seed)
    quantum = 2 * math.pi / 2048
    kinds = [k for k in KINDS if k != "bootstrap" or bootstrap]
    hits = {k: {n: 0 for n in FREE} for k in kinds}
    widths = {k: {n: [] for n in FREE} for k in kinds}
    target = target_for(plant=plant)
    t = np.arange(SAMPLES) * PERIOD
    with tempfile.TemporaryDirectory(prefix="furuta-coverage-") as folder:
        folder = Path(folder)
        (folder / "log.yaml").write_text(
            "data: log.csv\ncolumns: [t, V, theta, I]\ntime: t\ninputs: {V: {column: V, unit: V}}\n"
            f"outputs:\n  theta0: {{column: theta, unit: rad, quantum: {quantum!r}}}\n  i: {{column: I, unit: A, noise: {noise!r}}}\n"
            "start: {theta0: 0.0, dtheta0: 0.0, theta1: 3.141592653589793, dtheta1: 0.0, i: 0.0}\n")
        (folder / "spec.yaml").write_text(
            f"name: coverage\nplant: {plant}\nexperiments: [log.yaml]\nfree:\n" + "".join(
                f"  {n}: {{start: {1.1 * v!r}, bounds: [{0.2 * v!r}, {5 * v!r}]}}\n" for n, v in truth.items()))
        for r in range(replicates):
            rng = np.random.default_rng([seed, r])
            # the arm's own disturbance (cable, vibration) before the encoder counts it
            theta = np.round((clean[:, 0] + _ar1(rng, SAMPLES, phi, quantum)) / quantum) * quantum
            current = clean[:, 1] + _ar1(rng, SAMPLES, phi, noise)
            (folder / "log.csv").write_text("t,V,theta,I\n" + "".join(
                f"{a!r},{b!r},{c!r},{d!r}\n" for a, b, c, d in
                zip(t.tolist(), volts.tolist(), theta.tolist(), current.tolist())))
            spec = load_identify_spec(folder / "spec.yaml")
            result = fit(spec, target)
            document = result.document()
            found = {"textbook": {}, "sandwich": {}}
            for n in FREE:
                p = document["parameters"][n]
                found["sandwich"][n] = p["interval"]
                found["textbook"][n] = [p["value"] - 1.959964 * p["stderr_plain"],
                                        p["value"] + 1.959964 * p["stderr_plain"]]
            profiles = profile_all(spec, target, result)
            found["profile"] = {n: [(lo if lo is not None else -math.inf), (hi if hi is not None else math.inf)]
                                for n, (lo, hi) in ((n, profiles[n]["interval"] or (None, None)) for n in FREE)}
            if bootstrap:
                resampled = bootstrap_all(spec, target, result, replicates=bootstrap, seed=r)
                found["bootstrap"] = {n: resampled["parameters"][n]["interval"] for n in FREE}
            for kind in kinds:
                for n in FREE:
                    lo, hi = found[kind][n]
                    hits[kind][n] += int(lo <= truth[n] <= hi)
                    widths[kind][n].append((hi - lo) / truth[n])
            log(f"replicate {r + 1}/{replicates}: " + "; ".join(
                f"{kind} {sum(hits[kind].values())}/{len(FREE) * (r + 1)}" for kind in kinds))
    return {"replicates": replicates, "truth": truth, "phi": phi, "noise": noise, "bootstrap": bootstrap,
            "seed": seed, "coverage": {k: {n: hits[k][n] / replicates for n in FREE} for k in kinds},
            "width": {k: {n: float(np.mean(widths[k][n])) for n in FREE} for k in kinds}}
