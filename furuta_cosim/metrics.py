"""Metrics of a trace, with python-control's step_info names, and requirement verdicts.

Keys are ``<signal>.<metric>``. Every metric is one :class:`Metric` subclass below, registered
by being defined (:data:`METRICS`): the signals it belongs to (``of``), how it is computed,
whether it only grows along a run (:class:`Sum`, :class:`Peak`: their running form is what
early stopping watches, cosim/limits.py), its own regression tolerance, whether simulate's
table shows it, and the description the docs' table and the error messages are made from.
Which metrics one run records is :func:`catalogue`; the values of a trace are :func:`compute`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Iterable, Mapping, Sequence

import numpy as np

from furuta_cosim.signals import COMMAND, is_controller_state, is_estimate

THRESHOLD = 0.02
# the signals a metric belongs to: the applied input ``u``; the tracking error ``error`` (e =
# r - y); the tracked output's step response (python-control's step_info, computed together);
# every recorded signal; the plant outputs besides the tracked one that start away from 0
# (regulation); the angles among those that start more than pi/2 from 0 (a pendulum hanging)
GROUPS = ("input", "error", "step", "signal", "regulated", "wrapped")


@dataclass(frozen=True)
class Samples:
    """What a metric reads: one signal ``x`` at times ``t`` (a run's or a chunk of it), the
    sample period ``dt`` and, for the error, the scenario's window (a mask, or None)."""

    t: np.ndarray
    x: np.ndarray
    dt: float
    window: np.ndarray | None = None


class Metric:
    """One metric: subclass with ``name``, ``of`` (one of :data:`GROUPS`) and ``description``,
    and :meth:`value`; registered by being defined.

    ``grows``: it only grows along a run (sums of non-negative terms, maxima): subclass
    :class:`Sum` or :class:`Peak`, whose running form early stopping uses. ``rtol``/``atol``:
    the least regression tolerance it needs (a scenario's ``regression`` may widen it).
    ``shown``: simulate's table shows it. ``cost``: a larger value is worse (the tuning
    summary flags a tuned controller worse than its baseline on it). ``lower``: the least value
    it can take (0 for a norm, a sum of non-negative terms, a time), None when any.
    """

    name: ClassVar[str] = ""
    of: ClassVar[str] = ""
    description: ClassVar[str] = ""
    grows: ClassVar[bool] = False
    rtol: ClassVar[float] = 0.0
    atol: ClassVar[float] = 0.0
    shown: ClassVar[bool] = False
    cost: ClassVar[bool] = False
    # the least value it can take (a norm, a time: 0), None when any: a value sent back by a
    # rig below it is not a measurement (tuning/trials.py refuses it)
    lower: ClassVar[float | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.name:
            if cls.of not in GROUPS:
                raise TypeError(f"metric {cls.name}: of = {cls.of!r}, expected one of {GROUPS}")
            if (cls.of, cls.name) in METRICS:
                raise TypeError(f"metric {cls.of} {cls.name} is defined twice")
            METRICS[(cls.of, cls.name)] = cls()

    def value(self, s: Samples) -> float | None:
        """Its value over the samples (None: it has none for this signal)."""
        raise NotImplementedError


# (group, name) -> the metric, in the order they are defined (tables and docs keep it)
METRICS: dict[tuple[str, str], Metric] = {}


class Sum(Metric):
    lower = 0.0
    """A sum of non-negative terms times dt: it only grows, and its running value is the
    same terms over the samples run so far."""

    grows = True
    cost = True

    def term(self, s: Samples) -> np.ndarray:
        raise NotImplementedError

    def value(self, s: Samples) -> float:
        return self.running(0.0, s)

    def running(self, so_far: float, s: Samples) -> float:
        return so_far + float(np.sum(self.term(s))) * s.dt


class Peak(Metric):
    lower = 0.0
    """The largest magnitude: it only grows. A sample that is not a number is left to the
    run's own check of its outputs (a failure, not a bound)."""

    grows = True
    cost = True

    def value(self, s: Samples) -> float:
        return float(np.max(np.abs(s.x))) if len(s.x) else 0.0

    def running(self, so_far: float, s: Samples) -> float:
        if not len(s.x):
            return so_far
        peak = float(np.max(np.abs(s.x)))
        return so_far if math.isnan(peak) else max(so_far, peak)


class _StepInfo(Metric):
    """A name of python-control's step_info, computed for all at once (:func:`step_metrics`)."""

    of = "step"

    def value(self, s: Samples) -> float | None:
        raise TypeError("step metrics are computed together: step_metrics")


def _step(name: str, description: str, shown: bool = False, cost: bool = False, lower: float | None = None):
    return type(name, (_StepInfo,), {"name": name, "description": description, "shown": shown,
                                     "cost": cost, "lower": lower, "__module__": __name__})


_step("RiseTime", "time from 10 % to 90 % of the change (s)", shown=True, cost=True, lower=0.0)
_step("SettlingTime", "time after which it stays within 2 % of the change around its final value (s)",
      shown=True, cost=True, lower=0.0)
_step("SettlingMin", "its least value once risen")
_step("SettlingMax", "its greatest value once risen")
_step("Overshoot", "how far past the final value, in % of the change", shown=True, cost=True, lower=0.0)
_step("Undershoot", "how far the wrong way first, in % of the change", cost=True, lower=0.0)
_step("Peak", "its extreme in the direction of the change (a step down peaks at its lowest)", shown=True)
_step("PeakTime", "when it peaked (s)", lower=0.0)
_step("SteadyStateValue", "its final value")


class IAE(Sum):
    name, of, shown = "IAE", "error", True
    description = "integral of |e|"

    def term(self, s):
        return np.abs(s.x)


class ISE(Sum):
    name, of = "ISE", "error"
    description = "integral of e^2"

    def term(self, s):
        return s.x ** 2


class ITAE(Sum):
    name, of = "ITAE", "error"
    description = "integral of t |e|"

    def term(self, s):
        return np.asarray(s.t) * np.abs(s.x)


class ErrorRMS(Metric):
    name, of, shown, cost, lower = "RMS", "error", True, True, 0.0
    description = "root mean square of e (over the scenario's error window when it has one)"

    def value(self, s):
        x = s.x if s.window is None else s.x[s.window]
        return float(np.sqrt(np.mean(x ** 2)))


class InputPeak(Peak):
    name, of, shown = "peak_abs", "input", True
    description = "largest |u| (the voltage applied, after any limit)"


class InputRMS(Metric):
    name, of, shown, cost, lower = "rms", "input", True, True, 0.0
    description = "root mean square of u"

    def value(self, s):
        return float(np.sqrt(np.mean(s.x ** 2)))


class InputEnergy(Sum):
    name, of, shown = "energy", "input", True
    description = "integral of u^2"

    def term(self, s):
        return s.x ** 2


class MaxAbs(Peak):
    name, of, shown = "max_abs", "signal", True
    description = "largest magnitude of a recorded signal (plant outputs, u_command, controller states, ...)"


class RegulationSettling(Metric):
    name, of, shown, cost, lower = "SettlingTime", "regulated", True, True, 0.0
    description = ("time after which an output that starts away from 0 stays within 2 % of its "
                   "initial offset around 0 (s): \"the pendulum is back\"")

    def value(self, s):
        return regulation_settling(s.t, s.x)


class WrappedSettling(Metric):
    name, of, cost, lower = "WrappedSettlingTime", "wrapped", True, 0.0
    description = ("the same of an angle (rad) started more than pi/2 from 0, wrapped to (-pi, pi]: "
                   "upright whichever way round it swung up (s)")

    def value(self, s):
        return regulation_settling(s.t, _wrapped(s.x))


def lower_bound(key: str) -> float | None:
    """The least value of the metric ``key`` (``SIGNAL.NAME``, as results name them): the
    largest ``lower`` of the metrics of that name, None when none states one."""
    name = key.rsplit(".", 1)[-1]
    bounds = [m.lower for (_, n), m in METRICS.items() if n == name and m.lower is not None]
    return max(bounds) if bounds else None


def metrics_of(group: str, shown: bool = False) -> tuple[str, ...]:
    """The names of a group's metrics (``shown``: only those simulate's table shows)."""
    return tuple(m.name for (g, m_name), m in METRICS.items() if g == group and (m.shown or not shown))


def entry(key: str) -> Metric | None:
    """The registered metric of a key ``<signal>.<name>`` (None: no such name)."""
    signal, _, name = key.rpartition(".")
    groups = {"u": ("input",), "error": ("error",)}.get(signal, ("step", "signal", "regulated", "wrapped"))
    return next((METRICS[(g, name)] for g in groups if (g, name) in METRICS), None)


def peak_metric(signal: str) -> str:
    """The metric of a signal's largest magnitude (the input's is ``u.peak_abs``)."""
    return f"u.{InputPeak.name}" if signal == "u" else f"{signal}.{MaxAbs.name}"


STEP_NAMES = metrics_of("step")
# what a tuning summary compares a tuned controller with its baseline on, besides its own
# objective and constraints: the tracking error, the voltage's size and its peak
HEADLINE = (f"error.{ISE.name}", f"u.{InputRMS.name}", f"u.{InputPeak.name}")


def catalogue(tracked: str, outputs: Iterable[str], others: Iterable[str] = (),
              settles: bool = True, steps: int = 0, wrapped: Iterable[str] = ()) -> dict[str, tuple[str, ...]]:
    """The metrics a run records, by signal: the one place that says which exist.

    ``outputs`` are the plant outputs (the tracked one among them), ``others`` the further
    recorded signals (disturbance inputs, ``u_command``, estimates); ``steps``: how many steps
    of a piecewise-constant reference get metrics of their own (:func:`step_segments`);
    ``wrapped``: the angles that start more than pi/2 from 0. Controller states ``xc<k>``
    have the ``signal`` metrics too; they depend on the controller, so :func:`problem` accepts
    them by pattern.
    """
    result = {"u": metrics_of("input"), "error": metrics_of("error")}
    wrapped = set(wrapped)
    for name in outputs:
        result[name] = (metrics_of("step") + metrics_of("signal") if settles else metrics_of("signal")) \
            if name == tracked else \
            metrics_of("signal") + metrics_of("regulated") + (metrics_of("wrapped") if name in wrapped else ())
    for name in others:
        result.setdefault(name, metrics_of("signal"))
    if settles:
        result.update({f"{tracked}.step{k}": metrics_of("step") for k in range(1, steps + 1)})
    return result


def table_keys(tracked: str, watched: Iterable[str] = (), steps: int = 0) -> list[str]:
    """The metric keys simulate's table shows (``shown``) for a run tracking ``tracked``: the
    tracked output's step response, the error's, the input's, and for the watched outputs
    (Trace.watched: those in the tracked output's unit) theirs (a table leaves out the ones a
    run does not record); with ``steps`` (several steps), each step's."""
    prefixes = [f"{tracked}.step{k}" for k in range(1, steps + 1)] if steps else [tracked]
    keys = [f"{prefix}.{m}" for prefix in prefixes for m in metrics_of("step", shown=True)]
    keys += [f"error.{m}" for m in metrics_of("error", shown=True)]
    keys += [f"u.{m}" for m in metrics_of("input", shown=True)]
    return keys + [f"{name}.{m}" for name in watched
                   for m in metrics_of("signal", shown=True) + metrics_of("regulated", shown=True)]


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
        return f"expected <signal>.<metric> (e.g. y.SettlingTime), got {metric!r}"
    if known is None or is_controller_state(signal):
        names = {"u": metrics_of("input"), "error": metrics_of("error")}.get(
            signal, tuple(dict.fromkeys(name for _, name in METRICS)))  # any signal's, before the plant is known
        if is_controller_state(signal):
            names = metrics_of("signal")
        if name not in names:
            return f"{signal} has no metric {name!r} (expected one of: {', '.join(names)}){_nearest(signal, name, names)}"
        return None
    if signal not in known:
        return f"no signal {signal!r} is recorded (signals: {', '.join(known)})"
    if name not in known[signal]:
        return (f"{signal} has no metric {name!r} (its metrics: {', '.join(known[signal])})"
                f"{_nearest(signal, name, known[signal])}")
    return None


def _nearest(signal: str, name: str, names: Sequence[str]) -> str:
    """"; did you mean ...: what it is" for the registered name closest to ``name``."""
    import difflib

    close = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    found = entry(f"{signal}.{close[0]}") if close else None
    return f"; did you mean {close[0]}: {found.description}?" if found else ""


def _integrals(t: np.ndarray, e: np.ndarray, dt: float) -> dict:
    """The error's sums (IAE, ISE, ITAE, ...: every error metric that is a :class:`Sum`)."""
    samples = Samples(t, e, dt)
    return {name: m.value(samples) for (group, name), m in METRICS.items()
            if group == "error" and isinstance(m, Sum)}


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
    if change < 0:  # the least normalized value is the greatest output on a step down
        result["SettlingMin"], result["SettlingMax"] = result["SettlingMax"], result["SettlingMin"]
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
    window = None
    if error_window:
        window = (t >= error_window[0] - 1e-12) & (t < error_window[1] - 1e-12)
    regulated = _regulated(trace)
    for signal, x, groups in [("error", r - y, ("error",)), ("u", trace.u, ("input",))] + [
            (name, values, ("signal",) + (("regulated", "wrapped") if name != trace.tracked and name in regulated
                                          else ())) for name, values in trace.signals.items()]:
        samples = Samples(t, x, dt, window if signal == "error" else None)
        for (group, name), metric in METRICS.items():
            if group not in groups:
                continue
            if group == "wrapped" and not (trace.units.get(signal) == "rad"
                                           and abs(_wrapped(x[:1])[0]) > math.pi / 2):
                continue
            value = metric.value(samples)
            if value is not None:
                metrics[f"{signal}.{name}"] = value
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

