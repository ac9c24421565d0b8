"""Progress of long work on stderr: a live bar (tqdm) on a terminal, a line every few seconds
otherwise (a log file, CI), nothing for work that ends quickly."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm


class Progress:
    """Progress on stderr: a live bar on a terminal, a line every few seconds otherwise;
    nothing for work that ends within ``delay`` seconds. ``note`` adds text (best so far)."""

    def __init__(self, delay: float = 1.0, every: float = 5.0, unit: str = "step"):
        self._clock, self._delay, self._every, self._unit = time.monotonic, delay, every, unit
        self._bar, self._name, self._started, self._last = None, None, 0.0, 0.0

    def __call__(self, name: str, k: int, steps: int, note: str = "", unit: str | None = None) -> None:
        """``k`` of ``steps`` done in the stage ``name`` (counted in ``unit``, else the bar's)."""
        now = self._clock()
        unit = unit or self._unit
        if name != self._name:
            self.close()
            self._name, self._started, self._last = name, now, now
        if now - self._started < self._delay:
            return
        if sys.stderr.isatty():
            if self._bar is None:
                self._bar = tqdm(total=steps, desc=f"  {name}", unit=unit, unit_scale=True,
                                 leave=False, file=sys.stderr)
            if note:
                self._bar.set_postfix_str(note)
            self._bar.update(k - self._bar.n)
        elif now - self._last >= self._every or k == steps:
            self._last = now
            print(f"  {name}: {k}/{steps} {_plural(unit)} ({k / steps:.0%})" + (f", {note}" if note else ""),
                  file=sys.stderr)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def _plural(unit: str) -> str:
    """``evaluation`` -> ``evaluations``; a symbol (``s``, ``V``) stays as it is."""
    return unit if len(unit) <= 2 else unit + "s"
