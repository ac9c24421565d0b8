"""The loop that runs on a rig (design/rigloop.py) against the same loop built independently
with python-control: the plant sampled at half the period by python-control (its command half
a sample late: the sample's first half under the command before), the rate filter and the
gains as transfer functions, the closed loop by python-control's feedback."""

from __future__ import annotations

import math

import control
import numpy as np
import pytest

from furuta_cosim.design.margins import loop_margins
from furuta_cosim.design.rigloop import rig_analysis, rig_loop
from furuta_cosim.lqr_file import analyze_file

from helpers import run_cli

T = 0.002
HZ = 40.0


@pytest.fixture(scope="module")
def qube():
    found = analyze_file("lqr-qube")
    return found.model, found.cfile.controller


def _independent(model, controller, scale: float = 1.0):
    """(L as a 1x1 discrete system, the closed loop's poles with the gain scaled by ``scale``):
    the command T/2 late, the rates b (1 - 1/z) / (1 - a/z) of the angles."""
    half = control.sample_system(control.ss(model.A, model.B, np.eye(5), np.zeros((5, 1))), T / 2, method="zoh")
    Ah, Bh = half.A, half.B
    # over a sample: u[k-1] for its first half, then u[k]: the state keeps u[k-1]
    A = np.block([[Ah @ Ah, Ah @ Bh], [np.zeros((1, 5)), np.zeros((1, 1))]])
    B = np.vstack([Bh, np.ones((1, 1))])
    plant = control.ss(A, B, np.hstack([np.eye(5), np.zeros((5, 1))]), np.zeros((5, 1)), T)
    w = 2 * math.pi * HZ
    a, b = (2 - w * T) / (2 + w * T), 2 * w / (2 + w * T)
    rate = control.tf([b, -b], [1.0, -a], T)
    K = np.asarray(controller.Dc, dtype=float)[0]
    one = control.tf([1.0], [1.0], T)
    seen = {0: K[0] * one + K[1] * rate, 2: K[2] * one + K[3] * rate, 4: K[4] * one}   # theta0, theta1, i
    law = None
    for j, siso in seen.items():   # each a SISO system after picking its state: summed
        pick = control.ss(np.zeros((0, 0)), np.zeros((0, 5)), np.zeros((1, 0)), np.eye(5)[[j]], T)
        part = control.series(pick, control.ss(siso))
        law = part if law is None else control.parallel(law, part)
    L = control.series(plant, law)
    closed = control.feedback(plant, scale * law)
    return L, closed.poles()


def test_the_rig_loop_is_the_loop_python_control_builds_from_its_parts(qube):
    model, controller = qube
    plant, law = rig_loop(model, controller, delay=T / 2, rate_filter=HZ)
    ours = control.ss(law.Ac, law.Bc, law.Cc, law.Dc, T) * control.ss(plant.A, plant.B, np.eye(plant.A.shape[0]),
                                                                         np.zeros((plant.A.shape[0], 1)), T)
    theirs, _ = _independent(model, controller)
    omega = np.logspace(-2, math.log10(math.pi / T * 0.999), 300)
    np.testing.assert_allclose(np.asarray(ours.frequency_response(omega).complex).ravel(),
                               np.asarray(theirs.frequency_response(omega).complex).ravel(), rtol=1e-7, atol=1e-9)


def test_its_margins_are_the_independent_loop_s(qube):
    model, controller = qube
    found = rig_analysis(model, controller, delay=T / 2, rate_filter=HZ)
    assert found["stable"]
    margins = found["margins"]
    L, poles = _independent(model, controller)
    assert np.max(np.abs(poles)) < 1.0
    assert found["spectral_radius"] == pytest.approx(float(np.max(np.abs(poles))), abs=1e-9)
    omega = np.logspace(-3, math.log10(math.pi / T * (1 - 1e-9)), 4000)
    response = np.asarray(L.frequency_response(omega).complex).ravel()
    assert margins.ms == pytest.approx(float(np.max(np.abs(1 / (1 + response)))), rel=1e-6)
    assert margins.mt == pytest.approx(float(np.max(np.abs(response / (1 + response)))), rel=1e-6)
    # the upper gain margin: the independent loop is stable just below it, unstable just above
    high = margins.gain[1]
    assert np.max(np.abs(_independent(model, controller, 0.999 * high)[1])) < 1.0
    assert np.max(np.abs(_independent(model, controller, 1.001 * high)[1])) > 1.0
    # and narrower than the full-state loop's on every count it shares
    full = loop_margins(model, controller)
    assert high < 0.6 * full.gain[1] and margins.phase < full.phase - 10 and margins.ms > full.ms + 0.2


def test_analyze_prints_the_rig_s_loop_beside_the_full_state_one(capsys):
    code, out, err = run_cli(capsys, "analyze", "lqr-qube", "--rig", "--board-delay", "0.002", "--json")
    assert code == 0, err
    import json

    document = json.loads(out)
    assert document["rig"]["delay"] == 0.002 and document["rig"]["rate_filter"] == 40.0
    assert document["rig"]["margins"]["gain"][1] < document["margins"]["gain"][1]
    code, out, err = run_cli(capsys, "analyze", "lqr-qube", "--board-delay", "0.002")
    assert code == 2 and "give --rig" in err
    # a delay long enough to break the loop on the rig: the exit code says so
    code, out, err = run_cli(capsys, "analyze", "lqr-qube", "--rig", "--board-delay", "0.02")
    assert code == 1 and "the loop is UNSTABLE" in out, out
