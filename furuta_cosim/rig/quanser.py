"""A Quanser board through Quanser's Python HIL API (``quanser.hardware.HIL``): a QUBE-Servo 2
or 3 over USB.

The API comes with the Quanser SDK (not on PyPI; the docs' rig page says how a lab installs
it) and is imported only when this board is opened. A QUBE-Servo 3 is the board type
``qube_servo3_usb`` (a QUBE-Servo 2: ``qube_servo2_usb``), identifier ``0`` for the first one
on the USB bus; its channels: encoder inputs 0 (the arm, the motor's shaft) and 1 (the
pendulum), 2048 counts a revolution in quadrature; analog output 0, the motor's voltage;
digital output 0, the amplifier's enable; analog input 0, the motor's current. The board's
watchdog is set to drive analog output 0 to 0 V and digital output 0 low when it expires.
"""

from __future__ import annotations

import array

from furuta_cosim.errors import ConfigError
from furuta_cosim.rig.board import Board, Reading

BOARD_TYPES = ("qube_servo3_usb", "qube_servo2_usb")
ENCODERS = (0, 1)       # arm, pendulum
MOTOR = 0               # analog output: the motor's voltage
AMPLIFIER = 0           # digital output: the amplifier's enable
CURRENT = 0             # analog input: the motor's current
DIGITAL_LOW = 0         # the HIL API's digital state "low" (DIGITAL_STATE_LOW)


class QuanserBoard(Board):
    name = "quanser"
    description = ("a Quanser QUBE-Servo 2 or 3 over USB through Quanser's HIL API (options: "
                   "BOARD_TYPE[@IDENTIFIER], default qube_servo3_usb@0)")
    has_current = True

    def __init__(self, board_type: str = "qube_servo3_usb", identifier: str = "0", module=None):
        self.board_type, self.identifier = board_type, identifier
        self._module = module  # the quanser.hardware module (a test hands in a fake)
        self.card = None
        self._encoders = array.array("I", ENCODERS)
        self._counts = array.array("i", [0, 0])
        self._motor = array.array("I", [MOTOR])
        self._volts = array.array("d", [0.0])
        self._amplifier = array.array("I", [AMPLIFIER])
        self._states = array.array("b", [0])
        self._current_channel = array.array("I", [CURRENT])
        self._current = array.array("d", [0.0])

    @classmethod
    def from_argument(cls, argument: str, **options) -> "QuanserBoard":
        board_type, _, identifier = (argument or "qube_servo3_usb").partition("@")
        if board_type not in BOARD_TYPES:
            raise ConfigError([f"board: quanser:{argument}: expected a board type of {', '.join(BOARD_TYPES)} "
                               "(and @IDENTIFIER, default 0)"])
        if identifier and not identifier.replace("-", "").replace(".", "").isalnum():
            raise ConfigError([f"board: quanser:{argument}: the identifier must be a board number or name"])
        return cls(board_type, identifier or "0", options.get("module"))

    def _api(self):
        if self._module is not None:
            return self._module
        try:
            from quanser import hardware
        except ImportError:
            raise ConfigError(["board: quanser: Quanser's Python HIL API is not installed (it comes with "
                               "the Quanser SDK, not from PyPI: the rig page of the docs says how)"]) from None
        return hardware

    def _call(self, what: str, call, *args):
        error_type = getattr(self._api(), "HILError", Exception)
        try:
            return call(*args)
        except error_type as error:
            message = error.get_error_message() if hasattr(error, "get_error_message") else str(error)
            raise ConfigError([f"board: quanser {self.board_type}@{self.identifier}: {what}: {message}"]) from None

    # -- the interface ---------------------------------------------------------------------
    def open(self) -> None:
        card = self._api().HIL()
        self._call("open", card.open, self.board_type, self.identifier)
        self.card = card
        # whatever the board did before: the output at 0 V and the amplifier off, and the
        # watchdog told to bring them there when it expires
        self.write(0.0)
        self.disable()
        self._call("watchdog expiration (analog)", self.card.watchdog_set_analog_expiration_state,
                   self._motor, 1, array.array("d", [0.0]))
        self._call("watchdog expiration (digital)", self.card.watchdog_set_digital_expiration_state,
                   self._amplifier, 1, array.array("i", [DIGITAL_LOW]))

    def zero_encoders(self) -> None:
        self._call("set encoder counts", self.card.set_encoder_counts, self._encoders, 2, array.array("i", [0, 0]))

    def read(self) -> Reading:
        self._call("read encoders", self.card.read_encoder, self._encoders, 2, self._counts)
        self._call("read current", self.card.read_analog, self._current_channel, 1, self._current)
        return Reading(int(self._counts[0]), int(self._counts[1]), float(self._current[0]))

    def write(self, volts: float) -> None:
        self._volts[0] = volts
        self._call("write voltage", self.card.write_analog, self._motor, 1, self._volts)

    def enable(self) -> None:
        self._states[0] = 1
        self._call("enable the amplifier", self.card.write_digital, self._amplifier, 1, self._states)

    def disable(self) -> None:
        self._states[0] = 0
        self._call("disable the amplifier", self.card.write_digital, self._amplifier, 1, self._states)

    def arm_watchdog(self, timeout: float) -> None:
        self._call("start the watchdog", self.card.watchdog_start, float(timeout))

    def reload_watchdog(self) -> bool:
        return bool(self._call("reload the watchdog", self.card.watchdog_reload))

    def stop_watchdog(self) -> None:
        if self.card is not None:
            self._call("stop the watchdog", self.card.watchdog_stop)
            if self._call("ask the watchdog", self.card.watchdog_is_expired):
                self._call("clear the watchdog", self.card.watchdog_clear)

    def safe(self) -> list[str]:
        return super().safe() if self.card is not None else []

    def close(self) -> None:
        if self.card is not None:
            card, self.card = self.card, None
            self._call("close", card.close)
