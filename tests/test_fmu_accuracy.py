"""Accuracy of the FMU against an independent integration of the paper's equations.

The oracle below is written from the paper (Sec. III, with the readings of docs/pages/paper-readings.md §1):
the Euler-Lagrange form M1(q) q'' + M2(q, q') q' + M3(q) = T with the motor's electrical
equation, solved by scipy's Radau at rtol 1e-11. It shares no code with the C model.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.fmu.session import PlantSession

from helpers import STATES


def paper_rhs(p, voltage):
    J0 = p["I_a"] + p["r"] ** 2 * (p["m_p"] + p["m_c"]) + p["N"] ** 2 * p["I_m"]
    J1 = p["I_p"] + p["m_p"] * p["l_p"] ** 2
    mp, lp, r, g = p["m_p"], p["l_p"], p["r"], p["g"]

    def rhs(t, x):
        th0, w0, th1, w1, i = x
        M1 = np.array([[J0 + mp * lp**2 * np.sin(th1) ** 2, -mp * r * lp * np.cos(th1)],
                       [-mp * r * lp * np.cos(th1), J1]])
        M2 = np.array([[mp * lp**2 * w1 * np.sin(2 * th1) + p["C0"], mp * r * lp * w1 * np.sin(th1)],
                       [-0.5 * mp * lp**2 * w0 * np.sin(2 * th1), p["C1"]]])
        M3 = np.array([0.0, -mp * g * lp * np.sin(th1)])
        T = np.array([p["M_f"] * p["N"] * i, 0.0])
        qdd = np.linalg.solve(M1, T - M2 @ np.array([w0, w1]) - M3)
        di = (voltage - p["R_a"] * i - p["M_f"] * p["N"] * w0) / p["L_a"]
        return [w0, qdd[0], w1, qdd[1], di]

    return rhs


def fmu_run(fmu, substeps, steps=500, h=1e-3, voltage=1.0):
    with PlantSession.open(fmu) as plant:
        plant.reset({"theta1_start": 0.1, "n_substeps": substeps})
        plant.set_io(["V"], STATES)
        return np.array([plant.step([voltage], h) for _ in range(steps)])


@pytest.fixture(scope="module")
def oracle():
    parameters = dict(load_plant("paper-calibrated").parameters)
    t = np.arange(1, 501) * 1e-3
    solution = solve_ivp(paper_rhs(parameters, 1.0), (0.0, 0.5), [0, 0, 0.1, 0, 0], method="Radau",
                         rtol=1e-11, atol=1e-13, t_eval=t)
    assert solution.success
    return solution.y.T


def test_fmu_matches_the_paper_equations(furuta_fmu, oracle):
    fmu = fmu_run(furuta_fmu, substeps=10)
    assert np.max(np.abs(fmu[:, 2] - oracle[:, 2])) <= 1e-7
    # the run is not trivial: the pendulum and the arm moved
    assert abs(oracle[-1, 2] - 0.1) > 0.05 and abs(oracle[-1, 0]) > 1e-3


def test_halving_the_substep_changes_theta1_by_less_than_1e_8(furuta_fmu):
    coarse, fine = fmu_run(furuta_fmu, substeps=10), fmu_run(furuta_fmu, substeps=20)
    assert np.max(np.abs(coarse[:, 2] - fine[:, 2])) < 1e-8


def test_voltage_limit_saturates_inside_the_fmu(furuta_fmu):
    with PlantSession.open(furuta_fmu) as plant:
        plant.reset({"V_max": 2.0})
        plant.set_io(["V"], STATES)
        limited = np.array([plant.step([12.0], 1e-3) for _ in range(50)])
        plant.reset()
        at_limit = np.array([plant.step([2.0], 1e-3) for _ in range(50)])
    np.testing.assert_array_equal(limited, at_limit)


def test_continuous_linear_plant_fmu_matches_the_matrix_exponential():
    from scipy.linalg import expm

    from furuta_cosim.fmu.exporter import build_fmu

    plant = load_plant("paper-printed")
    A, B = np.array(plant.linear.A), np.array(plant.linear.B)
    with PlantSession.open(build_fmu(plant)) as session:
        session.reset({"theta1_start": 0.1})
        session.set_io(["V"], STATES)
        fmu = np.array([session.step([0.5], 1e-3) for _ in range(300)])
    # exact ZOH solution with constant input: x(t) = e^{At} x0 + int_0^t e^{As} ds B u
    M = expm(np.block([[A, B], [np.zeros((1, 6))]]) * 0.3)
    exact = M[:5, :5] @ np.array([0, 0, 0.1, 0, 0]) + M[:5, 5] * 0.5
    np.testing.assert_allclose(fmu[-1], exact, rtol=1e-8, atol=1e-10)
