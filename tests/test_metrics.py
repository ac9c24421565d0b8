"""Metric values computed by hand on traces small enough to check on paper."""

import math
import sys
from pathlib import Path
from types import SimpleNamespace

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
    # once risen (from 90 % of the change on) the output stays between SettlingMin and
    # SettlingMax, in its own units, the least below the greatest whichever way it stepped
    risen = y[np.argmax(y <= 1.0 - 0.9):]
    assert step["SettlingMin"] == pytest.approx(float(np.min(risen)), abs=1e-9)
    assert step["SettlingMax"] == pytest.approx(float(np.max(risen)), abs=1e-9)
    assert step["SettlingMin"] < step["SettlingMax"]
    up = step_metrics(t, -y, -1.0, 0.0)
    assert up["SettlingMin"] == pytest.approx(-step["SettlingMax"]) and up["SettlingMax"] == pytest.approx(-step["SettlingMin"])


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


def test_a_new_metric_is_one_registry_entry(monkeypatch):
    """A change task: the input's largest step between samples as one class. It is in the catalogue, computed,
    checked in requirement names, left out of simulate's table (not ``shown``), documented
    from its description, compared within its own tolerance, and not watched (it does not
    ``grow``)."""
    import numpy as np

    from furuta_cosim import metrics
    from furuta_cosim.cosim.limits import monotone
    from furuta_cosim.metrics import Metric, table_keys
    from furuta_cosim.scenario import Regression

    monkeypatch.setattr(metrics, "METRICS", dict(metrics.METRICS))
    table = table_keys("theta0", ["theta1"])

    class LargestStep(Metric):
        name, of, rtol = "largest_step", "input", 1e-4
        description = "largest |u[k+1] - u[k]| (V)"

        def value(self, s):
            return float(np.max(np.abs(np.diff(s.x)))) if len(s.x) > 1 else 0.0

    assert "largest_step" in catalogue("theta0", ["theta0", "theta1"])["u"]
    assert problem("u.largest_step") is None and problem("u.largest_stp").endswith(
        "did you mean largest_step: largest |u[k+1] - u[k]| (V)?")
    assert table_keys("theta0", ["theta1"]) == table
    assert Regression().tolerance("u.largest_step") == (1e-4, 1e-9)
    assert Regression(rtol=1e-3).tolerance("u.largest_step")[0] == 1e-3   # a scenario may widen it
    assert not monotone("u.largest_step", ["theta0"])
    trace = SimpleNamespace(t=np.arange(5) * 0.5, r=np.zeros(5), u=np.array([0.0, 1.0, -1.0, 0.0, 0.0]),
                            signals={"y": np.zeros(5)}, tracked="y", units={}, failure=None)
    assert compute(trace, settles=False)["u.largest_step"] == pytest.approx(2.0)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
    try:
        import docs_hooks
    finally:
        sys.path.pop(0)
    assert "| `largest_step` | `u` | largest \\|u[k+1] - u[k]\\| (V) | - | - | rtol 0.0001 |" in \
        docs_hooks.metrics_table()


def test_every_metric_that_grows_runs_as_it_ends():
    """One implementation: a growing metric's running value over chunks is its value over the
    whole run, for every registered one."""
    import numpy as np

    from furuta_cosim.metrics import METRICS, Samples

    rng = np.random.default_rng(3)
    t = np.arange(200) * 0.01
    x = rng.normal(size=200)
    grown = [m for m in METRICS.values() if m.grows]
    assert len(grown) >= 6
    for m in grown:
        running = 0.0
        for first in range(0, 200, 37):
            running = m.running(running, Samples(t[first:first + 37], x[first:first + 37], 0.01))
        assert running == pytest.approx(m.value(Samples(t, x, 0.01)), rel=1e-12), m.name
