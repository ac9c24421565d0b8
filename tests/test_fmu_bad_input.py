"""Bad input to the FMU gets a clear error from C (through the logger) and from Python."""

import math
import zipfile

import numpy as np
import pytest

from furuta_cosim.cli import main
from furuta_cosim.errors import ConfigError, FmuError
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.fmu.session import PlantSession

from helpers import STATES


@pytest.fixture(scope="module")
def plant(furuta_fmu):
    with PlantSession.open(furuta_fmu) as session:
        yield session


def test_unknown_variable_is_named(plant):
    with pytest.raises(FmuError, match=r"no variable 'thetaX'.*known: V, tau0"):
        plant.reset({"thetaX": 1.0})
    with pytest.raises(FmuError, match="no variable 'volts'"):
        plant.set_io(["volts"], STATES)


@pytest.mark.parametrize("name", ["m_p", "m_c", "I_p", "I_a", "I_m", "r", "l_p", "h", "L_a"])
@pytest.mark.parametrize("value", [0.0, -1.0])
def test_non_positive_physical_parameters_are_refused_by_the_fmu(plant, name, value):
    with pytest.raises(FmuError, match=rf"{name} = -?[01] must be > 0"):
        plant.reset({name: value})


@pytest.mark.parametrize("name", ["C0", "R_a", "V_max"])
def test_negative_friction_resistance_or_limit_are_refused(plant, name):
    with pytest.raises(FmuError, match=rf"{name} = -0.5"):
        plant.reset({name: -0.5})


def test_zero_substeps_are_refused(plant):
    with pytest.raises(FmuError, match=r"n_substeps = 0 must be in \[1, 1000\]"):
        plant.reset({"n_substeps": 0})


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_inputs_are_refused_by_the_fmu(plant, value):
    plant.reset()
    plant.set_io(["V", "tau1"], STATES)
    with pytest.raises(FmuError, match=r"V = -?(nan|inf) is not finite"):
        plant.step([value, 0.0], 1e-3)
    # the refused input was not applied: the plant is still at rest
    assert plant.step([0.0, 0.0], 1e-3) == [0.0] * 5


def test_a_step_too_large_for_rk4_is_an_error_not_nan(tmp_path):
    # a stiff linear plant (x' = -10^4 x, no time constant known to the glue) at one substep of
    # 10 ms: RK4 blows up, and the error names the parameter to raise and its value
    stiff = tmp_path / "stiff.yaml"
    stiff.write_text("model: linear\nidentifier: Stiff\ntime: continuous\nsubsteps: 1\nA: [[-10000]]\nB: [[1]]\n"
                     "C: [[1]]\nD: [[0]]\ninputs: [u]\noutputs: [y]\nstates: [x]\nx0: [1]\n")
    with PlantSession.open(build_fmu(load_plant(stiff))) as session:
        session.reset()
        session.set_io(["u"], ["y"])
        with pytest.raises(FmuError, match=r"integration diverged.*\(1 substeps\).*raise the parameter "
                                           r"n_substeps \(now 1\) or take a smaller step"):
            for _ in range(100):
                session.step([0.0], 0.01)


def test_the_substeps_follow_the_armatures_time_constant():
    # a QUBE with the QUBE-Servo 2's armature (8.4 ohm: L_a / R_a = 0.14 ms) at 4 ms and its
    # 10 substeps of 0.4 ms: beyond RK4's reach on that mode, so the step is cut finer (12
    # substeps) and the run is the one 100 substeps give
    qube = load_plant("qube-servo-3")
    runs = []
    for substeps in (10, 100):
        with PlantSession.open(build_fmu(qube)) as session:
            session.reset({**dict(qube.parameters), "R_a": 8.4, "theta1_start": 3.0, "n_substeps": substeps})
            session.set_io(["V"], STATES)
            runs.append([session.step([1.0 if k < 100 else 0.0], 0.004) for k in range(250)])
    coarse, fine = (np.array(r) for r in runs)
    assert abs(coarse - fine).max() < 1e-4 * (1.0 + abs(fine).max())


def test_parameters_cannot_change_while_running(plant):
    plant.reset()
    with pytest.raises(FmuError, match="parameter m_p can only be set before initialization"):
        plant.set({"m_p": 0.2})
    with pytest.raises(FmuError, match="theta0 is a output"):
        plant.set({"theta0": 0.2})


def test_plant_files_with_problems_list_them_all(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: linear\ntime: sometimes\nA: [[1, 2]]\nB: [[1], [2], [3]]\nC: [1, 1]\n"
                   "colour: red\n")
    with pytest.raises(ConfigError) as error:
        load_plant(bad)
    text = str(error.value)
    assert f"{bad}: colour: unknown key" in text
    assert "time: expected one of continuous, discrete, got 'sometimes'" in text
    assert "A: must be square, got 1x2" in text


def test_unknown_parameter_in_a_set_is_named(tmp_path):
    bad = tmp_path / "typo.yaml"
    bad.write_text("model: furuta\nextends: paper-calibrated\nparameters:\n  m_pp: 0.1\n")
    with pytest.raises(ConfigError, match=r"typo.yaml: parameters.m_pp: unknown parameter"):
        build_fmu(bad)


def test_cli_reports_bad_input_in_one_line_with_exit_2(tmp_path, capsys):
    assert main(["linearize", "--params", "no-such-plant"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no-such-plant: no such plant") and "Traceback" not in err


def test_validate_fmu_fails_on_a_broken_fmu(tmp_path, furuta_fmu, capsys):
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(furuta_fmu) as source, zipfile.ZipFile(broken, "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'causality="output"', b'causality="outputs"', 1)
            target.writestr(item, data)
    assert main(["validate-fmu", str(broken)]) == 1
    out = capsys.readouterr().out
    assert "FAIL  fmpy validate" in out and "problems found" in out


def test_validate_fmu_passes_both_fmus(furuta_fmu, toy_fmu, capsys):
    for fmu in (furuta_fmu, toy_fmu):
        assert main(["validate-fmu", str(fmu)]) == 0
        out = capsys.readouterr().out
        assert "ok    Ecos (same run as fmpy)" in out and out.rstrip().endswith("valid")


def test_build_fmu_prints_the_path_last(capsys, tmp_path):
    assert main(["build-fmu", "toy", "-o", str(tmp_path)]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == str(tmp_path / "Toy.fmu")


def test_a_set_extends_another_file_relative_to_itself(tmp_path):
    (tmp_path / "base.yaml").write_text("model: furuta\nextends: paper-calibrated\nparameters: {C1: 2.0e-3}\n")
    (tmp_path / "sub").mkdir()
    child = tmp_path / "sub" / "child.yaml"
    child.write_text("model: furuta\nextends: ../base.yaml\nparameters: {V_max: 12}\n")
    plant = load_plant(child)
    assert plant.parameters["C1"] == 2.0e-3 and plant.parameters["V_max"] == 12.0
    assert plant.parameters["N"] == 122.40


def test_a_set_with_a_bad_value_names_it(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: furuta\nextends: paper-calibrated\nparameters: {C1: lots}\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: parameters.C1: expected a number, got a string \('lots'\)"):
        load_plant(bad)


@pytest.mark.parametrize("line, expected", [
    ("n_substeps: 2.5", "parameters.n_substeps: expected a whole number, got 2.5"),
    ("n_substeps: 0", "parameters.n_substeps: must be a whole number in [1, 1000], got 0"),
    ("n_substeps: 2147483647", "parameters.n_substeps: must be a whole number in [1, 1000]"),
    ("m_p: 0", "parameters.m_p: must be > 0, got 0"),
    ("C0: -1", "parameters.C0: must be >= 0, got -1"),  # the declared range (min in the XML)
    ("V_max: -1", "parameters.V_max: must be >= 0, got -1"),
    ("R_a: 0", "parameters.R_a: must be > 0, got 0"),
])
def test_build_fmu_refuses_a_set_the_fmu_would_reject(tmp_path, capsys, line, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(f"model: furuta\nextends: paper-calibrated\nparameters: {{{line}}}\n")
    assert main(["build-fmu", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"error: {path}: {expected}" in err and len(err.strip().splitlines()) <= 2
    # nothing is left in the cache for it
    assert main(["build-fmu", str(path)]) == 2


def test_an_integer_override_beyond_32_bits_is_an_error(furuta_fmu):
    with PlantSession.open(furuta_fmu) as plant:
        with pytest.raises(FmuError, match="n_substeps must be a whole number"):
            plant.reset({"n_substeps": 1.0e10})
