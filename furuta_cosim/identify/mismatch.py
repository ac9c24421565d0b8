"""Why a rebuilt command is not the logged one: the cause measured, in words.

A log's loop is checked by rebuilding its command from what the log recorded (the law or the
controller that ran, on the logged angles, current and references: identify/replay.py
rebuilt_command, identify/laws.py) and comparing it with the logged column. When they part,
the difference itself says what is wrong more often than not, and the message names that one
cause instead of a list of possibilities:

- a constant factor (the logged command is ``a`` times the rebuilt one): a gain, or the
  column's unit or scale;
- the sign (a factor of -1): the column's sign, or the law's;
- a shift of whole samples (the logged column is the rebuilt command some samples later or
  earlier): a delay between the controller and the column, or the log's clock;
- none of these: another law or controller than the one stated.

    words = cause(rebuilt, logged, period=0.002)
"""

from __future__ import annotations

import math

import numpy as np

# the fraction of the logged command's RMS that a rebuilt command may be off and still count as
# the same loop: identify refuses a loop beyond it before any fit (identify/fit.py). The loops
# this project writes and reads rebuild to rounding (the virtual board's logs, on time or late,
# 0 V; a lab's PD in its own words, 4e-14 V); a wrong controller is off by about its own size
# (lqr-paper stated for a log of lqr-qube: 2.0 times the logged command's RMS)
MISMATCH = 0.10
MAX_SHIFT = 10      # samples: the shifts tried, each way
_FACTOR = 0.05      # a factor within this of -1 is the sign
EXPLAINED = 0.1     # a cause leaves at most this fraction of the difference it explains


def rms(values: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(values)))) if len(values) else 0.0


def apart(rebuilt: np.ndarray, logged: np.ndarray) -> float:
    """How far ``rebuilt`` is from ``logged``: the RMS of their difference over the logged
    command's RMS (inf where either is not finite)."""
    if not (np.all(np.isfinite(rebuilt)) and np.all(np.isfinite(logged))):
        return math.inf
    return rms(rebuilt - logged) / max(rms(logged), 1e-12)


def cause(rebuilt: np.ndarray, logged: np.ndarray, period: float, tolerance: float = MISMATCH) -> str:
    """The cause, in words, that explains the difference of ``rebuilt`` and ``logged`` (both
    over the same samples): a factor, the sign, or a shift of whole samples; "" when none does.
    A cause explains it when it brings the two within ``tolerance`` of the logged command's
    RMS and within a tenth of their difference (a factor of 0.97 that halves a
    discretization's difference is no explanation)."""
    if not (np.all(np.isfinite(rebuilt)) and np.all(np.isfinite(logged))) or len(logged) < 2:
        return ""
    scale = min(tolerance * max(rms(logged), 1e-12), EXPLAINED * rms(rebuilt - logged))
    energy = float(rebuilt @ rebuilt)
    if energy > 0:
        factor = float(rebuilt @ logged) / energy
        if rms(logged - factor * rebuilt) <= scale:
            if abs(factor + 1.0) <= _FACTOR:
                return ("the sign: the logged command is the rebuilt one negated (the command column's sign "
                        "or scale, or the law's sign)")
            return (f"a constant factor: the logged command is {factor:.4g} times the rebuilt one (a gain, "
                    "or the command column's unit or scale)")
    best = None
    n = len(logged)
    for shift in range(1, min(MAX_SHIFT, n - 2) + 1):
        for sign, (a, b) in ((1, (logged[shift:], rebuilt[:n - shift])), (-1, (logged[:n - shift], rebuilt[shift:]))):
            error = rms(a - b)
            if error <= scale and (best is None or error < best[0]):
                best = (error, shift * sign)
    if best is not None:
        shift = best[1]
        when = "later" if shift > 0 else "earlier"
        return (f"a shift of {abs(shift)} sample(s): the logged command is the rebuilt one {abs(shift)} "
                f"sample(s) ({abs(shift) * period * 1000:.4g} ms) {when} (the column is logged at another "
                "sample than the one the controller computed it at, or the log's clock; a delay to the "
                "motor, loop.delay, does not move the logged column)")
    return ""


def first_apart(rebuilt: np.ndarray, logged: np.ndarray, tolerance: float = MISMATCH) -> int:
    """The first sample where ``rebuilt`` and ``logged`` differ by more than ``tolerance`` of
    the logged command's RMS (a sample that is not finite counts), 0 if none does."""
    scale = max(rms(logged[np.isfinite(logged)]) if np.any(np.isfinite(logged)) else 0.0, 1e-12)
    bad = ~(np.abs(rebuilt - logged) <= tolerance * scale)
    return int(np.argmax(bad)) if np.any(bad) else 0
