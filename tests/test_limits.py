"""A run watched against bounds on metrics that only grow (cosim/limits.py): past one it
stops, with the full run's value up to that sample, a lower bound of the full run's."""

import math

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.cosim.limits import Watch, monotone
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario


@pytest.fixture(scope="module")
def tracking():
    return prepare(load_scenario("paper-tracking"))


def test_a_run_past_a_bound_stops_with_a_lower_bound_of_the_full_runs_value(tracking):
    with PlantSession.open(tracking.fmu) as session:
        full = evaluate(tracking, session, "lqr-paper")
        ise = full.metrics["error.ISE"]
        stopped = evaluate(tracking, session, "lqr-paper", limits={"error.ISE": 0.5 * ise})
        # a bound the run never reaches changes nothing, bit for bit
        same = evaluate(tracking, session, "lqr-paper",
                        limits={"error.ISE": 2 * ise, "theta1.max_abs": 10.0, "u.peak_abs": 100.0})
    assert full.stopped is None and same.stopped is None and same.metrics == full.metrics
    assert stopped.stopped["metric"] == "error.ISE" and not stopped.passed
    assert stopped.failure is None
    n = len(stopped.trace.t)
    assert 0 < n < len(full.trace.t)
    assert stopped.stopped["t"] == pytest.approx(full.trace.t[n - 1])
    # past the bound where it stopped, and below the full run's value: a lower bound
    assert 0.5 * ise < stopped.stopped["value"] <= ise
    assert stopped.metrics["error.ISE"] == pytest.approx(stopped.stopped["value"], rel=1e-12)
    # the running sum is the full run's over the same samples
    e = full.trace.r[:n] - full.trace.signals["theta0"][:n]
    dt = full.trace.t[1] - full.trace.t[0]
    assert stopped.metrics["error.ISE"] == pytest.approx(float(np.sum(e ** 2)) * dt, rel=1e-12)
    assert len(stopped.trace.u) < len(full.trace.u)  # fewer samples simulated (speed: tools/)


def test_only_metrics_that_grow_along_a_run_can_be_watched(tracking):
    outputs = tracking.outputs
    for metric in ("error.ISE", "error.IAE", "error.ITAE", "u.energy", "u.peak_abs", "theta1.max_abs"):
        assert monotone(metric, outputs), metric
    for metric in ("error.RMS", "u.rms", "theta0.SettlingTime", "nothing.max_abs"):
        assert not monotone(metric, outputs), metric
    with PlantSession.open(tracking.fmu) as session:
        with pytest.raises(ValueError, match="u.rms"):
            evaluate(tracking, session, "lqr-paper", limits={"u.rms": 1.0})


def test_a_peak_is_watched_and_not_a_number_is_left_to_the_runs_own_check():
    watch = Watch({"y.max_abs": 2.0}, ["y", "x"], "y", 0.1)
    assert watch.update([0.0, 0.1], [0.0, 0.0], [[1.0, 0.0], [-1.5, 9.0]], [0.0, 0.0]) is None
    assert watch.values["y.max_abs"] == 1.5
    assert watch.update([0.2], [0.0], [[math.nan, 0.0]], [0.0]) is None
    assert watch.update([0.3], [0.0], [[-2.5, 0.0]], [0.0]) == "y.max_abs"
