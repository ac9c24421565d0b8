"""validate-fmu on FMUs from other exporters: every FMI 2.0 variable type, FMI 3.0,
scheduled execution, and a pythonfmu export that fmpy flags. The verdict is right, every
check that can run runs, and nothing ends in a traceback."""

import re
import zipfile

import pytest

from furuta_cosim.cli import main

from helpers import FOREIGN, build_foreign, crash_with, rewritten, scheduled_only, with_a_clock


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
    assert "skip  smoke run" in out and "scheduled execution, with clocks, is not supported" in out
    # nothing here can run it: not "valid as far as checked"
    assert code == 1 and "nothing can run it" in out and out.rstrip().endswith("problems found"), out


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


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """TMPDIR of the test's own, to see what a run leaves in it."""
    import tempfile

    folder = tmp_path / "tmpdir"
    folder.mkdir()
    monkeypatch.setenv("TMPDIR", str(folder))
    monkeypatch.setattr(tempfile, "tempdir", None)
    return folder


def test_a_clocked_fmu_is_refused_and_the_other_checks_still_report(exports, tmp_path, private_tmp, capsys):
    clocked = with_a_clock(exports / "ForeignPendulum3.fmu", tmp_path / "Clocked.fmu")
    code, out = validate(capsys, clocked)
    assert code == 1 and out.rstrip().endswith("problems found"), out
    assert re.search(r"^FAIL +interfaces .*1 clock\(s\): clocked FMUs are refused", out, re.M), out
    assert re.search(r"^FAIL +smoke run .*clocked FMUs .* are not supported", out, re.M), out
    # Ecos aborts on a clock (SIGABRT): contained, it is Ecos's verdict and the output is whole
    assert re.search(r"^FAIL +Ecos .*Ecos crashed on this FMU: SIGABRT$", out, re.M), out
    assert re.search(r"^ok +fmpy validate", out, re.M) and out.rstrip().endswith("problems found")
    assert list(private_tmp.iterdir()) == []
    # the session refuses it as validate-fmu said
    code = main(["simulate", "paper-step", "--fmu", str(clocked)])
    err = capsys.readouterr().err
    assert code == 2 and "clock(s) (tick)" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("entry, problem", [
    ("../../../../escaped/x", "leaves the FMU's folder"),   # a zip-slip entry
    ("/etc/passwd-copy", "an absolute name"),
    ("resources\\\\x", "backslash"),
])
def test_an_fmu_zip_with_an_unsafe_entry_is_refused_before_extraction(exports, tmp_path, private_tmp,
                                                                      capsys, entry, problem):
    hostile = rewritten(exports / "ForeignPendulum3.fmu", tmp_path / "Hostile.fmu", extra={entry: b"x"})
    code, out = validate(capsys, hostile)
    assert code == 1 and re.search(rf"^FAIL +zip .*{re.escape(problem)}", out, re.M), out
    assert list(private_tmp.iterdir()) == [] and not (tmp_path.parent / "x").exists()
    code = main(["simulate", "paper-step", "--fmu", str(hostile)])
    err = capsys.readouterr().err
    assert code == 2 and "refused before extracting anything" in err, err


def test_a_symlink_entry_is_refused(exports, tmp_path):
    from furuta_cosim.errors import FmuError
    from furuta_cosim.fmu.archive import check_archive

    hostile = tmp_path / "Linked.fmu"
    rewritten(exports / "ForeignPendulum3.fmu", hostile)
    with zipfile.ZipFile(hostile, "a") as archive:
        info = zipfile.ZipInfo("resources/link")
        info.external_attr = (0o120777 << 16)
        archive.writestr(info, "/etc")
    with pytest.raises(FmuError, match="a symbolic link"):
        check_archive(hostile)


@pytest.mark.parametrize("how", ["SIGSEGV", "SIGABRT"])
def test_an_engine_that_crashes_is_its_verdict_not_ours(how, private_tmp):
    from furuta_cosim.fmu.contained import EngineFailed, contained

    with pytest.raises(EngineFailed, match=f"^Ecos crashed on this FMU: {how}$"):
        contained(crash_with, how, engine="Ecos", timeout=60)
    assert list(private_tmp.iterdir()) == []


def test_an_engine_that_hangs_is_stopped(private_tmp):
    import time

    from furuta_cosim.fmu.contained import EngineFailed, contained

    with pytest.raises(EngineFailed, match="did not finish in 2 s"):
        contained(time.sleep, 60, engine="fmpy", timeout=2)


def test_a_variable_declared_its_own_derivative_is_refused(exports, tmp_path, capsys):
    """It was accepted: the state vector then holds a state that is its own derivative."""
    looped = rewritten(exports / "ForeignPendulum3.fmu", tmp_path / "Looped.fmu",
                       lambda text: text.replace('valueReference="19" causality="local" variability="continuous" '
                                                 'derivative="18"', 'valueReference="19" causality="local" '
                                                 'variability="continuous" derivative="19"'))
    code, out = validate(capsys, looped)
    assert code == 1 and re.search(r"^FAIL +model description .*der\(arm_angle\) is declared the derivative "
                                   r"of itself", out, re.M), out
    code = main(["simulate", "paper-step", "--fmu", str(looped)])
    err = capsys.readouterr().err
    assert code == 2 and "is declared the derivative of itself" in err and len(err.strip().splitlines()) == 1, err
