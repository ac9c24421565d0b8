"""FMI 3.0 export: the plant and controller FMUs built for FMI 3.0 from the same C model and
glue pass fmpy's validation and give the FMI 2.0 build's numbers, in fmpy (co-simulation and
model exchange) and in our own session."""

import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.session import PlantSession, PlantSession3
from furuta_cosim.scenario import load_scenario

from helpers import run_cli

START = {"theta1_start": 0.1, "V": 0.5}


@pytest.fixture(scope="module")
def fmu3():
    return build_fmu("furuta", fmi_version="3.0")


def test_the_fmi3_plant_is_valid_and_declares_both_interfaces(fmu3):
    assert validate_fmu(str(fmu3)) == []
    md = read_model_description(str(fmu3))
    assert md.fmiVersion == "3.0" and md.coSimulation is not None and md.modelExchange is not None
    assert [d.variable.derivative.name for d in md.derivatives] == ["theta0", "dtheta0", "theta1", "dtheta1", "i"]
    with zipfile.ZipFile(fmu3) as archive:
        names = archive.namelist()
    assert "binaries/x86_64-linux/Furuta.so" in names and "sources/buildDescription.xml" in names


@pytest.mark.parametrize("interface", ["CoSimulation", "ModelExchange"])
def test_fmpy_runs_the_fmi3_plant_as_the_fmi2_one(fmu3, furuta_fmu, interface):
    runs = [simulate_fmu(str(f), stop_time=2.0, step_size=1e-3, output_interval=1e-3, start_values=START,
                         fmi_type=interface) for f in (fmu3, furuta_fmu)]
    assert len(runs[0]) == len(runs[1]) == 2001
    for name in ("theta0", "dtheta0", "theta1", "dtheta1", "i"):
        scale = np.max(np.abs(runs[1][name]))
        assert scale > 1e-3, name  # open loop with 0.5 V: every state moves
        assert np.max(np.abs(runs[0][name] - runs[1][name])) <= 1e-12 * scale, name


def test_paper_step_on_the_fmi3_plant_equals_the_fmi2_run(fmu3):
    native = prepare(load_scenario("paper-step"))
    given = prepare(load_scenario("paper-step"), fmu=fmu3)
    assert given.start == native.start
    with PlantSession.open(native.fmu) as session:
        a = evaluate(native, session, "lqr-paper")
    with PlantSession.open(fmu3) as session:
        assert isinstance(session, PlantSession3)
        b = evaluate(given, session, "lqr-paper")
        # the FMU state round-trips through the FMI 3.0 functions
        snapshot = session.save_state()
        before = session.get(["theta0", "theta1"])
        session.step([1.0], 1e-3)
        session.restore_state(snapshot)
        assert session.get(["theta0", "theta1"]) == before
    for name in ("theta0", "theta1", "i"):
        np.testing.assert_array_equal(a.trace[name], b.trace[name])
    assert a.metrics == b.metrics


def test_the_cli_builds_fmi3_plants_and_controllers(tmp_path, capsys):
    code, out, err = run_cli(capsys, "build-fmu", "furuta", "--fmi-version", "3.0", "-o", str(tmp_path))
    assert code == 0, err
    assert out.strip() == str(tmp_path / "Furuta.fmu")
    assert read_model_description(out.strip()).fmiVersion == "3.0"
    code, out, err = run_cli(capsys, "export-controller", "lqr-paper", "--fmi-version", "3.0",
                             "-o", str(tmp_path / "controller3.fmu"))
    assert code == 0, err
    controller3 = tmp_path / "controller3.fmu"
    assert validate_fmu(str(controller3)) == []
    code, out, err = run_cli(capsys, "export-controller", "lqr-paper", "-o", str(tmp_path / "controller2.fmu"))
    assert code == 0, err
    md = read_model_description(str(controller3))
    inputs = {v.name: 0.01 * (k + 1) for k, v in enumerate(md.modelVariables) if v.causality == "input"}
    runs = [simulate_fmu(str(tmp_path / f"controller{v}.fmu"), stop_time=0.02, step_size=0.002,
                         output_interval=0.002, start_values=inputs) for v in (3, 2)]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    assert outputs and all(np.max(np.abs(runs[0][n])) > 0 for n in outputs)
    for name in outputs:
        np.testing.assert_array_equal(runs[0][name], runs[1][name])
    code, out, err = run_cli(capsys, "validate-fmu", str(tmp_path / "Furuta.fmu"))
    assert code == 0 and out.rstrip().endswith(": valid"), out


def test_an_unknown_fmi_version_is_refused(capsys):
    with pytest.raises(SystemExit) as stop:
        run_cli(capsys, "build-fmu", "furuta", "--fmi-version", "1.0")
    assert stop.value.code == 2
    assert "invalid choice: '1.0'" in capsys.readouterr().err


def test_one_call_steps_equal_three_call_steps_and_fail_alike(fmu3):
    """Each FMI 3.0 step is one call into the compiled helper (set, doStep, get); without a
    compiler the session makes the three calls itself. Both give the same numbers, and a step
    the FMU rejects fails with the same message."""
    from furuta_cosim.errors import FmuError

    runs, errors = [], []
    for one_call in (True, False):
        with PlantSession.open(fmu3) as session:
            assert session._step_io != session._step_three_calls  # the helper compiles here (gcc)
            if not one_call:
                session._step_io = session._step_three_calls
            session.reset({"theta1_start": 0.1})
            session.set_io(["V"], ["theta0", "theta1", "i"])
            runs.append([session.step([np.sin(k / 50)], 2e-3) for k in range(500)])
            session.time = 0.5  # not where the FMU is (1.0 s)
            with pytest.raises(FmuError) as failed:
                session.step([0.0], 2e-3)
            errors.append(str(failed.value))
        with pytest.raises(FmuError, match="the instance is gone"):  # a closed session
            session.step([0.0], 2e-3)
    assert runs[0] == runs[1] and np.max(np.abs(np.array(runs[0])[:, 1] - 0.1)) > 1e-3
    assert errors[0] == errors[1] and "fmi3DoStep at t = 0.5" in errors[0], errors
