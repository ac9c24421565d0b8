"""Metric values computed by hand on traces small enough to check on paper."""

import math

import numpy as np
import pytest

from furuta_cosim.cosim.trace import Trace
from furuta_cosim.metrics import catalogue, compute, problem, regulation_settling, step_metrics, step_segments


def _trace(t, r, y, u, others=None):
    signals = {"y": np.asarray(y, float), **{k: np.asarray(v, float) for k, v in (others or {}).items()}}
    return Trace("c", np.asarray(t, float), np.asarray(r, float), np.asarray(u, float), signals, "y")


def test_the_error_integrals_and_input_metrics_by_hand():
    t = np.arange(4) * 0.5                       # dt = 0.5
    trace = _trace(t, [1, 1, 1, 1], [0, 0.5, 1, 1], [2, -1, 0, 0])
    m = compute(trace, settles=False)
    # e = [1, 0.5, 0, 0]
    assert m["error.IAE"] == pytest.approx(0.5 * 1.5)
    assert m["error.ISE"] == pytest.approx(0.5 * 1.25)
    assert m["error.ITAE"] == pytest.approx(0.5 * (0 * 1 + 0.5 * 0.5))
    assert m["error.RMS"] == pytest.approx(math.sqrt(1.25 / 4))
    assert m["u.peak_abs"] == 2 and m["u.rms"] == pytest.approx(math.sqrt(5 / 4))
    assert m["u.energy"] == pytest.approx(0.5 * 5) and m["y.max_abs"] == 1


def test_the_error_window_limits_the_rms_only():
    t = np.arange(4) * 1.0
    m = compute(_trace(t, [1, 1, 1, 1], [0, 0, 1, 1], [0] * 4), settles=False, error_window=(2.0, 4.0))
    assert m["error.RMS"] == 0 and m["error.IAE"] == 2


def test_a_step_down_peaks_at_its_lowest_value():
    t = np.linspace(0, 10, 1001)
    y = 1 - 1.2 * (1 - np.exp(-t)) * (1 + 0.2 * np.exp(-t) * np.sin(5 * t))  # overshoots 0
    step = step_metrics(t, y, 1.0, 0.0)
    assert step["Peak"] == pytest.approx(float(np.min(y)), abs=1e-12) and step["Peak"] < 0


def test_regulation_settling_by_hand():
    t = np.arange(5) * 1.0
    assert regulation_settling(t, np.array([1.0, 0.5, 0.03, 0.01, 0.0])) == 3.0
    assert regulation_settling(t, np.array([1.0, 0.5, 0.5, 0.5, 0.5])) == math.inf
    assert regulation_settling(t, np.zeros(5)) is None


def test_each_step_of_a_staircase_has_its_own_metrics():
    t = np.arange(3000) * 0.01
    r = np.where(t < 10, 0.0, 1.0) + np.where(t < 20, 0.0, -1.0)   # up at 10 s, down at 20 s
    # a first-order response with a 1 s time constant to each step
    y = np.zeros_like(t)
    for k in range(1, len(t)):
        y[k] = y[k - 1] + 0.01 * (r[k - 1] - y[k - 1])
    assert step_segments(r) == [(1000, 2000), (2000, 3000)]
    m = compute(_trace(t, r, y, np.zeros_like(t)))
    # a first-order rise from 10 % to 90 % takes ln(9) time constants
    assert m["y.step1.RiseTime"] == pytest.approx(math.log(9), abs=0.02)
    assert m["y.step2.RiseTime"] == pytest.approx(math.log(9), abs=0.02)
    assert m["y.step1.SettlingTime"] == pytest.approx(-math.log(0.02), abs=0.05)
    assert m["y.RiseTime"] == m["y.step2.RiseTime"]                 # the unprefixed: the last step
    known = catalogue("y", ["y"], settles=True, steps=2)
    assert problem("y.step2.Overshoot", known) is None and problem("y.step3.Overshoot", known)


def test_a_reference_of_many_changes_has_no_step_metrics_of_each():
    assert step_segments(np.sin(np.linspace(0, 10, 500))) == []
    assert step_segments(np.array([0.0, 1.0, 1.0])) == []            # one step: the unprefixed ones
