"""What a controller on a rig sees of the plant: angles as the encoders count them, and rates
as the filtered difference of those angles (the bilinear form of ``w s / (s + w)``). One
definition for the rig's runner (rig/runner.py) and for a replay that closes the loop the log
was recorded with (identify/replay.py), so that the simulated controller sees what the real
one saw."""

from __future__ import annotations

import math

RATE_FILTER = 40.0       # Hz: the rates' filtered difference, by default


def counted(angle: float, zero: float, per_count: float) -> float:
    """``angle`` as an encoder zeroed at ``zero`` with ``per_count`` rad a count reads it."""
    return zero + round((angle - zero) / per_count) * per_count


class RateFilter:
    """Filtered differences of the two angles at ``period``, cutoff ``hz``; the first sample's
    rates are 0."""

    def __init__(self, period: float, hz: float = RATE_FILTER):
        w = 2.0 * math.pi * hz
        self.a, self.b = (2.0 - w * period) / (2.0 + w * period), 2.0 * w / (2.0 + w * period)
        self.last = None
        self.rates = [0.0, 0.0]

    def __call__(self, angles):
        if self.last is not None:
            self.rates = [self.a * r + self.b * (a - p) for r, a, p in zip(self.rates, angles, self.last)]
        self.last = angles
        return self.rates
