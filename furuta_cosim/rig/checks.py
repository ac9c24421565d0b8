"""Read-only checks of a rig before anything drives it: the encoders' signs and the current
sensor's offset, read with the amplifier off (``furuta-cosim rig check-signs``).

The board is opened, its output set to 0 V and its amplifier disabled (never enabled), the
encoders zeroed with the rig at rest (the pendulum hanging), and the sensors read for a while
during which a person

1. turns the arm by hand, a quarter of a turn or so, in the direction a positive voltage
   turns it (the model's positive ``theta0``), and back;
2. lifts the pendulum a little to either side and lets it swing.

What the readings say, each verdict with what it rests on (a check without its motion says
so, never passes):

- **the arm's sign**: the largest excursion of ``theta0`` (averaged over a second, so that a
  swinging pendulum's rocking of the arm does not count) must be positive (the plant file's
  ``sensors.arm_sign`` as it is), else that sign is wrong;
- **the pendulum's sign against the arm's**: a swinging pendulum pushes the free arm, and the
  model says which way: the correlation of the two rates while the pendulum swings (and the
  arm is not being turned) must have the sign it has in the model's own free swing, else the
  pendulum's sign is wrong (given the arm's);
- **the current**: with the amplifier off it reads the sensor's offset and noise; an offset of
  more than three noise standard deviations (the plant file's ``sensors.current_noise``) is
  named.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from furuta_cosim.rig.board import Board

MOVED = 0.3        # rad: the arm turned by hand at least this far (its mean over a second)
SWUNG = 0.2        # rad: the pendulum swung at least this far from hanging
TURNING = 1.0      # rad/s: an arm faster than this is being turned by hand, not pushed by the pendulum
SMOOTH = 0.03      # s: the rates are differences over this span (the counts' steps smoothed)


def check_signs(board: Board, plant, *, seconds: float = 10.0, period: float = 0.002, zero: bool = True,
                progress: Callable[[float, float], None] | None = None) -> dict:
    """Read ``board`` for ``seconds`` with its amplifier off and judge its sensors (module
    docstring). Returns ``{"checks": {name: {"verdict": ok|wrong|unsure, "says": line}},
    "samples": n, "left": [what a safe stop could not do]}``."""
    if not (math.isfinite(seconds) and 0.5 <= seconds <= 600):
        from furuta_cosim.errors import ConfigError

        raise ConfigError([f"seconds: expected 0.5 to 600, got {seconds}"])
    counts = float(plant.sensors.get("encoder_counts", 2048))
    signs = (float(plant.sensors.get("arm_sign", 1)), float(plant.sensors.get("pendulum_sign", 1)))
    per_count = 2.0 * math.pi / counts
    steps = int(round(seconds / period))
    rows = np.full((steps, 3), np.nan)
    board.open()
    done = 0
    try:
        board.write(0.0)
        board.disable()
        if zero:
            board.zero_encoders()
        clock = board.clock()
        start = clock.now()
        for k in range(steps):
            clock.wait_until(start + k * period)
            reading = board.read()
            rows[k] = (signs[0] * reading.arm * per_count, math.pi + signs[1] * reading.pendulum * per_count,
                       reading.current if reading.current is not None else math.nan)
            done = k + 1
            if progress is not None and k % int(round(1.0 / period)) == 0:
                progress(k * period, seconds)
    finally:
        left = board.safe()
        board.close()
    found = judge(rows[:done], period, plant, signs)
    found["left"] = left
    return found


def judge(rows: np.ndarray, period: float, plant, signs: tuple[float, float]) -> dict:
    """The verdicts on readings ``rows`` (theta0, theta1 as the plant file's signs make them,
    the current), one per ``period`` s."""
    theta0, theta1, current = rows[:, 0], rows[:, 1], rows[:, 2]
    checks = {}
    key = lambda name, value: f"sensors.{name}: {value:g}"  # noqa: E731
    # the arm's excursion averaged over a second: a swinging pendulum rocks the light arm back
    # and forth (0.5 rad on a QUBE let go 1 rad from hanging), a hand turns it and holds
    window = max(1, min(len(theta0), int(round(1.0 / period))))
    excursion = (np.convolve(theta0 - theta0[0], np.ones(window) / window, mode="valid")
                 if len(theta0) else theta0)
    if not len(theta0) or np.max(np.abs(excursion)) < MOVED:
        checks["arm"] = {"verdict": "unsure", "says": f"the arm was not turned (at most "
                         f"{np.max(np.abs(excursion)) if len(theta0) else 0.0:.2f} rad): turn it by hand "
                         "a quarter of a turn the way a positive voltage turns it, and check again"}
    else:
        peak = float(excursion[np.argmax(np.abs(excursion))])
        if peak > 0:
            checks["arm"] = {"verdict": "ok", "says": f"turned by hand, theta0 grew to {peak:+.2f} rad (its mean "
                                                      "over a second): "
                                                      f"{key('arm_sign', signs[0])} is right"}
        else:
            checks["arm"] = {"verdict": "wrong", "says": f"turned by hand the way a positive voltage turns it, "
                                                         f"theta0 went to {peak:+.2f} rad: set "
                                                         f"{key('arm_sign', -signs[0])} in the plant file"}
    from furuta_cosim.swingup import wrap

    swing = np.array([wrap(v - math.pi) for v in theta1])
    span = max(2, int(round(SMOOTH / period)))
    if not len(swing) or np.max(np.abs(swing)) < SWUNG:
        checks["pendulum"] = {"verdict": "unsure", "says": "the pendulum did not swing (at most "
                              f"{np.max(np.abs(swing)) if len(swing) else 0.0:.2f} rad from hanging): lift it "
                              "a little, let it swing, and check again"}
    else:
        rate0 = (theta0[span:] - theta0[:-span]) / (span * period)
        rate1 = (swing[span:] - swing[:-span]) / (span * period)
        pushed = (np.abs(rate0) < TURNING) & (np.abs(swing[span:]) > 0.02)
        measured = _correlation(rate0[pushed], rate1[pushed])
        expected = model_coupling(plant, period, span)
        if measured is None or expected is None or abs(measured) < 0.2:
            checks["pendulum"] = {"verdict": "unsure", "says": "the pendulum swung but did not move the arm "
                                  "clearly (the arm held, or turned at the same time): let it swing alone, the "
                                  "arm free, and check again"
                                  + ("" if measured is None else f" (rates' correlation {measured:+.2f})")}
        else:
            arm = checks["arm"]["verdict"]
            # the relation read with the arm's sign corrected where the arm's check found it wrong
            agrees = (np.sign(measured) == np.sign(expected)) != (arm == "wrong")
            seen = (f"rates' correlation {measured:+.2f}, the model's {expected:+.2f}"
                    + (", with the arm's sign corrected" if arm == "wrong" else ""))
            if agrees:
                checks["pendulum"] = {"verdict": "ok", "says": f"the swinging pendulum moves the arm as the model's "
                                      f"does ({seen}): {key('pendulum_sign', signs[1])} is right"
                                      + (", given the arm's" if arm == "unsure" else "")}
            elif arm == "unsure":
                checks["pendulum"] = {"verdict": "wrong", "says": f"the swinging pendulum moves the arm against the "
                                      f"model's ({seen}): one of sensors.arm_sign and sensors.pendulum_sign is "
                                      "wrong; turn the arm by hand as well to tell which"}
            else:
                checks["pendulum"] = {"verdict": "wrong", "says": f"the swinging pendulum moves the arm against the "
                                      f"model's ({seen}): set {key('pendulum_sign', -signs[1])} in the plant file"}
    known = current[np.isfinite(current)]
    if len(known):
        noise = float(plant.sensors.get("current_noise", 0.004)) or 0.004
        offset = float(np.mean(known))
        spread = float(np.std(known))
        if abs(offset) > 3 * max(noise, spread / max(math.sqrt(len(known)), 1.0)):
            checks["current"] = {"verdict": "wrong", "says": f"with the amplifier off the current reads {offset:+.4g} A "
                                 f"on average (noise {spread:.2g} A): an offset of the sensor, or a motor driven"}
        else:
            checks["current"] = {"verdict": "ok", "says": f"with the amplifier off the current reads {offset:+.2g} A "
                                 f"on average, within its noise ({spread:.2g} A RMS; the plant file says {noise:g})"}
    return {"checks": checks, "samples": int(len(rows)), "period": period}


def model_coupling(plant, period: float, span: int) -> float | None:
    """The correlation of the arm's and the pendulum's rates in the model's own free swing
    (the pendulum let go 0.3 rad from hanging, the arm free, 0 V, 3 s), the rates taken as
    :func:`judge` takes them; None when the model does not move the arm at all."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.session import PlantSession

    session = PlantSession.open(build_fmu(plant))
    try:
        session.reset({**dict(plant.parameters), "theta1_start": math.pi + 0.3})
        session.set_io(["V"], ["theta0", "theta1"])
        rows = [session.get(["theta0", "theta1"])]
        for _ in range(int(round(3.0 / period))):
            rows.append(session.step([0.0], period))
    finally:
        session.close()
    rows = np.asarray(rows, dtype=float)
    rate0 = (rows[span:, 0] - rows[:-span, 0]) / (span * period)
    rate1 = (rows[span:, 1] - rows[:-span, 1]) / (span * period)
    return _correlation(rate0, rate1)


def _correlation(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) < 10 or np.std(a) == 0 or np.std(b) == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1])
