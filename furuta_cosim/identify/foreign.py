"""Synthetic logs as other labs record them, of a plant whose truth is known: to check that
the toolchain reads them as they come (the tests, tools/foreign_logs.py, the docs' "Logs from
other tools" page).

Each writes a CSV and its experiment file into a folder and returns the experiment file:

- :func:`pd_log`: a QUBE balancing under a lab's PD at 500 Hz, acting on the errors to two
  references (the arm's square wave, the pendulum's 0) with derivatives filtered at 50 rad/s
  by backward Euler; the arm logged in degrees, the pendulum with the opposite sign, the
  controller's own output logged, and a footer row of NaN (the last state, with no action);
  ``jitter``: the loop runs on a ROS 2 timer's clock (1.5 to 4.8 ms apart), its derivative over
  the time since its last run, and logs each run.
- :func:`chirp_log`: a hanging QUBE driven open loop by a chirp whose voltage reaches the
  motor ``delay`` seconds late; ``jitter`` logs it as a ROS bag converted by PlotJuggler does
  (a clock of 1.5 to 4.8 ms steps, the command and the angles on interleaved rows).

The controller and the delay here are written out by hand (not with identify/laws.py or the
replay's delay), so that a test of those reads an independent implementation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from furuta_cosim.files import write_text

COUNTS = 2048
PERIOD = 0.002
# the lab's PD, in its own units: the arm's error in degrees, the pendulum's in rad with the
# lab's sign (the opposite of ours); the derivative filter's cutoff in rad/s
PD_GAINS = {"arm": (-1.0 * math.pi / 180.0, -1.2 * math.pi / 180.0), "pendulum": (-34.0, -3.0)}
CUTOFF = 50.0


def _session(plant: str):
    from furuta_cosim.fmu.session import PlantSession
    from furuta_cosim.identify.replay import target_for

    return PlantSession.open(target_for(plant=plant).fmu)


def _counted(angle: float, zero: float) -> float:
    per = 2.0 * math.pi / COUNTS
    return zero + round((angle - zero) / per) * per


def _write(folder: Path, name: str, header: list[str], rows: np.ndarray, experiment: dict,
           footer: bool = False) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    lines = [",".join(header)] + [",".join(repr(float(v)) for v in row) for row in rows]
    if footer:
        lines.append(",".join(["nan"] * len(header)))
    write_text(folder / f"{name}.csv", "\n".join(lines) + "\n")
    path = folder / f"{name}.yaml"
    write_text(path, "# a synthetic log (furuta_cosim.identify.foreign)\n"
               + yaml.safe_dump(experiment, sort_keys=False))
    return path


def pd_log(folder: str | Path, *, plant: str = "qube-servo-3", duration: float = 6.0, seed: int = 0,
           amplitude: float = 10.0, square: float = 3.0, name: str = "pd", delay: float = 0.0,
           free_delay: tuple | None = None, truth: dict | None = None, jitter: bool = False) -> Path:
    """Write a balancing log under a lab's errors-PD (the module's first kind) and return its
    experiment file, which states the law in the lab's words and names its logged output.

    Parameters
    ----------
    folder : path
        Where ``<name>.csv`` and ``<name>.yaml`` are written (created if needed).
    plant : str
        The true plant (a plant file or name).
    duration : float
        Seconds logged.
    seed : int
        The start (the pendulum 0.01 to 0.03 rad off upright) and the current sensor's noise.
    amplitude : float
        The arm reference's square wave, in degrees (the linear estimate of a balancing log's
        angles holds for moves of about 10 degrees: identify's docs).
    square : float
        The square wave's period (s).
    name : str
        The files' name.
    delay : float
        Seconds from each command's write to the motor, inside the loop (the plant stepped in
        0.25 ms pieces, so a delay lands inside a sample); 0: the next sample's step.
    free_delay : (float, float), optional
        The experiment fits the loop's delay within these bounds (s); else it states ``delay``.
    truth : dict, optional
        Plant parameters that differ from the plant file's.
    jitter : bool
        The loop runs at instants 1.5 to 4.75 ms apart (on a 0.25 ms grid, 2 ms the most
        common), its derivatives over the time since the run before (the first over 2 ms).

    Returns
    -------
    Path
        The experiment file.
    """
    folder = Path(folder)
    off = 0.01 + 0.02 * np.random.default_rng(seed).random()
    if jitter:
        rng, fine_steps, t = np.random.default_rng([seed, 2]), [0], [0.0]
        while True:
            fine_steps.append(fine_steps[-1] + int(rng.choice([6, 7, 8, 8, 8, 8, 9, 10, 19])))
            if fine_steps[-1] * 0.00025 > duration + 1e-12:
                break
            t.append(fine_steps[-1] * 0.00025)
        t = np.array(t)
        n = len(t)
    else:
        n = int(round(duration / PERIOD)) + 1
        t = np.arange(n) * PERIOD
    arm_ref = np.where(np.floor(t / (square / 2.0)) % 2 == 0, 0.0, amplitude)
    pend_ref = np.zeros(n)
    last = {"arm": 0.0, "pendulum": 0.0}
    rate = {"arm": 0.0, "pendulum": 0.0}
    rows = []
    pending: list = []    # (when it reaches the motor, command), with a delay
    level, fine = 0.0, 0.00025

    def held(session, seconds):   # the motor's voltage held at ``level``, in fine pieces
        pieces = max(1, int(math.ceil(seconds / fine - 1e-9)))
        for _ in range(pieces):
            out = session.step([level], seconds / pieces)
        return out

    with _session(plant) as session:
        session.reset(parameters={**(truth or {}), "theta1_start": off})
        session.set_io(inputs=["V"], outputs=["theta0", "theta1", "i"])
        y = session.get(["theta0", "theta1", "i"])
        noise = np.random.default_rng([seed, 1]).normal(0.0, 0.004, n)
        for k in range(n):
            arm = math.degrees(_counted(y[0], 0.0))          # the lab logs degrees
            pendulum = -_counted(y[1], math.pi)              # and the pendulum the other way
            u = 0.0
            # backward Euler of s w / (s + w) over the time since the last run: d = a (d + w (e - e_prev))
            a = 1.0 / (1.0 + CUTOFF * (t[k] - t[k - 1] if k and jitter else PERIOD))
            for key, error in (("arm", arm_ref[k] - arm), ("pendulum", pend_ref[k] - pendulum)):
                rate[key] = a * (rate[key] + CUTOFF * (error - last[key]))
                last[key] = error
                kp, kd = PD_GAINS[key]
                u += kp * error + kd * rate[key]
            rows.append((t[k], arm_ref[k], pend_ref[k], arm, pendulum, y[2] + noise[k], u))
            if k < n - 1 and not delay and not jitter:
                y = session.step([u], PERIOD)
            elif k < n - 1:
                pending.append((t[k] + delay, u))
                now = t[k]
                while pending and pending[0][0] < t[k + 1] - 1e-12:
                    when, value = pending.pop(0)
                    if when > now + 1e-12:
                        held(session, when - now)
                        now = when
                    level = value
                y = held(session, t[k + 1] - now)
    quantum = 360.0 / COUNTS
    experiment = {
        "description": "a QUBE balancing under its lab's PD at 500 Hz" + (", on a clock that jitters" if jitter else "")
                       + " (synthetic)",
        "data": f"{name}.csv", "columns": ["time", "arm_ref", "pend_ref", "arm", "pend", "current", "u"],
        "time": "time", "window": [0.0, float(t[-1])],   # the footer row is outside it
        "inputs": {"V": {"column": "u", "unit": "V"}},
        "outputs": {"theta0": {"column": "arm", "unit": "deg", "quantum": quantum},
                    "theta1": {"column": "pend", "scale": -1.0, "quantum": 2.0 * math.pi / COUNTS},
                    "i": {"column": "current", "unit": "A", "noise": 0.004}},
        "start": {"theta0": 0.0, "dtheta0": 0.0, "theta1": float(off), "dtheta1": 0.0, "i": 0.0},
        "loop": {"law": {"terms": {"theta0": {"reference": "arm_ref", "kp": PD_GAINS["arm"][0],
                                              "kd": PD_GAINS["arm"][1]},
                                   "theta1": {"reference": "pend_ref", "kp": PD_GAINS["pendulum"][0],
                                              "kd": PD_GAINS["pendulum"][1]}},
                         "derivative": {"on": "error", "cutoff": CUTOFF, "method": "backward"},
                         "output": "u"},
                 "counts": COUNTS},
    }
    if free_delay is not None:
        experiment["loop"]["delay"] = {"free": [float(b) for b in free_delay]}
    elif delay:
        experiment["loop"]["delay"] = float(delay)
    return _write(folder, name, ["time", "arm_ref", "pend_ref", "arm", "pend", "current", "u"], np.array(rows),
                  experiment, footer=True)


def chirp(t: np.ndarray, amplitude: float = 2.0, low: float = 0.5, high: float = 8.0) -> np.ndarray:
    """A linear chirp from ``low`` to ``high`` Hz over ``t``, in volts."""
    span = float(t[-1] - t[0]) or 1.0
    phase = 2.0 * math.pi * (low * t + 0.5 * (high - low) * t ** 2 / span)
    return amplitude * np.sin(phase)


def chirp_log(folder: str | Path, *, delay: float = 0.012, plant: str = "qube-servo-3",
              duration: float = 4.0, seed: int = 0, jitter: bool = False, free_delay: tuple | None = None,
              name: str = "chirp", truth: dict | None = None) -> Path:
    """Write an open-loop chirp log of a hanging QUBE (the module's second kind) and return
    its experiment file. The voltage is logged as commanded and reaches the motor ``delay``
    late; the angles are counted by 2048-count encoders, the current has 4 mA of noise. The
    plant is stepped in 0.25 ms steps, so a delay lands inside a sample.

    Parameters
    ----------
    folder : path
        Where ``<name>.csv`` and ``<name>.yaml`` are written (created if needed).
    delay : float
        Seconds from a logged command to the motor.
    plant : str
        The true plant (a plant file or name).
    duration : float
        Seconds logged.
    seed : int
        The chirp (1.5 to 2.5 V, from 0.5 Hz up to 6 to 10 Hz), the noise and the jitter.
    jitter : bool
        Log it as a ROS bag converted by PlotJuggler: 1.5 to 4.8 ms steps, the command and
        the sensors on rows of their own (the experiment resamples it to 2 ms with fill).
    free_delay : (float, float), optional
        The experiment fits the input's delay within these bounds (s); else it states ``delay``.
    name : str
        The files' name.
    truth : dict, optional
        Plant parameters that differ from the plant file's.

    Returns
    -------
    Path
        The experiment file.
    """
    folder = Path(folder)
    rng = np.random.default_rng(seed)
    fine = 0.00025
    steps = int(round(duration / fine))
    t = np.arange(steps + 1) * fine
    command_times = np.arange(0.0, duration + 1e-12, PERIOD)
    commanded = chirp(command_times, amplitude=1.5 + rng.random(), high=6.0 + 4.0 * rng.random())
    with _session(plant) as session:
        session.reset(parameters={**(truth or {}), "theta1_start": math.pi})
        session.set_io(inputs=["V"], outputs=["theta0", "theta1", "i"])
        y = [session.get(["theta0", "theta1", "i"])]
        for k in range(steps):   # the command held from its write plus the delay
            j = int(math.floor((t[k] + 0.5 * fine - delay) / PERIOD + 1e-9))
            y.append(session.step([float(commanded[j]) if j >= 0 else 0.0], fine))
    y = np.array(y)
    if not jitter:
        every = int(round(PERIOD / fine))
        picked = np.arange(0, steps + 1, every)
        times = t[picked]
        values = y[picked]
        volts = commanded[:len(times)]
    else:   # 2 ms nominal, 1.5 to 4.8 ms steps on the fine grid
        times, k = [], 0
        while k <= steps:
            times.append(k)
            k += int(rng.choice([6, 7, 8, 8, 8, 8, 9, 10, 19]))
        picked = np.array(times)
        times = t[picked]
        values = y[picked]
        volts = commanded[np.minimum(np.floor(times / PERIOD + 1e-9).astype(int), len(commanded) - 1)]
    angles = np.array([[_counted(a, 0.0), _counted(b, math.pi)] for a, b in values[:, :2]])
    current = values[:, 2] + rng.normal(0.0, 0.004, len(times))
    quantum = 2.0 * math.pi / COUNTS
    delay_entry = {"free": [float(b) for b in free_delay]} if free_delay is not None else float(delay)
    experiment = {"description": f"a hanging QUBE driven by a chirp, its voltage {delay * 1000:g} ms late (synthetic)",
                  "data": f"{name}.csv", "columns": ["t", "V", "arm", "pend", "I"], "time": "t",
                  "inputs": {"V": {"column": "V", "unit": "V", "delay": delay_entry}},
                  "outputs": {"theta0": {"column": "arm", "unit": "rad", "quantum": quantum},
                              "theta1": {"column": "pend", "unit": "rad", "quantum": quantum},
                              "i": {"column": "I", "unit": "A", "noise": 0.004}},
                  "start": {"theta0": 0.0, "dtheta0": 0.0, "theta1": math.pi, "dtheta1": 0.0, "i": 0.0}}
    if not delay and free_delay is None:
        del experiment["inputs"]["V"]["delay"]
    rows = np.column_stack([times, volts, angles, current])
    if jitter:   # the command and the sensors as interleaved topics: each row holds one of them
        experiment["resample"] = {"period": PERIOD, "fill": True}
        split = [list(rows[0])]   # the first row holds every topic: fill carries from there
        for row in rows[1:]:
            split.append([row[0], row[1], np.nan, np.nan, np.nan])
            split.append([row[0] + 1e-4, np.nan, row[2], row[3], row[4]])
        rows = np.array(split)
    return _write(folder, name, ["t", "V", "arm", "pend", "I"], rows, experiment)
