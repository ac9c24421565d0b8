"""A fake of ``quanser.hardware`` with the signatures its documentation gives (HIL, HILError,
Clock), for testing the Quanser board without the SDK or a QUBE.

``HIL`` behind it is a QUBE-Servo 3 simulated in real time (furuta_cosim's virtual rig on
the qube-servo-3 plant): encoder 0 is the arm, 1 the pendulum, analog output 0 the motor's
voltage, digital output 0 the amplifier's enable, analog input 0 the current. Every call is
checked as the SDK checks it (a channel the board does not have, a buffer of the wrong type or
length, a call before open is a HILError) and recorded in ``HIL.calls`` (class-wide, for the
test to read).
"""

import array
import time

CALLS: list = []


class HILError(Exception):
    def __init__(self, code: int, message: str = ""):
        super().__init__(code, message)
        self.error_code, self._message = code, message or f"HIL error {code}"

    def get_error_message(self) -> str:
        return self._message


class Clock:
    HARDWARE_CLOCK_0 = 0
    SYSTEM_CLOCK_1 = -1


BOARDS = {"qube_servo3_usb", "qube_servo2_usb"}
ENCODERS, ANALOG_OUT, DIGITAL_OUT, ANALOG_IN = {0, 1}, {0}, {0}, {0}


def _check(channels, num_channels, buffer, allowed, codes, what):
    if not isinstance(num_channels, int) or num_channels < 1 or len(channels) < num_channels:
        raise HILError(-1, f"{what}: {num_channels} channels for a channel list of {len(channels)}")
    if any(c not in allowed for c in list(channels)[:num_channels]):
        raise HILError(-2, f"{what}: no such channel among {list(channels)[:num_channels]}")
    if len(buffer) < num_channels:
        raise HILError(-3, f"{what}: a buffer of {len(buffer)} for {num_channels} channels")
    code = getattr(buffer, "typecode", None) or getattr(getattr(buffer, "dtype", None), "char", None)
    if code not in codes:
        raise HILError(-4, f"{what}: a buffer of type {code!r}, expected one of {codes}")


class HIL:
    INFINITE = -1
    plant = None       # a test sets the PlantSet the fake QUBE runs (qube-servo-3 by default)
    fail_open = None   # a test sets an error code here to make open fail
    paced = True       # the rig's time is the host's; False: a test steps it (rig.advance) itself

    def __init__(self, board_type=None, board_identifier="0"):
        self.rig = None
        self.watchdog = None
        if board_type is not None:
            self.open(board_type, board_identifier)

    def _record(self, name, *args):
        CALLS.append((name,) + tuple(list(a) if isinstance(a, array.array) else a for a in args))

    def _need(self):
        if self.rig is None:
            raise HILError(-5, "the board is not open")
        if HIL.paced:
            self.rig.advance(time.perf_counter() - self.t0)

    def open(self, board_type, board_identifier):
        self._record("open", board_type, board_identifier)
        if HIL.fail_open is not None:
            raise HILError(HIL.fail_open, "no such board is connected")
        if board_type not in BOARDS or not isinstance(board_identifier, str):
            raise HILError(-10, f"unknown board {board_type!r}@{board_identifier!r}")
        import math

        from furuta_cosim.fmu.exporter import build_fmu
        from furuta_cosim.fmu.plants import load_plant
        from furuta_cosim.rig.virtual import VirtualRig

        plant = HIL.plant or load_plant("qube-servo-3")
        start = dict(plant.parameters, theta1_start=math.pi)
        self.rig = VirtualRig(str(build_fmu(plant)), start, dict(plant.sensors))
        self.t0 = time.perf_counter()

    def is_valid(self):
        return self.rig is not None

    def close(self):
        self._record("close")
        if self.rig is not None:
            self.rig.close()
            self.rig = None

    def read_encoder(self, channels, num_channels, buffer):
        self._need()
        _check(channels, num_channels, buffer, ENCODERS, ("i", "l"), "read_encoder")
        reading = self.rig.reading()
        for k, channel in enumerate(list(channels)[:num_channels]):
            buffer[k] = reading.arm if channel == 0 else reading.pendulum

    def read_analog(self, channels, num_channels, buffer):
        self._need()
        _check(channels, num_channels, buffer, ANALOG_IN, ("d",), "read_analog")
        buffer[0] = self.rig.reading().current

    def set_encoder_counts(self, channels, num_channels, buffer):
        self._record("set_encoder_counts", channels, num_channels, buffer)
        self._need()
        _check(channels, num_channels, buffer, ENCODERS, ("i", "l"), "set_encoder_counts")
        if any(v != 0 for v in list(buffer)[:num_channels]):
            raise HILError(-6, "this fake zeroes counts only")
        self.rig.zero_encoders()

    def write_analog(self, channels, num_channels, buffer):
        self._record("write_analog", channels, num_channels, buffer)
        self._need()
        _check(channels, num_channels, buffer, ANALOG_OUT, ("d",), "write_analog")
        self.rig.write(float(buffer[0]))

    def write_digital(self, channels, num_channels, buffer):
        self._record("write_digital", channels, num_channels, buffer)
        self._need()
        _check(channels, num_channels, buffer, DIGITAL_OUT, ("b", "B", "?", "i"), "write_digital")
        self.rig.enabled = bool(buffer[0]) and not self.rig.expired

    def watchdog_set_analog_expiration_state(self, channels, num_channels, voltages):
        self._record("watchdog_set_analog_expiration_state", channels, num_channels, voltages)
        _check(channels, num_channels, voltages, ANALOG_OUT, ("d",), "watchdog_set_analog_expiration_state")

    def watchdog_set_digital_expiration_state(self, channels, num_channels, states):
        self._record("watchdog_set_digital_expiration_state", channels, num_channels, states)
        _check(channels, num_channels, states, DIGITAL_OUT, ("i", "b", "B"), "watchdog_set_digital_expiration_state")

    def watchdog_start(self, timeout):
        self._record("watchdog_start", timeout)
        self._need()
        if not isinstance(timeout, float) or timeout <= 0:
            raise HILError(-7, f"watchdog_start: a timeout of {timeout!r}")
        self.rig.arm(timeout)

    def watchdog_reload(self):
        self._need()
        return 1 if self.rig.reload() else 0

    def watchdog_is_expired(self):
        self._need()
        return bool(self.rig.expired)

    def watchdog_stop(self):
        self._record("watchdog_stop")
        self._need()
        self.rig.watchdog = None

    def watchdog_clear(self):
        self._record("watchdog_clear")
        self.rig.expired = False
