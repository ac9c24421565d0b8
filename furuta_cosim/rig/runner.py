"""``rig run``: a controller on a board in real time, every sample logged.

At each control period T (the controller's own: 2 ms on the QUBE) the runner waits for the
sample's deadline on the board's clock, reads the encoders and the current, makes the state
the controller feeds back (angles from counts; rates by a filtered difference, the bilinear
form of ``w s / (s + w)`` at ``rate_filter`` Hz; the current as measured), computes the
command (the same generated controller code a simulation runs, swing-up and catch included),
lets the supervisor check the sample and clip the command to the amplifier's limit, writes it,
reloads the board's watchdog and records the sample. The loop runs in Python: a sample's
reading, controller and writing take tens of microseconds of a 2 ms period here (measured by
``tools/bench_rig.py``), a controller FMU would add an FMI call per sample for nothing, and the
C loop of the simulations steps an FMU, not a board.

A run folder holds ``log.csv`` (every sample: its time, how late its reading was sampled (the
board's own instant where it gives one: a paced virtual board's last step may be before the
deadline, and the column then reads negative) and how long from there to the command's write,
the reference, the command and the voltage applied, the angles, the current, the rates,
the counts, the mode), ``experiment.yaml`` (the log as an experiment file: the voltage applied
is its input, so ``replay``, ``identify`` and ``regress`` read it as they read any log), the
controller files it ran (``controllers/``), ``summary.json`` and ``summary.md`` (why it
stopped, the loop's timing, peaks, the swing-up's catch), and for the virtual board
``board.csv``, what the "hardware" applied.
"""

from __future__ import annotations

import sys

import json
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError, Signalled
from furuta_cosim.files import folder as make_folder, output_folder, write_text
from furuta_cosim.fmu.plants import content_sha256
from furuta_cosim.measurement import RATE_FILTER, RateFilter
from furuta_cosim.rig.board import Board
from furuta_cosim.rig.supervisor import (FINISHED, INTERRUPTED, TRIPPED, Limits,
                                         Supervisor, Trip)

COLUMNS = ("t", "late", "compute", "r", "V_command", "V", "theta0", "theta1", "i", "dtheta0",
           "dtheta1", "arm_counts", "pendulum_counts", "mode", "phase")
# mode: 0 swinging up, 1 the controller; phase: 0 for a plain run, a trial's phase (rig/trial.py)
WATCHDOG = 0.1           # s: the board's watchdog timeout
MAX_DURATION = 3600.0    # s: one run at most (its log is kept in memory)
LATE_WARNING = 0.1       # a sample later than this fraction of the period is worth a warning
# rad from upright: a balance-only controller is started only with its pendulum this close to
# upright (the swing-up's own catch angle, swingup.py, where it hands over to a balance law: a
# linear law designed at upright is not asked to catch a pendulum any farther out)
CATCH = 0.3


def controller_for(controller, period: float | None = None, scenario=None):
    """(controller file, runtime controller, reference times and values, period) for a rig
    run: on a scenario's reference and duration (its timing and delay), or regulating at 0."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.cosim.runtime import runtime_for

    if scenario is not None:
        from furuta_cosim.cosim import prepare
        from furuta_cosim.cosim.evaluation import compile_controller
        from furuta_cosim.scenario import load_scenario

        prepared = prepare(load_scenario(scenario))
        compiled = compile_controller(prepared, controller, key="controller")
        return compiled.cfile, compiled.runtime, prepared.t, prepared.rbar, prepared.control_period
    if callable(getattr(controller, "control", None)):  # a runtime of the rig's own: homing, a trial
        return None, controller, None, None, controller.period
    cfile = controller if not isinstance(controller, (str, Path)) else load_controller(controller)
    period = period or cfile.period or cfile.controller.period
    if not period:
        raise ConfigError([f"{cfile.source}: period: missing (a rig runs a controller at its period)"])
    cfile, runtime = runtime_for(cfile, period)
    return cfile, runtime, None, None, period


class Homing:
    """The damp-down that brings a rig to rest between runs, as a runtime controller: the swing-up's
    energy law reversed (:class:`~furuta_cosim.swingup.DampDown`: the pendulum's energy taken
    out, the arm pulled home); ``finished`` once the rig has been at rest for ``hold`` seconds."""

    n_xc = 0
    name = "home"

    def __init__(self, law, period: float, hold: float = 0.5):
        self.law, self.period, self.hold = law, period, hold
        self.reset()

    def reset(self) -> None:
        self.rest, self.finished = 0.0, False

    def state(self) -> list:
        return []

    def control(self, x, _rbar: float) -> float:
        self.rest = self.rest + self.period if self.law.done(x) else 0.0
        self.finished = self.rest >= self.hold
        return 0.0 if self.finished else self.law.control(x)


def home(board: Board, plant, output: str | Path, *, timeout: float = 20.0, period: float = 0.002,
         log: Callable[[str], None] = lambda line: None) -> dict:
    """Bring the rig to rest, the pendulum hanging still and the arm home (the damp-down on
    ``plant``'s pendulum), and write a run folder of it (as :func:`run_rig`); the board's
    counts go on from before.

    Parameters
    ----------
    board : Board
        Not yet opened.
    plant : PlantSet
        The rig's plant file: its pendulum, limits and sensors.
    output : path
        The run folder (new or empty).
    timeout : float
        Give up (status ``timeout``, exit code 1) when not at rest after this many seconds.
    period : float
        The loop's period (s).
    log : callable
        Takes the lines the run says.

    Returns
    -------
    dict
        The run's summary: ``finished`` once at rest, ``tripped`` if the supervisor stopped it,
        ``timeout``.
    """
    from furuta_cosim.swingup import DampDown, pendulum

    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not (
            math.isfinite(timeout) and 0 < timeout <= MAX_DURATION):
        raise ConfigError([f"timeout: expected seconds in (0, {MAX_DURATION:g}], got {timeout}"])
    if timeout < period:
        raise ConfigError([f"timeout: {timeout:g} s is shorter than one sample of the homing loop ({period:g} s)"])
    return run_rig(Homing(DampDown(*pendulum(plant.parameters)), period), board, plant, output,
                   duration=timeout, zero=False, log=log)


class _AtSamples:
    """Ctrl-C, SIGTERM and SIGHUP (the terminal closed) held until the next sample starts (in
    the main thread): raised inside a board's call (the virtual board steps its plant in this
    process) they could leave it between two states; raised at a sample's start the runner
    stops as it always does. Once the loop has ended (:meth:`closing`) every further signal
    is held until the rig is safe and the log, summary and experiment file are written: a
    second Ctrl-C then loses nothing (it used to kill the write and leave the folder empty)."""

    def __init__(self):
        import signal
        import threading

        self.pending, self.previous, self.closed = None, {}, False
        if threading.current_thread() is not threading.main_thread():
            return
        for number in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if number is None:
                continue
            self.previous[number] = signal.getsignal(number)
            signal.signal(number, self._hold)

    def _hold(self, number, _frame) -> None:
        if self.closed:   # the rig is being made safe and the run written: nothing interrupts that
            self.pending = self.pending or number
            return
        if self.pending is not None:  # a second one: a board's call hangs; stop now, as the first says
            self.deliver()
        self.pending = number

    def closing(self) -> None:
        """From here on signals wait for :meth:`restore` (the loop has ended)."""
        self.closed = True

    def deliver(self) -> None:
        import signal

        if self.pending is None:
            return
        number, self.pending = self.pending, None
        handler = self.previous.get(number)
        if handler is signal.SIG_IGN:
            return
        if callable(handler):   # the CLI's (the first signal raises) or Python's Ctrl-C
            handler(number, None)
            return
        if number == signal.SIGINT:
            raise KeyboardInterrupt()
        raise Signalled(signal.Signals(number).name, 128 + number)   # the default: stop as for Ctrl-C

    def restore(self) -> None:
        """The handlers as they were; a signal held while closing is dropped when the run
        already stops for one, else delivered now."""
        import signal

        for number, handler in self.previous.items():
            signal.signal(number, handler)
        pending, self.pending = self.pending, None
        if pending is not None and self.previous and sys.exc_info()[0] is None:
            self.pending = pending
            self.deliver()
        self.previous = {}


def run_rig(controller, board: Board, plant, output: str | Path, *, duration: float | None = None,
            scenario=None, watchdog: float = WATCHDOG, rate_filter: float = RATE_FILTER,
            limits: Limits | None = None, zero: bool = True, log: Callable[[str], None] = lambda line: None,
            progress: Callable[[float, float], None] | None = None, catch: float = CATCH) -> dict:
    """Run ``controller`` on ``board`` and write the run folder ``output`` (module docstring).

    Parameters
    ----------
    controller : str, path or ControllerFile
        Any controller file (a swing-up-and-balance file too).
    board : Board
        From :func:`furuta_cosim.rig.board.board_for` (not yet opened).
    plant : PlantSet
        The rig's plant file: its ``limits`` (the supervisor's) and ``sensors`` (counts per
        revolution, signs).
    output : path
        The run folder (new or empty).
    duration : float, optional
        Seconds to run (regulating at a reference of 0); or ``scenario``.
    scenario : str or path, optional
        Run on the scenario's reference, for its duration.
    watchdog : float
        The board's watchdog timeout (s).
    rate_filter : float
        The cutoff of the rates' filtered difference (Hz).
    limits : Limits, optional
        Instead of the plant file's.
    zero : bool
        Zero the encoders first: the rig must be at rest, the arm at its zero and the pendulum
        hanging (a run from rest); without, the board's counts go on from before (homing).
    log : callable
        Takes the lines a run says (a warning, why it stopped).
    progress : callable, optional
        ``progress(t, duration)`` about once a second.
    catch : float
        A balance-only controller (no swing-up) starts only with the pendulum within this many
        rad of upright; else the run is refused before the amplifier is enabled.

    Returns
    -------
    dict
        ``summary.json``: ``status`` (finished, tripped), ``code`` (0, 1), ``reason``, timing,
        peaks, the swing-up's catch, the files.

    Raises
    ------
    KeyboardInterrupt
        After the rig is safe and every file written (Ctrl-C; SIGTERM in the CLI).
    """
    if (duration is None) == (scenario is None):
        raise ConfigError(["duration: give a duration or a scenario (`scenario`), one of them"])
    if duration is not None and (not math.isfinite(duration) or not 0 < duration <= MAX_DURATION):
        raise ConfigError([f"duration: expected seconds in (0, {MAX_DURATION:g}], got {duration}"])
    for name, value, low, high in (("watchdog", watchdog, 0.005, 10.0), ("rate_filter", rate_filter, 0.1, 1e4),
                                   ("catch", catch, 1e-3, math.pi)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
            raise ConfigError([f"{name}: expected a number in [{low:g}, {high:g}], got {value}"])
    out = output_folder(output)
    if out.is_dir() and any(out.iterdir()):
        raise ConfigError([f"output {out}: holds files already; a rig run takes a new or empty folder"])
    cfile, runtime, times, reference, period = controller_for(controller, scenario=scenario)
    # what simulate refuses, refused before the board is opened: a period the plant file's
    # model does not integrate, a run shorter than one sample
    low, high = getattr(plant, "control_period", (None, None))
    if high is not None and period > high * (1 + 1e-9):
        raise ConfigError([f"{plant.path}: limits.control_period.max: {high:g} s, but the controller runs every "
                           f"{period:g} s (raise the plant's n_substeps and its max, or run a faster controller)"])
    if low is not None and period < low * (1 - 1e-9):
        raise ConfigError([f"{plant.path}: limits.control_period.min: {low:g} s, but the controller runs every "
                           f"{period:g} s"])
    if times is None and duration < period:
        raise ConfigError([f"duration: {duration:g} s is shorter than one sample of the controller ({period:g} s)"])
    steps = int(round(duration / period)) if times is None else len(times)
    reference = np.zeros(steps) if reference is None else np.asarray(reference, dtype=float)
    limits = limits or Limits.of(plant)
    if limits.voltage is None:
        log(f"warning: {plant.path}: no voltage limit (limits.voltage): commands go to the board "
            "unclipped (set your amplifier's limit)")
    supervisor = Supervisor(limits, period)
    counts = float(plant.sensors.get("encoder_counts", 2048))
    signs = (float(plant.sensors.get("arm_sign", 1)), float(plant.sensors.get("pendulum_sign", 1)))
    per_count = 2.0 * math.pi / counts
    rates = RateFilter(period, rate_filter)
    rows = np.full((steps, len(COLUMNS)), np.nan)
    woke_late = np.zeros(steps)   # s each sample's loop woke after its deadline (the machine's)
    stamps = np.full(steps, np.nan)   # when each sample's command was written
    mode = getattr(runtime, "mode", None)
    status, code, reason, failed = "finished", FINISHED, f"ran its {steps * period:g} s", []
    done = 0
    runtime.reset()
    existed = out.exists()
    board.open()  # a board that cannot be opened drove nothing: one error, no run folder
    try:
        if zero:
            board.zero_encoders()
        if cfile is not None and cfile.swingup is None and mode is None and _balances(cfile):
            _within_catch(board, cfile, signs, per_count, catch)
    except BaseException:
        board.close()   # never enabled: nothing was driven, and no run folder is left
        if not existed and out.is_dir():  # but for the log a board keeps of its own (the virtual's)
            for name in ("board.csv",):
                (out / name).unlink(missing_ok=True)
            try:
                out.rmdir()
            except OSError:
                pass
        raise
    make_folder(out, root=True)
    started_wall = time.time()
    signals = _AtSamples()
    woke = clock = first_read = read_at = None
    try:
        board.write(0.0)
        board.arm_watchdog(watchdog)
        board.enable()
        clock = board.clock()
        start = clock.now() + 2 * period
        shown = 0.0
        for k in range(steps):
            deadline = start + k * period
            woke = clock.wait_until(deadline)
            signals.deliver()  # a Ctrl-C or SIGTERM that came during the last sample, now
            reading = board.read()
            # when the reading was sampled: the board's own time where it says (a paced board's
            # process may have last stepped before the deadline), else as the loop woke
            read_at = reading.at if reading.at is not None else woke
            if k == 0:
                first_read = read_at   # the board's own record gives the state there (_start)
            theta0 = signs[0] * reading.arm * per_count
            theta1 = math.pi + signs[1] * reading.pendulum * per_count  # zeroed hanging
            dtheta0, dtheta1 = rates((theta0, theta1))
            current = reading.current if reading.current is not None else 0.0
            x = [theta0, dtheta0, theta1, dtheta1, current]
            command = runtime.control(x, float(reference[k]))
            volts = supervisor.clip(command)
            late = woke - deadline
            woke_late[k] = late
            # a trial's runtime says which reference it followed and in which phase it is
            rows[k] = (k * period, read_at - deadline, 0.0, getattr(runtime, "reference", reference[k]), command, volts,
                       theta0, theta1, current, dtheta0, dtheta1, reading.arm, reading.pendulum,
                       runtime.mode if mode is not None else 1.0, getattr(runtime, "phase", 0.0))
            done = k + 1
            supervisor.check(k * period, x, reading.current, volts, late)
            stamp = board.write(volts)
            written = stamp if stamp is not None else clock.now()
            if not board.reload_watchdog():
                raise Trip("watchdog", f"the board's watchdog had expired at t = {k * period:.4f} s "
                                       "(the loop stalled longer than its timeout)")
            rows[k, 2] = max(written - read_at, 0.0)
            stamps[k] = written
            if getattr(runtime, "finished", False):
                reason = f"at rest after {k * period:.3f} s"
                break
            if progress and k * period - shown >= 1.0:
                shown = k * period
                progress(shown, steps * period)
        if isinstance(runtime, Homing) and not runtime.finished:
            status, code, reason = "timeout", TRIPPED, f"not at rest after {steps * period:g} s"
    except Trip as trip:
        status, code, reason = "tripped", TRIPPED, trip.reason
        if done and trip.limit != "deadline":
            rows[done - 1, 5] = 0.0  # the command of the tripping sample was never written
        if done and rows[done - 1, 2] == 0.0 and woke is not None:
            # how long the tripping sample took too (a late sample trips a loaded machine's run)
            rows[done - 1, 2] = max(clock.now() - (read_at if read_at is not None else woke), 1e-9)
    except KeyboardInterrupt as stop:
        if isinstance(stop, Signalled):   # SIGTERM, SIGHUP
            status, code, said = "terminated", stop.code, stop.name
        else:
            status, code, said = "interrupted", INTERRUPTED, "Ctrl-C"
        reason = f"{said} at t = {max(done - 1, 0) * period:.4f} s"
        raise
    except BaseException as error:
        status, code = "failed", TRIPPED
        reason = f"{type(error).__name__}: {error}"
        raise
    finally:
        signals.closing()   # a second Ctrl-C (or SIGTERM, SIGHUP) now waits until all is written
        try:
            failed = board.safe()
            try:
                board.close()
            except Exception as error:  # noqa: BLE001 - the rig is safe; the log is what matters now
                failed.append(f"close: {type(error).__name__}: {error}")
            _taken(board, rows[:done], stamps[:done])
            summary = _write(out, rows[:done], cfile, board, plant, period, status, code, reason, failed,
                             started_wall, runtime, limits, scenario, rate_filter,
                             _start(board, first_read, rows[:done]), woke_late[:done])
            log(f"{'stopped' if code else 'done'}: {reason}; the rig is at 0 V with the amplifier "
                f"{'off' if not failed else 'in an unknown state: ' + '; '.join(failed)}")
        finally:
            signals.restore()
    return summary


def _balances(cfile) -> bool:
    """Whether a controller feeds the pendulum back (its angle or rate, states 2 and 3): a
    balance law, as against one that moves the arm alone with the pendulum hanging."""
    c = cfile.controller
    acts = np.abs(np.asarray(c.Dc, dtype=float))[:, 2:4].any()
    if c.n_xc:
        acts = acts or np.abs(np.asarray(c.Bc, dtype=float))[:, 2:4].any()
    return bool(acts)


def _within_catch(board, cfile, signs, per_count: float, catch: float) -> None:
    """Refuse (ConfigError) a balance-only controller whose pendulum, as the board reads it now
    with the amplifier off, is farther than ``catch`` from upright."""
    from furuta_cosim.swingup import wrap

    _, pendulum = board.counts()
    theta1 = math.pi + signs[1] * pendulum * per_count
    off = abs(wrap(theta1))
    if off > catch:
        raise ConfigError([f"{cfile.source}: a balance controller without a swing-up, and the pendulum reads "
                           f"{off:.3g} rad from upright (it balances only within {catch:g} rad, its catch "
                           "region): hold the pendulum upright and start it with `zero=False`, run a "
                           "swing-up-and-balance file (swingup-qube), or widen `catch` (in rad); nothing was "
                           "driven"])


def _taken(board, rows: np.ndarray, stamps: np.ndarray) -> None:
    """Each sample's `compute` from its reading to when the board took its write from, where
    the board says that was later than the write (its process saw it after its time had passed
    there): the log then says when the command reached the motor, less the delay."""
    times = board.write_times()
    if not times:
        return
    for k, stamp in enumerate(stamps):
        taken = times.get(float(stamp)) if np.isfinite(stamp) else None
        if taken is not None and taken > stamp:
            rows[k, 2] += taken - stamp


# rad/s: a start rate that the log cannot tell (a board that keeps no record of its own, and
# counts that moved over the first sample) is freed within this in the experiment file
FREE_RATE = 20.0


def _start(board, first_read: float | None, rows: np.ndarray) -> dict:
    """The experiment file's ``start:``: the angles as counted at the first sample (``data``);
    the rates and the current the board's own record shows there (the virtual board: a
    balance-only run's pendulum has fallen for two samples before the first one), else 0 where
    the counts stood still over the first sample and freed where they moved (a rig let go by
    hand: the log cannot tell how fast it was moving)."""
    start = {"theta0": "data", "dtheta0": 0.0, "theta1": "data", "dtheta1": 0.0, "i": 0.0}
    truth = board.state_at(first_read) if first_read is not None else None
    if truth is not None:
        start.update({k: float(truth[k]) for k in ("dtheta0", "dtheta1", "i")})
        return start
    if len(rows) >= 2:
        for name, column in (("dtheta0", 11), ("dtheta1", 12)):   # arm_counts, pendulum_counts
            if abs(float(rows[1, column]) - float(rows[0, column])) >= 2:
                start[name] = {"free": [-FREE_RATE, FREE_RATE]}
    return start


def _write(out: Path, rows: np.ndarray, cfile, board, plant, period, status, code, reason, failed,
           started_wall, runtime, limits, scenario, rate_filter, start: dict | None = None,
           woke_late: np.ndarray | None = None) -> dict:
    from furuta_cosim.config import plain_name
    from furuta_cosim.metrics import regulation_settling
    from furuta_cosim.swingup import wrap

    kept = _keep_controllers(cfile, out) if cfile is not None else None
    name = cfile.name if cfile is not None else runtime.name
    lines = [",".join(COLUMNS)] + [",".join(_cell(v) for v in row) for row in rows]
    write_text(out / "log.csv", "\n".join(lines) + "\n")
    counts = float(plant.sensors.get("encoder_counts", 2048))
    experiment = {
        # named after its folder (two runs fitted together need two names)
        "name": out.name if plain_name(out.name) and len(out.name) <= 64 else "rig-run", "description": f"{name} on the {board.name} board, {status}: {reason}",
        "data": "log.csv", "header": 1, "columns": list(COLUMNS), "time": "t",
        "inputs": {"V": {"column": "V", "unit": "V"}},
        "outputs": {"theta0": {"column": "theta0", "unit": "rad", "quantum": 2 * math.pi / counts},
                    "theta1": {"column": "theta1", "unit": "rad", "quantum": 2 * math.pi / counts}},
        # the angles as counted, the rates and current as the board's record shows them, else
        # 0 or freed (_start; a window cut from it later must say its own start:
        # identify/experiment.py refuses these where the data contradict them)
        "start": start or {"theta0": "data", "dtheta0": 0.0, "theta1": "data", "dtheta1": 0.0, "i": 0.0},
        "rig": {"board": board.name, "controller": kept or name, "period": period, "status": status,
                # the plant file it ran on (name and content): replay uses it unless told another
                "plant": plant.path.name, "plant_sha256": content_sha256(plant)},
    }
    if kept is not None:  # the loop that ran, for a replay that closes it again
        experiment["loop"] = {"controller": kept, "reference": "r", "rate_filter": rate_filter,
                              "counts": int(counts), "late": "late", "compute": "compute"}
        if getattr(runtime, "mode", None) is not None and getattr(runtime, "switches", None) is not None:
            experiment["loop"]["mode"] = "mode"   # a swing-up's: replay compares its own switches
        if limits.voltage is not None:
            experiment["loop"]["voltage"] = limits.voltage
        delay = getattr(board, "settings", {}).get("delay")  # known for the virtual board only
        if delay:
            experiment["loop"]["delay"] = float(delay)
    elif getattr(board, "settings", {}).get("delay"):
        # a table played open loop: its voltage reaches the motor the board's delay late (unsaid,
        # a fit of the board's own chirp took R_a 0.3 % low with the truth outside its interval)
        experiment["inputs"]["V"]["delay"] = float(board.settings["delay"])
    if board.has_current:
        experiment["outputs"]["i"] = {"column": "i", "unit": "A",
                                      "noise": float(plant.sensors.get("current_noise", 0.004)) or 0.004}
    if len(rows) < 2:
        experiment["description"] += " (fewer than two samples: not an experiment to replay)"
    write_text(out / "experiment.yaml", "# Written by furuta-cosim rig run: the run's log as an "
               "experiment file (replay, identify, regress read it).\n"
               + yaml.safe_dump(experiment, sort_keys=False))
    t = rows[:, 0] if len(rows) else np.zeros(0)
    read, compute = rows[:, 1] if len(rows) else np.zeros(0), rows[:, 2] if len(rows) else np.zeros(0)
    # the machine's timing: when the loop woke; a reading's own instant (the log's `late`) can be
    # older where the board samples on its own clock (a paced virtual board's last step)
    late = woke_late if woke_late is not None and len(woke_late) == len(rows) else read
    intervals = np.diff(t + late) if len(rows) > 1 else np.zeros(0)
    # a command written after the next deadline: its reading's instant plus the computing time
    overruns = int(np.sum(read[1:] + compute[1:] > period)) if len(rows) > 1 else 0
    timing = {"late_ms": _stats(1000 * late), "jitter_ms": _stats(1000 * np.abs(intervals - period)),
              "compute_ms": _stats(1000 * compute[np.isfinite(compute)]), "overruns": overruns,
              "period_ms": 1000 * period}
    warnings = []
    if len(rows) and timing["late_ms"]["p99"] > LATE_WARNING * 1000 * period:
        warnings.append(f"the loop's samples started up to {timing['late_ms']['p99']:.3f} ms late (99th "
                        f"percentile), more than {100 * LATE_WARNING:g} % of the {1000 * period:g} ms period "
                        "the controller was designed for")
    if overruns:
        warnings.append(f"{overruns} sample(s) wrote their command after the next sample's deadline")
    if limits.voltage is None:
        warnings.append("the rig's plant file states no voltage limit: commands went unclipped")
    summary = {"status": status, "code": code, "reason": reason, "board": board.name,
               "plant": plant.path.name, "plant_sha256": content_sha256(plant), "controller": name,
               "scenario": Path(scenario).name if scenario else None,
               "period": period, "samples": int(len(rows)), "seconds": float(len(rows) * period),
               "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(started_wall)),
               "safe": not failed, "safe_failures": failed, "timing": timing, "warnings": warnings,
               "limits": {k: v for k, v in limits.__dict__.items() if v is not None}}
    if len(rows):
        summary["peaks"] = {"V": float(np.max(np.abs(rows[:, 5]))), "V_command": float(np.max(np.abs(rows[:, 4]))),
                            "theta0": float(np.max(np.abs(rows[:, 6]))), "i": float(np.max(np.abs(rows[:, 8])))}
    if getattr(runtime, "mode", None) is not None and len(rows):
        caught = [k for k, m in runtime.switches if m == 1.0]
        wrapped = np.array([wrap(v) for v in rows[:, 7]])
        upright = regulation_settling(t, wrapped) if abs(wrapped[0]) > math.pi / 2 else None
        summary["swingup"] = {"caught_at": float(caught[0] * period) if caught else None,
                              "falls": sum(1 for _, m in runtime.switches if m == 0.0),
                              "upright_at": None if upright is None or not math.isfinite(upright) else upright}
    files = sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) + ["summary.json", "summary.md"]
    summary["files"] = sorted(set(files))
    write_text(out / "summary.json", dumps(summary, indent=2) + "\n")
    write_text(out / "summary.md", summary_text(summary))
    return summary


def _cell(value: float) -> str:
    return "" if not math.isfinite(value) else repr(float(value))


def _stats(values: np.ndarray) -> dict:
    if not len(values):
        return {"median": 0.0, "p99": 0.0, "max": 0.0}
    return {"median": float(np.median(values)), "p99": float(np.percentile(values, 99)),
            "max": float(np.max(values))}


def _keep_controllers(cfile, out: Path) -> str:
    """The controller files a run ran, copied into ``controllers/`` (a swing-up file with its
    balance controller beside it): the run folder is whole. Its path relative to ``out``."""
    from dataclasses import replace

    from furuta_cosim.controllers import save_controller

    folder = make_folder(out / "controllers")
    if cfile.swingup is not None:
        balance = replace(cfile, swingup=None, balance=None, own_name=None, plant=None,
                          path=None, provenance=dict(cfile.provenance))
        balance_path = save_controller(balance, folder / f"{cfile.controller.name}.yaml")
        cfile = replace(cfile, balance=balance_path)
    save_controller(cfile, folder / f"{cfile.name}.yaml")
    return f"controllers/{cfile.name}.yaml"


def summary_text(summary: dict) -> str:
    """summary.md: why the run stopped, the loop's timing, its peaks, the swing-up's catch."""
    timing = summary["timing"]
    lines = [f"# rig run: {summary['controller']} on the {summary['board']} board", "",
             f"**{summary['status']}** (exit code {summary['code']}): {summary['reason']}. "
             f"{summary['samples']} samples of {1000 * summary['period']:g} ms ({summary['seconds']:.3f} s); "
             + ("the rig was left at 0 V with the amplifier off." if summary["safe"] else
                "leaving the rig safe failed: " + "; ".join(summary["safe_failures"])), "",
             "| loop timing (ms) | median | 99th percentile | max |", "|---|---|---|---|"]
    for key, label in (("late_ms", "start after the deadline"), ("jitter_ms", "period jitter"),
                       ("compute_ms", "read, control, write")):
        s = timing[key]
        lines.append(f"| {label} | {s['median']:.4f} | {s['p99']:.4f} | {s['max']:.4f} |")
    lines += ["", f"Deadline overruns (a command written after the next deadline): {timing['overruns']}."]
    if "peaks" in summary:
        p = summary["peaks"]
        lines += ["", f"Peaks: {p['V']:.3f} V applied ({p['V_command']:.3f} V commanded), arm "
                      f"{p['theta0']:.3f} rad, current {p['i']:.3f} A."]
    if "swingup" in summary:
        s = summary["swingup"]
        caught = "never caught" if s["caught_at"] is None else f"caught at {s['caught_at']:.3f} s"
        upright = ("" if s["upright_at"] is None else f", upright (within 2 % of pi) from {s['upright_at']:.3f} s")
        lines += ["", f"Swing-up: {caught}{upright}; {s['falls']} fall(s)."]
    lines += [""] + [f"- warning: {w}" for w in summary["warnings"]]
    lines += ["", "Files: " + ", ".join(summary["files"]) + "."]
    return "\n".join(lines) + "\n"


def read_summary(folder: str | Path) -> dict:
    return json.loads((Path(folder) / "summary.json").read_text())
