"""Malformed scenario files: one clear line naming file, key and expectation; exit 2."""

import pytest
from helpers import run_cli

from furuta_cosim.cli import main
from furuta_cosim.references import KINDS

BASE = """\
plant: {model: furuta, initial: {theta1: 0.1}}
timing: {duration: 0.1}
reference: {output: theta0, signal: {type: constant, value: 0}}
controllers: [lqr-paper]
"""


def edit(old, new):
    assert old in BASE
    return BASE.replace(old, new)


CASES = {
    "yaml-syntax": ("plant: {model: furuta\ntiming: [", "line 2: invalid YAML"),
    "not-a-mapping": ("- plant\n- timing\n", "expected a mapping, got a list of 2"),
    "missing-plant": (edit("plant: {model: furuta, initial: {theta1: 0.1}}\n", ""), "plant: missing"),
    "missing-timing": (edit("timing: {duration: 0.1}\n", ""), "timing: missing"),
    "missing-controllers": (edit("controllers: [lqr-paper]\n", ""), "controllers: missing"),
    "unknown-key": (BASE + "colour: blue\n", "colour: unknown key (expected one of:"),
    "negative-duration": (edit("duration: 0.1", "duration: -1"), "timing.duration: must be > 0, got -1"),
    "zero-duration": (edit("duration: 0.1", "duration: 0"), "timing.duration: must be > 0, got 0"),
    "negative-period": (edit("duration: 0.1", "duration: 0.1, control_period: -1"),
                        "timing.control_period: must be > 0, got -1"),
    "period-not-multiple": (edit("duration: 0.1", "duration: 0.1, control_period: 0.0025, communication_step: 0.001"),
                            "timing.control_period: must be a whole multiple of timing.communication_step (0.001), got 0.0025"),
    "nan-duration": (edit("duration: 0.1", "duration: .nan"), "timing.duration: must be finite, got nan"),
    "string-duration": (edit("duration: 0.1", "duration: ten"), "timing.duration: expected a number, got a string ('ten')"),
    "unknown-signal": (edit("type: constant, value: 0", "type: chirp, value: 0"),
                       "reference.signal.type: expected one of " + ", ".join(KINDS) + ", got 'chirp'"),
    "zero-sine-period": (edit("type: constant, value: 0", "type: sine, amplitude: 1, period: 0"),
                         "reference.signal.period: must be > 0, got 0"),
    "step-without-amplitude": (edit("type: constant, value: 0", "type: step, time: 1"),
                               "reference.signal.amplitude: missing"),
    "table-times-decrease": (edit("type: constant, value: 0", "type: table, points: [[0, 0], [2, 1], [1, 0]]"),
                             "reference.signal.points: times must increase"),
    "square-duty": (edit("type: constant, value: 0", "type: square, amplitude: 1, period: 2, duty: 1.5"),
                    "reference.signal.duty: must be between 0 and 1, got 1.5"),
    "negative-seed": (BASE + "noise: {seed: -3}\n", "noise.seed: must be >= 0, got -3"),
    "negative-noise": (BASE + "noise: {seed: 1, process: {tau1: -0.1}}\n", "noise.process.tau1: must be >= 0, got -0.1"),
    "noise-on-control-input": (BASE + "noise: {seed: 1, process: {V: 0.1}}\n",
                               "noise.process.V: not a disturbance input (inputs besides V: tau0, tau1)"),
    "noise-on-unknown-signal": (BASE + "noise: {seed: 1, measurement: {theta9: 0.1}}\n",
                                "noise.measurement.theta9: not a fed-back signal (fed back: theta0, dtheta0, theta1, dtheta1, i)"),
    "pulse-without-duration": (BASE + "disturbances: [{input: tau1, start: 1, value: 0.1}]\n",
                               "disturbances[0].duration: missing"),
    "pulse-on-unknown-input": (BASE + "disturbances: [{input: tau9, start: 0, duration: 0.01, value: 0.1}]\n",
                               "disturbances[0].input: not a disturbance input"),
    "unknown-state": (edit("initial: {theta1: 0.1}", "initial: {theta7: 0.1}"),
                      "plant.initial.theta7: not a state (states: theta0, dtheta0, theta1, dtheta1, i)"),
    "unknown-parameter": (edit("initial: {theta1: 0.1}", "overrides: {mass: 1}"),
                          "plant.overrides.mass: not a parameter of paper-calibrated"),
    "unknown-plant": (edit("model: furuta", "model: segway"), "plant.model: segway: no such plant file or name"),
    "nan-initial": (edit("theta1: 0.1", "theta1: .nan"), "plant.initial.theta1: must be finite, got nan"),
    "unknown-controller": (edit("[lqr-paper]", "[lqr-papr]"),
                           "controllers[0]: lqr-papr: no such controller file or name"),
    "controller-does-not-fit": (edit("[lqr-paper]", "[lqr-paper, toy-classical]"),
                                "controllers[1]: "),
    "zero-actuator-limit": (BASE + "actuator: {limit: 0}\n", "actuator.limit: must be > 0, got 0"),
    "unknown-output": (edit("output: theta0", "output: phi"),
                       "reference.output: not an output (outputs: theta0, dtheta0, theta1, dtheta1, i)"),
    "requirement-without-bound": (BASE + "requirements: [{metric: u.peak_abs}]\n",
                                  "requirements[0]: expected a bound: max and/or min"),
    "requirement-bad-metric": (BASE + "requirements: [{metric: peak, max: 1}]\n",
                               "requirements[0].metric: expected <signal>.<metric>"),
    "requirement-unknown-metric": (BASE + "requirements: [{metric: theta1.SettlingTme, max: 1}]\n",
                                   "requirements[0].metric: theta1 has no metric 'SettlingTme' (expected one of: RiseTime,"),
    "requirement-unknown-signal": (BASE + "requirements: [{metric: thet1.max_abs, max: 1}]\n",
                                   "requirements[0].metric: no signal 'thet1' is recorded"),
    "table-not-pairs": (edit("type: constant, value: 0", "type: table, points: [1, 2]"),
                        "reference.signal.points: expected a list of [time, value] pairs"),
    "unknown-estimator": (BASE + "estimator: {type: luenberger, measured: [theta0]}\n",
                          "estimator.type: expected one of kalman, got 'luenberger'"),
    # silently accepted before: the model was ignored, one input got two disturbances' values
    "empty-plant": (edit("plant: {model: furuta, initial: {theta1: 0.1}}", "plant: {}"),
                    "plant: expected model (a plant name or file) or fmu"),  # found by tests/test_fuzz.py
    "model-and-fmu": (edit("model: furuta,", "model: furuta, fmu: other.fmu,"),
                      "plant: model and fmu both given"),
    "two-disturbances-one-input": (edit("initial: {theta1: 0.1}}", "initial: {theta1: 0.1}, mapping: "
                                        "{disturbances: {tau0: arm_torque, tau1: arm_torque}}}"),
                                   "plant.mapping.disturbances: two disturbances act on the same FMU input (arm_torque)"),
    "estimator-unknown-output": (BASE + "estimator: {type: kalman, measured: [theta0, psi]}\n",
                                 "estimator.measured: 'psi' is not an output"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_scenario(tmp_path, capsys, case):
    text, expected = CASES[case]
    path = tmp_path / f"{case}.yaml"
    path.write_text(text)
    code, out, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    lines = err.strip().splitlines()
    assert code == 2, (out, err)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"error: {path}: ") and expected in lines[0], lines[0]
    assert out == "" and not (tmp_path / "out").exists()


def test_missing_scenario_file(tmp_path, capsys):
    path = tmp_path / "nowhere.yaml"
    assert main(["simulate", str(path)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {path}: file not found"


def test_unknown_scenario_name(capsys):
    assert main(["simulate", "paper-stepp"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: paper-stepp: no such scenario file or name (known: ") and "paper-step" in err


def test_controller_that_does_not_fit_names_its_file_and_key(tmp_path, capsys):
    path = tmp_path / "mixed.yaml"
    path.write_text(CASES["controller-does-not-fit"][0])
    main(["simulate", str(path)])
    err = capsys.readouterr().err
    assert "controllers[1]: " in err
    assert "toy-classical.yaml: K: expected 5 values per row (plant paper-calibrated has 5 states), got 2" in err


def test_all_problems_of_a_file_are_reported_at_once(tmp_path, capsys):
    path = tmp_path / "many.yaml"
    path.write_text("plant: {model: furuta}\ntiming: {duration: -1, control_period: 0}\n"
                    "controllers: []\nextra: 1\n")
    assert main(["simulate", str(path)]) == 2
    err = capsys.readouterr().err
    for expected in ("extra: unknown key", "timing.duration: must be > 0", "timing.control_period: must be > 0",
                     "controllers: expected at least one controller"):
        assert expected in err


@pytest.mark.parametrize("edit_from, edit_to, expected", [
    ("duration: 0.1", "duraton: 0.1", "timing.duraton: unknown key (expected one of: communication_step, "
                                      "control_period, delay, duration); did you mean 'duration'?"),
    ("type: constant, value: 0", "type: sinus, amplitude: 1, period: 1",
     "got 'sinus'; did you mean 'sine'?"),
    ("controllers: [lqr-paper]", "controllers: [lqr-papr]", "; did you mean 'lqr-paper'?"),
])
def test_a_misspelt_name_gets_a_did_you_mean(tmp_path, capsys, edit_from, edit_to, expected):
    path = tmp_path / "s.yaml"
    path.write_text(BASE.replace(edit_from, edit_to))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 2 and expected in err, err
