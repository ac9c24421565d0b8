"""analyze's margins at the plant input, against loops whose margins are known by hand."""

import json
import math

import numpy as np
import pytest

from furuta_cosim.design import GeneralizedController, analyze
from furuta_cosim.design.controller import discretize_controller
from furuta_cosim.design.linear import LinearModel
from furuta_cosim.design.margins import loop_margins

from helpers import run_cli


def _unstable_first_order() -> LinearModel:
    """x' = x + u: unstable open loop."""
    return LinearModel("first-order", np.array([[1.0]]), np.array([[1.0]]), np.array([[1.0]]),
                       np.zeros((1, 1)), ("x",), ("u",), ("x",))


def test_margins_of_a_loop_unstable_open_loop_are_the_known_ones():
    # u = -2 x: L = 2 / (s - 1). Stable for every gain k > 1/2 (s = 1 - 2k), none too high;
    # |L| = 1 at w = sqrt(3), where arg L = -120 deg: a phase margin of 60 deg
    m = loop_margins(_unstable_first_order(), GeneralizedController.static([[2.0]]))
    assert m.gain[0] == pytest.approx(0.5, rel=1e-6) and math.isinf(m.gain[1])
    assert m.phase == pytest.approx(60.0, abs=0.05) and m.crossover == pytest.approx(math.sqrt(3), rel=1e-3)
    # the disk margin guarantees gain and phase at once: inside the separate margins
    low = 10 ** (-m.disk_gain / 20)
    assert 0.5 * (1 - 1e-6) < low < 1.0 and 0 < m.disk_phase < 60.0   # here alpha = 2/3: low = 1/2


def test_a_discrete_controller_has_its_sampled_loop_margins():
    # the same law sampled fast: margins near the continuous ones, the sample's delay costing
    # phase (about w T / 2 = 0.1 deg at 10 ms)
    law = discretize_controller(GeneralizedController.static([[2.0]]), 0.01)
    m = loop_margins(_unstable_first_order(), law)
    assert m.gain[0] == pytest.approx(0.5, rel=0.02) and m.gain[1] > 50
    assert 58.0 < m.phase < 60.0


def test_analyze_prints_the_margins_and_the_slowest_mode(capsys):
    code, out, err = run_cli(capsys, "analyze", "lqr-qube")
    assert code == 0, err
    line = next(l for l in out.splitlines() if l.startswith("Margins at the plant input"))
    assert "dB" in line and "deg at" in line and "disk" in line
    assert "settles (2 %) in about" in out
    code, out, err = run_cli(capsys, "analyze", "lqr-qube", "--json")
    margins = json.loads(out)["margins"]
    assert 0 < margins["gain"][0] < 1 < margins["gain"][1] and margins["phase_deg"] > 30
    assert 0 < margins["disk"] < 2
