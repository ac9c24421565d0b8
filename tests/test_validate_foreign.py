"""validate-fmu on FMUs from other exporters: every FMI 2.0 variable type, FMI 3.0,
scheduled execution, and a pythonfmu export that fmpy flags. The verdict is right, every
check that can run runs, and nothing ends in a traceback."""

import re
import zipfile

import pytest

from furuta_cosim.cli import main

from helpers import FOREIGN, build_foreign, scheduled_only


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exports")
    build_foreign("pythonfmu", FOREIGN / "mixed_fmu.py", folder)
    build_foreign("pythonfmu3", FOREIGN / "pendulum3_fmu.py", folder, FOREIGN / "pendulum_physics.py")
    scheduled_only(folder / "ForeignPendulum3.fmu", folder / "Scheduled.fmu")
    return folder


def validate(capsys, path):
    code = main(["validate-fmu", str(path)])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return code, captured.out


def test_integer_boolean_and_string_variables_are_valid(exports, capsys):
    code, out = validate(capsys, exports / "MixedTypes.fmu")
    assert code == 0 and out.rstrip().endswith(": valid"), out
    assert "1 floating-point outputs finite (1 Boolean, 1 Integer outputs not read)" in out
    assert "ok    Ecos (same run as fmpy)" in out


def test_an_fmi3_fmu_is_valid_and_runs_everywhere(exports, capsys):
    code, out = validate(capsys, exports / "ForeignPendulum3.fmu")
    assert code == 0 and out.rstrip().endswith(": valid"), out
    assert "FMI 3.0, co-simulation, model exchange" in out and "no binary" not in out
    for check in ("smoke run", "fmpy simulate_fmu", "Ecos (same run as fmpy)"):
        assert re.search(rf"^ok +{re.escape(check)}", out, re.M), (check, out)


def test_scheduled_execution_is_named_not_a_traceback(exports, capsys):
    code, out = validate(capsys, exports / "Scheduled.fmu")
    assert code == 0, out
    assert "skip  smoke run" in out and "scheduled execution, with clocks, is not supported" in out
    assert out.rstrip().endswith("valid as far as checked (1 check(s) not run)")


def test_fmpy_problems_are_reported_and_the_runs_still_run(foreign_fmu, capsys):
    """pythonfmu leaves its outputs out of ModelStructure/InitialUnknowns: fmpy says so, and
    the FMU still runs in every engine."""
    code, out = validate(capsys, foreign_fmu)
    assert code == 1 and out.rstrip().endswith("problems found"), out
    assert "FAIL  fmpy validate" in out and "InitialUnknowns" in out
    for check in ("smoke run", "fmpy simulate_fmu", "Ecos (same run as fmpy)"):
        assert re.search(rf"^ok +{re.escape(check)}", out, re.M), (check, out)


def test_an_unreadable_model_description_is_a_finding(tmp_path, capsys):
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(broken, "w") as archive:
        archive.writestr("modelDescription.xml", "<fmiModelDescription")
    code, out = validate(capsys, broken)
    assert code == 1 and "problems found" in out
