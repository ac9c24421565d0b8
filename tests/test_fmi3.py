"""FMI 3.0 plants from another exporter: the foreign pendulum built by pythonfmu3
(tests/foreign/pendulum3_fmu.py: co-simulation and model exchange, Float64 variables, the
states' start values on the states themselves) runs the scenarios, regress, simulate and tune
as the same pendulum exported for FMI 2.0 by pythonfmu does."""

import json
import shutil

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.fmu.session import PlantSession, PlantSession3
from furuta_cosim.regression import regress
from furuta_cosim.scenario import load_scenario

from helpers import FOREIGN, build_foreign, run_cli, scheduled_only

STATES = "{theta0: arm_angle, dtheta0: arm_rate, theta1: pend_angle, dtheta1: pend_rate, i: current}"
PLANT = """\
plant:
  fmu: %s
  initial: {theta1: 0.1}
  control_input: voltage
  mapping:
    states: %s
    disturbances: {tau0: arm_torque, tau1: pend_torque}
%s"""


@pytest.fixture(scope="module")
def fmi3(tmp_path_factory, foreign_fmu):
    """A folder with ForeignPendulum3.fmu, ForeignPendulum.fmu (FMI 2.0) and paper-step mapped
    onto each."""
    folder = tmp_path_factory.mktemp("fmi3")
    build_foreign("pythonfmu3", FOREIGN / "pendulum3_fmu.py", folder, FOREIGN / "pendulum_physics.py")
    shutil.copy(foreign_fmu, folder / foreign_fmu.name)
    text = load_scenario("paper-step").path.read_text()
    plant = text[text.index("plant:"):text.index("timing:")]
    (folder / "step3.yaml").write_text(text.replace(plant, PLANT % ("ForeignPendulum3.fmu", STATES, "")))
    (folder / "step2.yaml").write_text(text.replace(plant, PLANT % (
        "ForeignPendulum.fmu", STATES, "    initial: {theta1: pend_angle_0}\n")))
    return folder


def run(path):
    prepared = prepare(load_scenario(path))
    with PlantSession.open(prepared.fmu) as session:
        return prepared, session, evaluate(prepared, session, "lqr-paper")


@pytest.mark.slow
def test_the_fmi3_pendulum_runs_paper_step_as_its_fmi2_twin(fmi3):
    prepared, session, result = run(fmi3 / "step3.yaml")
    _, _, twin = run(fmi3 / "step2.yaml")
    assert isinstance(session, PlantSession3)
    assert prepared.start == {"pend_angle": 0.1}  # on the state itself: it has no start parameter
    assert result.passed and len(result.trace.t) == 5000
    assert result.trace["theta1"][0] == 0.1 and np.max(np.abs(result.trace["theta0"])) > 1e-3
    for name in ("theta0", "dtheta0", "theta1", "dtheta1", "i"):
        assert np.max(np.abs(result.trace[name] - twin.trace[name])) <= 1e-12, name
    assert prepared.units["theta1"] == "rad" and prepared.units["dtheta1"] == "rad/s"


@pytest.mark.slow
def test_simulate_and_regress_take_the_fmi3_plant(fmi3, tmp_path, capsys):
    code, out, err = run_cli(capsys, "simulate", str(fmi3 / "step3.yaml"), "--controller", "lqr-paper",
                             "-o", str(tmp_path / "run"), "--json")
    assert code == 0, err
    assert json.loads(out)["passed"]
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(f"control_input: voltage\nstates: {STATES}\n"
                       "disturbances: {tau0: arm_torque, tau1: pend_torque}\n")
    report = regress(["paper-step"], fmu=fmi3 / "ForeignPendulum3.fmu", mapping=mapping, workers=1)
    assert [c.status for c in report.cases] == ["pass", "pass"], [c.lines() for c in report.cases]


@pytest.mark.slow
def test_tune_takes_the_fmi3_plant(fmi3, tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"""\
controller: {{n_xc: 0, time: continuous, period: 0.002, model: paper-printed}}
parameters:
  Dc: {{lqr: [-2, 3], R: 10}}
objective:
  type: scenarios
  scenarios: [{fmi3 / 'step3.yaml'}]
  terms: [{{metric: error.ISE}}]
constraints: {{requirements: false}}
optimizer: {{method: random, n_calls: 4, seed: 1, batch: 1}}
""")
    code, out, err = run_cli(capsys, "tune", str(spec), "-o", str(tmp_path / "run"), "--workers", "1")
    assert code == 0, err
    lines = [json.loads(line) for line in (tmp_path / "run" / "history.jsonl").read_text().splitlines()]
    assert len(lines) == 4 and any(line.get("feasible") for line in lines)


def test_scheduled_execution_only_is_one_line(fmi3, tmp_path, capsys):
    """An FMU with clocks that offers only scheduled execution is named, not run."""
    target = scheduled_only(fmi3 / "ForeignPendulum3.fmu", tmp_path / "Scheduled.fmu")
    code, _, err = run_cli(capsys, "simulate", "paper-step", "--fmu", str(target), "-o", str(tmp_path / "o"))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "not an FMI 2.0 or 3.0 co-simulation FMU (FMI 3.0, scheduled execution only)" in err


MAPPING_FILE = ("control_input: voltage\nstates: " + STATES + "\n"
                "disturbances: {tau0: arm_torque, tau1: pend_torque}\n")


def test_linearize_and_design_on_the_foreign_plant_match_ours(fmi3, tmp_path, capsys):
    """Through model exchange: the states from the model structure, named by the mapping."""
    from furuta_cosim.models import load_model

    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING_FILE)
    fmu = fmi3 / "ForeignPendulum3.fmu"
    theirs, ours = load_model(f"{fmu}#{mapping}"), load_model("derived")
    assert theirs.states == ours.states == ("theta0", "dtheta0", "theta1", "dtheta1", "i")
    # the same physics written twice: equal to the finite differences' accuracy
    np.testing.assert_allclose(theirs.A, ours.A, rtol=1e-6, atol=1e-6 * np.abs(ours.A).max())
    np.testing.assert_allclose(theirs.B, ours.B, rtol=1e-6)
    code, out, err = run_cli(capsys, "design", "lqr", "--model", str(fmu), "--mapping", str(mapping),
                             "-o", str(tmp_path / "theirs.yaml"), "--json")
    assert code == 0, err
    K = np.array(json.loads(out)["K"])
    code, out, _ = run_cli(capsys, "design", "lqr", "--model", "derived", "--json")
    np.testing.assert_allclose(K, np.array(json.loads(out)["K"]), rtol=1e-5)
    # the file names its model with the mapping: analyze finds both again
    code, out, err = run_cli(capsys, "analyze", str(tmp_path / "theirs.yaml"))
    assert code == 0 and "The closed loop is stable" in out, err
    code, out, err = run_cli(capsys, "linearize", "--fmu", str(fmu), "--mapping", str(mapping), "--json")
    assert code == 0 and json.loads(out)["states"] == list(ours.states)


def test_a_cosimulation_only_fmu_cannot_be_linearized_and_says_so(foreign_fmu, capsys):
    code, _, err = run_cli(capsys, "design", "lqr", "--model", str(foreign_fmu))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "linearization needs model exchange" in err and "has only co-simulation" in err


def test_a_mapping_that_leaves_a_state_out_is_one_line(fmi3, tmp_path, capsys):
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING_FILE.replace(", i: current", ""))
    code, _, err = run_cli(capsys, "linearize", "--fmu", str(fmi3 / "ForeignPendulum3.fmu"),
                           "--mapping", str(mapping))
    assert code == 2 and err.strip() == f"error: {mapping}: states: the FMU's states current are not mapped"


@pytest.mark.slow
def test_the_kalman_scenario_runs_on_the_fmi3_plant_and_is_unfit_for_a_cosimulation_only_one(
        fmi3, foreign_fmu, tmp_path):
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING_FILE)
    report = regress(["noise-kalman", "paper-step"], fmu=fmi3 / "ForeignPendulum3.fmu", mapping=mapping, workers=1)
    assert [c.status for c in report.cases] == ["pass"] * 4, [c.lines() for c in report.cases]
    mapping.write_text(MAPPING_FILE + "initial: {theta1: pend_angle_0}\n")
    report = regress(["noise-kalman", "paper-step"], fmu=foreign_fmu, mapping=mapping, workers=1)
    statuses = {(c.scenario, c.controller): c.status for c in report.cases}
    assert statuses == {("noise-kalman", "lqr-paper"): "unfit", ("noise-kalman", "bo-paper"): "unfit",
                        ("paper-step", "lqr-paper"): "pass", ("paper-step", "bo-paper"): "pass"}
    line = next(c for c in report.cases if c.status == "unfit").lines()[0]
    assert "through model exchange, which ForeignPendulum.fmu does not offer" in line


def test_an_fmu_that_asks_to_end_fails_the_step_alike_on_both_step_paths(tmp_path):
    """A doStep that answers OK but sets terminateSimulation ends the run with a step error
    that says so, whether the step is one call into the compiled helper or three calls."""
    from furuta_cosim.errors import FmuError

    build_foreign("pythonfmu3", FOREIGN / "ending3_fmu.py", tmp_path)
    errors = []
    for one_call in (True, False):
        with PlantSession.open(tmp_path / "EndingPlant3.fmu") as session:
            assert isinstance(session, PlantSession3)
            if not one_call:
                session._step_io = session._step_three_calls
            session.reset()
            session.set_io(["u"], ["x"])
            values = [session.step([1.0], 2e-3)[0] for _ in range(5)]  # up to t = 10 ms
            with pytest.raises(FmuError) as failed:
                session.step([1.0], 2e-3)
            errors.append(str(failed.value))
        np.testing.assert_allclose(values, 2e-3 * np.arange(1, 6), rtol=1e-12)
    assert errors[0] == errors[1], errors
    assert "fmi3DoStep at t = 0.01 failed: the FMU asked to end the simulation" in errors[0], errors
