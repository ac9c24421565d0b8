"""The closed loop as an SSP: written valid against the standard's schemas, run in Ecos and
libcosim to the master's numbers, read back as a plant, and read as hostile input."""

from __future__ import annotations

import io
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario
from furuta_cosim.ssp import base_unit, export_ssp, read_ssp

from helpers import DYNAMIC, ROOT, one_line, run_cli

AGREE = 1e-6  # rad: the exported loop in another engine against our master


def _hold(folder: Path) -> Path:
    """qube-step with its arm reference at 0.3 rad from the start (an SSP of two FMUs holds a
    constant reference) and an actuator limit of 0.13 V, which the first commands reach (0.149 V
    unlimited) and the SSP carries as the plant's V_max (the controller's output, V, is the
    command before the limit; the plant applies it clipped)."""
    text = (ROOT / "scenarios" / "qube-step.yaml").read_text()
    path = folder / "qube-hold.yaml"
    path.write_text(text.replace("points: [[0.0, 0.0], [0.5, 0.3]]", "points: [[0.0, 0.3]]")
                    .replace("name: qube-step", "name: qube-hold") + "actuator: {limit: 0.13}\n")
    return path


def _controller(folder: Path, name: str) -> str:
    if name == "dynamic":
        (folder / "dynamic.yaml").write_text(DYNAMIC)
        return str(folder / "dynamic.yaml")
    return name


def _master(scenario, controller):
    prepared = prepare(replace(load_scenario(scenario), delay=1))
    with PlantSession.open(prepared.fmu) as session:
        return evaluate(prepared, session, controller).trace


def _ecos(path: Path, found: dict, parameter_set: str) -> np.ndarray:
    from ecospy import EcosSimulation

    names = ["plant::theta0", "plant::theta1", "plant::V"]
    rows = []
    with EcosSimulation(step_size=found["step"], ssp_path=str(path)) as simulation:
        simulation.init(parameter_set=parameter_set)
        for _ in range(int(round(found["stop"] / found["step"]))):
            rows.append([simulation.get_real(name) for name in names])
            simulation.step()
        simulation.terminate()
    return np.array(rows)


@pytest.mark.parametrize("scenario,controller,version", [
    ("paper-step", "lqr-paper", "2.0"), ("paper-step", "dynamic", "2.0"),
    ("paper-step", "lqr-paper", "3.0"), ("paper-step", "dynamic", "3.0"), ("hold", "lqr-qube", "2.0")])
def test_the_exported_loop_runs_in_ecos_as_our_master_runs_it(tmp_path, scenario, controller, version):
    scenario = str(_hold(tmp_path)) if scenario == "hold" else scenario
    controller = _controller(tmp_path, controller)
    found = export_ssp(scenario, controller, tmp_path / "loop.ssp", fmi_version=version)
    rows = _ecos(tmp_path / "loop.ssp", found, found["sets"][0])
    master = _master(scenario, controller)
    assert len(rows) == len(master.t)
    assert np.max(np.abs(rows[:, 0] - master["theta0"])) <= AGREE
    assert np.max(np.abs(rows[:, 1] - master["theta1"])) <= AGREE
    limit = 0.13 if "hold" in scenario else np.inf
    assert np.max(np.abs(np.clip(rows[:, 2], -limit, limit) - master.u)) <= 1e-6 * max(1.0, np.max(np.abs(master.u)))
    assert np.max(np.abs(master["theta0"])) > 1e-2  # the loop did something
    if "hold" in scenario:  # the limit held the first commands, in both
        assert np.sum(np.isclose(np.abs(master.u), 0.13, rtol=0, atol=1e-12)) >= 2
        assert np.sum(np.abs(rows[:, 2]) > 0.13) >= 2


def _libcosim(path: Path, found: dict) -> np.ndarray:
    """The plant's theta0, theta1 and V after each step of the archive in libcosim (its first
    set: libcosimpy takes no set name)."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_ssp_file(str(path), step_size=int(round(found["step"] * 1e9)))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    plant = {s.name.decode(): s.index for s in execution.slave_infos()}["plant"]
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(plant)}
    rows = []
    for _ in range(int(round(found["stop"] / found["step"]))):
        execution.step()
        rows.append(observer.last_real_values(plant, [refs["theta0"], refs["theta1"], refs["V"]]))
    return np.array(rows)


@pytest.mark.parametrize("controller", ["lqr-paper", "dynamic"])
def test_the_exported_loop_runs_in_libcosim_as_our_master_runs_it(tmp_path, controller):
    controller = _controller(tmp_path, controller)
    found = export_ssp("paper-step", controller, tmp_path / "loop.ssp")
    rows = _libcosim(tmp_path / "loop.ssp", found)
    master = _master("paper-step", controller)
    # libcosim's observer reads after each step: the angles of the next sample, the command
    # that step ran with
    assert np.max(np.abs(rows[:-1, 0] - master["theta0"][1:])) <= AGREE
    assert np.max(np.abs(rows[:-1, 1] - master["theta1"][1:])) <= AGREE
    assert np.max(np.abs(rows[:, 2] - master.u)) <= 1e-6 * max(1.0, np.max(np.abs(master.u)))
    assert np.max(np.abs(master["theta0"])) > 1e-2


def _schema(name: str):
    import xmlschema
    import pyssp_standard

    return xmlschema.XMLSchema(str(Path(pyssp_standard.__file__).parent / "resources" / name))


def test_every_exported_file_is_valid_against_the_standards_schemas(tmp_path):
    found = export_ssp("qube-step", "lqr-qube", tmp_path / "loop.ssp", plants=["qube-servo-3", "qube-servo-3-worn"])
    with zipfile.ZipFile(tmp_path / "loop.ssp") as archive:
        names = archive.namelist()
        _schema("SystemStructureDescription.xsd").validate(io.BytesIO(archive.read("SystemStructure.ssd")))
        sets = [n for n in names if n.endswith(".ssv")]
        assert len(sets) == 4  # the plant's and the controller's, per set
        for name in sets:
            _schema("SystemStructureParameterValues.xsd").validate(io.BytesIO(archive.read(name)))
    assert {"resources/plant.fmu", "resources/controller.fmu", "resources/source.fmu"} <= set(names)
    assert found["sets"] == ["qube-servo-3", "qube-servo-3-worn"] and found["validated"]
    assert not found["reference_held"] and found["source"]
    assert "the reference as it changes come from the component source" in found["note"]
    # the same inputs give the same bytes
    export_ssp("qube-step", "lqr-qube", tmp_path / "again.ssp", plants=["qube-servo-3", "qube-servo-3-worn"])
    assert (tmp_path / "loop.ssp").read_bytes() == (tmp_path / "again.ssp").read_bytes()


@pytest.mark.slow
def test_a_parameter_set_read_back_is_the_plant_it_came_from(tmp_path, capsys):
    """simulate on an SSP's set is simulate on that plant file, sample for sample."""
    assert run_cli(capsys, "export-ssp", "qube-step", "--plant", "qube-servo-3", "--plant", "qube-servo-3-worn",
                   "-o", str(tmp_path / "q.ssp"))[0] == 0
    plant = read_ssp(tmp_path / "q.ssp", "qube-servo-3-worn", folder=tmp_path / "x")
    assert plant.component == "plant" and plant.sets == ["qube-servo-3", "qube-servo-3-worn"]
    assert plant.parameters["C0"] == 6.0e-4 and plant.parameters["V_max"] == 10.0
    assert plant.stop == 8.0 and plant.step == 0.002
    runs = {}
    for label, given in (("ssp", f"{tmp_path / 'q.ssp'}:qube-servo-3-worn"), ("file", "qube-servo-3-worn")):
        code, _, _ = run_cli(capsys, "simulate", "qube-step", "--plant", given, "-o", str(tmp_path / label))
        assert code == 0
        runs[label] = np.genfromtxt(tmp_path / label / "lqr-qube.csv", delimiter=",", names=True)
    for column in ("theta0", "theta1", "u"):
        assert np.max(np.abs(runs["ssp"][column] - runs["file"][column])) <= 1e-12, column
    # simulate on the archive itself runs its system, the worn set when named
    code, _, err = run_cli(capsys, "simulate", f"{tmp_path / 'q.ssp'}:qube-servo-3-worn", "-o", str(tmp_path / "own"))
    assert code == 0 and "set qube-servo-3-worn" in err
    assert (tmp_path / "own" / "system.csv").is_file()


def test_every_unit_of_the_plant_has_its_si_exponents():
    from furuta_cosim.fmu.session import model_description

    md = model_description(prepare(load_scenario("qube-step")).fmu)
    units = {u.name for u in md.unitDefinitions}
    assert units and all(base_unit(u) is not None for u in units), [u for u in units if base_unit(u) is None]
    assert base_unit("N.m.s/rad") == {"kg": 1, "m": 2, "s": -1, "rad": -1}
    assert base_unit("rad/s/s") == {"s": -2, "rad": 1}
    assert base_unit("kg.m2") == {"kg": 1, "m": 2}
    assert base_unit("furlong") is None


def _rewritten(source: Path, target: Path, change) -> Path:
    """A copy of the archive ``source`` with ``change(name, bytes) -> bytes | None`` applied
    to each entry (None drops it); the copy differs from the source."""
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as out:
        changed = False
        for info in archive.infolist():
            original = archive.read(info.filename)
            data = change(info.filename, original)
            changed = changed or data != original
            if data is not None:
                out.writestr(info.filename, data)
    assert changed
    return target


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ssp")
    export_ssp("paper-step", "lqr-paper", folder / "loop.ssp")
    return folder / "loop.ssp"


def _replace(entry: str, old: bytes, new: bytes):
    def change(name, data):
        if name == entry:
            assert old in data, (name, old)
            return data.replace(old, new)
        return data
    return change


@pytest.mark.parametrize("change,expected", [
    (_replace("SystemStructure.ssd", b'name="theta1" kind="input"', b'name="theta9" kind="input"'),
     r"\(SystemStructure.ssd\): component controller: connector 'theta9' is no variable of resources/controller.fmu"),
    (lambda name, data: None if name == "resources/plant.fmu" else data,
     r"\(resources/plant.fmu\): component plant's FMU is missing from the archive"),
    (_replace("resources/paper-calibrated.ssv", b'value="8.0" unit="Ohm"', b'value="8.0" unit="kOhm"'),
     r"\(resources/paper-calibrated.ssv\): parameter 'R_a': in kOhm, where the FMU declares Ohm"),
    (_replace("resources/paper-calibrated.ssv", b'<ssv:Real value="8.0" unit="Ohm" />', b'<ssv:Integer value="8" />'),
     r"\(resources/paper-calibrated.ssv\): parameter 'R_a': an Integer value for the FMU's Real"),
    (_replace("resources/paper-calibrated.ssv", b'value="8.0" unit="Ohm"', b'value="nan" unit="Ohm"'),
     r"parameter 'R_a': value nan is not finite"),
    (_replace("SystemStructure.ssd", b"</ssd:Elements>", b"</ssd:Element>"),
     r"\(SystemStructure.ssd\): not well-formed XML"),
    (_replace("SystemStructure.ssd", b"<ssd:SystemStructureDescription",
              b'<!DOCTYPE x [<!ENTITY a "aaaa">]><ssd:SystemStructureDescription'),
     r"\(SystemStructure.ssd\): declares a DOCTYPE or entities"),
])
def test_a_broken_ssp_is_one_line_naming_the_entry(tmp_path, capsys, exported, change, expected):
    import re

    bad = _rewritten(exported, tmp_path / "bad.ssp", change)
    line = one_line(capsys, "simulate", "paper-step", "--plant", str(bad), "-o", str(tmp_path / "o"))
    assert re.search(expected, line), line
    assert str(bad) in line


def test_a_parameter_the_fmu_does_not_have_is_ignored_and_said(tmp_path, capsys, exported):
    # the standard has a tool ignore it; we say so, and the set's other values still apply
    bad = _rewritten(exported, tmp_path / "extra.ssp", _replace("resources/paper-calibrated.ssv",
                                                                  b'name="R_a"', b'name="R_b"'))
    plant = read_ssp(bad)
    assert "R_a" not in plant.parameters and plant.parameters["L_a"] > 0
    assert len(plant.warnings) == 1 and "parameter 'R_b' is no variable" in plant.warnings[0]
    assert "ignored" in plant.warnings[0]
    code, _, err = run_cli(capsys, "simulate", "paper-step", "--plant", str(bad), "-o", str(tmp_path / "o"))
    assert code == 0 and "parameter 'R_b' is no variable" in err and "ignored" in err


def test_an_archive_is_hostile_input(tmp_path, capsys, exported, monkeypatch):
    from furuta_cosim.ssp import read as ssp

    (tmp_path / "text.ssp").write_text("not a zip")
    assert "not an SSP: not a zip archive" in one_line(capsys, "simulate", "paper-step", "--plant",
                                                       str(tmp_path / "text.ssp"))
    with zipfile.ZipFile(exported) as archive, zipfile.ZipFile(tmp_path / "escape.ssp", "w") as out:
        for info in archive.infolist():
            out.writestr(info.filename, archive.read(info.filename))
        out.writestr("../outside.txt", b"x")
    assert "(../outside.txt): an entry outside the archive's folder" in one_line(
        capsys, "simulate", "paper-step", "--plant", str(tmp_path / "escape.ssp"))
    assert not (tmp_path / "outside.txt").exists()
    monkeypatch.setattr(ssp, "MAX_ENTRIES", 3)
    assert "entries (at most 3)" in one_line(capsys, "simulate", "paper-step", "--plant", str(exported))
    monkeypatch.setattr(ssp, "MAX_ENTRIES", 1000)
    monkeypatch.setattr(ssp, "MAX_ENTRY", 20000)  # above the system description, below the FMUs
    assert "(resources/plant.fmu): larger than" in one_line(capsys, "simulate", "paper-step", "--plant",
                                                            str(exported))
    monkeypatch.setattr(ssp, "MAX_ENTRY", 200 * 2**20)
    # many components of one FMU entry: each read counts (the declared sizes pass)
    many = b"".join(b'<ssd:Component name="c%d" source="resources/plant.fmu"/>' % k for k in range(40))
    crowded = _rewritten(exported, tmp_path / "crowded.ssp", _replace("SystemStructure.ssd", b"</ssd:Elements>",
                                                                    many + b"</ssd:Elements>"))
    monkeypatch.setattr(ssp, "MAX_TOTAL", 300000)
    assert "MB read from the archive in all" in one_line(capsys, "simulate", "paper-step", "--plant", str(crowded))
    monkeypatch.setattr(ssp, "MAX_TOTAL", 500 * 2**20)
    # an entry whose compressed bytes were damaged: its checksum (or inflation) fails
    raw = bytearray(exported.read_bytes())
    with zipfile.ZipFile(exported) as archive:
        info = archive.getinfo("resources/paper-calibrated.ssv")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    raw[start + info.compress_size // 2] ^= 0xFF
    broken = tmp_path / "corrupt.ssp"
    broken.write_bytes(bytes(raw))
    assert "(resources/paper-calibrated.ssv): a corrupt entry" in one_line(capsys, "simulate", "paper-step",
                                                                        "--plant", str(broken))
    assert "no parameter set 'worn' for component plant (it has: paper-calibrated)" in one_line(
        capsys, "simulate", "paper-step", "--plant", f"{exported}:worn")
    assert "no such file" in one_line(capsys, "simulate", "paper-step", "--plant", str(tmp_path / "none.ssp"))


def test_another_tools_ssp_is_read_by_its_plant_components_input(tmp_path, capsys, exported):
    """An SSP whose components are named otherwise: the plant is the one component whose FMU
    takes the control input; simulate runs its system as it is wired, whatever the names."""
    def rename(name, data):
        if name == "SystemStructure.ssd":
            data = data.replace(b'"plant"', b'"pendulum"').replace(b'"controller"', b'"lqr"')
        return None if name.startswith("resources/furuta-cosim/") else data

    foreign = _rewritten(exported, tmp_path / "foreign.ssp", rename)
    plant = read_ssp(foreign, folder=tmp_path / "x")
    assert plant.component == "pendulum" and plant.parameters["R_a"] == 8.0
    code, _, err = run_cli(capsys, "simulate", str(foreign), "-o", str(tmp_path / "own"))
    assert code == 0 and "pendulum (pendulum.fmu" in err
    ran = np.genfromtxt(tmp_path / "own" / "system.csv", delimiter=",", names=True)
    assert abs(ran["pendulumtheta1"][0] - 0.1) < 1e-12 and abs(ran["pendulumtheta1"][-1]) < 1e-3
    code, _, _ = run_cli(capsys, "simulate", "paper-step", "--plant", str(foreign), "-o", str(tmp_path / "o"))
    assert code == 0


def test_an_archive_the_schemas_refuse_is_not_written(tmp_path, monkeypatch):
    from furuta_cosim.ssp import write as ssp

    original = ssp._ssd
    monkeypatch.setattr(ssp, "_ssd", lambda *a: original(*a).replace(b'kind="input"', b'kind="sideways"', 1))
    with pytest.raises(ConfigError, match=r"would not be valid SSP 1.0 \(nothing written\): "
                                          r"SystemStructure.ssd: .*sideways"):
        export_ssp("paper-step", "lqr-paper", tmp_path / "bad.ssp")
    assert not (tmp_path / "bad.ssp").exists()


def test_what_the_archive_cannot_hold_is_refused_before_anything_is_written(tmp_path, capsys):
    line = one_line(capsys, "export-ssp", "noise-kalman", "-o", str(tmp_path / "n.ssp"))
    assert "estimator: the Kalman filter runs in furuta-cosim's master" in line
    assert "nothing written" in line and not (tmp_path / "n.ssp").exists()
    line = one_line(capsys, "export-ssp", "paper-step", "--plant", "qube-servo-3", "--plant", "qube-servo-3",
                    "-o", str(tmp_path / "t.ssp"))
    assert "the parameter set 'qube-servo-3' is there twice" in line
    assert "ends in .ssp" in one_line(capsys, "export-ssp", "paper-step", "-o", str(tmp_path / "t.zip"))
    with pytest.raises(ConfigError, match="fmi_version"):
        export_ssp("paper-step", "lqr-paper", tmp_path / "v.ssp", fmi_version="1.0")


def test_without_the_schemas_the_archive_says_it_was_not_validated(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pyssp_standard", None)  # as if not installed
    code, out, _ = run_cli(capsys, "export-ssp", "paper-step", "-o", str(tmp_path / "p.ssp"))
    assert code == 0 and "schemas: not validated (install pyssp-standard" in out
    assert (tmp_path / "p.ssp").is_file()


def test_libcosim_refuses_the_fmi_3_archive_as_the_page_says(tmp_path):
    """The exchange page says libcosimpy reads FMI 2.0 only: should a release read 3.0, this
    fails and the page is to be corrected."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.ERROR)
    export_ssp("paper-step", "lqr-paper", tmp_path / "three.ssp", fmi_version="3.0")
    with pytest.raises(AssertionError, match="Unable to create execution"):
        CosimExecution.from_ssp_file(str(tmp_path / "three.ssp"), step_size=2_000_000)


def test_an_fmi_3_export_says_which_engines_run_it(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "export-ssp", "paper-step", "--fmi-version", "3.0", "-o", str(tmp_path / "t.ssp"))
    assert code == 0 and "libcosimpy 0.0.6) runs FMI 2.0 archives only" in out
    code, out, _ = run_cli(capsys, "export-ssp", "paper-step", "-o", str(tmp_path / "two.ssp"))
    assert code == 0 and "libcosimpy" not in out


def test_a_plant_file_identify_wrote_is_a_set_named_after_its_run_folder(tmp_path):
    folder = tmp_path / "qube-fit"
    folder.mkdir()
    (folder / "plant.yaml").write_text("model: furuta\nextends: qube-servo-3\ndescription: a fit\n"
                                       "parameters:\n  R_a: 7.66\n  M_f: 0.04266\n")
    found = export_ssp("qube-step", "lqr-qube", tmp_path / "fit.ssp", plants=[str(folder / "plant.yaml"), "qube-servo-3"])
    assert found["sets"] == ["qube-fit", "qube-servo-3"]
    plant = read_ssp(tmp_path / "fit.ssp", folder=tmp_path / "x")
    assert plant.set_name == "qube-fit" and plant.parameters["R_a"] == 7.66 and plant.parameters["M_f"] == 0.04266
    assert read_ssp(tmp_path / "fit.ssp", "qube-servo-3", folder=tmp_path / "y").parameters["R_a"] == 7.5
