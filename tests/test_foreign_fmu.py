"""A plant FMU that this project did not build, run through a scenario's plant mapping.

The FMU is built here by another exporter (pythonfmu) from tests/foreign/pendulum_fmu.py: the
same pendulum, written independently of fmu_src/furuta, under other variable names.
"""

import json
import shutil

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

from helpers import FOREIGN, build_foreign, run_cli

MAPPING = """\
plant:
  fmu: ForeignPendulum.fmu
  initial: {theta1: 0.1}
  control_input: voltage
  mapping:
    states: {theta0: arm_angle, dtheta0: arm_rate, theta1: pend_angle, dtheta1: pend_rate, i: current}
    disturbances: {tau0: arm_torque, tau1: pend_torque}
    initial: {theta1: pend_angle_0}
"""


@pytest.fixture(scope="module")
def foreign(tmp_path_factory, foreign_fmu):
    """The scenario folder: ForeignPendulum.fmu and paper-step with the plant mapped onto it."""
    folder = tmp_path_factory.mktemp("foreign")
    shutil.copy(foreign_fmu, folder / foreign_fmu.name)
    text = load_scenario("paper-step").path.read_text()
    plant = text[text.index("plant:"):text.index("timing:")]
    (folder / "paper-step-mapped.yaml").write_text(text.replace(plant, MAPPING))
    return folder


def test_the_mapped_fmu_runs_paper_step_as_the_native_one(foreign):
    native = prepare(load_scenario("paper-step"))
    mapped = prepare(load_scenario(foreign / "paper-step-mapped.yaml"))
    assert mapped.plant is None and mapped.states == native.states
    assert mapped.outputs == ["arm_angle", "arm_rate", "pend_angle", "pend_rate", "current"]
    with PlantSession.open(native.fmu) as session:
        a = evaluate(native, session, "lqr-paper")
    with PlantSession.open(mapped.fmu) as session:
        b = evaluate(mapped, session, "lqr-paper")
    assert b.passed and len(b.trace.t) == len(a.trace.t) == 5000
    for name in ("theta0", "theta1"):
        assert np.max(np.abs(a.trace[name] - b.trace[name])) <= 1e-6, name
    # not trivially equal: the pendulum moved
    assert np.max(np.abs(b.trace["theta0"])) > 1e-3
    assert b.metrics["u.peak_abs"] == pytest.approx(a.metrics["u.peak_abs"], rel=1e-6)


def test_the_cli_runs_the_mapped_scenario(foreign, tmp_path, capsys):
    code, out, err = run_cli(capsys, "simulate", str(foreign / "paper-step-mapped.yaml"),
                             "--controller", "lqr-paper", "-o", str(tmp_path), "--json")
    assert code == 0, err
    document = json.loads(out)
    assert document["plant"] == "ForeignPendulum.fmu" and document["passed"]
    header = (tmp_path / "lqr-paper.csv").read_text().splitlines()[0].split(",")
    assert header == ["t", "r", "u", "theta0", "dtheta0", "theta1", "dtheta1", "i"]


@pytest.mark.parametrize("edit, key, expected", [
    ("theta1: pend_angle,", "plant.mapping.states.theta1",
     "ForeignPendulum has no Real output 'pendulum_angle'"),
    ("tau1: pend_torque}", "plant.mapping.disturbances.tau1",
     "ForeignPendulum has no disturbance input 'pendulum_torque'"),
    ("{theta1: pend_angle_0}", "plant.mapping.initial.theta1",
     "ForeignPendulum has no parameter 'pendulum_angle_0'"),
])
def test_a_mapping_naming_a_missing_variable_is_one_line(foreign, tmp_path, capsys, edit, key, expected):
    path = foreign / f"broken-{key.rsplit('.', 2)[1]}.yaml"
    path.write_text((foreign / "paper-step-mapped.yaml").read_text().replace(
        edit, edit.replace("pend_", "pendulum_")))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {path}: {key}: {expected}"), lines[0]


def test_an_unmapped_foreign_fmu_asks_for_a_mapping(foreign, tmp_path, capsys):
    code, _, err = run_cli(capsys, "simulate", "paper-step", "--fmu",
                           str(foreign / "ForeignPendulum.fmu"), "-o", str(tmp_path))
    assert code == 2
    assert "plant.mapping.states: ForeignPendulum does not mark its states" in err


def test_our_own_fmu_given_with_fmu_needs_no_mapping(furuta_fmu, tmp_path, capsys):
    copy = tmp_path / "Furuta.fmu"
    shutil.copy(furuta_fmu, copy)
    native = prepare(load_scenario("paper-step"))
    given = prepare(load_scenario("paper-step"), fmu=copy)
    assert given.start == native.start and given.fmu == copy
    with PlantSession.open(copy) as session:
        a = evaluate(given, session, "lqr-paper")
        b = evaluate(native, session, "lqr-paper")
    np.testing.assert_array_equal(a.trace["theta1"], b.trace["theta1"])
    code, _, err = run_cli(capsys, "simulate", "paper-step", "--fmu", str(tmp_path / "missing.fmu"),
                           "-o", str(tmp_path / "out"))
    assert code == 2 and err == f"error: --fmu {tmp_path / 'missing.fmu'}: no such FMU file\n"


@pytest.fixture(scope="module")
def nan_plant(tmp_path_factory, foreign):
    """paper-step on a pythonfmu plant whose outputs turn NaN at 14 ms, mapped like the
    foreign pendulum."""
    folder = tmp_path_factory.mktemp("nan-plant")
    build_foreign("pythonfmu", FOREIGN / "nan_fmu.py", folder, FOREIGN / "pendulum_physics.py")
    text = (foreign / "paper-step-mapped.yaml").read_text()
    (folder / "paper-step-nan.yaml").write_text(text.replace("ForeignPendulum.fmu", "NanPlant.fmu"))
    return folder


def test_a_plant_output_that_turns_nan_fails_the_run(nan_plant, tmp_path, capsys):
    scenario = nan_plant / "paper-step-nan.yaml"
    prepared = prepare(load_scenario(scenario))
    with PlantSession.open(prepared.fmu) as session:
        result = evaluate(prepared, session, "lqr-paper")
    # the first sample read after the step that crosses 14 ms, named by the scenario's name
    assert result.failure and "output theta0 is nan at t = 0.016" in result.failure, result.failure
    assert not result.passed
    # the metrics come from the samples before it: none of them is NaN
    assert len(result.trace.t) == 8 and all(np.isfinite(result.trace["theta1"]))
    assert not any(np.isnan(v) for v in result.metrics.values() if v is not None)  # inf: never settled
    code, out, err = run_cli(capsys, "simulate", str(scenario), "-o", str(tmp_path / "run"), "--no-trace")
    assert code == 1, (out, err)
    assert "is nan at t = 0.016" in out + err
    code, out, err = run_cli(capsys, "regress", str(scenario), "--baselines", str(tmp_path / "b"),
                             "--workers", "1")
    assert code == 1 and "Traceback" not in err, (out, err)
