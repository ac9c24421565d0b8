"""The safety supervisor: what a rig run is held to at every sample, and why it stops.

Limits come from the rig's plant file (``limits:``): the amplifier's voltage (every command is
clipped to it: the command beyond it is logged, the voltage applied is the clipped one), the
arm angle, the motor current, a stall (a command of ``stall_voltage`` or more for
``stall_seconds`` while the arm stands still). Besides, the loop's deadlines: a sample that
starts more than ``late_periods`` periods after its deadline trips it (the controller was
designed for its period). A command that is not a number trips it at once. Whatever stops a
run (a trip, an exception, Ctrl-C, SIGTERM, its end), the runner leaves the rig at 0 V with
the amplifier disabled (:meth:`Board.safe`), and the board's watchdog does the same if the
runner itself is killed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from furuta_cosim.fmu.plants import voltage_limit

# the exit codes of a rig run, one per way it ends (the CLI's and the docs' table)
FINISHED, TRIPPED, INTERRUPTED = 0, 1, 130   # a signal other than Ctrl-C: 128 + its number


class Trip(Exception):
    """The supervisor stopped the run: ``reason`` in words, ``limit`` the one broken."""

    def __init__(self, limit: str, reason: str):
        super().__init__(reason)
        self.limit, self.reason = limit, reason


@dataclass(frozen=True)
class Limits:
    """What a run is held to; None: not checked.

    Parameters
    ----------
    voltage : float, optional
        Every command is clipped to +-voltage (V).
    current : float, optional
        A current beyond +-current trips the run (A).
    theta0 : float, optional
        An arm angle beyond +-theta0 trips it (rad).
    stall_voltage : float, optional
        A command of this many volts or more for ``stall_seconds`` with the arm still trips it.
    stall_seconds : float, optional
        See ``stall_voltage``.
    late_periods : float
        A sample that starts this many periods late trips it.
    still_rate : float
        The arm stands still below this rate (rad/s).
    """

    voltage: float | None = None
    current: float | None = None
    theta0: float | None = None
    stall_voltage: float | None = None
    stall_seconds: float | None = None
    late_periods: float = 5.0          # a sample this many periods late trips the run
    still_rate: float = 0.05           # rad/s: the arm "stands still" below it

    @classmethod
    def of(cls, plant, **changes) -> "Limits":
        """The limits of a rig's plant file.

        Parameters
        ----------
        plant : PlantSet
            Its ``limits``.
        changes : keyword arguments
            Limits to use instead of the file's (``late_periods=10``).
        """
        known = {k: float(v) for k, v in plant.limits.items() if k in cls.__dataclass_fields__}
        known["voltage"] = voltage_limit(plant)  # limits.voltage, or the model's V_max
        known.update(changes)
        return cls(**known)


class Supervisor:
    """Checks each sample (:meth:`check`) and clips each command (:meth:`clip`)."""

    def __init__(self, limits: Limits, period: float):
        self.limits, self.period = limits, period
        self.stalled_for = 0.0

    def clip(self, command: float) -> float:
        if not math.isfinite(command):
            raise Trip("command", f"the controller commanded {command} V")
        v = self.limits.voltage
        return command if v is None else max(-v, min(v, command))

    def check(self, t: float, x, current: float | None, command: float, late: float) -> None:
        """Raise Trip when sample ``t`` (state estimate ``x``, measured ``current``, the
        ``command`` about to be applied, ``late`` s after its deadline) breaks a limit."""
        limits = self.limits
        if late > limits.late_periods * self.period:
            raise Trip("deadline", f"the sample at t = {t:.4f} s started {1000 * late:.2f} ms late "
                                   f"(more than {limits.late_periods:g} periods of {1000 * self.period:g} ms)")
        if not all(math.isfinite(v) for v in x):
            raise Trip("measurement", f"a measurement is not a number at t = {t:.4f} s")
        if limits.theta0 is not None and abs(x[0]) > limits.theta0:
            raise Trip("theta0", f"the arm reached {x[0]:+.3f} rad at t = {t:.4f} s (limit +-{limits.theta0:g})")
        if limits.current is not None and current is not None and abs(current) > limits.current:
            raise Trip("current", f"the motor current reached {current:+.3f} A at t = {t:.4f} s "
                                  f"(limit +-{limits.current:g})")
        if limits.stall_voltage is not None and limits.stall_seconds is not None:
            pushing = abs(command) >= limits.stall_voltage and abs(x[1]) < limits.still_rate
            self.stalled_for = self.stalled_for + self.period if pushing else 0.0
            if self.stalled_for >= limits.stall_seconds:
                raise Trip("stall", f"{abs(command):.2f} V for {self.stalled_for:.2f} s with the arm standing "
                                    f"still at t = {t:.4f} s (a stalled motor)")
