"""Experiment files: a measured log (CSV) and what it says about the plant.

An experiment file names the CSV beside it, its columns, which columns are plant inputs
(applied zero-order hold from each sample to the next) and which are plant outputs (with
their units, offsets, encoder quantum and noise), the initial states and the plant
parameters that differ in this experiment. Reading it checks everything that can be checked
without an FMU; every problem names the file and the key, or the CSV and its row.

    experiment = load_experiment("scenarios/rigs/qube-servo-3/free-swing.yaml")
    experiment.t, experiment.outputs["theta1"].values
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping

import numpy as np

from furuta_cosim.config import Checker, Frozen, excerpt, load_yaml, plain_name
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.clocks import (LEAD_IN, MAX_DELAY_SAMPLES, UNIFORM_TOLERANCE, Delayed, LeadIn,  # noqa: F401
                                          held_means, read_clock, read_free_delay, read_lead_in, read_window,
                                          resample_log, shifted, timing_column)
from furuta_cosim.identify.columns import (LINE, Free, Measured, csv_path, finite_within, read_csv,
                                           read_outputs, read_signal, used_columns)
from furuta_cosim.identify.loops import Loop, read_loop


_KEYS = ("name", "description", "data", "header", "columns", "time", "window", "inputs",
         "outputs", "start", "parameters", "delimiter", "rig", "loop", "segments", "resample")


@dataclass(frozen=True)
class Experiment:
    """A checked experiment: ``t`` the window's sample times (s), ``period`` their spacing."""

    name: str
    description: str
    path: Path
    data: Path
    sha256: str
    t: np.ndarray
    period: float
    inputs: Mapping[str, np.ndarray | float]
    outputs: Mapping[str, Measured]
    start: Mapping[str, float | Free]
    parameters: Mapping[str, float] = field(default_factory=lambda: Frozen({}))
    units: Mapping[str, str] = field(default_factory=lambda: Frozen({}))  # input/output -> its unit key
    loop: Loop | None = None     # the controller in the loop: the replay closes it (inputs unused)
    segments: float = 0.0        # s: fitted by multiple shooting in segments this long (0: whole)
    alias: str = ""              # a part of a log (identify/split.py): the whole log's name
    # how a start given as `data` was read (state -> a line identify prints)
    start_from: Mapping[str, str] = field(default_factory=lambda: Frozen({}))
    from_data: frozenset = frozenset()   # the start states ``start: data`` read from the log
    # s after each row's time that its outputs were read (a rig's `late` column; None: on time)
    late: np.ndarray | None = None
    # inputs whose delay is fitted: kept as logged in ``inputs`` (identify/fit.py)
    delays: Mapping[str, Delayed] = field(default_factory=lambda: Frozen({}))
    # a closed-loop log whose clock jitters: ``t`` as logged, ``period`` its typical step; the
    # replay steps the loop over each logged interval (identify/replay.py, estimate.py)
    jittered: bool = False

    @property
    def read_at(self) -> np.ndarray:
        """When each sample was read: ``t``, plus ``late`` where the log records it."""
        return self.t if self.late is None else self.t + self.late

    @property
    def samples(self) -> int:
        return len(self.t)

    def lead_in_at(self, first: int) -> LeadIn | None:
        """The loop's rows before sample ``first`` of the window (Loop.lead_in): the log's before
        the window, then the window's own, the last ``LEAD_IN`` s."""
        loop = self.loop
        if loop is None or first == 0:
            return None if loop is None else loop.lead_in
        if "theta0" not in self.outputs or "theta1" not in self.outputs:
            return None
        rows = slice(max(0, first - int(round(LEAD_IN / self.period))), first)
        count = rows.stop - rows.start
        angles = np.column_stack([self.outputs[n].values[rows] for n in ("theta0", "theta1")])
        current = self.outputs["i"].values[rows] if "i" in self.outputs else np.zeros(count)
        reference = loop.reference[rows] if loop.reference is not None else np.zeros(count)
        v = self.inputs.get("V")
        command = None if v is None or np.isscalar(v) else np.asarray(v[rows], dtype=float)
        lead = LeadIn(angles, current, reference, command)
        if loop.lead_in is not None and rows.start == 0:
            lead = loop.lead_in.then(angles, current, reference, command).last(int(round(LEAD_IN / self.period)))
        return lead

    def free_starts(self) -> dict[str, Free]:
        """What the fit chooses besides plant parameters: free initial states (by state
        name) and sensor biases (``<output>.bias``)."""
        found = {name: value for name, value in self.start.items() if isinstance(value, Free)}
        found.update({f"{name}.bias": m.bias for name, m in self.outputs.items() if m.bias is not None})
        found.update({d.key or f"{name}.delay": d.free for name, d in self.delays.items()})
        if self.loop is not None and self.loop.free_delay is not None:
            found["loop.delay"] = self.loop.free_delay
        return found

    def loop_delay(self, values: Mapping[str, float] | None = None) -> float:
        """The loop's delay (s) from a sample to its command at the motor: its value in
        ``values`` where the fit chooses it (``loop.delay: {free: ...}``), else as stated."""
        if self.loop is None:
            return 0.0
        if self.loop.free_delay is None:
            return self.loop.delay
        return float((values or {}).get(f"{self.alias or self.name}.loop.delay", self.loop.delay))

    def corrected(self, simulated: Mapping[str, np.ndarray], values: Mapping[str, float]) -> dict:
        """The simulated outputs as the sensors would read them: plus each fitted bias."""
        return {name: y + values.get(f"{self.alias or self.name}.{name}.bias", 0.0) for name, y in simulated.items()}

    def input_at(self, name: str, values: Mapping[str, float] | None = None) -> np.ndarray:
        """The input over every sample of the window (a constant repeated); an input whose
        delay is fitted, delayed by its value in ``values`` (its start without)."""
        value = self.inputs[name]
        if np.isscalar(value):
            return np.full(self.samples, float(value))
        delayed = self.delays.get(name)
        if delayed is None:
            return value
        seconds = (values or {}).get(f"{self.alias or self.name}.{delayed.key or name + '.delay'}",
                                     delayed.free.start)
        if delayed.timed is not None:
            writes, commands, read, first = delayed.timed
            return held_means(np.maximum.accumulate(writes + seconds), commands, read)[first:first + self.samples]
        m = len(delayed.before)
        return shifted(np.concatenate([delayed.before, value]), seconds / self.period)[m:]

    def truncated(self, seconds: float) -> "Experiment":
        """The first ``seconds`` of the window (at least two samples): the growing-horizon fit
        starts on these."""
        keep = max(2, int(np.searchsorted(self.t, self.t[0] + seconds, side="right")))
        if keep >= self.samples:
            return self
        inputs = {k: v if np.isscalar(v) else v[:keep] for k, v in self.inputs.items()}
        outputs = {k: replace(m, values=m.values[:keep]) for k, m in self.outputs.items()}
        loop = None if self.loop is None else self.loop.cut(slice(None, keep))
        return replace(self, t=self.t[:keep], inputs=Frozen(inputs), outputs=Frozen(outputs), loop=loop,
                       late=None if self.late is None else self.late[:keep])


def load_experiment(path: str | Path) -> Experiment:
    """Read and check an experiment file and its CSV; raises ConfigError naming the file and
    the key (or the CSV and its row) of every problem."""
    path = Path(path)
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", required=("data", "columns", "time", "outputs"), optional=_KEYS)
    check.done()
    name = check.file_name(top.get("name", path.stem), "name") if "name" in top else path.stem
    if not plain_name(name or ""):
        check.fail("name", f"the file's name {excerpt(path.stem)} is not a plain name: give a name: key")
    description = check.text(top.get("description", ""), "description")
    columns = check.names(top["columns"], "columns")
    header = check.number(top.get("header", 1), "header", minimum=0, integer=True)
    delimiter = top.get("delimiter", ",")
    if not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in "\r\n\"'0123456789.-+eE":
        check.fail("delimiter", f"expected one character that cannot be part of a number, got {excerpt(str(delimiter))}")
    time_column = check.string(top["time"], "time")
    if columns and time_column and time_column not in columns:
        check.fail("time", f"{excerpt(time_column)} is not one of columns ({', '.join(columns)})")
    csv = csv_path(check, top["data"], path)
    check.done()
    try:
        table = read_csv(csv, columns, header, delimiter)
    except ConfigError as error:  # the log and the experiment's columns disagree: name both
        raise error.within(f"{path}: data") from None
    t = table[time_column]
    first, last = read_window(check, top.get("window"), t, csv, table[LINE])
    check.done()
    if "resample" in top and "loop" in top:
        check.fail("resample", "the log has a loop: a closed loop is replayed at the instants it ran (its "
                               "controller re-run on interpolated angles is not the loop that ran); leave "
                               "resample out, it is for open-loop logs")
        check.done()
    if "resample" in top:
        table, first, last = resample_log(check, top, table, time_column, first, last, csv)
        t = table[time_column]
        check.done()
    keep = slice(first, last)
    filled = isinstance(top.get("resample"), dict) and top["resample"].get("fill") is True
    finite_within(check, table, used_columns(top, time_column), keep, csv, "window" in top,
                   resampled="resample" in top, filled=filled, time_column=time_column)
    check.done()
    t = t[keep]
    if len(t) < 2:
        check.fail("window", f"holds {len(t)} sample(s) of {csv.name}: at least 2 are needed")
        check.done()
    period, jittered = read_clock(check, t, csv, table[LINE][keep], closed="loop" in top)
    check.done()
    delays: dict = {}
    if "loop" in top and isinstance(top.get("inputs"), dict):
        for key, entry in top["inputs"].items():
            if isinstance(entry, dict) and "delay" in entry:   # the replay closes the loop: never read
                check.fail(f"inputs.{key}.delay", "the log has a loop, whose replay computes the command: "
                                                   "its delay from a sample to the motor is loop.delay (s, or "
                                                   "{free: [lo, hi]} to fit it)")
        check.done()
    inputs = _inputs(check, top.get("inputs", {}), table, columns, keep, period, delays)
    outputs = read_outputs(check, top["outputs"], table, columns, keep)
    # a stated start is checked against the data where the window cuts the log after its first
    # row: a log's own first row is where its logger knew the state (a rig run starts at rest)
    start, start_from = _start(check, top.get("start", {}), outputs, t, cut=first > 0)
    parameters = check.numbers(top.get("parameters", {}), "parameters")
    times = np.asarray(table[time_column], dtype=float) if jittered else None
    loop = read_loop(check, top, path, table, columns, keep, period, csv, times) if "loop" in top else None
    segments = 0.0
    if "segments" in top:
        segments = check.number(top["segments"], "segments", positive=True, maximum=1e6)
        if segments is not None and segments < 3 * period:
            check.fail("segments", f"{segments:g} s is shorter than 3 samples ({period:g} s each)")
    if "rig" in top:  # what `rig run` records of the run (its board, controller, period, plant)
        rig = check.mapping(top["rig"], "rig", optional=tuple(top["rig"]) if isinstance(top["rig"], dict) else ())
        if rig and "plant" in rig:   # replay runs it there (identify/replay.py recorded_plant)
            check.string(rig["plant"], "rig.plant")
    for state in start:
        if f"{state}_start" in parameters:  # one of the two would be dropped without a word
            check.fail(f"parameters.{state}_start", f"sets the start of {state}, which start.{state} "
                                                    "sets too: give it in one place")
    check.done()
    if loop is not None and first > 0:   # the rows before the window, from the same columns
        loop = replace(loop, lead_in=read_lead_in(check, top, table, columns, first, period, jittered))
    units = {}
    for key in ("inputs", "outputs"):
        section = top.get(key) if isinstance(top.get(key), dict) else {}
        units.update({str(n): e["unit"] for n, e in section.items() if isinstance(e, dict) and "unit" in e})
    late = None
    if loop is not None and isinstance(top.get("loop"), dict) and "late" in top["loop"]:
        late = timing_column(check, top["loop"], "late", table, columns, keep, period, csv, t)
        check.done()
    digest = hashlib.sha256(csv.read_bytes()).hexdigest()
    return Experiment(name, description, path, csv, digest, t, period, Frozen(inputs),
                      Frozen(outputs), Frozen(start), parameters, Frozen(units), loop, float(segments or 0.0),
                      start_from=Frozen(start_from), late=late, delays=Frozen(delays), jittered=jittered,
                      from_data=frozenset(n for n, v in (top.get("start") or {}).items() if v == "data"))


def _inputs(check: Checker, value, table, columns, keep, period: float = 0.0,
            delays: dict | None = None) -> dict:
    """``inputs:`` over the window; an input whose delay is fitted (``delay: {free: [lo,
    hi]}``) is kept as logged, its samples before the window and its bounds put in
    ``delays``."""
    section = check.mapping(value, "inputs", optional=tuple(value) if isinstance(value, dict) else ())
    delays = {} if delays is None else delays
    found = {}
    for name, entry in (section or {}).items():
        key = f"inputs.{name}"
        if isinstance(entry, (int, float)) and not isinstance(entry, bool):
            number = check.number(entry, key)
            if number is not None:
                found[str(name)] = number
            continue
        signal = read_signal(check, entry, key, table, columns, slice(None), extra=("delay",))
        if signal is None:
            continue
        values, _, raw = signal
        if "delay" in raw and isinstance(raw["delay"], dict):   # fitted: {free: [lo, hi]}
            free = read_free_delay(check, raw["delay"], f"{key}.delay", period)
            if free is not None and period:
                m = int(math.ceil(free.bounds[1] / period)) + 1
                first = keep.start or 0
                before = np.concatenate([np.zeros(max(m - first, 0)), values[max(first - m, 0):first]])
                delays[str(name)] = Delayed(free, np.nan_to_num(before, nan=0.0, posinf=0.0, neginf=0.0))
        elif "delay" in raw:  # the logged value reaches the plant this much later
            delay = check.number(raw["delay"], f"{key}.delay", minimum=0.0)
            if delay is not None and period and delay > MAX_DELAY_SAMPLES * period * (1 + UNIFORM_TOLERANCE):
                check.fail(f"{key}.delay", f"{delay:g} s is more than {MAX_DELAY_SAMPLES} samples of the log "
                                           f"({period:g} s each)")
            elif delay and period:
                values = shifted(values, delay / period)
        found[str(name)] = values[keep]
    return found


# a rate's start read from its angle: a quadratic through the angle's first RATE_SPAN seconds
# (at least RATE_SAMPLES samples); a stated start further than CONTRADICTS standard errors from
# what the data say (and than one quantum) is refused
RATE_SPAN, RATE_SAMPLES, CONTRADICTS = 0.02, 5, 5.0


_RATES = {"dtheta0": "theta0", "dtheta1": "theta1"}


_STATE_UNITS = {"theta0": "rad", "theta1": "rad", "dtheta0": "rad/s", "dtheta1": "rad/s", "i": "A"}


def start_rate(measured: Measured, t: np.ndarray) -> tuple[float, float, int]:
    """(rate, its standard error, samples used) of a measured angle at the window's start: the
    slope at the first sample of a least-squares quadratic through its first RATE_SPAN s."""
    m = min(len(t), max(RATE_SAMPLES, int(np.searchsorted(t, t[0] + RATE_SPAN, side="right"))))
    if m < 3:
        return 0.0, math.inf, m
    s = t[:m] - t[0]
    X = np.column_stack([np.ones(m), s, s * s])
    coefficients, *_ = np.linalg.lstsq(X, measured.values[:m], rcond=None)
    spread = np.linalg.pinv(X.T @ X)
    return float(coefficients[1]), float(measured.sigma * math.sqrt(max(spread[1, 1], 0.0))), m


def _start(check: Checker, value, outputs: Mapping[str, Measured], t: np.ndarray,
           cut: bool = True) -> tuple[dict, dict]:
    """The start states: a number, ``data`` (a measured output's first sample; a rate, its
    angle's slope at the window's start) or ``{free: [lo, hi]}``; and how each ``data`` was
    read. A number that the data contradict (beyond the noise) is refused: a window cut from a
    log mid-motion keeps the log's own start (rates 0, current 0) otherwise, and the fit bends
    the plant to it (checked where ``cut``: the window starts after the log's first row)."""
    section = check.mapping(value, "start", optional=tuple(value) if isinstance(value, dict) else ())
    found, start_from = {}, {}
    for name, entry in (section or {}).items():
        key = f"start.{name}"
        if entry == "data" and name in _RATES and name not in outputs:
            angle = _RATES[name]
            if angle not in outputs:
                check.fail(key, f"'data' takes {name} from the measured {angle} at the window's start, "
                                f"but outputs names no {angle} (outputs: {', '.join(outputs) or 'none'})")
                continue
            rate, error, m = start_rate(outputs[angle], t)
            found[str(name)] = rate
            start_from[str(name)] = (f"{rate:.4g} rad/s (+-{error:.2g}), the slope of {angle} over its first "
                                     f"{m} samples")
        elif entry == "data":
            if name not in outputs:
                check.fail(key, f"'data' takes the measured {name} at the window's start, but "
                                f"outputs names no {name} (outputs: {', '.join(outputs) or 'none'})")
            else:
                found[str(name)] = float(outputs[name].values[0])
        elif isinstance(entry, dict):
            free = check.mapping(entry, key, required=("free",))
            bounds = check.vector(free.get("free"), f"{key}.free", 2) if free and "free" in free else None
            if bounds is None:
                continue
            lo, hi = bounds
            if not lo < hi:
                check.fail(f"{key}.free", f"expected [lo, hi] with lo < hi, got [{lo:g}, {hi:g}]")
                continue
            if max(abs(lo), abs(hi)) > MAX_MAGNITUDE:
                check.fail(f"{key}.free", f"expected magnitudes of at most {MAX_MAGNITUDE:g}")
                continue
            guess = float(outputs[name].values[0]) if name in outputs else 0.5 * (lo + hi)
            found[str(name)] = Free((lo, hi), min(max(guess, lo), hi))
        else:
            if isinstance(entry, str):
                check.fail(key, f"expected a number, 'data' or {{free: [lo, hi]}}, got {excerpt(entry)}")
                continue
            number = check.number(entry, key)
            if number is not None:
                found[str(name)] = number
                if cut:
                    _contradicted(check, key, str(name), number, outputs, t)
    return found, start_from


def _contradicted(check: Checker, key: str, name: str, stated: float, outputs: Mapping[str, Measured],
                  t: np.ndarray) -> None:
    """A stated start the data say otherwise of, by more than CONTRADICTS standard errors of
    what they say and more than a quantum (or noise standard deviation): one line."""
    unit = _STATE_UNITS.get(name, "")
    if name in outputs:
        m = outputs[name]
        said, error, how = float(m.values[0]), m.sigma, f"the measured {name} at the window's start"
        slack = max(m.quantum, m.sigma)
    elif name in _RATES and _RATES[name] in outputs:
        m = outputs[_RATES[name]]
        said, error, used = start_rate(m, t)
        how = f"the slope of the measured {_RATES[name]} over the window's first {used} samples"
        slack = max(m.quantum, m.sigma) / max(float(t[min(used, len(t)) - 1] - t[0]), 1e-300)
    else:
        return
    if math.isfinite(error) and abs(stated - said) > CONTRADICTS * error + slack:
        check.fail(key, f"{stated:g} {unit}, but {how} is {said:.4g} {unit} (+-{error:.2g}; t = {t[0]:g} s): "
                        f"a window cut mid-motion keeps the log's own start otherwise; give {name}: data "
                        "(read from the log), {free: [lo, hi]}, or the value at the window's start".replace("  ", " "))
