"""The virtual board: a rig that is a plant FMU, read and driven as a real board is.

:class:`VirtualRig` is the hardware: the plant FMU of a plant file (a fitted one, say, or one
with more friction than the fit: a "true" plant unlike the model) stepped every ``step``
seconds with the voltage the amplifier applies: the last command, ``delay`` seconds after it
was written (transport over USB), clipped to the amplifier's range, 0 while the amplifier is
disabled or the watchdog has expired. Its sensors read as a QUBE's do (the plant file's
``sensors``): encoder counts (``encoder_counts`` per revolution, zeroed where the rig rests
when the runner starts) and a current with noise. It keeps its own log of what it applied,
independent of the runner's (``board.csv``), so a test can check what the "hardware" saw.

:class:`VirtualBoard` runs it in real time in a process of its own (``paced``: the runner's
timing is as on hardware, and a runner killed with -9 leaves it running until its watchdog
drives it to 0 V, as a real board's would), or in the runner's process on a simulated clock
that advances as the runner waits (``paced=False``: as fast as it can, for tests and
benchmarks; the same rig, sample for sample).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
from pathlib import Path

from furuta_cosim.errors import ConfigError
from furuta_cosim.rig.board import Board, Clock, Reading

AMPLIFIER = 15.0        # V: a QUBE's amplifier range, the virtual one's saturation by default
STEP = 0.0005           # s: the plant's step between the runner's samples
DELAY = 0.001           # s: from a write to the voltage at the motor
ADC_QUANTUM = 6.0 / 4096  # A: a 12-bit current sensor over +-3 A
# "reloaded": when the watchdog was last reloaded (NaN unarmed): a runner that writes the same
# command twice reloads without changing V_written
LOG_COLUMNS = ("t", "V_written", "V_applied", "enabled", "watchdog_expired", "theta0", "theta1", "i",
               "reloaded")


class VirtualRig:
    """The simulated hardware (see the module docstring); ``advance(t)`` steps it to ``t``."""

    def __init__(self, fmu: str, start: dict, sensors: dict, *, amplifier: float = AMPLIFIER,
                 delay: float = DELAY, step: float = STEP, seed: int = 0, capacity: int = 1_000_000,
                 lifted: bool = False, held: bool = False):
        import numpy as np

        from furuta_cosim.fmu.session import PlantSession

        self.session = PlantSession.open(fmu)
        self.session.reset(start)
        self.session.set_io(["V"], ["theta0", "theta1", "i"])
        self.theta0, self.theta1, self.current = self.session.get(["theta0", "theta1", "i"])
        self.counts = float(sensors.get("encoder_counts", 2048))
        self.signs = (float(sensors.get("arm_sign", 1)), float(sensors.get("pendulum_sign", 1)))
        self.noise = float(sensors.get("current_noise", 0.004))
        self.amplifier, self.delay, self.step = float(amplifier), float(delay), float(step)
        self.rng = np.random.default_rng(seed)
        self.t = 0.0
        # the counts as a board powered up with the rig at rest counts them: from the arm's zero
        # and the pendulum hanging (a runner zeroes them again when it starts a run)
        self.zero = (0.0, math.pi)
        # held up by hand before the run (``upright=``): the pendulum's encoder keeps the zero it
        # was given hanging, and a runner's zeroing moves the arm's alone
        self.lifted = bool(lifted)
        # a pendulum held up by hand (``upright=``) is let go when the amplifier is first
        # enabled: until then the plant does not move, however long the board runs before the
        # run starts (a paced board's process starts half a second early; it had fallen)
        self.held = bool(held)
        self.pending: list[tuple[float, float]] = []   # (when it reaches the motor, volts)
        self.written = 0.0      # the last command written
        self.level = 0.0        # what the amplifier is driving toward (after the delay)
        self.enabled = False
        self.watchdog: tuple[float, float] | None = None  # (timeout, last reload)
        self.expired = False
        self.log = np.zeros((min(capacity, 10_000), len(LOG_COLUMNS)))
        self.rows = 0
        self.capacity = capacity

    # -- what the runner does through the board ------------------------------------------------
    def write(self, volts: float, at: float | None = None) -> float:
        """A command written at ``at`` (the rig's time; None: now), reaching the motor the
        delay later: a paced board learns of a write up to a step after it was made, and
        applies it from when it was made (or from now, where that has passed here); returns
        the time it is taken from."""
        if not math.isfinite(volts):
            volts = 0.0  # a board drives no NaN: the runner's supervisor has already refused it
        self.written = volts
        when = self.t if at is None or not math.isfinite(at) else max(float(at), self.t)
        self.pending.append((when + self.delay, volts))
        return when

    def arm(self, timeout: float) -> None:
        self.watchdog = (float(timeout), self.t)

    def reload(self) -> bool:
        if self.watchdog is not None and not self.expired:
            self.watchdog = (self.watchdog[0], self.t)
        return not self.expired

    def zero_encoders(self) -> None:
        self.zero = (self.theta0, self.zero[1] if self.lifted else self.theta1)

    def encoders(self) -> tuple[int, int]:
        """The counts alone: no current sampled, so the sensor's noise stream is not drawn."""
        scale = self.counts / (2.0 * math.pi)
        return (int(round(self.signs[0] * (self.theta0 - self.zero[0]) * scale)),
                int(round(self.signs[1] * (self.theta1 - self.zero[1]) * scale)))

    def reading(self) -> Reading:
        scale = self.counts / (2.0 * math.pi)
        arm = int(round(self.signs[0] * (self.theta0 - self.zero[0]) * scale))
        pendulum = int(round(self.signs[1] * (self.theta1 - self.zero[1]) * scale))
        current = self.current + float(self.rng.normal(0.0, self.noise)) if self.noise else self.current
        current = round(current / ADC_QUANTUM) * ADC_QUANTUM
        return Reading(arm, pendulum, current)

    # -- the hardware's own time -----------------------------------------------------------------
    def applied(self) -> float:
        """The voltage at the motor now."""
        while self.pending and self.pending[0][0] <= self.t + 1e-12:
            self.level = self.pending.pop(0)[1]
        if self.watchdog is not None and not self.expired and self.t - self.watchdog[1] > self.watchdog[0] + 1e-9:
            self.expired = True  # as a hardware watchdog: 0 V and the amplifier off until reopened
            self.enabled = False
        if not self.enabled or self.expired:
            return 0.0
        return max(-self.amplifier, min(self.amplifier, self.level))

    def advance(self, until: float) -> None:
        """Step the plant to ``until`` (steps of ``step`` on its grid), logging each step; a
        command that reaches the motor inside a step splits it there, so the voltage switches
        when the write and the delay say, not at the next step. It never passes ``until`` (a
        paced board's wall time): a reading is of a state that has been, and a write stamped
        now is never behind it."""
        while True:
            end = (math.floor(self.t / self.step + 1e-6) + 1) * self.step   # the grid's next point
            if end > until + 1e-9 * self.step:
                break
            volts = self.applied()   # the commands due by now taken first: the next is then ahead
            if self.pending and self.t + 1e-9 * self.step < self.pending[0][0] < end - 1e-9 * self.step:
                end = self.pending[0][0]
            self.held = self.held and not self.enabled
            if not self.held:
                self.theta0, self.theta1, self.current = self.session.step([volts], end - self.t)
            self._record(volts)
            self.t = end

    def _record(self, volts: float) -> None:
        if self.rows == len(self.log):
            import numpy as np

            if self.rows >= self.capacity:
                return  # a day-long run keeps its first rows: the log is bounded
            self.log = np.vstack([self.log, np.zeros((min(len(self.log), self.capacity - self.rows),
                                                     len(LOG_COLUMNS)))])
        self.log[self.rows] = (self.t, self.written, volts, float(self.enabled), float(self.expired),
                               self.theta0, self.theta1, self.current,
                               self.watchdog[1] if self.watchdog is not None else math.nan)
        self.rows += 1

    def save_log(self, path: Path) -> None:
        from furuta_cosim.files import write_text

        lines = [",".join(LOG_COLUMNS)] + [",".join(repr(float(v)) for v in row) for row in self.log[:self.rows]]
        write_text(path, "\n".join(lines) + "\n")

    def close(self) -> None:
        self.session.close()


def read_board_log(path: Path) -> dict:
    """A virtual board's own log, by column (numpy arrays)."""
    import numpy as np

    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {name: table[:, k] for k, name in enumerate(LOG_COLUMNS)}


class VirtualBoard(Board):
    """The virtual board (see the module docstring).

    Parameters
    ----------
    plant : PlantSet
        The plant it runs (any plant file: a fitted one, or a "true" plant unlike the model),
        and its sensors.
    paced : bool
        Real time in a process of its own (True), or in the runner's process on a simulated
        clock, as fast as it can.
    log : path, optional
        Where it writes its own log (``board.csv``) when it closes.
    amplifier : float
        The amplifier's range (V).
    delay : float
        From a write to the voltage at the motor (s).
    step : float
        The plant's step (s).
    seed : int
        The current sensor's noise.
    overrides : dict, optional
        Plant parameters and start values on top of the plant file's.
    hanging : bool
        Start the pendulum hanging at rest (``theta1_start`` pi) unless ``overrides`` says else.
    """

    name = "virtual"
    description = ("the rig stand-in: a plant FMU stepped in real time in a process of its own, "
                   "read and driven as a QUBE's board (options: fast, to run it as fast as it can; "
                   "delay=SECONDS, 0.001 by default; amplifier=VOLTS, 15 by default; pendulum=RAD, "
                   "the pendulum held that far from hanging at the start, for a free swing; upright=RAD, "
                   "the pendulum held that far from upright at the start, for a balance-only run; late=SECONDS, "
                   "with fast, each sample up to that late, in whole 0.5 ms steps)")
    has_current = True

    def __init__(self, plant, *, paced: bool = True, log: Path | None = None, amplifier: float = AMPLIFIER,
                 delay: float = DELAY, step: float = STEP, seed: int = 0, overrides: dict | None = None,
                 hanging: bool = True, lifted: bool = False, late: float = 0.0):
        from furuta_cosim.fmu.exporter import build_fmu

        self.plant = plant
        self.paced = paced
        self.log_path = Path(log) if log is not None else None
        start = dict(plant.parameters)
        start.update(overrides or {})
        if hanging:  # a real pendulum starts hanging down, at rest
            start.setdefault("theta1_start", math.pi)
        self.arguments = (str(build_fmu(plant)), start, dict(plant.sensors))
        self.settings = {"amplifier": amplifier, "delay": delay, "step": step, "seed": seed, "lifted": bool(lifted),
                         "held": bool(lifted)}
        self.late = float(late)   # the simulated clock's lateness at most (fast only)
        self.rig: VirtualRig | None = None
        self._process = self._shared = None
        self._t0: float | None = None   # a paced board's t0 on the host's clock (its time is since then)
        self._record = None             # a simulated rig's own record, kept at close
        self._tickets: dict = {}        # a paced board's writes: count -> [made, taken by its process]
        self._open: set = set()         # the counts not yet taken

    @classmethod
    def from_argument(cls, argument: str, plant=None, **options) -> "VirtualBoard":
        """``virtual[:OPTION,...]``: ``fast`` (as fast as it can), ``delay=SECONDS`` (from a write
        to the motor), ``amplifier=VOLTS`` (its range), ``pendulum=RAD`` (held that far from
        hanging when the run starts, then let go: a free swing, run with the counts kept),
        ``upright=RAD`` (held that far from upright, -0.5 to 0.5, when the run starts, its encoder
        zeroed hanging before it was lifted: a balance controller takes over at once)."""
        if plant is None:
            raise ConfigError(["board: the virtual board runs a plant: give `plant`"])
        paced = options.pop("paced", True)
        for item in filter(None, argument.split(",")):
            name, equals, text = item.partition("=")
            if item == "fast":
                paced = False
                continue
            bounds = {"delay": (0.0, 0.1), "amplifier": (0.1, 1000.0), "pendulum": (-3.0, 3.0),
                      "upright": (-0.5, 0.5), "late": (0.0, 0.01)}.get(name)
            try:
                value = float(text) if equals and bounds else math.nan
            except ValueError:
                value = math.nan
            if bounds is None or not bounds[0] <= value <= bounds[1]:
                raise ConfigError([f"board: virtual:{argument}: {item!r}: expected fast, delay=SECONDS "
                                   "(0 to 0.1), amplifier=VOLTS (0.1 to 1000), pendulum=RAD (-3 to 3), upright=RAD "
                                   "(-0.5 to 0.5) or late=SECONDS (0 to 0.01, with fast), "
                                   "separated by commas"])
            if name == "pendulum":
                options.setdefault("overrides", {})["theta1_start"] = math.pi + value
                continue
            if name == "upright":
                options.setdefault("overrides", {})["theta1_start"] = value
                options["lifted"] = True
                continue
            options[name] = value
        if options.get("late") and paced:
            raise ConfigError([f"board: virtual:{argument}: late=SECONDS makes the simulated clock wake "
                               "late: it takes fast (a paced board is as late as its machine makes it)"])
        return cls(plant, paced=paced, **options)

    # -- the interface ---------------------------------------------------------------------
    def open(self) -> None:
        if not self.paced:
            self.rig = VirtualRig(*self.arguments, **self.settings)
            return
        context = multiprocessing.get_context("spawn")
        self._shared = context.Array("d", _SLOTS, lock=False)
        self._process = context.Process(target=_serve, args=(self.arguments, self.settings, self._shared,
                                                             str(self.log_path) if self.log_path else "",
                                                             os.getpid()), daemon=False)
        self._process.start()
        deadline = time.monotonic() + 60
        while self._shared[_READY] == 0.0:
            if not self._process.is_alive() or time.monotonic() > deadline:
                raise ConfigError([f"board: the virtual board did not start (exit code {self._process.exitcode})"])
            time.sleep(0.005)
        self._t0 = self._shared[_T0]   # its time starts when it is ready (its process took a while)

    def zero_encoders(self) -> None:
        if self.rig is not None:
            self.rig.zero_encoders()
        else:
            self._signal(_ZERO)

    def read(self) -> Reading:
        if self.rig is not None:
            return self.rig.reading()
        shared = self._shared
        while True:  # a seqlock: retried while the board writes a reading
            before = shared[_SEQ]
            values = (shared[_ARM_COUNTS], shared[_PENDULUM_COUNTS], shared[_CURRENT], shared[_READ_T])
            if before == shared[_SEQ] and int(before) % 2 == 0:
                # sampled at the board's time of its last step, which a busy process may leave behind
                return Reading(int(values[0]), int(values[1]), values[2], at=self._t0 + values[3])

    def counts(self) -> tuple[int, int]:
        if self.rig is not None:   # a check before a run draws none of the current's noise
            return self.rig.encoders()
        reading = self.read()
        return reading.arm, reading.pendulum

    def write(self, volts: float) -> float | None:
        """Drive the motor; returns when the write was made on the clock's scale (a paced board:
        its process applies it from then), None on the simulated clock (at its now)."""
        if self.rig is not None:
            self.rig.write(volts)
            return None
        if self._shared is not None:
            self._collect()
            count = int(self._shared[_WRITES]) + 1
            slot = _RING + 3 * (count % _RING_SIZE)
            stamp = time.perf_counter()
            self._shared[slot], self._shared[slot + 1], self._shared[slot + 2] = stamp - self._t0, volts, math.nan
            self._shared[_VOLTS] = volts
            self._signal(_WRITES)
            self._tickets[count] = [stamp, None]
            self._open.add(count)
            return stamp
        return None

    def enable(self) -> None:
        self._set_enabled(1.0)

    def disable(self) -> None:
        self._set_enabled(0.0)

    def _set_enabled(self, value: float) -> None:
        if self.rig is not None:
            self.rig.enabled = bool(value) and not self.rig.expired
        elif self._shared is not None:
            self._shared[_ENABLE] = value

    def arm_watchdog(self, timeout: float) -> None:
        if self.rig is not None:
            self.rig.arm(timeout)
        else:
            self._shared[_TIMEOUT] = timeout
            self._signal(_ARMED)

    def reload_watchdog(self) -> bool:
        if self.rig is not None:
            return self.rig.reload()
        self._signal(_RELOADS)
        return self._shared[_EXPIRED] == 0.0

    def stop_watchdog(self) -> None:
        if self.rig is not None:
            self.rig.watchdog = None
        elif self._shared is not None:
            self._shared[_TIMEOUT] = 0.0
            self._signal(_ARMED)

    def close(self) -> None:
        if self.rig is not None:
            # the hardware goes on after the runner stops: its log shows where the stop left it
            self.rig.advance(self.rig.t + self.rig.delay + 2 * self.rig.step)
            if self.log_path is not None:
                self.rig.save_log(self.log_path)
            self._record = self.rig.log[:self.rig.rows].copy()   # state_at reads it
            self.rig.close()
            self.rig = None
        if self._process is not None:
            self._shared[_STOP] = 1.0
            self._process.join(timeout=30)
            if self._process.is_alive():
                self._process.kill()
            self._process = None

    def clock(self) -> Clock:
        return Clock() if self.rig is None else _SimulatedClock(self.rig, self.late, self.settings["seed"])

    def _collect(self) -> None:
        """The times the board's process took the writes it has seen from (ring slots it
        filled), kept before the ring comes round to them again."""
        for count in list(self._open):
            value = self._shared[_RING + 3 * (count % _RING_SIZE) + 2]
            if math.isfinite(value):
                self._tickets[count][1] = self._t0 + value
                self._open.discard(count)

    def write_times(self) -> dict:
        """{when a write was made: when the board's process took it from}, on the clock's
        scale, for each write of a paced board whose process has taken it."""
        if self._shared is None:
            return {}
        self._collect()
        return {stamp: taken for stamp, taken in self._tickets.values() if taken is not None}

    def state_at(self, when: float) -> dict | None:
        """From its record (board.csv, written at close): each row holds the state at the end
        of the step that starts at its ``t``, on the rig's time (the clock's, or since t0 for a
        paced board); the rates by a central difference of the angles over one step each way
        (the record keeps no rates; 0.5 ms steps: within 1e-3 rad/s of the model's)."""
        import numpy as np

        if self._record is not None:   # the simulated rig's, kept in memory
            rows = {name: self._record[:, j] for j, name in enumerate(LOG_COLUMNS)}
        elif self.log_path is not None and self.log_path.is_file():
            rows = np.genfromtxt(self.log_path, delimiter=",", names=True)
            if rows.ndim == 0:
                return None
        else:
            return None
        if len(rows["t"]) < 3:
            return None
        step = self.settings["step"]
        at = when if self._t0 is None else when - self._t0
        starts = np.asarray(rows["t"], dtype=float)
        ends = np.append(starts[1:], starts[-1] + step)   # each row: the state at the end of its step
        k = int(np.argmin(np.abs(ends - at)))
        if not 1 <= k < len(ends) - 1 or abs(ends[k] - at) > 0.5 * step:
            return None
        span = float(ends[k + 1] - ends[k - 1])
        rate = {name: (float(rows[name][k + 1]) - float(rows[name][k - 1])) / span for name in ("theta0", "theta1")}
        return {"theta0": float(rows["theta0"][k]), "dtheta0": rate["theta0"], "theta1": float(rows["theta1"][k]),
                "dtheta1": rate["theta1"], "i": float(rows["i"][k])}

    def _signal(self, slot: int) -> None:
        self._shared[slot] += 1.0


class _SimulatedClock(Clock):
    """The virtual rig's own time: waiting for a deadline steps the rig to it; with ``late``
    (s) each wait ends a random whole number of the rig's steps after its deadline, up to
    ``late``, as a busy machine wakes a loop late (``virtual:fast,late=SECONDS``)."""

    def __init__(self, rig: VirtualRig, late: float = 0.0, seed: int = 0):
        import numpy as np

        self.rig = rig
        self.most = int(math.floor(late / rig.step + 1e-9))
        self.rng = np.random.default_rng([seed, 17])

    def now(self) -> float:
        return self.rig.t

    def wait_until(self, deadline: float) -> float:
        if self.most:
            deadline += self.rig.step * int(self.rng.integers(0, self.most + 1))
        self.rig.advance(deadline)
        return max(self.rig.t, deadline)


# the shared slots between the runner and the board's process (one writer each); a signal
# slot counts up, and the board acts once per new count
(_T0, _READY, _STOP, _VOLTS, _WRITES, _ENABLE, _TIMEOUT, _ARMED, _RELOADS, _ZERO, _EXPIRED, _SEQ,
 _ARM_COUNTS, _PENDULUM_COUNTS, _CURRENT, _READ_T) = range(16)
# the runner's writes, in a ring the board's process reads in order: a process held up by a busy
# machine still applies every command from when it was made (with one slot it saw the last alone)
_RING, _RING_SIZE = 16, 256          # (time, volts, taken) triples from slot _RING on
_SLOTS = _RING + 3 * _RING_SIZE
_GRACE = 0.5  # s the board runs on after its watchdog expired with its runner gone


def _serve(arguments, settings, shared, log: str, parent: int) -> None:
    """The board's process: the rig in real time until told to stop, or until its runner is
    gone and the watchdog has held it at 0 V for a while; then its log.

    It stands in for hardware, which a terminal's Ctrl-C does not reach: SIGINT is ignored (the
    runner hears it, writes 0 V and tells the board to stop). SIGTERM (a scheduler's, to the
    whole group) stops it as the runner's stop does. Every ending leaves it at 0 V with the
    amplifier off, and its record (``board.csv``) complete to that."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ended = []
    signal.signal(signal.SIGTERM, lambda *_: ended.append(True))
    rig = VirtualRig(*arguments, **settings)
    seen = {slot: 0.0 for slot in (_WRITES, _ARMED, _RELOADS, _ZERO)}
    clock = Clock()
    # the rig's time starts now, once its plant is loaded (the same clock as the runner's): a
    # time taken before the process started left it half a second behind, reading stale states
    shared[_T0] = t0 = clock.now()
    orphaned_at = None
    try:
        publish(rig, shared)
        shared[_READY] = 1.0
        k, stop_at = 0, None
        while stop_at is None or rig.t < stop_at:
            k += 1
            now = clock.wait_until(t0 + k * rig.step) - t0
            if stop_at is None and (shared[_STOP] != 0.0 or ended):  # told to stop: what the runner wrote
                stop_at = now + rig.delay + 2 * rig.step  # last, then long enough for the log to show it
            if shared[_ZERO] != seen[_ZERO]:
                seen[_ZERO] = shared[_ZERO]
                rig.zero_encoders()
            if shared[_ARMED] != seen[_ARMED]:
                seen[_ARMED] = shared[_ARMED]
                rig.watchdog = (shared[_TIMEOUT], rig.t) if shared[_TIMEOUT] > 0 else None
            if shared[_RELOADS] != seen[_RELOADS]:
                seen[_RELOADS] = shared[_RELOADS]
                rig.reload()
            if shared[_WRITES] != seen[_WRITES]:
                latest = int(shared[_WRITES])
                for count in range(max(int(seen[_WRITES]) + 1, latest - _RING_SIZE + 1), latest + 1):
                    slot = _RING + 3 * (count % _RING_SIZE)
                    # taken from when it was made, or from now if this process saw it after its
                    # time had passed here (the runner held up between its stamp and its signal)
                    shared[slot + 2] = rig.write(shared[slot + 1], at=shared[slot])
                seen[_WRITES] = float(latest)
            rig.enabled = shared[_ENABLE] == 1.0 and not rig.expired and not ended
            rig.advance(now)
            shared[_EXPIRED] = float(rig.expired)
            publish(rig, shared)
            if os.getppid() != parent:  # the runner is gone (killed): the watchdog is all that is left
                orphaned_at = orphaned_at if orphaned_at is not None else rig.t
                if rig.expired or rig.watchdog is None:
                    if rig.t - orphaned_at > _GRACE:
                        break
    finally:
        try:   # whatever ended it: 0 V, the amplifier off, and the record shows them applied
            rig.enabled = False
            rig.write(0.0, at=rig.t)
            rig.advance(rig.t + rig.delay + 2 * rig.step)
        finally:
            if log:
                rig.save_log(Path(log))
            rig.close()


def publish(rig: VirtualRig, shared) -> None:
    reading = rig.reading()
    shared[_SEQ] += 1.0  # odd: being written
    shared[_ARM_COUNTS], shared[_PENDULUM_COUNTS], shared[_CURRENT] = reading.arm, reading.pendulum, reading.current
    shared[_READ_T] = rig.t
    shared[_SEQ] += 1.0
