"""Whether a rig's measured metrics can be what a rig measured, before a tuning believes them.

A board's or an external rig's result is physics: effort within the
amplifier's limit and, on a balance, not zero (a pendulum held upright needs a command); a
signal's peak at least its RMS; the pendulum's angle, wrapped, within pi of upright; the arm
within the supervisor's limit (beyond it the supervisor would have tripped); a tracking error no
larger than the arm's range and the reference's allow over the run. A result that breaks one is
refused naming the field: a tuning that learned from it would be measured against nothing (a
baseline effort of 1e308 makes every candidate's effort term 0; an error of 1e308 disarms the
no-worse-than-the-baseline constraint).
"""

from __future__ import annotations

import math

import numpy as np

# V: the least RMS command of a trial that balanced: a pendulum held upright on a real motor
# needs some (the virtual board's balances measure about 0.05 V)
MIN_EFFORT = 1e-6
_AMPLITUDES = ("max_abs", "peak_abs", "rms", "RMS")


def implausible(values: dict, prepared, finished: bool = True) -> list[str]:
    """What cannot be true of ``values`` (metric -> number) measured on a rig running
    ``prepared`` (its period, duration, reference, plant and limits): one line per problem,
    each naming the metric. ``finished``: the scenario ran to its end (a run the supervisor
    tripped may have passed the arm's limit, and one cut short may have commanded nothing)."""
    problems = []
    # a metric that has no value (a settling time that never came: None or NaN) is no claim;
    # an external rig's are checked finite where they are read (tuning/trials.py read_result)
    values = {k: float(v) for k, v in values.items()
              if isinstance(v, (int, float)) and not isinstance(v, bool) and _finite(v)}
    if finished and values and all(v == 0 for v in values.values()):
        return ["every metric is 0: no trial on a rig measures nothing at all"]
    limit = prepared.limit
    for metric in ("u.rms", "u.peak_abs"):
        if metric in values and limit and values[metric] > limit * (1 + 1e-6):
            problems.append(f"{metric}: {values[metric]:.4g} V is above the amplifier's limit ({limit:g} V), "
                            "which every command is clipped to")
    if finished and "u.rms" in values and values["u.rms"] < MIN_EFFORT:
        problems.append(f"u.rms: {values['u.rms']:.4g} V: a trial that held the pendulum needs a command "
                        f"(at least {MIN_EFFORT:g} V RMS)")
    for signal, peak in (("u", "peak_abs"), ("theta0", "max_abs"), ("theta1", "max_abs"), ("i", "max_abs")):
        top, mean = values.get(f"{signal}.{peak}"), values.get(f"{signal}.rms")
        if top is not None and mean is not None and top < mean * (1 - 1e-9) - 1e-12:
            problems.append(f"{signal}.{peak}: {top:.4g} is below {signal}.rms ({mean:.4g}): no signal's peak "
                            "is below its RMS")
    for metric, value in values.items():
        signal, _, name = metric.rpartition(".")
        if signal == "theta1" and name in _AMPLITUDES and value > math.pi + 1e-9:
            problems.append(f"{metric}: {value:.4g} rad: the pendulum's angle, wrapped, is within pi of upright")
    arm = _arm_limit(prepared)
    if finished and arm is not None and values.get("theta0.max_abs", 0.0) > arm * (1 + 1e-6):
        problems.append(f"theta0.max_abs: {values['theta0.max_abs']:.4g} rad is beyond the supervisor's "
                        f"{arm:g} rad, where it trips the run")
    span = _error_span(prepared, arm)
    if span is not None:
        duration = float(prepared.t[-1] - prepared.t[0]) + prepared.control_period if len(prepared.t) else 0.0
        bounds = {"error.IAE": span * duration, "error.ISE": span ** 2 * duration, "error.RMS": span,
                  "error.ITAE": span * duration ** 2}
        for metric, most in bounds.items():
            if metric in values and values[metric] > most * (1 + 1e-6):
                problems.append(f"{metric}: {values[metric]:.4g} is more than the arm's range and the reference "
                                f"allow over the run ({most:.4g})")
    return problems


def _finite(value) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:   # an integer of hundreds of digits
        return False


def _arm_limit(prepared) -> float | None:
    plant = getattr(prepared, "plant", None)
    limits = getattr(plant, "limits", None) or {}
    value = limits.get("theta0")
    return float(value) if value else None


def _error_span(prepared, arm: float | None) -> float | None:
    """The largest tracking error the run can have: the arm's range plus the reference's
    largest magnitude (None when the tracked output is not the arm, or its range is unknown)."""
    if arm is None or prepared.tracked != "theta0":
        return None
    reference = float(np.max(np.abs(prepared.rbar))) if len(prepared.rbar) else 0.0
    return arm + reference
