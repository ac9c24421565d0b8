"""The sample loop in C (cosim/native.py) gives the Python loop's results bit for bit: every
configuration it takes, an FMI 3.0 plant, a run the plant gives up on, a run stopped at a
bound; it leaves an estimator and unit conversions to the Python loop."""

import dataclasses
import itertools

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.cosim import native as native_module
from furuta_cosim.cosim import evaluation as evaluate_module
from furuta_cosim.cosim.native import NativeLoop
from furuta_cosim.design import GeneralizedController
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.session import PlantSession, PlantSession3
from furuta_cosim.scenario import load_scenario

from test_loop import variant


def both(prepared, session, controller, monkeypatch, **options):
    """The run through the C loop and through the Python loop, and how many C chunks ran."""
    chunks = []
    run = NativeLoop.run
    monkeypatch.setattr(NativeLoop, "run", lambda self, a, b: chunks.append((a, b)) or run(self, a, b))
    in_c = evaluate(prepared, session, controller, **options)
    after_c = session.time
    monkeypatch.setenv(native_module.OFF, "1")
    in_python = evaluate(prepared, session, controller, **options)
    monkeypatch.delenv(native_module.OFF)
    assert session.time == after_c  # the session's clock is handed back as the Python loop keeps it
    return in_c, in_python, len(chunks)


def assert_same(a, b):
    assert a.trace.columns() == b.trace.columns()
    for name in a.trace.columns():
        np.testing.assert_array_equal(a.trace[name], b.trace[name], err_msg=name)
    assert a.trace.failure == b.trace.failure
    assert a.metrics == b.metrics and a.stopped == b.stopped and a.passed == b.passed


@pytest.fixture(scope="module")
def session(furuta_fmu):
    with PlantSession.open(furuta_fmu) as plant:
        yield plant


# noise, limit, disturbances, substeps, controller state, delay: every one without an estimator
CONFIGURATIONS = list(itertools.product([False, True], repeat=6))


@pytest.mark.parametrize("configuration", CONFIGURATIONS,
                         ids=lambda c: "".join("NLDSXY"[i] if on else "-" for i, on in enumerate(c)))
def test_every_configuration_without_an_estimator_equals_the_python_loop(configuration, session,
                                                                        monkeypatch):
    noise, limited, disturbances, substeps, controller_state, delay = configuration
    scenario = variant(noise, False, limited, disturbances, substeps, controller_state)
    if delay:
        scenario = dataclasses.replace(scenario, delay=1)
    prepared = prepare(scenario)
    in_c, in_python, chunks = both(prepared, session, prepared.scenario.controllers[0], monkeypatch)
    assert chunks == 1
    assert_same(in_c, in_python)
    assert len(in_c.trace.t) == prepared.steps and np.ptp(in_c.trace.u) > 0
    if limited:
        assert np.max(np.abs(in_c.trace.u)) <= 5.0


def test_a_controller_with_two_states_and_zero_coefficients_equals_the_python_loop(session, monkeypatch):
    prepared = prepare(dataclasses.replace(load_scenario("paper-step"), duration=1.0))
    lqr = [[-1.0, -4.0, 30.0, 3.0, 0.0]]  # a zero coefficient, left out as the Python loop does
    controller = GeneralizedController(Ac=[[-5.0, 0.0], [1.0, -2.0]], Bc=[[0.0] * 5, [0.1, 0, 0, 0, 0]],
                                       Cc=[[0.0, 0.5]], Dc=lqr)
    in_c, in_python, chunks = both(prepared, session, controller, monkeypatch)
    assert chunks == 1 and "xc2" in in_c.trace.columns()
    assert_same(in_c, in_python)


def test_a_run_stopped_at_a_bound_stops_at_the_same_sample(session, monkeypatch):
    prepared = prepare(load_scenario("paper-tracking"))
    in_c, in_python, chunks = both(prepared, session, "lqr-paper", monkeypatch, limits={"error.ISE": 0.5})
    assert in_c.stopped is not None and in_c.stopped["metric"] == "error.ISE"
    assert 1 < chunks < prepared.steps // 250 and len(in_c.trace.t) < prepared.steps
    assert_same(in_c, in_python)


def test_a_run_the_plant_gives_up_on_fails_at_the_same_sample(session, monkeypatch):
    prepared = prepare(dataclasses.replace(load_scenario("paper-step"), duration=5.0))
    unstable = GeneralizedController.static([[-100.0, -10.0, 0.0, 0.0, 0.0]])  # the arm runs away
    in_c, in_python, chunks = both(prepared, session, unstable, monkeypatch)
    assert chunks == 1
    assert in_c.trace.failure and "diverg" in in_c.trace.failure, in_c.trace.failure
    assert len(in_c.trace.t) < prepared.steps
    assert_same(in_c, in_python)


def test_an_fmi3_plant_runs_in_c_as_in_python(monkeypatch):
    prepared = prepare(dataclasses.replace(load_scenario("paper-step"), duration=1.0),
                       fmu=build_fmu("furuta", fmi_version="3.0"))
    with PlantSession.open(prepared.fmu) as fmi3:
        assert isinstance(fmi3, PlantSession3)
        in_c, in_python, chunks = both(prepared, fmi3, "bo-paper", monkeypatch)
    assert chunks == 1
    assert_same(in_c, in_python)


def test_an_estimator_is_left_to_the_python_loop(session, monkeypatch):
    prepared = prepare(variant(True, True, False, False, False, False))
    chunks = []
    monkeypatch.setattr(NativeLoop, "run", lambda *a: chunks.append(a))
    result = evaluate(prepared, session, "lqr-paper")
    assert chunks == [] and len(result.trace.t) == prepared.steps


def test_arrays_shorter_than_the_run_are_left_to_the_python_loop(session):
    """The C loop checks no bounds itself: what it would read past an end never reaches it."""
    prepared = prepare(variant(True, False, False, True, False, False))
    runtime = evaluate_module.compile_controller(prepared, "lqr-paper").runtime
    session.set_io([prepared.control_input] + prepared.disturbance_inputs, prepared.outputs)
    pick, values = list(range(len(prepared.states))), [0.0] * len(prepared.outputs)
    noisy = [prepared.states.index(n) for n in prepared.noisy]
    assert NativeLoop.on(prepared, session, runtime, pick, noisy, values) is not None
    for change in ({"rbar": prepared.rbar[:10]}, {"measurement_noise": prepared.measurement_noise[:10]},
                   {"disturbance": prepared.disturbance[:10]}):
        short = dataclasses.replace(prepared, **change)
        assert NativeLoop.on(short, session, runtime, pick, noisy, values) is None, change
    session.set_io([prepared.control_input], prepared.outputs)  # a disturbance input missing
    assert NativeLoop.on(prepared, session, runtime, pick, noisy, values) is None
