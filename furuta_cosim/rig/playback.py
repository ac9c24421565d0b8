"""An excitation played open loop on a rig: a voltage table (``design-experiment`` writes one)
as a runtime controller for :func:`~furuta_cosim.rig.runner.run_rig`.

The table is a CSV file with a header and two columns, ``t`` (s, from 0, uniform: the loop's
period) and ``V`` (volts). It is read as hostile input: finite numbers, a uniform time base,
at most the runner's longest run; the supervisor clips and checks what it plays as it does any
controller's command.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from furuta_cosim.errors import ConfigError

MAX_ROWS = 10_000_000


def load_input(path: str | Path) -> tuple[float, np.ndarray]:
    """(period, volts) of an input table (module docstring); a bad file is one ConfigError
    naming the file, the row and what was expected."""
    path = Path(path)
    try:
        with path.open(encoding="utf-8") as handle:
            header = handle.readline().strip().replace(" ", "").lower()
            if header != "t,v":
                raise ConfigError([f"{path}: line 1: expected the header `t,V`, got {header[:60]!r}"])
            rows = []
            for number, line in enumerate(handle, start=2):
                if not line.strip():
                    continue
                cells = line.split(",")
                try:
                    t, v = (float(c) for c in cells)
                except ValueError:
                    raise ConfigError([f"{path}: line {number}: expected two numbers `t,V`, "
                                       f"got {line.strip()[:60]!r}"]) from None
                if not (math.isfinite(t) and math.isfinite(v)):
                    raise ConfigError([f"{path}: line {number}: expected finite numbers, got {line.strip()[:60]!r}"])
                rows.append((t, v))
                if len(rows) > MAX_ROWS:
                    raise ConfigError([f"{path}: more than {MAX_ROWS} rows"])
    except OSError as error:
        raise ConfigError([f"{path}: cannot be read ({error.strerror or error})"]) from None
    except UnicodeDecodeError:
        raise ConfigError([f"{path}: not a text file (a CSV of t,V expected)"]) from None
    if len(rows) < 2:
        raise ConfigError([f"{path}: fewer than two rows: an input table needs a period"])
    table = np.array(rows)
    steps = np.diff(table[:, 0])
    period = float(steps[0])
    if table[0, 0] != 0.0 or not 1e-4 <= period <= 1.0 or np.max(np.abs(steps - period)) > 1e-6 * period + 1e-9:
        raise ConfigError([f"{path}: column t: expected times from 0 at a uniform period "
                           f"(0.1 ms to 1 s), got {table[0, 0]:g}, {table[1, 0]:g}, ..."])
    return period, table[:, 1].copy()


class Playback:
    """The table's voltages, one a sample, as a runtime controller (the measurements unused)."""

    n_xc = 0
    name = "input"

    def __init__(self, volts: np.ndarray, period: float, name: str = "input"):
        self.volts, self.period, self.name = np.asarray(volts, dtype=float), float(period), name
        self.reset()

    def reset(self) -> None:
        self.k, self.finished = 0, False

    def state(self) -> list:
        return []

    def control(self, _x, _rbar: float) -> float:
        value = float(self.volts[min(self.k, len(self.volts) - 1)])
        self.k += 1
        return value

    @property
    def duration(self) -> float:
        return len(self.volts) * self.period
