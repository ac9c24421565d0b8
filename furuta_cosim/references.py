"""Reference kinds: one class per ``type`` of a scenario's ``reference.signal``, registered
once in :data:`KINDS`. A scenario reads its keys and checks from here, a reference evaluates
through it, and the docs and error messages list :data:`KINDS`; a new kind is one class here
(with its test).

A kind says its keys (``required``, ``optional``), which of its numbers are periods (> 0)
or times (>= 0), whether a reference made of it ends constant (``settles``: step metrics
apply), and how it evaluates on the control instants.
"""

from __future__ import annotations

import math
from typing import ClassVar, Mapping

import numpy as np

KINDS: dict[str, type[Kind]] = {}
PLAIN = object()  # what Kind.read returns for a key that is a plain number
EPS = 1e-12  # an instant counts as reached within this (sample times are sums of floats)


class Kind:
    """One reference kind; subclasses set the class attributes and :meth:`value`."""

    name: ClassVar[str]
    required: ClassVar[tuple[str, ...]] = ()
    optional: ClassVar[tuple[str, ...]] = ()
    positive: ClassVar[tuple[str, ...]] = ()    # numbers that must be > 0
    times: ClassVar[tuple[str, ...]] = ()       # numbers that must be >= 0 (instants)
    settles: ClassVar[bool] = False             # ends constant: step metrics apply

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.name in KINDS:
            raise ValueError(f"reference kind {cls.name!r} registered twice")
        KINDS[cls.name] = cls

    @staticmethod
    def value(p: Mapping, t: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    @classmethod
    def read(cls, check, section: Mapping, key: str, name: str):
        """The value of key ``name`` by the kind's own check (``points``, ``interpolation``,
        ``duty``), None when it fails; :data:`PLAIN` for a plain number (the scenario reads
        those, bounded like every number of a reference)."""
        return PLAIN


class Constant(Kind):
    name = "constant"
    required = ("value",)
    settles = True

    @staticmethod
    def value(p, t):
        return np.full_like(t, p["value"])


class Step(Kind):
    name = "step"
    required = ("time", "amplitude")
    optional = ("initial",)
    times = ("time",)
    settles = True

    @staticmethod
    def value(p, t):
        return np.where(t >= p["time"] - EPS, p["amplitude"], p.get("initial", 0.0))


class Sine(Kind):
    name = "sine"
    required = ("amplitude", "period")
    optional = ("phase", "offset", "start")
    positive = ("period",)
    times = ("start",)

    @staticmethod
    def value(p, t):
        start = p.get("start", 0.0)
        phase = 2 * math.pi * (t - start) / p["period"] + p.get("phase", 0.0)
        return np.where(t >= start - EPS, p.get("offset", 0.0) + p["amplitude"] * np.sin(phase), 0.0)


class Square(Kind):
    name = "square"
    required = ("amplitude", "period")
    optional = ("duty", "offset", "start")
    positive = ("period",)
    times = ("start",)

    @staticmethod
    def value(p, t):
        start = p.get("start", 0.0)
        fraction = np.mod((t - start) / p["period"] + EPS, 1.0)
        level = np.where(fraction < p.get("duty", 0.5), p["amplitude"], -p["amplitude"])
        return np.where(t >= start - EPS, p.get("offset", 0.0) + level, 0.0)

    @classmethod
    def read(cls, check, section, key, name):
        if name != "duty":
            return PLAIN
        number = check.number(section[name], f"{key}.duty")
        if number is not None and not 0 < number < 1:
            check.fail(f"{key}.duty", f"must be between 0 and 1, got {number}")
        return number


class Ramp(Kind):
    name = "ramp"
    required = ("slope",)
    optional = ("start", "initial")
    times = ("start",)

    @staticmethod
    def value(p, t):
        start = p.get("start", 0.0)
        return p.get("initial", 0.0) + np.where(t >= start - EPS, p["slope"] * (t - start), 0.0)


class Table(Kind):
    name = "table"
    required = ("points",)
    optional = ("interpolation",)
    settles = True

    @staticmethod
    def value(p, t):
        times, values = (np.array(c) for c in zip(*p["points"]))
        if p.get("interpolation", "hold") == "linear":
            return np.interp(t, times, values)
        index = np.searchsorted(times, t + EPS, side="right") - 1
        return np.where(index >= 0, values[np.clip(index, 0, None)], 0.0)

    @classmethod
    def read(cls, check, section, key, name):
        if name == "interpolation":
            return check.string(section[name], f"{key}.{name}", ("hold", "linear"))
        pairs = section["points"]
        if not (isinstance(pairs, list) and pairs and all(isinstance(p, list) for p in pairs)):
            check.fail(f"{key}.points", "expected a list of [time, value] pairs")
            return None
        rows = check.matrix(pairs, f"{key}.points", cols=2)
        if rows is None:
            return None
        times = [r[0] for r in rows]
        if any(b <= a for a, b in zip(times, times[1:])):
            check.fail(f"{key}.points", "times must increase")
        return tuple(tuple(r) for r in rows)
