"""An experiment's windows and clocks: the time column read (uniform within a tolerance, or
jittered and replayed at its instants), a log resampled where the file asks, a loop's timing
columns (when each sample was read and each command written), the lead-in before a window, and
delays of whole and fractional samples (:func:`shifted`, :func:`held_means`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from furuta_cosim.config import Checker, excerpt
from furuta_cosim.identify.columns import LINE, Free, read_signal


# two successive sample times may differ from the mean period by this fraction (loggers print
# rounded times); beyond it the log is refused: nothing here resamples
UNIFORM_TOLERANCE = 0.01


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


def read_lead_in(check: Checker, top: dict, table, columns, first: int, period: float,
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
        return read_signal(check, entry, key, table, columns, part, extra=extra)[0]

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


def resample_log(check: Checker, top: dict, table: dict, time_column: str, first: int, last: int,
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


def timing_column(check: Checker, entry: dict, key: str, table, columns, keep, period: float, csv: Path,
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


def read_free_delay(check: Checker, value, key: str, period: float) -> Free | None:
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


def read_window(check: Checker, value, t: np.ndarray, csv: Path, lines: np.ndarray) -> tuple[int, int]:
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


def read_clock(check: Checker, t: np.ndarray, csv: Path, lines: np.ndarray, closed: bool) -> tuple[float, bool]:
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


def shifted(values: np.ndarray, samples: float) -> np.ndarray:
    """``values`` (held over each sample) as they arrive ``samples`` samples later (0 before
    the first): a whole number of samples moves them; a fraction f of one blends each sample
    with the one before, (1 - f) now + f before, the mean of the held input over the sample."""
    whole = int(math.floor(samples + 1e-9))
    fraction = max(samples - whole, 0.0)
    now = np.concatenate([np.zeros(min(whole, len(values))), values[:max(len(values) - whole, 0)]])
    return (1.0 - fraction) * now + fraction * np.concatenate([[0.0], now[:-1]])


def held_means(switches: np.ndarray, values: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Per interval [samples[k], samples[k+1]) the mean of a signal that is 0 before
    ``switches[0]`` and ``values[j]`` from ``switches[j]`` on (``switches`` not decreasing); the
    last sample's interval as long as the one before it (a period where that is none). An
    interval of no time (two samples read at one instant) takes the signal's value there."""
    last = samples[-1] - samples[-2] if len(samples) > 1 else 0.0
    if not last > 0:
        positive = np.diff(samples)[np.diff(samples) > 0] if len(samples) > 1 else np.zeros(0)
        last = float(np.median(positive)) if len(positive) else 1.0
    ends = np.append(samples, samples[-1] + last)
    # the signal's integral from switches[0] to each switch, then to each end
    widths = np.diff(switches)
    area = np.concatenate([[0.0], np.cumsum(values[:-1] * widths)])

    def integral(x):
        j = np.searchsorted(switches, x, side="right") - 1
        inside = j >= 0
        found = np.zeros_like(x, dtype=float)
        found[inside] = area[j[inside]] + values[j[inside]] * (x[inside] - switches[j[inside]])
        return found

    total = integral(ends)
    width = np.diff(ends)
    j = np.searchsorted(switches, samples, side="right") - 1
    at = np.where(j >= 0, values[np.maximum(j, 0)], 0.0)   # the value at each sample's instant
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(width > 0, np.diff(total) / np.where(width > 0, width, 1.0), at)
