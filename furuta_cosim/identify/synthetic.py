"""A synthetic balancing rig: logs of a known plant balanced under a known controller, to
check a fit of balancing logs against the truth (tools/bench_balancing.py, the tests).

The virtual board (rig/virtual.py) runs the plant file's FMU with encoder quantization, a
noisy 12-bit current sensor, the amplifier's saturation and a transport delay (one control
sample by default); the controller balances the pendulum from just off upright while the
arm follows a square wave (the reference that excites the loop). A controller given as a
state-feedback law is logged as a tool of another maker would log it: the experiment names
the law and its gains (``loop.law``), not a controller file of ours.

    experiment = balancing_log(folder, seed=3)                 # under lqr-qube
    experiment = balancing_log(folder, law=([-1, -1.2, 34, 3], -1))   # under a PD law
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from furuta_cosim.files import write_text


def balancing_log(folder: str | Path, *, seed: int = 0, plant: str = "qube-servo-3",
                  controller: str = "lqr-qube", law: tuple | None = None, duration: float = 10.0,
                  delay: float = 0.002, amplitude: float = 0.3, period: float = 4.0,
                  window: tuple[float, float] | None = None, board_log: Path | None = None) -> Path:
    """Record a balancing log on the virtual board into ``folder`` (new or empty) and return
    its experiment file.

    Parameters
    ----------
    folder : path
        The rig run's folder.
    seed : int
        The current sensor's noise, and the start: the pendulum 0.01 to 0.03 rad off upright.
    plant : str
        The true plant (a plant file or name).
    controller : str
        The balance controller (a controller file or name); or ``law``.
    law : (K, F), optional
        A state-feedback law u = F r - K x (x: theta0, its rate, theta1, its rate), logged as
        ``loop.law`` of the experiment.
    duration : float
        Seconds recorded.
    delay : float
        From a command's write to the motor (s): 0.002 is one sample at 500 Hz.
    amplitude, period : float
        The arm's square-wave reference (rad, s).
    window : (float, float), optional
        The experiment's window (s); the whole log when None.
    board_log : path, optional
        Where the virtual board writes what it applied and the true angles (rig/virtual.py).

    Returns
    -------
    Path
        The experiment file (``experiment.yaml`` in ``folder``).
    """
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.rig.runner import run_rig
    from furuta_cosim.rig.virtual import VirtualBoard

    folder = Path(folder)
    scratch = folder.parent / f".{folder.name}-setup"
    scratch.mkdir(parents=True, exist_ok=True)
    if law is not None:
        K, F = law
        gains = [float(k) for k in K] + [0.0] * (5 - len(K))
        write_text(scratch / "law.yaml", yaml.safe_dump({
            "name": "law", "type": "static", "time": "discrete", "period": 0.002, "K": gains,
            "prefilter": {"output": "theta0", "F": float(F)}}, sort_keys=False))
        controller = str(scratch / "law.yaml")
    write_text(scratch / "reference.yaml", yaml.safe_dump({
        "name": "balancing", "description": "the arm's square wave while the pendulum is balanced",
        "plant": {"model": plant}, "timing": {"duration": float(duration), "control_period": 0.002},
        "reference": {"output": "theta0", "signal": {"type": "square", "amplitude": float(amplitude),
                                                     "period": float(period)}},
        "controllers": ["lqr-qube"]}, sort_keys=False))
    loaded = load_plant(plant)
    off = 0.01 + 0.02 * np.random.default_rng(seed).random()
    board = VirtualBoard(loaded, paced=False, delay=delay, seed=seed, overrides={"theta1_start": off},
                         log=None if board_log is None else Path(board_log))
    run_rig(controller, board, loaded, folder, scenario=scratch / "reference.yaml", zero=False)
    experiment = folder / "experiment.yaml"
    data = yaml.safe_load(experiment.read_text())
    if window is not None:
        data["window"] = [float(window[0]), float(window[1])]
    if law is not None:  # as another tool logs it: the gains, not our controller file
        data["loop"].pop("controller")
        data["loop"]["law"] = {"K": [float(k) for k in law[0]], "F": float(law[1]), "period": 0.002}
        data["rig"].pop("controller", None)
    write_text(experiment, "# a synthetic balancing log (furuta_cosim.identify.synthetic)\n"
               + yaml.safe_dump(data, sort_keys=False))
    for name in ("law.yaml", "reference.yaml"):
        (scratch / name).unlink(missing_ok=True)
    scratch.rmdir()
    return experiment


def truth(plant: str = "qube-servo-3") -> dict[str, float]:
    """The true plant's parameters (what a fit of its logs should find)."""
    from furuta_cosim.fmu.plants import load_plant

    return {k: float(v) for k, v in load_plant(plant).parameters.items() if isinstance(v, (int, float))
            and math.isfinite(float(v))}


def open_loop_log(folder: str | Path, plant: str | Path, inputs: dict, *, period: float,
                  outputs: dict, truth: dict | None = None, start: dict | None = None,
                  name: str = "log", seed: int = 0) -> Path:
    """Record an open-loop log of any plant (a plant file or folder) at known parameters into
    ``folder`` and return its experiment file: what identify reads, of a known truth.

    Parameters
    ----------
    folder : path
        Where the CSV and the experiment file go (created).
    plant : str or path
        The plant (its FMU runs the log).
    inputs : dict
        Input name -> the values it takes, one per sample (held over each sample).
    period : float
        The sample period (s).
    outputs : dict
        Output name -> ``(unit, quantum)``: each is logged rounded to its sensor's quantum.
    truth : dict, optional
        The parameters the log is recorded at (the plant file's otherwise).
    start : dict, optional
        The start state, by state name (the declaration's otherwise); written into the
        experiment file as its ``start``.
    name : str
        The experiment's name and its files' (``NAME.csv``, ``NAME.yaml``).
    seed : int
        Where each quantizer's grid starts (a sensor's zero is anywhere within one count).
    """
    from furuta_cosim.fmu.exporter import build_fmu, declaration
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.fmu.session import PlantSession

    folder = Path(folder)
    loaded = load_plant(plant)
    model = declaration(loaded)
    states = [s.name for s in model.states]
    start = {s: float(v) for s, v in (start or {}).items()}
    values = {**(truth or {}), **{f"{s}_start": v for s, v in start.items()}}
    names = list(inputs)
    columns = [np.asarray(inputs[n], dtype=float) for n in names]
    count = len(columns[0])
    rng = np.random.default_rng(seed)
    with PlantSession.open(build_fmu(loaded)) as session:
        session.reset(values)
        session.set_io(names, list(outputs))
        rows = [session.get(list(outputs))]
        for k in range(count - 1):
            rows.append(session.step([c[k] for c in columns], period))
        rows = np.array(rows)
    for j, (_, quantum) in enumerate(outputs.values()):
        if quantum:
            offset = rng.uniform(-0.5, 0.5) * quantum
            rows[:, j] = np.round((rows[:, j] - offset) / quantum) * quantum + offset
    t = period * np.arange(count)
    header = ",".join(["t", *names, *outputs])
    table = np.column_stack([t, *columns, rows])
    write_text(folder / f"{name}.csv", header + "\n" + "\n".join(",".join(repr(float(v)) for v in row)
                                                               for row in table) + "\n")
    stated = {s: start.get(s, next(v.start for v in model.reals if v.name == f"{s}_start")) for s in states}
    document = {"name": name, "description": f"open-loop log of {loaded.name}, recorded at known values",
                "data": f"{name}.csv", "header": 1, "columns": ["t", *names, *outputs], "time": "t",
                "inputs": {n: {"column": n, "unit": _unit(model, n)} for n in names},
                "outputs": {n: {"column": n, "unit": unit, **({"quantum": float(q)} if q else {})}
                            for n, (unit, q) in outputs.items()},
                "start": stated}
    path = folder / f"{name}.yaml"
    write_text(path, yaml.safe_dump(document, sort_keys=False))
    return path


def _unit(model, name: str) -> str:
    return next(v.unit for v in model.reals if v.name == name)
