"""An experiment's loop (``loop:``): the controller or law that closed it, its period, limit,
rate filter, delay (fixed or free) and timing, read and checked at load.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from furuta_cosim.config import Checker, excerpt
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.measurement import RATE_FILTER
from furuta_cosim.identify.clocks import (MAX_DELAY_SAMPLES, UNIFORM_TOLERANCE, LeadIn, read_free_delay,
                                          timing_column)
from furuta_cosim.identify.columns import LINE, Free, to_si
from furuta_cosim.identify.laws import LinearLaw, is_linear, read_law


MAX_CONTROLLER_BYTES = 10_000_000   # a loop's controller file (YAML of gains and matrices)


_LOOP_KEYS = ("controller", "law", "reference", "feedforward", "rate_filter", "voltage", "counts", "delay",
              "late", "compute", "mode")


_LAW_KEYS = ("K", "F", "period")


@dataclass(frozen=True)
class Loop:
    """The controller that ran while a log was recorded, as the replay closes it again: its
    file (and the file's sha256), or for a log from another tool a state-feedback ``law``
    (``u = F r - K x`` on x = theta0, its rate, theta1, its rate, and the current if K has a
    fifth gain); the reference it followed at each sample of the window (None: 0) and a
    feedforward added to its command (None: none), the rates' filter (Hz), the voltage limit it
    was clipped to (None: none), the encoders' counts per revolution (what the controller saw of
    the angles) and the delay from a sample to its command at the motor (s, any number of
    samples)."""

    controller: Path | None
    sha256: str
    reference: np.ndarray | None
    rate_filter: float
    voltage: float | None
    counts: float
    delay: float = 0.0
    law: tuple | None = None     # (K, F) of a state-feedback law, instead of a controller file
    feedforward: np.ndarray | None = None
    # a balancing log: the controller sees its logged angles moved by the simulation's departure
    # from their estimated true values (identify/estimate.py sets it)
    estimate: bool = False
    # s from each sample's reading to its command's write (a rig's `compute` column; None: 0)
    compute: np.ndarray | None = None
    # a law in the logger's own words (identify/laws.py): references and measurements to command
    linear: "LinearLaw | None" = None
    # the log's rows before a window that cuts it after its first row (None: the log's start)
    lead_in: LeadIn | None = None
    # ``loop.delay: {free: [lo, hi]}``: the delay is fitted (``delay`` its start, the bounds' low end)
    free_delay: Free | None = None
    # the controller's mode at each sample, as logged (a swing-up: 0 swinging up, 1 balancing)
    mode: np.ndarray | None = None

    def cut(self, keep: slice, lead_in: LeadIn | None = None) -> "Loop":
        """The loop over the samples ``keep`` of its log's window; ``lead_in``: the rows
        before them, where ``keep`` starts after the window's first."""
        def part(values):
            return None if values is None else values[keep]

        return replace(self, reference=part(self.reference), feedforward=part(self.feedforward),
                       compute=part(self.compute), mode=part(self.mode),
                       lead_in=self.lead_in if not keep.start else lead_in,
                       linear=None if self.linear is None else self.linear.cut(keep))

    def controller_file(self):
        """The ControllerFile the replay runs: the file's, or the law's as a static controller."""
        from furuta_cosim.controllers import ControllerFile, load_controller

        if self.law is None:
            return load_controller(self.controller)
        from furuta_cosim.design.controller import GeneralizedController

        K, F = self.law
        gains = list(K) + [0.0] * (5 - len(K))
        return ControllerFile(GeneralizedController.static([gains], 0.0, "law"), 0.0,
                              tracked_output="theta0", F=F)

    def describe(self) -> str:
        if self.linear is not None:
            return self.linear.words
        return self.controller.name if self.law is None else f"the law K = {list(self.law[0])}"


def read_loop(check: Checker, top: dict, path: Path, table, columns, keep, period: float, csv: Path,
          times: np.ndarray | None = None) -> Loop | None:
    """``loop:``: the controller file (beside the experiment file) or a law (state feedback, or
    in the logger's own words: identify/laws.py), the reference and feedforward columns, the
    rates' filter, the voltage limit, the encoders' counts, the delay (the keys ``rig run``
    writes, and ``law``/``feedforward`` for a log from another tool)."""
    entry = check.mapping(top["loop"], "loop", optional=_LOOP_KEYS)
    if entry is None:
        return None
    if ("controller" in entry) == ("law" in entry):
        check.fail("loop", "name the controller that ran: a controller file (`controller`) or a "
                           "state-feedback law (`law: {K: [...], F: ...}`), one of them")
        return None
    controller, law, digest = None, None, ""
    if "controller" in entry:
        text = check.string(entry.get("controller"), "loop.controller")
        if text is not None:
            controller = Path(text) if Path(text).is_absolute() else path.parent / text
            if not controller.is_file():
                check.fail("loop.controller", f"{controller}: no such controller file")
                controller = None
            elif controller.stat().st_size > MAX_CONTROLLER_BYTES:   # read whole for its hash
                check.fail("loop.controller", f"{controller}: larger than {MAX_CONTROLLER_BYTES // 1_000_000} MB: "
                                              "not a controller file")
                controller = None
            else:
                digest = hashlib.sha256(controller.read_bytes()).hexdigest()
                problem = _not_a_controller(controller)
                if problem:
                    check.fail("loop.controller", f"{controller}: not a controller file ({problem})")
                    controller = None
    elif not is_linear(entry["law"]):
        law = _law(check, entry["law"], period)
        digest = hashlib.sha256(repr(law).encode()).hexdigest()

    def column(key: str):
        if key not in entry:
            return None
        name = check.string(entry[key], f"loop.{key}")
        if name is not None and name not in columns:
            check.fail(f"loop.{key}", f"{excerpt(name)} is not one of columns ({', '.join(columns)})")
        elif name is not None:
            return table[name][keep].copy()
        return None

    reference, feedforward, mode = column("reference"), column("feedforward"), column("mode")
    compute = None
    if "compute" in entry:
        compute = timing_column(check, entry, "compute", table, columns, keep, period, csv)
    rate = check.number(entry.get("rate_filter", RATE_FILTER), "loop.rate_filter", minimum=0.1, maximum=1e4)
    voltage = entry.get("voltage")
    if voltage is not None:
        voltage = check.number(voltage, "loop.voltage", positive=True, maximum=1e4)
    counts = check.number(entry.get("counts", 2048), "loop.counts", minimum=4, maximum=2 ** 31, integer=True)
    free_delay = None
    if isinstance(entry.get("delay"), dict):   # fitted inside the loop: {free: [lo, hi]}
        free_delay = read_free_delay(check, entry["delay"], "loop.delay", period)
        delay = free_delay.start if free_delay is not None else 0.0
    else:
        delay = check.number(entry.get("delay", 0.0), "loop.delay", minimum=0.0)
        if delay is not None and period and delay > MAX_DELAY_SAMPLES * period * (1 + UNIFORM_TOLERANCE):
            check.fail("loop.delay", f"{delay:g} s is more than {MAX_DELAY_SAMPLES} samples of the log "
                                     f"({period:g} s each)")
    check.done()
    linear = None
    if "law" in entry and is_linear(entry["law"]):
        outputs = top.get("outputs") if isinstance(top.get("outputs"), dict) else {}
        signal = (top.get("inputs") or {}).get("V") if isinstance(top.get("inputs"), dict) else None
        command = to_si(signal)[1:] if isinstance(signal, dict) else (1.0, 0.0)
        linear = read_law(check, entry["law"], period, table, columns, keep,
                          {n: to_si(e) for n, e in outputs.items() if isinstance(e, dict)}, command,
                          voltage, feedforward, csv.name, table[LINE], times=times)
        check.done()
        digest = hashlib.sha256(repr((linear.A, linear.B, linear.C, linear.D, linear.sources)).encode()).hexdigest()
    if law is None and controller is None and linear is None:
        return None
    return Loop(controller, digest, reference, float(rate), None if voltage is None else float(voltage),
                float(counts), float(delay), law, feedforward, compute=compute, linear=linear,
                free_delay=free_delay, mode=mode)


def _not_a_controller(path: Path) -> str | None:
    """Why the file a loop names is not a controller (its first problem, a plant file's keys
    among them), or None."""
    from furuta_cosim.controllers import load_controller

    try:
        load_controller(path)
    except ConfigError as error:
        first = str(error).splitlines()[0]
        return first.split(": ", 1)[1] if first.startswith(f"{path}: ") else first
    return None


def _law(check: Checker, value, period: float) -> tuple | None:
    """``loop.law``: K (4 gains on theta0, its rate, theta1, its rate; a 5th on the current), F
    (the reference's gain; K's first by default: the law acts on theta0 - reference) and the
    period it ran at, which must be the log's."""
    entry = check.mapping(value, "loop.law", required=("K",), optional=_LAW_KEYS)
    if not entry or "K" not in entry:
        return None
    K = check.vector(entry["K"], "loop.law.K")
    if K is not None and len(K) not in (4, 5):
        check.fail("loop.law.K", f"expected 4 gains (theta0, its rate, theta1, its rate) or 5 (and "
                                 f"the current), got {len(K)}")
        return None
    if K is not None and max(abs(k) for k in K) > MAX_MAGNITUDE:
        check.fail("loop.law.K", f"expected gains of magnitude at most {MAX_MAGNITUDE:g}")
        return None
    F = check.number(entry["F"], "loop.law.F") if "F" in entry else (K[0] if K else None)
    if F is not None and abs(F) > MAX_MAGNITUDE:
        check.fail("loop.law.F", f"expected a magnitude of at most {MAX_MAGNITUDE:g}, got {F:g}")
    if "period" in entry:
        ran = check.number(entry["period"], "loop.law.period", positive=True, maximum=10.0)
        if ran is not None and period and abs(ran - period) > UNIFORM_TOLERANCE * period:
            check.fail("loop.law.period", f"the law ran every {ran:g} s but the log's samples are "
                                          f"{period:g} s apart: the replay closes the loop at the log's samples")
    if K is None or F is None:
        return None
    return tuple(float(k) for k in K), float(F)
