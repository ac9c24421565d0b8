"""Linearization of the FMUs reproduces the paper's printed A and B (paper-readings §1)."""

import json

import numpy as np
import pytest

from furuta_cosim.cli import main
from furuta_cosim.fmu.linearize import linearize

# The paper's printed A and B (Sec. V-B); row 1's "1 0" is a typo for 1.
PRINTED_A = [["0", "1", "0", "0", "0"],
             ["0", "-0.31", "2.99", "-0.02", "81.47"],
             ["0", "0", "0", "1", "0"],
             ["0", "-0.02", "61.49", "-0.5", "63.88"],
             ["0", "-261.94", "0", "0", "-800"]]
PRINTED_B = ["0", "0", "0", "0", "100"]


def decimals(text):
    return len(text.split(".")[1]) if "." in text else 0


def run_json(capsys, *argv):
    assert main(list(argv)) == 0
    return json.loads(capsys.readouterr().out)


def test_cli_reproduces_every_printed_entry_but_a22(capsys):
    result = run_json(capsys, "linearize", "--json")
    assert result["states"] == ["theta0", "dtheta0", "theta1", "dtheta1", "i"]
    assert result["inputs"] == ["V", "tau0", "tau1"]
    A, B = np.array(result["A"]), np.array(result["B"])
    mismatches = []
    for i in range(5):
        for j in range(5):
            printed = PRINTED_A[i][j]
            if round(A[i, j], decimals(printed)) != float(printed):
                mismatches.append((i + 1, j + 1, A[i, j], printed))
        if round(B[i, 0], decimals(PRINTED_B[i])) != float(PRINTED_B[i]):
            mismatches.append(("B", i + 1, B[i, 0], PRINTED_B[i]))
    # A(2,2) alone differs: derived -0.031 against the printed -0.31 (paper-readings §1)
    assert [m[:2] for m in mismatches] == [(2, 2)]
    assert A[1, 1] == pytest.approx(-0.0311, abs=5e-5)
    np.testing.assert_allclose(np.array(result["C"]), np.eye(5), atol=1e-9)
    np.testing.assert_allclose(np.array(result["D"]), 0.0, atol=1e-9)


def test_disturbance_inputs_enter_the_mechanics(capsys):
    B = np.array(run_json(capsys, "linearize", "--json")["B"])
    # tau0 acts on the arm and, through the coupling, on the pendulum; never on the current
    assert B[1, 1] > 0 and B[3, 1] > 0 and B[3, 2] > B[3, 1] and B[4, 1] == 0.0


def test_table_literal_gives_the_unphysical_back_emf(capsys):
    A = np.array(run_json(capsys, "linearize", "--params", "table-literal", "--json")["A"])
    assert A[4, 1] == pytest.approx(-0.0214 * 59927 / 0.010, rel=1e-9)  # about -1.3e5


def test_toy_plant_linearizes_exactly(toy_fmu):
    result = linearize(toy_fmu, inputs={"u": 0.0})
    np.testing.assert_allclose(result.A, [[0.5, 0.0], [0.7, 1.2]], atol=1e-12)
    np.testing.assert_allclose(result.B, [[0.0], [0.1]], atol=1e-12)
    assert result.outputs == ["y", "x1", "x2"] and result.period == 1.0
    np.testing.assert_allclose(result.C[0], [1.0, 1.0], atol=1e-12)


def test_linearization_at_an_offset_state_sees_the_nonlinearity(furuta_fmu):
    upright = linearize(furuta_fmu, inputs={"V": 0.0})
    tilted = linearize(furuta_fmu, state={"theta1": 0.5}, inputs={"V": 0.0})
    # gravity's stiffness falls with cos(theta1) (and the inertia changes too)
    assert tilted.A[3, 2] < 0.9 * upright.A[3, 2]
