"""The board interface: what the runner needs of a rig's I/O, and the registry of boards.

A board reads the arm and pendulum encoders (counts), the motor current where it has a
sensor, writes the motor voltage, enables and disables the amplifier, and arms and reloads a
watchdog that drives the output to 0 V when it is not reloaded in time. It also gives the
runner its clock: the host's monotonic clock for a board in real time, or a simulated one for
a virtual board run as fast as it can. A new board is one subclass of :class:`Board`,
registered by being defined (``BOARDS``); ``rig run --board NAME[:OPTIONS]`` and the docs read
the registry.
"""

from __future__ import annotations

from pathlib import Path

import time
from dataclasses import dataclass

from furuta_cosim.errors import ConfigError

BOARDS: dict[str, type["Board"]] = {}


@dataclass(frozen=True)
class Reading:
    """One read of the board: encoder counts, and the current (A) where there is a sensor."""

    arm: int
    pendulum: int
    current: float | None = None
    at: float | None = None   # when the board sampled it, on its clock's scale (None: as it was read)


class Clock:
    """The host's monotonic clock: ``now()`` in seconds, ``wait_until(t)`` sleeps then spins
    the last half millisecond (a sleep alone overshoots by up to a scheduler tick)."""

    SPIN = 0.0005

    def now(self) -> float:
        return time.perf_counter()

    def wait_until(self, deadline: float) -> float:
        remaining = deadline - time.perf_counter()
        if remaining > self.SPIN:
            time.sleep(remaining - self.SPIN)
        while (now := time.perf_counter()) < deadline:
            pass
        return now


class Board:
    """One rig's I/O (see the module docstring). Subclasses set ``name`` and ``description``
    and implement the calls; :meth:`safe` is what every stop ends with."""

    name = ""
    description = ""
    has_current = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name"):  # a board of its own, not a variant of one (a test's)
            BOARDS[cls.name] = cls

    # -- the interface ---------------------------------------------------------------------
    def open(self) -> None:
        """Connect; the amplifier stays disabled and the output at 0 V."""
        raise NotImplementedError

    def zero_encoders(self) -> None:
        """Count from here: the rig at rest, the arm at its zero, the pendulum hanging."""
        raise NotImplementedError

    def read(self) -> Reading:
        """The encoders' counts and the current now."""
        raise NotImplementedError

    def counts(self) -> tuple[int, int]:
        """The encoders' counts now (arm, pendulum), for a check that needs no current."""
        reading = self.read()
        return reading.arm, reading.pendulum

    def write(self, volts: float) -> float | None:
        """Drive the motor.

        Parameters
        ----------
        volts : float
            The voltage (the board's own range limits it further).

        Returns
        -------
        float or None
            When the board takes the write to have been made, on :meth:`clock`'s scale; None:
            as the call returns.
        """
        raise NotImplementedError

    def enable(self) -> None:
        """Enable the amplifier."""
        raise NotImplementedError

    def disable(self) -> None:
        """Disable the amplifier: the motor is driven by nothing."""
        raise NotImplementedError

    def arm_watchdog(self, timeout: float) -> None:
        """Start the watchdog: 0 V and the amplifier disabled unless it is reloaded in time.

        Parameters
        ----------
        timeout : float
            Seconds between reloads at most.
        """
        raise NotImplementedError

    def reload_watchdog(self) -> bool:
        """Reload it; False once it has expired (the output is then held at 0 V)."""
        raise NotImplementedError

    def stop_watchdog(self) -> None:
        """Stop the watchdog (and clear it, where it had expired)."""
        raise NotImplementedError

    def close(self) -> None:
        """Disconnect (after :meth:`safe`)."""
        raise NotImplementedError

    def write_times(self) -> dict:
        """Where a board applies a write from another time than it was made (a process of
        its own that saw it late): {the time :meth:`write` returned: the time it took it
        from}; empty for a board that applies each write as it is made."""
        return {}

    def state_at(self, when: float) -> dict | None:
        """The rig's true state from a record the board keeps of its own, after :meth:`close`.

        Parameters
        ----------
        when : float
            A time on :meth:`clock`'s scale (a sample's reading).

        Returns
        -------
        dict or None
            theta0, dtheta0, theta1, dtheta1 and i there (SI, the model's convention); None for
            a board that keeps no record (real hardware).
        """
        return None

    def clock(self) -> Clock:
        """The runner's clock: the host's, or a simulated one (a virtual board run fast)."""
        return Clock()

    # -- what every stop ends with ---------------------------------------------------------
    def safe(self) -> list[str]:
        """0 V, the amplifier disabled, the watchdog stopped: each step tried whatever the one
        before did; what failed is returned in words (an empty list: all done)."""
        failed = []
        for what, call in (("write 0 V", lambda: self.write(0.0)), ("disable the amplifier", self.disable),
                           ("stop the watchdog", self.stop_watchdog)):
            try:
                call()
            except Exception as error:  # noqa: BLE001 - every step is tried, each failure said
                failed.append(f"{what}: {type(error).__name__}: {error}")
        return failed


def board_for(text: str, plant=None, **options) -> Board:
    """The board named as ``--board`` names it.

    Parameters
    ----------
    text : str
        ``NAME[:OPTIONS]``: ``virtual``, ``virtual:fast``, ``quanser``,
        ``quanser:qube_servo3_usb@0``.
    plant : PlantSet, optional
        The rig's plant file (the virtual board runs it).
    options : keyword arguments
        Passed to the board's class: ``log`` (the virtual board's own log file), ``seed``
        (its sensor noise), ``module`` (a stand-in for Quanser's API, in tests).

    Returns
    -------
    Board
        Not yet opened.
    """
    from furuta_cosim.rig import quanser, virtual  # noqa: F401 - they register their boards

    if plant is not None and plant.model != "furuta":
        kind = (f"a plant of the folder {Path(plant.model).name}/" if plant.folder is not None
                else f"a {plant.model} plant")
        raise ConfigError([f"plant {plant.name}: {kind}; the boards here run a Furuta pendulum "
                           "(the QUBE's arm and pendulum encoders, its motor's current and amplifier): name a "
                           "plant of model furuta"])
    name, _, argument = str(text).partition(":")
    if name not in BOARDS:
        from furuta_cosim.config import did_you_mean

        raise ConfigError([f"board: expected one of {', '.join(BOARDS)} (NAME or NAME:OPTIONS), got "
                           f"{text!r}{did_you_mean(name, BOARDS)}"])
    return BOARDS[name].from_argument(argument, plant=plant, **options)
