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
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping

import numpy as np

from furuta_cosim.config import Checker, Frozen, excerpt, load_yaml, plain_name
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.variables import MAX_FACTOR, MAX_OFFSET, MIN_FACTOR
from furuta_cosim.identify.laws import LinearLaw, is_linear, read_law
from furuta_cosim.measurement import RATE_FILTER

# unit -> factor to SI (rad, rad/s, A, V, s): value_SI = (value + offset) * factor
UNITS = {"rad": 1.0, "deg": math.pi / 180.0, "rev": 2.0 * math.pi, "rad/s": 1.0,
         "deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0, "A": 1.0, "mA": 1e-3, "V": 1.0,
         "s": 1.0, "ms": 1e-3}
MAX_CSV_BYTES = 200_000_000
MAX_QUANTUM = 2 * math.pi / 16      # rad: an angle's quantum at most (16 counts a turn)
MAX_CONTROLLER_BYTES = 10_000_000   # a loop's controller file (YAML of gains and matrices)
# two successive sample times may differ from the mean period by this fraction (loggers print
# rounded times); beyond it the log is refused: nothing here resamples
UNIFORM_TOLERANCE = 0.01
LINE = "\0line"  # read_csv's entry for the line number of each row in the file
_KEYS = ("name", "description", "data", "header", "columns", "time", "window", "inputs",
         "outputs", "start", "parameters", "delimiter", "rig", "loop", "segments", "resample")
_LOOP_KEYS = ("controller", "law", "reference", "feedforward", "rate_filter", "voltage", "counts", "delay",
              "late", "compute", "mode")
_LAW_KEYS = ("K", "F", "period")
MAX_DELAY_SAMPLES = 10   # a loop's delay, in samples of its log, at most
# samples a resampled log may have: about the rows of the largest log read (MAX_CSV_BYTES of
# short rows); a finer grid is a period typed wrong, not a finer log
MAX_RESAMPLED = 5_000_000
# a closed-loop log whose clock jitters is replayed at its instants; a step longer than this many
# of its typical steps is a gap in the log (the controller's commands there are not logged)
MAX_JITTER_STEPS = 10
MAX_STALE_SAMPLES = 100  # a reading older than its sample's time (loop.late < 0) by at most this
# s of the log before a window that a closed-loop replay runs its controller over (its rate
# filter forgets in milliseconds, a dynamic controller's state in well under this)
LEAD_IN = 2.0
_SIGNAL_KEYS = ("column", "unit", "scale", "offset")


@dataclass(frozen=True)
class Measured:
    """One measured output in SI units, with the standard deviation that weights its residuals
    (``sigma``: from ``noise`` and ``quantum``, else estimated from the data; ``sigma_from``
    says which)."""

    column: str
    values: np.ndarray
    sigma: float
    sigma_from: str
    bias: "Free | None" = None   # an unknown zero error of the sensor (SI), fitted
    quantum: float = 0.0         # the sensor's resolution (SI), 0 when not stated


@dataclass(frozen=True)
class Free:
    """An initial state the fit chooses within ``bounds`` (``start``: its first guess)."""

    bounds: tuple[float, float]
    start: float


@dataclass(frozen=True)
class Delayed:
    """An input whose delay (s) the fit chooses within ``free.bounds``; ``before``: the
    logged samples before the window (0 where the log has none), which a delay brings in.
    ``key``: the fitted value's name within the experiment (``<input>.delay``; ``loop.delay``
    for a closed loop's delay, replayed open loop on its logged command: identify/split.py);
    ``timed``: for such a log that records when each sample was read and its command written,
    (each command's write time, the commands, each sample's read time, over the whole window;
    the index of this experiment's first sample in them): a command reaches the motor at its
    write plus the delay, averaged over each sample."""

    free: Free
    before: np.ndarray
    key: str = ""
    timed: tuple | None = None


@dataclass(frozen=True)
class LeadIn:
    """The log's rows just before a window that cuts it mid-run, in SI: what the controller
    saw there (the angles as counted, the current, 0 where the log has none, the reference)
    and the command written (None where the log has no voltage column). The closed-loop
    replay runs the controller over them, so its rate filter and state are at the cut where
    they were on the rig, and takes from them the commands still on their way to the motor."""

    angles: np.ndarray           # (rows, 2): theta0, theta1
    current: np.ndarray
    reference: np.ndarray
    command: np.ndarray | None

    def then(self, angles, current, reference, command) -> "LeadIn":
        """These rows followed by more (a part of the window cut after its start), the last
        ``LEAD_IN`` s' worth kept by the caller."""
        joined = None
        if self.command is not None and command is not None:
            joined = np.concatenate([self.command, command])
        return LeadIn(np.vstack([self.angles, angles]), np.concatenate([self.current, current]),
                      np.concatenate([self.reference, reference]), joined)

    def last(self, rows: int) -> "LeadIn":
        """The last ``rows`` rows."""
        return LeadIn(self.angles[-rows:], self.current[-rows:], self.reference[-rows:],
                      None if self.command is None else self.command[-rows:])


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
            from furuta_cosim.identify.split import held_means

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
    csv = _csv_path(check, top["data"], path)
    check.done()
    try:
        table = read_csv(csv, columns, header, delimiter)
    except ConfigError as error:  # the log and the experiment's columns disagree: name both
        raise error.within(f"{path}: data") from None
    t = table[time_column]
    first, last = _window(check, top.get("window"), t, csv, table[LINE])
    check.done()
    if "resample" in top and "loop" in top:
        check.fail("resample", "the log has a loop: a closed loop is replayed at the instants it ran (its "
                               "controller re-run on interpolated angles is not the loop that ran); leave "
                               "resample out, it is for open-loop logs")
        check.done()
    if "resample" in top:
        table, first, last = _resampled(check, top, table, time_column, first, last, csv)
        t = table[time_column]
        check.done()
    keep = slice(first, last)
    filled = isinstance(top.get("resample"), dict) and top["resample"].get("fill") is True
    _finite_within(check, table, _used_columns(top, time_column), keep, csv, "window" in top,
                   resampled="resample" in top, filled=filled, time_column=time_column)
    check.done()
    t = t[keep]
    if len(t) < 2:
        check.fail("window", f"holds {len(t)} sample(s) of {csv.name}: at least 2 are needed")
        check.done()
    period, jittered = _clock(check, t, csv, table[LINE][keep], closed="loop" in top)
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
    outputs = _outputs(check, top["outputs"], table, columns, keep)
    # a stated start is checked against the data where the window cuts the log after its first
    # row: a log's own first row is where its logger knew the state (a rig run starts at rest)
    start, start_from = _start(check, top.get("start", {}), outputs, t, cut=first > 0)
    parameters = check.numbers(top.get("parameters", {}), "parameters")
    times = np.asarray(table[time_column], dtype=float) if jittered else None
    loop = _loop(check, top, path, table, columns, keep, period, csv, times) if "loop" in top else None
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
        loop = replace(loop, lead_in=_lead_in(check, top, table, columns, first, period, jittered))
    units = {}
    for key in ("inputs", "outputs"):
        section = top.get(key) if isinstance(top.get(key), dict) else {}
        units.update({str(n): e["unit"] for n, e in section.items() if isinstance(e, dict) and "unit" in e})
    late = None
    if loop is not None and isinstance(top.get("loop"), dict) and "late" in top["loop"]:
        late = _timing_column(check, top["loop"], "late", table, columns, keep, period, csv, t)
        check.done()
    digest = hashlib.sha256(csv.read_bytes()).hexdigest()
    return Experiment(name, description, path, csv, digest, t, period, Frozen(inputs),
                      Frozen(outputs), Frozen(start), parameters, Frozen(units), loop, float(segments or 0.0),
                      start_from=Frozen(start_from), late=late, delays=Frozen(delays), jittered=jittered,
                      from_data=frozenset(n for n, v in (top.get("start") or {}).items() if v == "data"))


def _lead_in(check: Checker, top: dict, table, columns, first: int, period: float,
             jittered: bool = False) -> LeadIn | None:
    """The ``LEAD_IN`` s of rows before the window (none before a row whose numbers are missing
    or a step that is not the period: on a clock that jitters, one that does not increase or
    is a gap), read as the window's own are; None without both angles.
    The entries were checked on the window, so reading them again cannot fail."""
    outputs = top["outputs"]
    if not all(isinstance(outputs.get(n), dict) for n in ("theta0", "theta1")):
        return None
    begin = max(0, first - int(round(LEAD_IN / period)))
    part = slice(begin, first)
    rows = first - begin

    def signal(entry, key, extra):
        return _signal(check, entry, key, table, columns, part, extra=extra)[0]

    extra = ("quantum", "noise", "bias")
    angles = np.column_stack([signal(outputs[n], f"outputs.{n}", extra) for n in ("theta0", "theta1")])
    current = signal(outputs["i"], "outputs.i", extra) if isinstance(outputs.get("i"), dict) else np.zeros(rows)
    entry = top["loop"]
    reference = np.asarray(table[entry["reference"]][part], dtype=float) if "reference" in entry else np.zeros(rows)
    v = (top.get("inputs") or {}).get("V")
    command = signal(v, "inputs.V", ("delay",)) if isinstance(v, dict) else None
    t = np.asarray(table[top["time"]][begin:first + 1], dtype=float)
    usable = np.all(np.isfinite(angles), axis=1) & np.isfinite(current) & np.isfinite(reference)
    if command is not None:
        usable &= np.isfinite(command)
    steps = np.diff(t)   # the step to the next row
    usable &= (((steps > 0) & (steps <= MAX_JITTER_STEPS * period)) if jittered
               else np.abs(steps - period) <= UNIFORM_TOLERANCE * period)
    start = int(len(usable) - np.argmin(usable[::-1])) if not usable.all() else 0
    if start >= rows:
        return None
    return LeadIn(angles[start:], current[start:], reference[start:],
                  None if command is None else command[start:])


def _resampled(check: Checker, top: dict, table: dict, time_column: str, first: int, last: int,
               csv: Path) -> tuple[dict, int, int]:
    """``resample:`` a log whose clock jitters (a ROS log: 2 ms nominal, 1.5 to 4.8 ms apart) put
    on a uniform grid of ``period`` s over its window: outputs interpolated linearly, inputs
    and the loop's reference and feedforward held from their last sample (as a command is), an
    interval between two samples longer than ``gap`` (10 periods by default) refused with its
    time; with ``fill: true`` a column's empty cells (interleaved topics: each row holds one
    topic's fields) take the last value before them first. Returns (the new table, 0, its
    length)."""
    entry = top["resample"]
    if isinstance(entry, (int, float)) and not isinstance(entry, bool):
        entry = {"period": entry}
    section = check.mapping(entry, "resample", required=("period",), optional=("period", "gap", "fill"))
    if not section or "period" not in section:
        return table, first, last
    period = check.number(section["period"], "resample.period", positive=True, maximum=10.0)
    gap = check.number(section.get("gap", 10 * (period or 1.0)), "resample.gap", positive=True, maximum=1e6)
    fill = section.get("fill", False)
    if not isinstance(fill, bool):
        check.fail("resample.fill", f"expected true or false, got {excerpt(str(fill))}")
    if period is None or gap is None or not isinstance(fill, bool):
        return table, first, last
    columns = [k for k in table if k != LINE]
    if fill:
        for name in columns:
            values = np.asarray(table[name], dtype=float).copy()
            known = np.isfinite(values)
            index = np.where(known, np.arange(len(values)), 0)
            np.maximum.accumulate(index, out=index)
            filled = values[index]
            filled[~np.maximum.accumulate(known)] = np.nan   # nothing before: stays empty
            table = {**table, name: filled}
    t = np.asarray(table[time_column][first:last], dtype=float)
    samples = (t[-1] - t[0]) / period if len(t) else 0.0
    if samples > MAX_RESAMPLED:
        check.fail("resample.period", f"{period:g} s over the window's {t[-1] - t[0]:g} s is {samples:.3g} samples "
                                      f"(at most {MAX_RESAMPLED:,}): give the period the log is meant to be on "
                                      f"(its median step is {float(np.median(np.diff(t))):g} s)")
        return table, first, last
    steps = np.diff(t)
    if np.any(steps > gap):
        k = int(np.argmax(steps > gap))
        key, said = (("resample.gap", f"the {gap:g} s a gap may last") if "gap" in section else
                     ("resample", f"the {gap:g} s a gap may last (10 periods, unless resample names "
                                  "its own gap: SECONDS)"))
        check.fail(key, f"{csv.name}: line {table[LINE][first + k + 1]}: {steps[k]:g} s without a "
                        f"sample (from t = {t[k]:g} s), more than {said}")
        return table, first, last
    grid = t[0] + period * np.arange(int(math.floor((t[-1] - t[0]) / period + 1e-9)) + 1)
    held = set()
    for key in ("inputs",):
        section_of = top.get(key) if isinstance(top.get(key), dict) else {}
        held |= {e["column"] for e in section_of.values() if isinstance(e, dict) and isinstance(e.get("column"), str)}
    loop = top.get("loop") if isinstance(top.get("loop"), dict) else {}
    held |= {loop[k] for k in ("reference", "feedforward") if isinstance(loop.get(k), str)}
    before = np.clip(np.searchsorted(t, grid + 1e-12 * period, side="right") - 1, 0, len(t) - 1)
    found = {LINE: np.asarray(table[LINE][first:last])[before]}
    for name in columns:
        values = np.asarray(table[name][first:last], dtype=float)
        if name == time_column:
            found[name] = grid
        elif name in held:
            found[name] = values[before]
        else:
            found[name] = np.interp(grid, t, values)
    return found, 0, len(grid)


def _used_columns(top: dict, time_column: str) -> list[str]:
    """The columns an experiment file reads: its time, each input's and output's, and its
    loop's reference, feedforward and timing."""
    used = [time_column]
    for key in ("inputs", "outputs"):
        section = top.get(key) if isinstance(top.get(key), dict) else {}
        used += [e["column"] for e in section.values() if isinstance(e, dict) and isinstance(e.get("column"), str)]
    loop = top.get("loop") if isinstance(top.get("loop"), dict) else {}
    used += [loop[k] for k in ("reference", "feedforward", "late", "compute", "mode") if isinstance(loop.get(k), str)]
    return list(dict.fromkeys(used))


def _finite_within(check: Checker, table, used: list[str], keep: slice, csv: Path, windowed: bool,
                   resampled: bool = False, filled: bool = False, time_column: str = "") -> None:
    """A column the experiment reads holds a number at every row of its window (a not-finite
    cell elsewhere, a logger's footer, is never read). ``filled``: the log was resampled with
    ``fill: true``, so an empty cell left is one before its topic's first message: the line
    names the first row where every column read has a value."""
    lines = table[LINE][keep]
    for name in used:
        if name not in table:
            continue
        bad = np.nonzero(~np.isfinite(table[name][keep]))[0]
        if len(bad):
            k = int(bad[0])
            if filled:
                known = np.all([np.isfinite(table[n]) for n in used if n in table], axis=0)
                first = int(np.argmax(known)) if np.any(known) else None
                where = ("no row has a value in every column it reads" if first is None else
                         f"the first row where every column it reads has one is line {table[LINE][first]} "
                         f"(t = {float(table[time_column][first]):g} s): start the window there")
                check.fail("window" if windowed else "data",
                           f"{csv.name}: line {lines[k]}, column {name}: no value yet (its topic's first message "
                           f"comes later; fill: true carries a value forward, never back); {where}")
                return
            check.fail("window" if windowed else "data",
                       f"{csv.name}: line {lines[k]}, column {name}: not a finite number"
                       + (" inside the window" if windowed else "")
                       + ("; an empty cell of a topic logged on other rows: resample with fill: true"
                          if resampled else "; give a window that leaves it out (window: [start, end], s)"))
            return


def _timing_column(check: Checker, entry: dict, key: str, table, columns, keep, period: float, csv: Path,
                   t: np.ndarray | None = None) -> np.ndarray | None:
    """``loop.late`` or ``loop.compute``: a column of seconds per sample, each from 0 to
    MAX_DELAY_SAMPLES periods; the samples' read times (``t`` + late) must increase."""
    name = check.string(entry[key], f"loop.{key}")
    if name is None:
        return None
    if name not in columns:
        check.fail(f"loop.{key}", f"{excerpt(name)} is not one of columns ({', '.join(columns)})")
        return None
    values = np.asarray(table[name][keep], dtype=float)
    lines = table[LINE][keep]
    values = np.where((values < 0) & (values > -1e-9), 0.0, values)  # a clock's rounding below 0
    # a reading sampled before its sample's time (a board that samples on its own clock) is late
    # by less than 0; the time from a reading to its write is never
    # (a board busy elsewhere samples late on its own clock: the reading is older, its write
    # further from it, by up to MAX_STALE_SAMPLES)
    lowest = -MAX_STALE_SAMPLES * period if key == "late" else 0.0
    highest = (MAX_DELAY_SAMPLES if key == "late" else MAX_STALE_SAMPLES) * period
    bad = np.nonzero(~np.isfinite(values) | (values < lowest) | (values > highest))[0]
    if len(bad):
        k = int(bad[0])
        check.fail(f"loop.{key}", f"{csv.name}: line {lines[k]}: {float(values[k])!r} s: expected seconds from "
                                  f"{lowest:g} to {highest:g} ({round(highest / period)} samples)")
        return None
    if not np.any(np.abs(values) > 1e-9):
        return None   # on time to the nanosecond (a simulated clock): the nominal times are exact
    if t is not None:
        # two readings at one instant are possible (a late sample's successor read at once, on a
        # clock that counts no computing time); one before the one before it is not
        backwards = np.nonzero(np.diff(t + values) < -1e-9 * period)[0]
        if len(backwards):
            k = int(backwards[0]) + 1
            check.fail("loop.late", f"{csv.name}: line {lines[k]}: read before the sample before it "
                                    "(time + late does not increase)")
            return None
    return values


def _loop(check: Checker, top: dict, path: Path, table, columns, keep, period: float, csv: Path,
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
        compute = _timing_column(check, entry, "compute", table, columns, keep, period, csv)
    rate = check.number(entry.get("rate_filter", RATE_FILTER), "loop.rate_filter", minimum=0.1, maximum=1e4)
    voltage = entry.get("voltage")
    if voltage is not None:
        voltage = check.number(voltage, "loop.voltage", positive=True, maximum=1e4)
    counts = check.number(entry.get("counts", 2048), "loop.counts", minimum=4, maximum=2 ** 31, integer=True)
    free_delay = None
    if isinstance(entry.get("delay"), dict):   # fitted inside the loop: {free: [lo, hi]}
        free_delay = _free_delay(check, entry["delay"], "loop.delay", period)
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
        command = _conversion(signal)[1:] if isinstance(signal, dict) else (1.0, 0.0)
        linear = read_law(check, entry["law"], period, table, columns, keep,
                          {n: _conversion(e) for n, e in outputs.items() if isinstance(e, dict)}, command,
                          voltage, feedforward, csv.name, table[LINE], times=times)
        check.done()
        digest = hashlib.sha256(repr((linear.A, linear.B, linear.C, linear.D, linear.sources)).encode()).hexdigest()
    if law is None and controller is None and linear is None:
        return None
    return Loop(controller, digest, reference, float(rate), None if voltage is None else float(voltage),
                float(counts), float(delay), law, feedforward, compute=compute, linear=linear,
                free_delay=free_delay, mode=mode)


def _free_delay(check: Checker, value, key: str, period: float) -> Free | None:
    """A fitted delay, ``{free: [lo, hi]}`` (s), checked: 0 <= lo < hi, at most
    MAX_DELAY_SAMPLES samples of the log; its start the low bound."""
    entry = check.mapping(value, key, required=("free",))
    bounds = check.vector(entry.get("free"), f"{key}.free", 2) if entry and "free" in entry else None
    if bounds is None:
        return None
    if not 0.0 <= bounds[0] < bounds[1]:
        check.fail(f"{key}.free", f"expected [lo, hi] with 0 <= lo < hi (s), got {bounds}")
    elif period and bounds[1] > MAX_DELAY_SAMPLES * period * (1 + UNIFORM_TOLERANCE):
        check.fail(f"{key}.free", f"{bounds[1]:g} s is more than {MAX_DELAY_SAMPLES} samples of "
                                  f"the log ({period:g} s each)")
    else:
        return Free((float(bounds[0]), float(bounds[1])), float(bounds[0]))
    return None


def _conversion(spec: dict) -> tuple[str, float, float]:
    """(column, factor, offset) of a signal already checked: SI = (column + offset) * factor."""
    factor = UNITS[spec["unit"]] if "unit" in spec else float(spec["scale"])
    return str(spec["column"]), float(factor), float(spec.get("offset", 0.0))


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


def _csv_path(check: Checker, value, path: Path) -> Path | None:
    text = check.string(value, "data")
    if text is None:
        return None
    csv = Path(text)
    csv = csv if csv.is_absolute() else path.parent / csv
    if not csv.is_file():
        check.fail("data", f"{csv}: no such file")
        return None
    return csv


# a cell is an ASCII decimal number: digits, a sign, a point, an exponent (no '_', no other
# script's digits, no nan or inf), and spaces around it
_CELL = re.compile(rb"[ \t]*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?[ \t]*")
_NOT_FINITE = {"nan", "inf", "infinity"}


def read_csv(path: Path, columns: list[str], header: int, delimiter: str = ",") -> dict[str, np.ndarray]:
    """The CSV's numbers by column; one problem (the first bad row) raises ConfigError.

    Every cell must be an ASCII decimal number, or ``nan``/``inf`` or empty (read as NaN: a
    logger's footer, a topic logged on other rows; :func:`load_experiment` refuses one inside
    the window it uses). A file of up to ``MAX_CSV_BYTES`` is read
    whole and parsed by numpy: about 3.5 times the file's size in memory at most (the bytes,
    numpy's parse, the table and the columns); a bad file is then read again line by line to
    name the first bad line."""
    from furuta_cosim.inputs import read_input

    raw = read_input(path, MAX_CSV_BYTES, beyond="more than a log this reads")
    if b"\x00" in raw:
        raise ConfigError([f"{path}: not a text file (it holds NUL bytes)"])
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if b"\n" not in raw and b"\r" in raw:  # lines ended by a lone carriage return
        raw = raw.replace(b"\r", b"\n")
    starts = _line_starts(raw, header)
    if starts is None:
        lines = raw.count(b"\n") + (0 if raw.endswith(b"\n") or not raw else 1)
        raise ConfigError([f"{path}: {lines} line(s), all of them header (header: {header}): no data"])
    try:
        raw[:starts].decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError([f"{path}: not a text file (not UTF-8)"]) from None
    body = raw[starts:]
    table = None
    if body.isascii():
        import io
        import warnings

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # an empty body: numpy warns, we refuse below
                table = np.loadtxt(io.BytesIO(body), delimiter=delimiter, dtype=float, ndmin=2,
                                   comments=None, encoding="ascii")
        except (ValueError, UserWarning):
            table = None
        if table is not None and (table.shape[1] != len(columns) or not np.all(np.isfinite(table))
                                  or not _plain_cells(body, delimiter)):
            table = None   # read again line by line: a not-finite cell becomes NaN there
    if table is None or not len(table):
        # raises at a bad file's first bad line; else numpy could not read what is fine (lines
        # ended by a lone carriage return, say) and this reading is the table
        table, lines = _read_slowly(path, raw, header, columns, delimiter)
    else:
        lines = _row_lines(body, header, len(table))
    found = {name: np.ascontiguousarray(table[:, k]) for k, name in enumerate(columns)}
    found[LINE] = lines
    return found


def _line_starts(raw: bytes, header: int) -> int | None:
    """The offset of the first line after ``header`` lines, None when there is none."""
    offset = 0
    for _ in range(header):
        newline = raw.find(b"\n", offset)
        if newline < 0:
            return None
        offset = newline + 1
    return offset if raw[offset:].strip() else None


def _plain_cells(body: bytes, delimiter: str) -> bool:
    """Only what a cell of numbers may hold: numpy's parser takes '1_000' and 'nan' too."""
    allowed = b"0123456789.+-eE \t\r\n" + delimiter.encode("ascii")
    return not body.translate(None, allowed)


def _row_lines(body: bytes, header: int, rows: int) -> np.ndarray:
    """The line number in the file of each row of the table (blank lines are skipped)."""
    if not re.search(rb"(^|\n)[ \t\r]*(\n|$)", body.rstrip(b"\r\n")):
        return np.arange(header + 1, header + 1 + rows)
    numbers = [header + 1 + k for k, line in enumerate(body.split(b"\n")) if line.strip()]
    return np.array(numbers[:rows])


def _read_slowly(path: Path, raw: bytes, header: int, columns: list[str],
                 delimiter: str) -> tuple[np.ndarray, np.ndarray]:
    """Read the file line by line: ConfigError at the first bad line, else (table, lines)."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError([f"{path}: not a text file (not UTF-8)"]) from None
    rows, numbers = [], []
    for number, line in enumerate(text.splitlines()[header:], start=header + 1):
        if not line.strip():
            continue
        fields = line.split(delimiter)
        if len(fields) != len(columns):
            raise ConfigError([f"{path}: line {number}: {len(fields)} field(s), but columns names "
                               f"{len(columns)} ({', '.join(columns)})"])
        row = []
        for name, cell in zip(columns, fields):
            if cell.strip().lower().lstrip("+-") in _NOT_FINITE or not cell.strip():
                row.append(math.nan)   # refused where the experiment uses it (its window)
                continue
            if not cell.isascii() or not _CELL.fullmatch(cell.encode("ascii")):
                raise ConfigError([f"{path}: line {number}, column {name}: not a number "
                                   f"({excerpt(cell.strip())}): cells are ASCII decimal numbers"])
            if not math.isfinite(float(cell)):
                raise ConfigError([f"{path}: line {number}, column {name}: {cell.strip()} is not a "
                                   "finite number (beyond the range of a double)"])
            row.append(float(cell))
        rows.append(row)
        numbers.append(number)
    if not rows:
        raise ConfigError([f"{path}: no data after the {header} header line(s)"])
    return np.array(rows, dtype=float), np.array(numbers)


def _window(check: Checker, value, t: np.ndarray, csv: Path, lines: np.ndarray) -> tuple[int, int]:
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        check.fail("time", f"{csv.name}: line {lines[k + 1]}: time does not increase "
                           f"({t[k]:g} then {t[k + 1]:g})")
        return 0, 0
    if value is None:
        return 0, len(t)
    bounds = check.vector(value, "window", 2)
    if bounds is None:
        return 0, 0
    lo, hi = bounds
    if not lo < hi:
        check.fail("window", f"expected [start, end] with start < end, got [{lo:g}, {hi:g}]")
        return 0, 0
    first, last = int(np.searchsorted(t, lo, side="left")), int(np.searchsorted(t, hi, side="right"))
    if last - first < 2:
        check.fail("window", f"[{lo:g}, {hi:g}] s holds {max(last - first, 0)} sample(s) of "
                             f"{csv.name} (its time runs from {t[0]:g} to {t[-1]:g} s)")
    return first, last


def _clock(check: Checker, t: np.ndarray, csv: Path, lines: np.ndarray, closed: bool) -> tuple[float, bool]:
    """(the period, whether the clock jitters) of the window's times ``t``: uniform, or, for a
    closed-loop log (replayed at its instants), increasing with no step longer than
    MAX_JITTER_STEPS typical ones (its period the typical step, the median)."""
    steps = np.diff(t)
    typical = float(np.median(steps))
    if not closed or not np.any(np.abs(steps - typical) > UNIFORM_TOLERANCE * typical):
        return _uniform(check, t, csv, lines), False
    bad = np.nonzero(~(steps > 0))[0]
    if len(bad):
        k = int(bad[0])
        check.fail("time", f"{csv.name}: line {lines[k + 1]}: {t[k + 1]:g} s is not after the row before "
                           f"({t[k]:g} s): a loop's samples follow one another")
        return typical, True
    long = np.nonzero(steps > MAX_JITTER_STEPS * typical)[0]
    if len(long):
        k = int(long[0])
        check.fail("time", f"{csv.name}: line {lines[k + 1]}: {steps[k]:g} s after the row before, more than "
                           f"{MAX_JITTER_STEPS} typical steps ({typical:g} s): a gap in the log, where the loop's "
                           "commands are not logged; give a window that leaves it out (window: [start, end], s)")
    return typical, True


def _uniform(check: Checker, t: np.ndarray, csv: Path, lines: np.ndarray) -> float:
    period = float(t[-1] - t[0]) / (len(t) - 1)
    steps = np.diff(t)
    typical = float(np.median(steps))  # a single odd step stands out from the median, not the mean
    off = np.abs(steps - typical) > UNIFORM_TOLERANCE * typical
    if np.any(off):
        k = int(np.argmax(off))
        check.fail("time", f"{csv.name}: line {lines[k + 1]}: not sampled uniformly: the step "
                           f"before it is {steps[k]:g} s, the others {typical:g} s "
                           "(a clock that jitters: give resample: PERIOD to put it on a uniform grid)")
    return period


def _signal(check: Checker, entry, key: str, table, columns, keep, extra=()) -> tuple | None:
    """(SI values, factor to SI, the entry) of {column, unit | scale, offset, ...}."""
    section = check.mapping(entry, key, required=("column",), optional=_SIGNAL_KEYS + extra)
    if not section or "column" not in section:
        return None
    column = check.string(section["column"], f"{key}.column")
    if column is None:
        return None
    if column not in columns:
        check.fail(f"{key}.column", f"{excerpt(column)} is not one of columns ({', '.join(columns)})")
        return None
    if "unit" in section and "scale" in section:
        check.fail(key, "give unit or scale, not both")
        return None
    if "unit" not in section and "scale" not in section:
        # a column read in the wrong unit replays as an error of thousands of degrees: say it
        check.fail(key, f"give the unit of column {excerpt(column)} (unit: one of {', '.join(UNITS)}; "
                        "the model's own are rad, rad/s, A and V) or a scale to SI")
        return None
    factor = 1.0
    if "unit" in section:
        unit = section["unit"]
        if not isinstance(unit, str) or unit not in UNITS:
            check.fail(f"{key}.unit", f"unknown unit {excerpt(str(unit))} (known: {', '.join(UNITS)}; "
                                      "scale: a factor to SI for anything else)")
            return None
        factor = UNITS[unit]
    elif "scale" in section:
        factor = check.number(section["scale"], f"{key}.scale")
        if factor is not None and not MIN_FACTOR <= abs(factor) <= MAX_FACTOR:
            check.fail(f"{key}.scale", f"expected a magnitude in [{MIN_FACTOR:g}, {MAX_FACTOR:g}], got {factor:g}")
            return None
    offset = check.number(section.get("offset", 0.0), f"{key}.offset")
    if offset is not None and abs(offset) > MAX_OFFSET:
        check.fail(f"{key}.offset", f"expected a magnitude of at most {MAX_OFFSET:g}, got {offset:g}")
        return None
    if factor is None or offset is None:
        return None
    return (table[column][keep] + offset) * factor, abs(factor), section


def shifted(values: np.ndarray, samples: float) -> np.ndarray:
    """``values`` (held over each sample) as they arrive ``samples`` samples later (0 before
    the first): a whole number of samples moves them; a fraction f of one blends each sample
    with the one before, (1 - f) now + f before, the mean of the held input over the sample."""
    whole = int(math.floor(samples + 1e-9))
    fraction = max(samples - whole, 0.0)
    now = np.concatenate([np.zeros(min(whole, len(values))), values[:max(len(values) - whole, 0)]])
    return (1.0 - fraction) * now + fraction * np.concatenate([[0.0], now[:-1]])


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
        signal = _signal(check, entry, key, table, columns, slice(None), extra=("delay",))
        if signal is None:
            continue
        values, _, raw = signal
        if "delay" in raw and isinstance(raw["delay"], dict):   # fitted: {free: [lo, hi]}
            free = _free_delay(check, raw["delay"], f"{key}.delay", period)
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


def _outputs(check: Checker, value, table, columns, keep) -> dict[str, Measured]:
    section = check.mapping(value, "outputs", optional=tuple(value) if isinstance(value, dict) else ())
    if section is not None and not section:
        check.fail("outputs", "names no output: a fit needs at least one measured output")
    found = {}
    for name, entry in (section or {}).items():
        key = f"outputs.{name}"
        signal = _signal(check, entry, key, table, columns, keep, extra=("quantum", "noise", "bias"))
        if signal is None:
            continue
        values, factor, raw = signal
        quantum = check.number(raw.get("quantum", 0.0), f"{key}.quantum", minimum=0.0,
                               maximum=MAX_MAGNITUDE / factor)
        if quantum is not None and raw.get("unit") in ("rad", "deg", "rev") and quantum * factor > MAX_QUANTUM:
            # a quantum of 1000 deg made a 180 deg offset 0.18 noise floors
            check.fail(f"{key}.quantum", f"{quantum:g} {raw['unit']} is more than a 16th of a turn: an encoder "
                                         "counts finer (give its resolution in the column's unit)")
            quantum = None
        noise = check.number(raw.get("noise", 0.0), f"{key}.noise", minimum=0.0,
                             maximum=MAX_MAGNITUDE / factor)
        if quantum is None or noise is None:
            continue
        variance = (noise * factor) ** 2 + (quantum * factor) ** 2 / 12.0
        if variance > 0:
            sigma, source = math.sqrt(variance), "+".join(k for k in ("noise", "quantum") if raw.get(k))
        else:
            sigma, source = estimated_noise(values), "estimated"
        bias = None
        if "bias" in raw:
            entry = check.mapping(raw["bias"], f"{key}.bias", required=("free",))
            bounds = check.vector(entry.get("free"), f"{key}.bias.free", 2) if entry and "free" in entry else None
            if bounds is not None and max(abs(b) for b in bounds) * factor > MAX_MAGNITUDE:
                check.fail(f"{key}.bias.free", f"expected magnitudes of at most {MAX_MAGNITUDE / factor:g}")
            elif bounds is not None and not bounds[0] < 0.0 < bounds[1]:
                check.fail(f"{key}.bias.free", f"expected [lo, hi] with lo < 0 < hi, got {bounds}")
            elif bounds is not None:
                bias = Free((bounds[0] * factor, bounds[1] * factor), 0.0)
        found[str(name)] = Measured(raw["column"], values, sigma, source, bias, float(quantum * factor))
    return found


def estimated_noise(values: np.ndarray) -> float:
    """The measurement noise of a smooth signal, from its second differences (white noise of
    standard deviation s gives second differences of standard deviation s * sqrt(6)); never
    below a millionth of the signal's largest magnitude, so a constant column weighs finitely."""
    floor = 1e-6 * max(float(np.max(np.abs(values))), 1e-12)
    if len(values) < 3:
        return floor
    return max(float(np.std(np.diff(values, 2))) / math.sqrt(6.0), floor)


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
