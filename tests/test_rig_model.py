"""What a real rig adds to the Furuta model: Coulomb friction, the encoder cable, end stops;
and how linear models treat the friction."""

import math

import numpy as np
import pytest

from furuta_cosim.errors import FmuError
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.session import PlantSession

from helpers import run_cli


@pytest.fixture(scope="module")
def qube():
    with PlantSession.open(build_fmu("qube-servo-3")) as session:
        yield session


def _run(session, parameters, seconds, h=0.002, V=0.0, outputs=("theta0", "theta1")):
    session.reset(parameters=parameters)
    session.set_io(inputs=["V"], outputs=list(outputs))
    return np.array([session.step([V], h) for _ in range(int(round(seconds / h)))])


def _peaks(y):
    k = np.nonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]))[0] + 1
    return y[k]


def test_coulomb_friction_makes_a_free_swing_decay_linearly(qube):
    still = {"I_a": 1.0, "C1": 0.0, "Tc1": 5e-6, "theta1_start": math.pi + 0.08}
    swing = _run(qube, still, 20.0)[:, 1] - math.pi
    peaks = _peaks(swing)
    peaks = peaks[peaks > 0.01]
    drops = -np.diff(peaks)
    # the classic result: a Coulomb torque Tc takes 4 Tc / k off the amplitude each period,
    # k = m_p g l_p the pendulum's stiffness about hanging
    k = 0.024 * 9.7807 * 0.064325
    assert np.median(drops) == pytest.approx(4 * 5e-6 / k, rel=0.1)
    assert np.std(drops) < 0.2 * np.median(drops)  # the same drop every period: linear decay
    viscous = _run(qube, {**still, "Tc1": 0.0, "C1": 2e-5}, 20.0)[:, 1] - math.pi
    ratios = _peaks(viscous)[1:] / _peaks(viscous)[:-1]
    assert np.std(ratios) < 0.01  # exponential: the same ratio every period


def test_the_cable_pulls_the_arm_to_its_rest_angle(qube):
    y = _run(qube, {"K_c": 2.4e-3, "theta0_rest": 0.3, "C0": 4e-4, "Tc0": 0.0}, 20.0)
    assert y[-1, 0] == pytest.approx(0.3, abs=1e-3)
    free = _run(qube, {"K_c": 0.0, "theta0_rest": 0.3, "C0": 4e-4, "Tc0": 0.0}, 2.0)
    assert np.all(free[:, 0] == 0.0)  # no cable: nothing moves the arm


def test_end_stops_hold_the_arm_and_only_ever_push(qube):
    stops = {"theta0_min": -2.0, "theta0_max": 2.0, "K_stop": 5.0, "D_stop": 0.02}
    y = _run(qube, stops, 1.0, V=7.0)
    # it hits at about 13 rad/s: the spring takes the arm's energy within sqrt(2 E / K) = 0.1
    # rad, then the stall torque (M_f 7 V / R_a = 0.039 N m) holds it 8 mrad in
    assert 2.0 < y[:, 0].max() < 2.12
    assert y[-1, 0] == pytest.approx(2.0 + 0.0422 * 7.0 / 7.5 / 5.0, abs=2e-3)
    loose = _run(qube, {**stops, "K_stop": 0.0, "D_stop": 0.0}, 1.0, V=7.0)
    assert loose[-1, 0] > 5.0  # without stops the arm runs on


def test_rig_parameters_out_of_range_are_refused(qube):
    for bad in ({"Tc0": -1e-3}, {"K_c": -1.0}, {"K_stop": 1.0, "theta0_min": 1.0, "theta0_max": -1.0},
                {"w_c": 0.0}):
        with pytest.raises(FmuError):
            qube.reset(parameters=bad)


def test_linear_models_leave_coulomb_friction_out_and_say_so(capsys):
    from furuta_cosim.models import derived, linearize_plant

    model = derived("qube-servo-3")
    assert "Coulomb friction (Tc0 = 2.91e-05, Tc1 = 6.1e-06) is left out" in model.provenance["note"]
    _, _, result, note = linearize_plant("qube-servo-3")
    assert note == model.provenance["note"]
    # the arm's damping in A is the viscous C0 alone, not C0 + Tc0 / w_c
    without = np.array(model.A)
    assert abs(without[1, 1]) < 10 and np.all(np.isfinite(without))
    paper = derived("paper-calibrated")
    assert "note" not in paper.provenance
    code, out, err = run_cli(capsys, "design", "lqr", "--model", "derived:qube-servo-3", "--json")
    assert code == 0 and "left out of the linear model" in err
    import json

    assert json.loads(out)["notes"] == [model.provenance["note"]]


def test_fmi3_builds_carry_the_rig_terms():
    from pathlib import Path

    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import open_session, simulate, target_for

    experiment = load_experiment(Path(__file__).resolve().parent.parent / "scenarios" / "rigs"
                                 / "qube-servo-3" / "motor-7V.yaml")
    results = []
    for version in ("2.0", "3.0"):
        target = target_for(plant="qube-servo-3", fmi_version=version)
        with open_session(target) as session:
            results.append(simulate(session, target, experiment, {"K_stop": 5.0, "theta0_max": 1.0}))
    two, three = results
    assert two["theta0"].max() < 1.1  # the stop held: the terms are in the build
    for name in ("theta0", "i"):
        np.testing.assert_allclose(three[name], two[name], rtol=0, atol=1e-12)
