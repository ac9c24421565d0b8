"""An experiment's columns and units: the CSV read as hostile input (size, cells, lines named
for every problem), each signal's column, unit, offset, factor, quantum and noise converted to SI,
and which columns a file uses; the lowest layer of reading an experiment (identify/experiment.py).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from furuta_cosim.config import Checker, excerpt
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.variables import MAX_FACTOR, MAX_OFFSET, MIN_FACTOR


# unit -> factor to SI (rad, rad/s, A, V, s): value_SI = (value + offset) * factor
UNITS = {"rad": 1.0, "deg": math.pi / 180.0, "rev": 2.0 * math.pi, "rad/s": 1.0,
         "deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0, "A": 1.0, "mA": 1e-3, "V": 1.0,
         "s": 1.0, "ms": 1e-3, "m": 1.0, "cm": 1e-2, "mm": 1e-3, "m/s": 1.0, "mm/s": 1e-3,
         "N": 1.0, "N.m": 1.0}


MAX_CSV_BYTES = 200_000_000


MAX_QUANTUM = 2 * math.pi / 16      # rad: an angle's quantum at most (16 counts a turn)


LINE = "\0line"  # read_csv's entry for the line number of each row in the file


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


def used_columns(top: dict, time_column: str) -> list[str]:
    """The columns an experiment file reads: its time, each input's and output's, and its
    loop's reference, feedforward and timing."""
    used = [time_column]
    for key in ("inputs", "outputs"):
        section = top.get(key) if isinstance(top.get(key), dict) else {}
        used += [e["column"] for e in section.values() if isinstance(e, dict) and isinstance(e.get("column"), str)]
    loop = top.get("loop") if isinstance(top.get("loop"), dict) else {}
    used += [loop[k] for k in ("reference", "feedforward", "late", "compute", "mode") if isinstance(loop.get(k), str)]
    return list(dict.fromkeys(used))


def finite_within(check: Checker, table, used: list[str], keep: slice, csv: Path, windowed: bool,
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


def to_si(spec: dict) -> tuple[str, float, float]:
    """(column, factor, offset) of a signal already checked: SI = (column + offset) * factor."""
    factor = UNITS[spec["unit"]] if "unit" in spec else float(spec["scale"])
    return str(spec["column"]), float(factor), float(spec.get("offset", 0.0))


def csv_path(check: Checker, value, path: Path) -> Path | None:
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


def read_signal(check: Checker, entry, key: str, table, columns, keep, extra=()) -> tuple | None:
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


def read_outputs(check: Checker, value, table, columns, keep) -> dict[str, Measured]:
    section = check.mapping(value, "outputs", optional=tuple(value) if isinstance(value, dict) else ())
    if section is not None and not section:
        check.fail("outputs", "names no output: a fit needs at least one measured output")
    found = {}
    for name, entry in (section or {}).items():
        key = f"outputs.{name}"
        signal = read_signal(check, entry, key, table, columns, keep, extra=("quantum", "noise", "bias"))
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
