"""Units and start values in a plant mapping: the foreign pendulum with its angles in degrees
and no start parameters (tests/foreign/pendulum_fmu.py with DEGREES set, START_PARAMETERS
not), converted by an explicit scale
in the mapping or by the unit its model description declares, runs paper-step as the same
pendulum in radians does."""

import re
import shutil
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

from helpers import FOREIGN, build_foreign, run_cli

DEG = 0.017453292519943295  # rad per degree

# a mapping file (regress --mapping) with explicit scales; indented, it is a plant.mapping
MAPPING_FILE = """\
control_input: voltage
states:
  theta0: {variable: arm_angle, scale: %(deg)r}
  dtheta0: {variable: arm_rate, scale: %(deg)r}
  theta1: {variable: pend_angle, scale: %(deg)r}
  dtheta1: {variable: pend_rate, scale: %(deg)r}
  i: current
disturbances: {tau0: arm_torque, tau1: pend_torque}
""" % {"deg": DEG}

SCALED = ("plant:\n  fmu: DegreePendulum.fmu\n  initial: {theta1: 0.1}\n  control_input: voltage\n"
          "  mapping:\n" + textwrap.indent(MAPPING_FILE.split("\n", 1)[1], "    "))

DECLARED = """\
plant:
  fmu: DeclaredPendulum.fmu
  initial: {theta1: 0.1}
  control_input: voltage
  mapping:
    states: {theta0: arm_angle, dtheta0: arm_rate, theta1: pend_angle, dtheta1: pend_rate, i: current}
    disturbances: {tau0: arm_torque, tau1: pend_torque}
"""

UNITS = """<UnitDefinitions>
<Unit name="deg"><BaseUnit rad="1" factor="0.017453292519943295"/></Unit>
<Unit name="deg/s"><BaseUnit rad="1" s="-1" factor="0.017453292519943295"/></Unit>
</UnitDefinitions>
"""


def declare_units(source: Path, target: Path, units: str = UNITS) -> None:
    """``source`` with deg and deg/s declared on its angles, as a Modelica tool exports them
    (``units``: the UnitDefinitions element to declare them with)."""
    with zipfile.ZipFile(source) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    text = files["modelDescription.xml"].decode()
    text = re.sub(r"(</CoSimulation>|<CoSimulation[^>]*/>)", lambda m: m.group(1) + "\n" + units, text, count=1)
    for name, unit in (("arm_angle", "deg"), ("pend_angle", "deg"), ("arm_rate", "deg/s"), ("pend_rate", "deg/s")):
        text, count = re.subn(rf'(<ScalarVariable name="{name}"[^>]*>\s*<Real)', rf'\1 unit="{unit}"', text)
        assert count == 1, name
    files["modelDescription.xml"] = text.encode()
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(name, data)


@pytest.fixture(scope="module")
def degrees(tmp_path_factory, foreign_fmu):
    folder = tmp_path_factory.mktemp("degrees")
    # one self-contained script: pythonfmu finds the slave class again only in its own module
    text = (FOREIGN / "pendulum_fmu.py").read_text()
    variant = (text.replace("class ForeignPendulum(", "class DegreePendulum(")
               .replace("DEGREES = False", "DEGREES = True")
               .replace("START_PARAMETERS = True", "START_PARAMETERS = False"))
    assert "DEGREES = True" in variant and "START_PARAMETERS = False" in variant
    script = folder / "degree_pendulum_fmu.py"
    script.write_text(variant)
    build_foreign("pythonfmu", script, folder, FOREIGN / "pendulum_physics.py")
    declare_units(folder / "DegreePendulum.fmu", folder / "DeclaredPendulum.fmu")
    shutil.copy(foreign_fmu, folder / foreign_fmu.name)
    text = load_scenario("paper-step").path.read_text()
    plant = text[text.index("plant:"):text.index("timing:")]
    for name, block in (("scaled", SCALED), ("declared", DECLARED)):
        (folder / f"paper-step-{name}.yaml").write_text(text.replace(plant, block))
    radians = block.replace("DeclaredPendulum", "ForeignPendulum") + "    initial: {theta1: pend_angle_0}\n"
    (folder / "paper-step-radians.yaml").write_text(text.replace(plant, radians))
    return folder


def run(path):
    prepared = prepare(load_scenario(path))
    with PlantSession.open(prepared.fmu) as session:
        return prepared, evaluate(prepared, session, "lqr-paper")


@pytest.mark.parametrize("name", ["scaled", "declared"])
@pytest.mark.slow
def test_the_degree_pendulum_runs_paper_step_as_the_radian_one(degrees, name):
    _, reference = run(degrees / "paper-step-radians.yaml")
    prepared, result = run(degrees / f"paper-step-{name}.yaml")
    # the start of theta1 is set on the state itself, in degrees
    assert prepared.start == {"pend_angle": pytest.approx(0.1 / DEG, rel=1e-15)}
    assert result.passed and len(result.trace.t) == len(reference.trace.t) == 5000
    assert result.trace["theta1"][0] == pytest.approx(0.1, rel=1e-14)
    for signal in ("theta0", "dtheta0", "theta1", "dtheta1", "i"):
        assert np.max(np.abs(result.trace[signal] - reference.trace[signal])) <= 1e-9, signal
    assert np.max(np.abs(result.trace["theta0"])) > 1e-3  # the arm moved
    assert result.metrics["theta1.SettlingTime"] == pytest.approx(reference.metrics["theta1.SettlingTime"], abs=1e-3)


def test_declared_units_give_the_view_its_si_units(degrees):
    prepared, _ = run(degrees / "paper-step-declared.yaml")
    assert prepared.conversions["pend_rate"] == (DEG, 0.0)
    assert prepared.units["theta1"] == "rad" and prepared.units["dtheta1"] == "rad/s"
    scaled = prepare(load_scenario(degrees / "paper-step-scaled.yaml"))
    assert "theta1" not in scaled.units  # a scale alone says nothing of the unit


@pytest.mark.slow
def test_without_conversion_the_degree_pendulum_is_another_experiment(degrees):
    """The check has teeth: read as radians, the same FMU falls over."""
    path = degrees / "paper-step-plain.yaml"
    text = (degrees / "paper-step-declared.yaml").read_text()
    path.write_text(text.replace("DeclaredPendulum", "DegreePendulum"))
    _, result = run(path)
    _, reference = run(degrees / "paper-step-radians.yaml")
    n = min(len(result.trace.t), len(reference.trace.t))
    assert np.max(np.abs(result.trace["theta1"][:n] - reference.trace["theta1"][:n])) > 1e-2


def test_a_zero_scale_is_one_line(degrees, tmp_path, capsys):
    path = degrees / "paper-step-zero.yaml"
    path.write_text((degrees / "paper-step-scaled.yaml").read_text().replace(
        "{variable: pend_angle, scale: %r}" % DEG, "{variable: pend_angle, scale: 0}"))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path))
    assert code == 2 and err.strip().splitlines() == [
        f"error: {path}: plant.mapping.states.theta1.scale: expected a magnitude in [1e-12, 1e+12] "
        "(the view's value is scale * FMU value + offset), got 0"]


@pytest.mark.parametrize("entry, key, expected", [
    ("scale: 0.017453292519943295, offset: 1.0e+300", "offset", "expected a magnitude of at most 1e+06"),
    ("scale: 1.0e+300", "scale", "expected a magnitude in [1e-12, 1e+12]"),
    ("scale: .nan", "scale", "finite"),
])
def test_a_mapping_scale_or_offset_out_of_bounds_is_one_line(degrees, tmp_path, capsys, entry, key, expected):
    """An offset of 1e300 once made theta1 identically 0 in the view, and the run passed."""
    path = degrees / f"paper-step-{key}.yaml"
    path.write_text((degrees / "paper-step-scaled.yaml").read_text().replace(
        "{variable: pend_angle, scale: %r}" % DEG, "{variable: pend_angle, %s}" % entry))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and f"plant.mapping.states.theta1.{key}: " in lines[0], err
    assert expected in lines[0], err


HOSTILE_UNITS = {
    "factor 0": ('<Unit name="deg"><BaseUnit rad="1" factor="0"/></Unit>', "unit 'deg': factor 0.0"),
    "factor NaN": ('<Unit name="deg"><BaseUnit rad="1" factor="NaN"/></Unit>', "unit 'deg': factor nan"),
    "offset 1e300": ('<Unit name="deg"><BaseUnit rad="1" factor="0.0174" offset="1e300"/></Unit>',
                     "unit 'deg': offset 1e+300"),
    "defined twice": ('<Unit name="deg"><BaseUnit rad="1" factor="0.0174"/></Unit>'
                      '<Unit name="deg"><BaseUnit rad="1" factor="1"/></Unit>', "unit 'deg' is defined twice"),
    "mm on an angle": ('<Unit name="deg"><BaseUnit m="1" factor="0.001"/></Unit>',
                       "pend_angle is in 'deg', not a unit of rad"),
}


@pytest.mark.parametrize("case", HOSTILE_UNITS)
def test_a_declared_unit_is_checked_like_a_file(degrees, tmp_path, capsys, case):
    """simulate refuses it with a line naming the FMU and the unit, and validate-fmu says the
    same (it once called all of these valid; factor 0 was a ZeroDivisionError)."""
    definition, expected = HOSTILE_UNITS[case]
    units = ("<UnitDefinitions>\n" + definition
             + '\n<Unit name="deg/s"><BaseUnit rad="1" s="-1" factor="0.017453292519943295"/></Unit>'
             + "\n</UnitDefinitions>\n")
    declare_units(degrees / "DegreePendulum.fmu", tmp_path / "DeclaredPendulum.fmu", units)
    scenario = tmp_path / "paper-step-declared.yaml"
    scenario.write_text((degrees / "paper-step-declared.yaml").read_text())
    code, _, err = run_cli(capsys, "simulate", str(scenario), "-o", str(tmp_path / "out"))
    assert code == 2 and "Traceback" not in err, err
    assert any(str(tmp_path / "DeclaredPendulum.fmu") in line and expected in line
               for line in err.splitlines()), err
    if case != "mm on an angle":  # the FMU alone cannot tell which quantity a variable is
        code, out, _ = run_cli(capsys, "validate-fmu", str(tmp_path / "DeclaredPendulum.fmu"))
        assert code == 1 and re.search(rf"^FAIL +units .*{re.escape(expected)}", out, re.M), out


def test_a_state_without_a_start_is_named(degrees, tmp_path, capsys):
    path = degrees / "paper-step-nostart.yaml"
    path.write_text((degrees / "paper-step-radians.yaml").read_text().replace(
        "    initial: {theta1: pend_angle_0}\n", ""))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path))
    assert code == 2
    assert ("plant.initial.theta1: ForeignPendulum has no parameter 'pend_angle_start' to set the start "
            "of theta1 and its output 'pend_angle' takes no start value") in err


@pytest.mark.slow
def test_regress_notes_the_degree_pendulums_extra_output_until_it_is_ignored(degrees, tmp_path):
    from furuta_cosim.regression import regress

    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING_FILE)
    fmu = degrees / "DegreePendulum.fmu"
    report = regress(["paper-step"], fmu=fmu, mapping=mapping, workers=1)
    # arm_turns is not a state and not in the native plant's baselines: a note (open world)
    assert [c.status for c in report.cases] == ["pass", "pass"]
    assert any("signal arm_turns" in note for note in report.cases[0].notes), report.cases[0].notes
    mapping.write_text(MAPPING_FILE + "ignore: [arm_turns]\n")
    report = regress(["paper-step"], fmu=fmu, mapping=mapping, workers=1)
    assert [c.status for c in report.cases] == ["pass", "pass"], [c.lines() for c in report.cases]
    assert not any("arm_turns" in note for c in report.cases for note in c.notes)
    assert min(c.checked for c in report.cases) >= 10


def test_a_non_state_output_can_be_renamed(degrees):
    path = degrees / "paper-step-renamed.yaml"
    path.write_text((degrees / "paper-step-scaled.yaml").read_text().replace(
        "    disturbances:", "    outputs: {turns: arm_turns}\n    disturbances:"))
    prepared, result = run(path)
    assert "turns" in prepared.signals and "arm_turns" not in prepared.signals
    np.testing.assert_allclose(result.trace["turns"], result.trace["theta0"] / (2 * np.pi), rtol=1e-12, atol=1e-15)


def test_ignoring_an_output_that_does_not_exist_is_one_line(degrees, tmp_path, capsys):
    path = degrees / "paper-step-ignore.yaml"
    path.write_text((degrees / "paper-step-scaled.yaml").read_text().replace(
        "    disturbances:", "    ignore: [no_such]\n    disturbances:"))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"error: {path}: plant.mapping.ignore: DegreePendulum has no Real output 'no_such'")


def test_simulate_names_the_plants_own_variables(degrees, tmp_path, capsys):
    code, out, err = run_cli(capsys, "simulate", str(degrees / "paper-step-scaled.yaml"), "-o", str(tmp_path),
                             "--no-trace", "--controller", "lqr-paper")
    assert code == 0, err
    assert ("on DegreePendulum.fmu: theta0 = arm_angle x 0.0174533, dtheta0 = arm_rate x 0.0174533, "
            "theta1 = pend_angle x 0.0174533, dtheta1 = pend_rate x 0.0174533, i = current\n") in out + err
