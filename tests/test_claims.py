"""Scenarios that test what they claim: the loop's tracking bandwidth, a sine below it, and a
warning for a tracking constraint that an arm that never moves would meet."""

import json

import numpy as np
import pytest

from furuta_cosim.controllers import load_controller
from furuta_cosim.design.prefilter import dc_gain, prefilter, tracking_bandwidth
from furuta_cosim.models import load_model
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

from helpers import run_cli


def gain(model, controller, F, w):
    import control

    from furuta_cosim.design.controller import augmented

    A, B = augmented(model, controller)
    c = np.concatenate([model.output_vector("theta0"), np.zeros(controller.n_xc)])[None, :]
    loop = control.ss(A, B * F, c, 0, controller.period if controller.discrete else 0)
    return float(np.abs(np.squeeze(loop.frequency_response([w]).magnitude)))


def test_the_tracking_bandwidth_is_where_the_gain_falls_3_db():
    model = load_model("paper-printed")
    for name in ("lqr-paper", "bo-paper"):
        controller = load_controller(name).controller
        F = prefilter(model, controller, "theta0")
        w = tracking_bandwidth(model, controller, "theta0", F)
        level = abs(dc_gain(model, controller, "theta0") * F) / np.sqrt(2)
        # python-control's frequency response, an independent evaluation of the same loop
        assert gain(model, controller, F, w) == pytest.approx(level, rel=1e-6), name
        assert all(gain(model, controller, F, v) > level for v in np.linspace(1e-4, 0.98 * w, 40))
    # the LQR's: slower than its slowest mode's 0.11 1/s suggests, far below the 10 s sine
    lqr = load_controller("lqr-paper").controller
    w = tracking_bandwidth(model, lqr, "theta0", prefilter(model, lqr, "theta0"))
    assert 0.09 < w < 0.13 and 2 * np.pi / w < 60.0


def test_analyze_states_the_bandwidth(capsys):
    code, out, _ = run_cli(capsys, "analyze", "lqr-paper", "--model", "paper-printed")
    assert code == 0 and "Tracking bandwidth (-3 dB, r to theta0): 0.11" in out


def still_ratio(scenario, tmp_path, capsys):
    """error.ISE of lqr-paper over that of an arm that never moves, on a scenario."""
    from furuta_cosim.cosim import evaluate, prepare
    from furuta_cosim.cosim.worker import session_for
    from furuta_cosim.metrics import standing_still
    from furuta_cosim.scenario import load_scenario

    prepared = prepare(load_scenario(scenario))
    result = evaluate(prepared, session_for(prepared), "lqr-paper")
    return result.metrics["error.ISE"] / standing_still(result.trace)["error.ISE"]


def test_the_shipped_sine_is_vacuous_and_sine_follow_is_not(tmp_path, capsys):
    assert still_ratio("sine", tmp_path, capsys) > 0.99
    assert still_ratio("sine-follow", tmp_path, capsys) < 0.5


SPEC = """\
name: vacuous
controller: {n_xc: 1, time: continuous, period: 0.002, model: paper-printed}
parameters:
  Ac: {log: [-1, 2], sign: -1}
  Bc: {box: [-1, 1]}
  Cc: {fixed: [[1.0]]}
  Dc: {lqr: [-2, 3], R: 10}
objective:
  type: scenarios
  scenarios: [SCENARIOS]
  terms: [{metric: u.rms}]
constraints: {stability_margin: 0.01, requirements: false,
              no_worse_than: {controller: lqr-paper, metrics: {error.ISE: 1.05}}}
optimizer: {n_calls: 2, n_initial_points: 2}
"""


@pytest.mark.slow  # two tunings: 5.2 to 5.4 s on this 2-core machine, over the quick suite's 5 s
def test_a_vacuous_tracking_constraint_is_said_at_the_start_and_in_the_summary(tmp_path, capsys):
    path = tmp_path / "vacuous.yaml"
    path.write_text(SPEC.replace("SCENARIOS", "sine, noise, paper-step"))
    code, out, err = run_cli(capsys, "tune", str(path), "-o", str(tmp_path / "run"), "--workers", "1")
    assert code in (0, 1), err
    warned = [line for line in err.splitlines() if line.startswith("warning:")]
    # the 10 s sine only: noise and paper-step hold the reference still (regulation)
    assert len(warned) == 1 and "error.ISE is vacuous on sine" in warned[0], err
    assert "Warning: constraints.no_worse_than.error.ISE is vacuous on sine" in out
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert len(summary["warnings"]) == 1
    path.write_text(SPEC.replace("SCENARIOS", "sine-follow"))
    document = tune(load_spec(path), tmp_path / "follow", workers=1)
    assert document["warnings"] == []
