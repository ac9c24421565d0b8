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


def test_peaks_of_the_sensitivities_are_the_known_ones():
    # L = 2/(s - 1): S = (s - 1)/(s + 1) is all-pass (|S| = 1 at every frequency) and
    # T = 2/(s + 1) peaks at w = 0 with |T| = 2
    m = loop_margins(_unstable_first_order(), GeneralizedController.static([[2.0]]))
    assert m.ms == pytest.approx(1.0, abs=1e-6)
    assert m.mt == pytest.approx(2.0, rel=1e-5) and m.mt_at < 0.01


def _sampled_closed_loop_radius(model, controller, period: float, k: float) -> float:
    """The spectral radius of the sampled loop with the plant's input scaled by k, built from
    scipy's zero-order hold alone (not python-control's, not this project's)."""
    from scipy.signal import cont2discrete

    n, m = model.A.shape[0], model.B.shape[1]
    Phi, Gam, *_ = cont2discrete((model.A, model.B, np.eye(n), np.zeros((n, m))), period, method="zoh")
    nc = controller.Ac.shape[0]
    if nc:
        Ad, Bd, *_ = cont2discrete((controller.Ac, controller.Bc, controller.Cc, controller.Dc), period,
                                   method="zoh")
        top = np.hstack([Phi - k * Gam @ controller.Dc, -k * Gam @ controller.Cc])
        closed = np.vstack([top, np.hstack([Bd, Ad])])
    else:
        closed = Phi - k * Gam @ controller.Dc
    return float(np.max(np.abs(np.linalg.eigvals(closed))))


def test_a_continuous_controller_has_the_margins_of_the_sampled_loop_that_runs():
    # the paper's generalized controller, continuous, runs at 2 ms: its input-gain range is the
    # sampled loop's (about 0.64 to 3.14), far narrower at the top than the continuous loop's
    # (about 13.8); checked against the sampled loop's eigenvalues built independently
    from furuta_cosim.lqr_file import analyze_file

    found = analyze_file("bo-paper")
    analysis, model, controller = found.analysis, found.model, found.cfile.controller
    assert not controller.discrete and analysis.sampled is not None
    running, designed = analysis.running_margins, analysis.margins
    assert running is analysis.sampled.margins and designed is not None
    period = analysis.sampled.period
    low, high = running.gain
    for k, stable in ((low * 1.01, True), (high * 0.99, True), (low * 0.99, False), (high * 1.01, False)):
        assert (_sampled_closed_loop_radius(model, controller, period, k) < 1.0) is stable, k
    assert high < 0.5 * designed.gain[1]     # the hold's delay costs most of the upper margin
    verdict = analysis.verdict()
    assert any(line.startswith("Margins of the loop that runs (the sampled loop") for line in verdict)
    assert any("continuous loop as designed (not the loop that runs)" in line for line in verdict)
    document = analysis.as_dict()
    assert document["margins"]["gain"][1] == pytest.approx(high)
    assert document["margins_continuous"]["gain"][1] == pytest.approx(designed.gain[1])
    assert "sampled loop" in document["margins_of"]


def test_analyze_plot_writes_bode_nyquist_and_sensitivity(capsys, tmp_path):
    code, out, err = run_cli(capsys, "analyze", "bo-paper", "--plot", str(tmp_path / "loop"))
    assert code == 0, err
    for name in ("bode", "nyquist", "sensitivity"):
        for suffix in (".png", ".svg"):
            path = tmp_path / "loop" / f"{name}{suffix}"
            assert path.stat().st_size > 5000, path
    assert (tmp_path / "loop" / "bode.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in err and "Ms " in out and "Mt " in out
