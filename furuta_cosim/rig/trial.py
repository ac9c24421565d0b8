"""A rig trial: one candidate controller run on the rig through a tuning spec's scenarios.

A trial is one ``rig run`` of a :class:`TrialRuntime`: from the rig at rest, the safe
swing-up-and-balance controller swings the pendulum up and holds it until it has been still
upright with the arm home for ``settle`` seconds (the reset); then for each scenario the
candidate takes over (its state reset) and follows the scenario's reference for its duration,
the safe controller holding the pendulum again between scenarios; then the damp-down brings the
rig to rest for the next trial. While it holds the pendulum, the safe controller's arm
reference is the integral of the arm's angle (``hold_gain`` rad per rad s, within
``hold_limit`` rad): a rig whose encoder cable pulls the arm off home settles off home under
state feedback alone (the cable's torque balanced by the arm's error), and the integral moves
the reference until the arm stands at home; on a rig like its model it stays near 0. It runs
only with the pendulum upright and the arm slow (:data:`HOLD_RATE`); within half of ``home``
of home it holds still: with the arm's Coulomb friction an integral
that never rests makes the arm hunt about home (a limit cycle of about 7 s on a QUBE whose
cable pulls the arm 3 degrees off, at 2 rad per rad s). The
reference the reset ends at (when the first scenario starts) is the trial's ``hold_offset``. A candidate that lets the pendulum fall beyond ``fall`` rad from
upright fails that scenario, and the trial ends there: the damp-down lets the pendulum fall on
and brings it to rest (the scenarios after it are not run). A trip of the supervisor ends the
run, the rig left at 0 V.

Each sample's phase is in the log (``phase``: -1 the reset, k >= 0 scenario k, -2 settling
between scenarios, -3 damping down), and so is each scenario's reference, so a scenario's
samples make a trace whose metrics are computed as a simulation's are (:func:`segment_traces`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.errors import ConfigError
from furuta_cosim.swingup import BALANCE, wrap

RESET, SETTLE, DAMP = -1.0, -2.0, -3.0
# the integral holding the arm home runs while the arm moves slower than this (rad/s): not while
# the catch throws the arm about (it wound up there and doubled the reset's time on a rig like
# its model, 8 s to 14 s, at 0.25 rad per rad s)
HOLD_RATE = 0.2


@dataclass(frozen=True)
class Segment:
    """A scenario as a trial runs it: the candidate's runtime controller for it (``control``,
    ``reset``) and its reference at each control sample."""

    name: str
    controller: object
    r: np.ndarray


class TrialRuntime:
    """The phases of a trial (module docstring) as a runtime controller for the rig runner:
    ``control(x, r)``, ``reset()``, ``finished``, and for the log the ``phase`` whose controller
    computed the last command and the ``reference`` it followed (``state`` is the phase the next
    sample starts in)."""

    n_xc = 0
    name = "trial"

    def __init__(self, safe, segments: list[Segment], damp, period: float, *,
                 settle: float = 1.0, upright: float = 0.05, still: float = 1.0, home: float = 0.05,
                 fall: float = 0.5, reset_timeout: float = 25.0, rest: float = 0.5,
                 damp_timeout: float = 15.0, hold_gain: float = 0.25, hold_limit: float = 0.5):
        self.safe, self.segments, self.damp, self.period = safe, segments, damp, period
        self.hold_gain, self.hold_limit = hold_gain, hold_limit
        self.settle, self.upright, self.still, self.home, self.fall = settle, upright, still, home, fall
        self.reset_timeout, self.rest_hold, self.damp_timeout = reset_timeout, rest, damp_timeout
        self.reset()

    def reset(self) -> None:
        self.safe.reset()
        self.state, self.j, self.quiet, self.rest, self.elapsed = RESET, 0, 0.0, 0.0, 0.0
        self.phase = RESET
        self.next_segment = 0
        self.failures: dict[str, str] = {}
        self.reference = 0.0
        self.hold_offset = 0.0  # the safe controller's arm reference (module docstring)
        self.reset_offset: float | None = None  # hold_offset when the reset handed over
        self.finished = self.at_rest = False

    @property
    def mode(self) -> float:
        """The log's ``mode``: the safe controller's (0 swinging up, 1 balancing), 1 while the
        candidate runs."""
        return 1.0 if self.phase >= 0 else self.safe.mode

    @property
    def switches(self) -> list:
        return self.safe.switches

    def _enter(self, phase: float) -> None:
        self.state, self.j, self.quiet, self.rest, self.elapsed = phase, 0, 0.0, 0.0, 0.0

    def control(self, x, _rbar: float) -> float:
        self.elapsed += self.period
        self.reference = 0.0
        theta1 = wrap(x[2])
        self.phase = self.state
        if self.state in (RESET, SETTLE):
            if self.safe.mode != BALANCE:  # swinging up (or up again after a fall): it starts over
                self.hold_offset = 0.0
            elif abs(x[0]) > self.home / 2 and abs(theta1) < self.upright and abs(x[1]) < HOLD_RATE:
                step = self.hold_offset - self.hold_gain * self.period * x[0]
                self.hold_offset = min(self.hold_limit, max(-self.hold_limit, step))
            u = self.safe.control(x, self.hold_offset)
            self.reference = self.hold_offset
            held = (self.safe.mode == BALANCE and abs(theta1) < self.upright and abs(x[3]) < self.still
                    and abs(x[0]) < self.home and abs(x[1]) < self.still)
            self.quiet = self.quiet + self.period if held else 0.0
            if self.quiet >= self.settle:
                if self.next_segment == len(self.segments):
                    self._enter(DAMP)
                else:
                    if self.state == RESET:
                        self.reset_offset = self.hold_offset
                    self.segments[self.next_segment].controller.reset()
                    self._enter(float(self.next_segment))
            elif self.elapsed > self.reset_timeout:
                self.failures.setdefault("reset", f"the safe controller did not hold the pendulum still "
                                                  f"upright within {self.reset_timeout:g} s")
                self._enter(DAMP)
            return u
        if self.state >= 0:
            k = int(self.state)
            segment = self.segments[k]
            self.reference = float(segment.r[self.j])
            u = segment.controller.control([x[0], x[1], theta1] + list(x[3:]), self.reference)
            self.j += 1
            if abs(theta1) > self.fall:
                self.failures[segment.name] = (f"the pendulum fell beyond {self.fall:g} rad from upright "
                                               f"{self.j * self.period:.3f} s into {segment.name}")
                # the damp-down takes over: the pendulum falls on at 0 V and is brought to rest
                # (catching a pendulum already falling fast saturated the balance controller and
                # threw the arm to its limit; swinging it up again from there sent it over the top)
                self._enter(DAMP)
            elif self.j == len(segment.r):
                self.next_segment = k + 1
                self.safe.mode = BALANCE
                self.safe.balance.reset()
                self._enter(SETTLE)
            return u
        # damping down to rest for the next trial
        if self.damp.done(x):
            self.rest += self.period
        else:
            self.rest = 0.0
        if self.rest >= self.rest_hold or self.elapsed > self.damp_timeout:
            self.finished, self.at_rest = True, self.rest >= self.rest_hold
            return 0.0
        return self.damp.control(x)


def run_trial(segments: list[Segment], board, plant, output: str | Path, *, reset="swingup-qube",
              period: float = 0.002, zero: bool = True, fall: float = 0.5,
              log: Callable[[str], None] = lambda line: None) -> dict:
    """One trial on ``board`` (module docstring): ``reset``, a swing-up-and-balance file, resets
    the rig and holds the pendulum between the ``segments``; the run folder ``output`` is as
    ``rig run`` writes it.

    Parameters
    ----------
    segments : list of Segment
        Each scenario's candidate controller and reference, in the order they run.
    board : Board
        Not yet opened.
    plant : PlantSet
        The rig's plant file (its limits, sensors and pendulum).
    output : path
        The trial's run folder (new or empty).
    reset : str, path or ControllerFile
        The safe swing-up-and-balance controller.
    period : float
        The loop's period (s).
    zero : bool
        Zero the encoders first (the rig at rest, hanging); without, counts go on from before.
    fall : float
        A candidate that lets the pendulum fall this far from upright (rad) fails its scenario.
    log : callable
        Takes the lines the run says.

    Returns
    -------
    dict
        The run's summary (``rig run``'s) with ``failures`` (what failed: a scenario, or the
        reset, and why), ``tripped`` and ``at_rest`` (the damp-down finished: the next trial may
        zero the encoders).
    """
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.cosim.runtime import RuntimeController
    from furuta_cosim.design.controller import discretize_controller
    from furuta_cosim.rig.runner import run_rig
    from furuta_cosim.swingup import DampDown, SwingUpRuntime, pendulum

    cfile = load_controller(reset) if isinstance(reset, (str, Path)) else reset
    if cfile.swingup is None:
        raise ConfigError([f"{cfile.source}: not a swing-up file: a trial resets the rig by swinging "
                           "the pendulum up with one"])
    balance = RuntimeController(discretize_controller(cfile.controller, period),
                                cfile.F if cfile.F is not None else 1.0)
    runtime = TrialRuntime(SwingUpRuntime(balance, cfile.swingup), segments,
                           DampDown(*pendulum(plant.parameters)), period, fall=fall)
    # the longest a trial can take: each phase's timeout, each scenario's duration
    longest = runtime.reset_timeout + sum(len(s.r) * period + runtime.reset_timeout
                                          for s in segments) + runtime.damp_timeout
    summary = run_rig(runtime, board, plant, output, duration=longest, zero=zero, log=log)
    summary["failures"] = dict(runtime.failures)
    summary["tripped"] = summary["status"] == "tripped"
    summary["at_rest"] = runtime.at_rest
    summary["hold_offset"] = runtime.reset_offset
    return summary


def segment_traces(folder: str | Path, segments: list[Segment], tracked: str = "theta0") -> dict:
    """The trace of each scenario a trial ran, from its log (``name -> Trace``): the samples
    the candidate controlled, time from 0, the angles as the candidate saw them (the
    pendulum's wrapped to (-pi, pi]), the voltage applied as the input. A scenario cut short
    (a fall, a trip) has the trace of what ran and a ``failure``; one never reached has none."""
    from furuta_cosim.cosim.trace import Trace
    from furuta_cosim.rig.runner import COLUMNS

    path = Path(folder) / "log.csv"
    log = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2) if path.stat().st_size else np.zeros((0, 0))
    column = {name: k for k, name in enumerate(COLUMNS)}
    phase = log[:, column["phase"]] if len(log) else np.zeros(0)
    traces = {}
    for k, segment in enumerate(segments):
        rows = log[phase == k]
        if not len(rows):
            continue
        t = rows[:, column["t"]] - rows[0, column["t"]]
        signals = {"theta0": rows[:, column["theta0"]], "dtheta0": rows[:, column["dtheta0"]],
                   "theta1": np.array([wrap(v) for v in rows[:, column["theta1"]]]),
                   "dtheta1": rows[:, column["dtheta1"]], "i": rows[:, column["i"]]}
        failure = None if len(rows) == len(segment.r) else \
            f"the candidate ran {len(rows)} of its {len(segment.r)} samples"
        traces[segment.name] = Trace(segment.name, t, rows[:, column["r"]], rows[:, column["V"]], signals,
                                     tracked, "V", failure,
                                     {"theta0": "rad", "dtheta0": "rad/s", "theta1": "rad",
                                      "dtheta1": "rad/s", "i": "A", "V": "V"})
    return traces
