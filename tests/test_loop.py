"""The generated sample loops: every configuration equals a plain loop written here, and a
traceback through generated code shows its source line."""

import dataclasses
import itertools
import traceback

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.cosim import evaluation as evaluate_module
from furuta_cosim.cosim.loop import ARGUMENTS, loop_for
from furuta_cosim.cosim.runtime import RuntimeController
from furuta_cosim.design import GeneralizedController
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import Estimator, Noise, Pulse, load_scenario


def plain_loop(n_sources, pick, noisy, estimator, record_state, limited, n_disturbances, substeps):
    """The master's order of events, written out with no generation and no shortcuts."""

    def loop(step, control, state, correct, predict, rbar, measurement, disturbance, h, first,
             last, values, limit, rows, inputs, commands, states, estimates):
        for k in range(first, last):
            fed = [values[i] for i in pick] if pick is not None else list(values)
            for position, j in enumerate(noisy):
                fed[j] = fed[j] + measurement[k][position]
            if estimator:
                fed = correct(fed)
                estimates(fed)
            if record_state:
                states(state())
            command = control(fed, rbar[k])
            u = min(max(command, -limit), limit) if limited else command
            if limited:
                commands(command)
            if estimator:
                predict(u)
            rows(values)
            inputs(u)
            applied = [u] + (list(disturbance[k]) if n_disturbances else [])
            for _ in range(substeps):
                values = step(applied, h)
        return values

    return loop


CONFIGURATIONS = list(itertools.product([False, True], repeat=6))


def variant(noise, estimator, limited, disturbances, substeps, controller_state):
    scenario = load_scenario("paper-step")
    changes = {"duration": 1.0, "requirements": (),
               "controllers": ("bo-paper" if controller_state else "lqr-paper",)}
    if noise or disturbances:
        changes["noise"] = Noise(3, {"tau0": 1e-3} if disturbances else {},
                                 {"theta1": 1e-3} if noise else {})
    if disturbances:
        changes["disturbances"] = (Pulse("tau1", 0.2, 0.05, 0.02),)
    if estimator:
        changes["estimator"] = Estimator("kalman", ("theta0", "theta1", "i"))
        if noise:
            changes["noise"] = dataclasses.replace(changes["noise"], measurement={"theta1": 1e-3, "i": 1e-2})
    if limited:
        changes["actuator_limit"] = 5.0
    if substeps:
        changes["communication_step"] = 0.001
    return dataclasses.replace(scenario, **changes)


@pytest.fixture(scope="module")
def session(furuta_fmu):
    with PlantSession.open(furuta_fmu) as plant:
        yield plant


@pytest.mark.parametrize("configuration", CONFIGURATIONS,
                         ids=lambda c: "".join("NELDSX"[i] if on else "-" for i, on in enumerate(c)))
def test_every_generated_configuration_equals_the_plain_loop(configuration, session, monkeypatch):
    prepared = prepare(variant(*configuration))
    controller = prepared.scenario.controllers[0]
    generated = evaluate(prepared, session, controller)
    used = []
    monkeypatch.setattr(evaluate_module, "loop_for",
                        lambda *config: used.append(config) or plain_loop(*config))
    plain = evaluate(prepared, session, controller)
    noise, estimator, limited, disturbances, substeps, controller_state = configuration
    n_sources, pick, noisy, has_estimator, record_state, has_limit, n_disturbances, n_sub = used[0]
    # the configuration the generator was asked for is the one meant
    assert (bool(noisy), has_estimator, has_limit, n_disturbances > 0, n_sub > 1, record_state) == \
        (noise, estimator, limited, disturbances, substeps, controller_state)
    assert (pick is not None) == estimator  # the estimator picks the measured outputs
    assert generated.trace.columns() == plain.trace.columns()
    for name in generated.trace.columns():
        np.testing.assert_array_equal(generated.trace[name], plain.trace[name], err_msg=name)
    assert generated.metrics == plain.metrics
    if limited:
        assert np.max(np.abs(generated.trace.u)) <= 5.0


def test_a_traceback_through_the_generated_loop_shows_its_line():
    loop = loop_for(5, None, (), False, False, False, 0, 1)

    def broken_plant(applied, h):
        raise ZeroDivisionError("the plant failed")

    arguments = dict.fromkeys(ARGUMENTS)
    arguments.update(step=broken_plant, control=lambda x, r: 0.0, rbar=[0.0], h=1e-3, first=0,
                     last=1, values=[0.0] * 5, limit=0.0, rows=list().append, inputs=list().append)
    with pytest.raises(ZeroDivisionError) as caught:
        loop(*(arguments[name] for name in ARGUMENTS))
    text = "".join(traceback.format_exception(caught.value))
    assert '<furuta-cosim loop ' in text and "values = step([u], h)" in text


def test_a_traceback_through_a_generated_controller_shows_its_line():
    controller = RuntimeController(GeneralizedController.static([[1.0, 2.0]], period=1.0))
    with pytest.raises(ValueError) as caught:
        controller([1.0, 2.0, 3.0], 0.0)  # three values for two states
    text = "".join(traceback.format_exception(caught.value))
    assert "<furuta-cosim controller " in text and "x0, x1, = x" in text
