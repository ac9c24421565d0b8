"""Metrics of a trace, with python-control's step_info names, and requirement verdicts.

Keys are ``<signal>.<metric>``:

- the tracked output (when the reference ends constant): ``RiseTime``, ``SettlingTime``,
  ``SettlingMin``, ``SettlingMax``, ``Overshoot``, ``Undershoot``, ``Peak``, ``PeakTime``,
  ``SteadyStateValue`` of the response since the reference's last change, computed by
  ``control.step_info`` on the response normalized to a unit step (``Peak``: the extreme in
  the direction of the change); for a reference of 2 to :data:`MAX_STEPS` steps, the same of
  each step until the next, as ``<output>.step<k>.<name>``;
- ``error.IAE``, ``error.ISE``, ``error.ITAE``, ``error.RMS`` of e = r - y (RMS over the
  scenario's error window when it has one);
- ``u.peak_abs``, ``u.rms``, ``u.energy`` (the integral of u^2);
- for every recorded output ``<name>.max_abs``, and for an output that starts away from 0
  while the reference is not about it, ``<name>.SettlingTime``: the time after which it stays
  within 2 % of its initial offset around 0 (regulation); for an angle that starts more than
  pi/2 from 0 (a pendulum hanging), ``<name>.WrappedSettlingTime``: the same of the angle
  wrapped to (-pi, pi], the time after which it stays within 2 % of its start from upright,
  whichever way round it swung up.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping, Sequence

import numpy as np

from furuta_cosim.signals import COMMAND, is_controller_state, is_estimate

THRESHOLD = 0.02
STEP_NAMES = ("RiseTime", "SettlingTime", "SettlingMin", "SettlingMax", "Overshoot",
              "Undershoot", "Peak", "PeakTime", "SteadyStateValue")
INPUT_METRICS = ("peak_abs", "rms", "energy")         # of the applied input u
ERROR_METRICS = ("IAE", "ISE", "ITAE", "RMS")          # of e = r - y
OUTPUT_METRICS = ("max_abs", "SettlingTime")           # of any other plant output (regulation)
# of an angle (rad) that starts more than pi/2 from 0: a pendulum swung up from hanging, upright
# whichever way round it went
WRAPPED_METRICS = ("WrappedSettlingTime",)
SIGNAL_METRICS = ("max_abs",)                          # of any other recorded signal
# every metric name that some signal can have: what a scenario file may name before the plant
# is known; :func:`catalogue` says which exist for one prepared scenario
ALL_NAMES = tuple(dict.fromkeys(STEP_NAMES + INPUT_METRICS + ERROR_METRICS + OUTPUT_METRICS + WRAPPED_METRICS))


def catalogue(tracked: str, outputs: Iterable[str], others: Iterable[str] = (),
              settles: bool = True, steps: int = 0, wrapped: Iterable[str] = ()) -> dict[str, tuple[str, ...]]:
    """The metrics a run records, by signal: the one place that says which exist.

    ``outputs`` are the plant outputs (the tracked one among them), ``others`` the further
    recorded signals (disturbance inputs, ``u_command``, estimates); ``steps``: how many steps
    of a piecewise-constant reference get metrics of their own (:func:`step_segments`);
    ``wrapped``: the angles that start more than pi/2 from 0 (:data:`WRAPPED_METRICS`). Controller states
    ``xc<k>`` have ``max_abs`` too; they depend on the controller, so :func:`problem` accepts
    them by pattern.
    """
    result = {"u": INPUT_METRICS, "error": ERROR_METRICS}
    wrapped = set(wrapped)
    for name in outputs:
        result[name] = (STEP_NAMES + ("max_abs",) if settles else ("max_abs",)) if name == tracked \
            else OUTPUT_METRICS + (WRAPPED_METRICS if name in wrapped else ())
    for name in others:
        result.setdefault(name, SIGNAL_METRICS)
    if settles:
        result.update({f"{tracked}.step{k}": STEP_NAMES for k in range(1, steps + 1)})
    return result


# what a table of a run shows first, by signal: the tracked output's step response, the
# error's integrals, the input's size, and for the watched outputs (Trace.watched: those in the
# tracked output's unit) their peak and settling
TABLE = {"tracked": ("RiseTime", "SettlingTime", "Overshoot", "Peak"),
         "error": ("IAE", "RMS"), "u": INPUT_METRICS, "watched": OUTPUT_METRICS}


def table_keys(tracked: str, watched: Iterable[str] = (), steps: int = 0) -> list[str]:
    """The metric keys of :data:`TABLE` for a run tracking ``tracked`` (a table leaves out the
    ones a run does not record); with ``steps`` (several steps), each step's."""
    prefixes = [f"{tracked}.step{k}" for k in range(1, steps + 1)] if steps else [tracked]
    keys = [f"{prefix}.{m}" for prefix in prefixes for m in TABLE["tracked"]]
    keys += [f"error.{m}" for m in TABLE["error"]] + [f"u.{m}" for m in TABLE["u"]]
    return keys + [f"{name}.{m}" for name in watched for m in TABLE["watched"]]


def checked(check, value, key: str) -> str | None:
    """A metric name read from a file, ``<signal>.<metric>``: its form and name, reported
    through ``check`` (a :class:`~furuta_cosim.config.Checker`) with its key. Which signals a
    run records is known once its plant is; ``prepare`` checks that."""
    text = check.string(value, key)
    wrong = problem(text) if text else None
    if wrong:
        check.fail(key, wrong)
        return None
    return text


def problem(metric: str, known: Mapping[str, tuple[str, ...]] | None = None) -> str | None:
    """Why ``metric`` ("<signal>.<name>") is not recorded, or None when it is.

    Without ``known`` only the form and the name are checked (any signal may exist)."""
    signal, dot, name = metric.rpartition(".")
    if not dot or not signal or not name:
        return f"expected <signal>.<metric> (e.g. theta1.SettlingTime), got {metric!r}"
    if known is None or is_controller_state(signal):
        names = {"u": INPUT_METRICS, "error": ERROR_METRICS}.get(signal, ALL_NAMES)
        if is_controller_state(signal):
            names = SIGNAL_METRICS
        if name not in names:
            return f"{signal} has no metric {name!r} (expected one of: {', '.join(names)})"
        return None
    if signal not in known:
        return f"no signal {signal!r} is recorded (signals: {', '.join(known)})"
    if name not in known[signal]:
        return f"{signal} has no metric {name!r} (its metrics: {', '.join(known[signal])})"
    return None


def _integrals(t: np.ndarray, e: np.ndarray, dt: float) -> dict:
    return {"IAE": float(np.sum(np.abs(e)) * dt), "ISE": float(np.sum(e ** 2) * dt),
            "ITAE": float(np.sum(t * np.abs(e)) * dt)}


def standing_still(trace, error_window=None) -> dict[str, float]:
    """The error metrics of ``trace``'s reference had the tracked output stayed at its first
    value: what a tracking metric of a controller that does nothing about the reference is
    compared with. Empty when the reference never moves: then the error is regulation, which
    no controller gets for free."""
    if not len(trace.r) or np.ptp(trace.r) == 0:
        return {}
    t, dt = trace.t, (trace.t[1] - trace.t[0]) if len(trace.t) > 1 else 1.0
    y = trace.signals[trace.tracked]
    e = trace.r - (y[0] if len(y) else 0.0)
    metrics = {f"error.{name}": value for name, value in _integrals(t, e, dt).items()}
    window = slice(None)
    if error_window:
        window = (t >= error_window[0] - 1e-12) & (t < error_window[1] - 1e-12)
    metrics["error.RMS"] = float(np.sqrt(np.mean(e[window] ** 2)))
    return metrics


def step_metrics(t: np.ndarray, y: np.ndarray, y0: float, yfinal: float) -> dict | None:
    """step_info of y going from y0 to yfinal; None when there is no change to measure."""
    change = yfinal - y0
    if abs(change) < 1e-12 or len(t) < 3:
        return None
    normalized = (y - y0) / change
    import control  # here: importing python-control costs a second, and few callers need it

    try:
        info = control.step_info(normalized, T=t - t[0], yfinal=1.0, SettlingTimeThreshold=THRESHOLD)
    except IndexError:
        # step_info needs the response to pass 90 % of the change; this one never did
        info = {name: math.inf for name in STEP_NAMES}
        info.update(SettlingMin=float(np.min(normalized)), SettlingMax=float(np.max(normalized)),
                    Overshoot=0.0, Undershoot=float(max(0.0, -np.min(normalized)) * 100),
                    Peak=float(np.max(np.abs(normalized))), PeakTime=float(t[np.argmax(np.abs(normalized))] - t[0]),
                    SteadyStateValue=float(normalized[-1]))
    scale = {"SettlingMin", "SettlingMax", "Peak", "SteadyStateValue"}
    result = {}
    for name in STEP_NAMES:
        value = float(info[name])
        result[name] = y0 + value * change if name in scale else value
    # the extreme in the direction of the change (a step down peaks at its lowest value), not
    # the largest |y|, which for a step back toward 0 is where it started
    result["Peak"] = y0 + float(np.max(normalized)) * change
    return result


# a reference with 2 to this many steps gets each step's metrics as well (``<y>.step<k>.*``)
MAX_STEPS = 20


def step_segments(r: np.ndarray) -> list[tuple[int, int]]:
    """The samples ``[begin, end)`` after each change of a piecewise-constant reference
    (empty when it changes more than :data:`MAX_STEPS` times: a ramp, a sine)."""
    changes = np.nonzero(np.abs(np.diff(r)) > 0)[0]
    if not 2 <= len(changes) <= MAX_STEPS:
        return []
    begins = list(changes + 1)
    return list(zip(begins, begins[1:] + [len(r)]))


def regulation_settling(t: np.ndarray, y: np.ndarray) -> float | None:
    """Time after which |y| stays within 2 % of |y(0)|; None if y starts at 0."""
    band = THRESHOLD * abs(y[0])
    if band == 0:
        return None
    outside = np.nonzero(np.abs(y) > band)[0]
    if len(outside) == 0:
        return 0.0
    if outside[-1] == len(y) - 1:
        return math.inf
    return float(t[outside[-1] + 1])


def compute(trace, settles: bool = True, error_window=None) -> dict[str, float]:
    """All metrics of a trace as a flat ``{"signal.Metric": value}`` mapping. A run that blew
    up gives infinite integrals (shown as "never"), not warnings."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _compute(trace, settles, error_window)


def _compute(trace, settles: bool, error_window) -> dict[str, float]:
    t, dt = trace.t, (trace.t[1] - trace.t[0]) if len(trace.t) > 1 else 1.0
    y, r = trace.signals[trace.tracked], trace.r
    metrics: dict[str, float] = {}
    metrics[f"{trace.tracked}.max_abs"] = float(np.max(np.abs(y))) if len(y) else 0.0
    if settles:
        changes = np.nonzero(np.abs(np.diff(r)) > 0)[0]
        begin = changes[-1] + 1 if len(changes) else 0
        step = step_metrics(t[begin:], y[begin:], float(y[begin]), float(r[-1]))
        for name, value in (step or {}).items():
            metrics[f"{trace.tracked}.{name}"] = value
        # several steps: each one's response too, until the next step (the unprefixed ones
        # are the last step's)
        for k, (first, end) in enumerate(step_segments(r), start=1):
            step = step_metrics(t[first:end], y[first:end], float(y[first]), float(r[first]))
            for name, value in (step or {}).items():
                metrics[f"{trace.tracked}.step{k}.{name}"] = value
    e = r - y
    for name, value in _integrals(t, e, dt).items():
        metrics[f"error.{name}"] = value
    window = slice(None)
    if error_window:
        window = (t >= error_window[0] - 1e-12) & (t < error_window[1] - 1e-12)
    metrics["error.RMS"] = float(np.sqrt(np.mean(e[window] ** 2)))
    u = trace.u
    metrics.update({"u.peak_abs": float(np.max(np.abs(u))), "u.rms": float(np.sqrt(np.mean(u ** 2))),
                    "u.energy": float(np.sum(u ** 2) * dt)})
    for name, values in trace.signals.items():
        metrics[f"{name}.max_abs"] = float(np.max(np.abs(values)))
        if name != trace.tracked and name in _regulated(trace):
            settling = regulation_settling(t, values)
            if settling is not None:
                metrics[f"{name}.SettlingTime"] = settling
            if trace.units.get(name) == "rad" and abs(_wrapped(values[:1])[0]) > math.pi / 2:
                metrics[f"{name}.WrappedSettlingTime"] = regulation_settling(t, _wrapped(values))
    if trace.failure:
        # a run that stopped early never settled, whatever its last samples show
        metrics.update({k: math.inf for k in metrics if k.endswith(("SettlingTime", "RiseTime"))})
    return metrics


def _wrapped(values: np.ndarray) -> np.ndarray:
    """Angles in (-pi, pi]."""
    return np.pi - np.mod(np.pi - values, 2.0 * np.pi)


def _regulated(trace) -> set[str]:
    """Outputs (not inputs, controller states or estimates) that start away from zero."""
    return {n for n, v in trace.signals.items()
            if not (is_controller_state(n) or is_estimate(n) or n == COMMAND) and v[0] != 0.0}


def verdicts(metrics: Mapping[str, float], requirements: Sequence,
             controller: str) -> dict[str, dict]:
    """``{"<requirement>": {"value": v, "pass": bool}}`` of the requirements (scenario
    :class:`~furuta_cosim.scenario.Requirement`) that apply to ``controller``; a missing metric
    fails."""
    result = {}
    for requirement in (r for r in requirements if r.applies_to(controller)):
        value = metrics.get(requirement.metric)
        result[requirement.describe()] = {"metric": requirement.metric, "value": value,
                                          "max": requirement.max, "min": requirement.min,
                                          "pass": requirement.check(value)}
    return result


def all_pass(results: Mapping[str, dict]) -> bool:
    return all(v["pass"] for v in results.values())

