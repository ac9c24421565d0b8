"""simulate LOOP.ssp runs the system the archive describes: its FMUs, wiring, sets and
experiment, checked first, stepped by a Jacobi master, as Ecos runs the same archive; another
tool's archive too."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.export import export_controller
from furuta_cosim.ssp import export_ssp
from furuta_cosim.ssp.system import SystemFailed, load_system, run_system

from helpers import DYNAMIC, ROOT, build_foreign, one_line, run_cli
from test_ssp import _ecos, _hold, _master, _replace, _rewritten

FOREIGN = ROOT / "tests" / "foreign"
ANGLES = ("theta0", "theta1")


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    folder = tmp_path_factory.mktemp("system")
    found = export_ssp("paper-step", "lqr-paper", folder / "loop.ssp")
    return folder / "loop.ssp", found


@pytest.mark.parametrize("controller,version", [("lqr-paper", "2.0"), ("lqr-paper", "3.0"), ("dynamic", "2.0")])
def test_the_system_runs_as_ecos_runs_it_and_as_the_master_runs_its_scenario(tmp_path, controller, version):
    if controller == "dynamic":
        (tmp_path / "dynamic.yaml").write_text(DYNAMIC)
        controller = str(tmp_path / "dynamic.yaml")
    found = export_ssp("paper-step", controller, tmp_path / "loop.ssp", fmi_version=version)
    run = run_system(load_system(tmp_path / "loop.ssp"))
    ecos = _ecos(tmp_path / "loop.ssp", found, found["sets"][0])
    master = _master("paper-step", controller)
    n = len(ecos)
    assert len(run.t) == n + 1 and run.order == "Jacobi"
    for j, name in enumerate([*ANGLES, "V"]):
        assert np.max(np.abs(run[f"plant.{name}"][:n] - ecos[:, j])) <= 1e-12, name
    for name in ANGLES:
        assert np.max(np.abs(run[f"plant.{name}"][:n] - master[name])) <= 1e-9, name
    assert np.max(np.abs(run["plant.V"][:n] - master.u)) <= 1e-9 * np.max(np.abs(master.u))
    assert np.max(np.abs(run["plant.theta0"])) > 0.1        # the loop moved


def test_a_parameter_set_is_chosen_by_name(tmp_path):
    found = export_ssp(_hold(tmp_path), "lqr-qube", tmp_path / "q.ssp", plants=["qube-servo-3", "qube-servo-3-worn"])
    runs = {}
    for name in found["sets"]:
        system = load_system(tmp_path / "q.ssp", name)
        assert system.parts["plant"].set_name == name
        runs[name] = run_system(system)
        ecos = _ecos(tmp_path / "q.ssp", found, name)
        assert np.max(np.abs(runs[name]["plant.theta0"][:len(ecos)] - ecos[:, 0])) <= 1e-12
    assert load_system(tmp_path / "q.ssp").parts["plant"].set_name == "qube-servo-3"   # the first by default
    apart = np.max(np.abs(runs["qube-servo-3"]["plant.theta0"] - runs["qube-servo-3-worn"]["plant.theta0"]))
    assert apart > 1e-4    # the sets are different plants
    with pytest.raises(ConfigError, match="no parameter set 'nosuch' for component plant"):
        load_system(tmp_path / "q.ssp", "nosuch")


def test_the_master_order_is_stated_and_measured(loop):
    path, _ = loop
    system = load_system(path)
    jacobi = run_system(system)
    for order in (["plant", "controller"], ["controller", "plant"]):
        other = run_system(system, order=order)
        assert other.order.startswith("Gauss-Seidel")
        # another loop: each command reaches the plant a step earlier or a sample later
        assert np.max(np.abs(other["plant.theta0"] - jacobi["plant.theta0"])) > 1e-3
    with pytest.raises(ConfigError, match="order: expected each component once"):
        run_system(system, order=["plant"])


# each broken archive: (what is changed, what its one line says)
BROKEN = [
    (_replace("SystemStructure.ssd", b'endElement="controller" endConnector="theta1"',
              b'endElement="controler" endConnector="theta1"'),
     r"connection plant.theta1 -> controler.theta1: no element 'controler'"),
    (_replace("SystemStructure.ssd", b'startElement="plant" startConnector="theta1"',
              b'startElement="plant" startConnector="i"'),
     r"connection plant.i -> controller.theta1: from A to rad \(no conversion is applied\)"),
    (_replace("SystemStructure.ssd", b'startElement="plant" startConnector="theta1" endElement="controller" '
              b'endConnector="theta1"', b'startElement="plant" startConnector="theta0" endElement="controller" '
              b'endConnector="theta0"'),
     r"controller.theta0 is already fed by plant.theta0"),
    (_replace("SystemStructure.ssd",
              b'<ssd:Connection startElement="controller" startConnector="V" endElement="plant" endConnector="V" />',
              b""),
     r"component plant: input 'V' is connected to nothing and no parameter set gives it a value"),
    (_replace("SystemStructure.ssd", b'<ssd:Connector name="V" kind="input">', b'<ssd:Connector name="V" kind="output">'),
     r"component plant: connector 'V' is kind output, where its FMU declares it input"),
    (_replace("SystemStructure.ssd", b'<ssd:Connector name="theta1" kind="output">\n            <ssc:Real unit="rad" />',
              b'<ssd:Connector name="theta1" kind="output">\n            <ssc:Real unit="deg" />'),
     r"component plant: connector 'theta1' is in deg, where its FMU declares rad"),
    (_replace("SystemStructure.ssd", b' version="1.0" name="paper-step"', b' name="paper-step"'),
     r"has no version"),
    (_replace("SystemStructure.ssd", b'endElement="controller" endConnector="dtheta0"',
              b'endElement="controller" endConnector="r"'),
     r"component controller declares no connector 'r'"),
]


@pytest.mark.parametrize("change,expected", BROKEN)
def test_a_system_that_cannot_run_as_written_is_one_line_and_exit_2(tmp_path, capsys, loop, change, expected):
    import re

    bad = _rewritten(loop[0], tmp_path / "bad.ssp", change)
    line = one_line(capsys, "simulate", str(bad), "-o", str(tmp_path / "o"))
    assert re.search(expected, line), line
    assert str(bad) in line and not (tmp_path / "o").exists()


def test_simulate_writes_the_run_and_says_what_ran(tmp_path, capsys, loop):
    code, out, err = run_cli(capsys, "simulate", str(loop[0]), "-o", str(tmp_path / "o"))
    assert code == 0
    assert "2 components: plant (plant.fmu, FMI 2.0, set paper-calibrated), controller" in err
    assert "6 connections; 0 to 10 s in steps of 0.002 s" in err
    assert "5000 steps (Jacobi)" in out
    table = np.genfromtxt(tmp_path / "o" / "system.csv", delimiter=",", names=True)
    run = run_system(load_system(loop[0]))
    assert np.array_equal(table["plantV"], run["plant.V"]) and np.array_equal(table["time"], run.t)
    assert (tmp_path / "o" / "system.png").stat().st_size > 10_000
    code, _, _ = run_cli(capsys, "simulate", str(loop[0]), "--controller", "lqr-paper")
    assert code == 2


def _foreign_system(folder: Path, pendulum: Path) -> Path:
    """Three FMUs from three places in an .ssd written here: the pythonfmu pendulum under its
    own names, our controller FMU (one sample late) and a pythonfmu first-order lag fed the
    pendulum's angle; the pendulum starts 0.1 rad off upright (its set)."""
    build_foreign("pythonfmu", FOREIGN / "mixed_fmu.py", folder)
    controller = export_controller("lqr-paper", folder, delay=1)
    pairs = [("arm_angle", "theta0"), ("arm_rate", "dtheta0"), ("pend_angle", "theta1"),
             ("pend_rate", "dtheta1"), ("current", "i")]

    def connectors(items):
        return "".join(f'<ssd:Connector name="{n}" kind="{k}"/>' for n, k in items)

    ssd = f"""<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"
  xmlns:osp="http://opensimulationplatform.com/SSP/OSPAnnotations"
  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="foreign">
 <ssd:System name="three">
  <ssd:Elements>
   <ssd:Component name="pendulum" source="resources/pendulum.fmu">
    <ssd:Connectors>{connectors([(a, "output") for a, _ in pairs] + [("voltage", "input")])}</ssd:Connectors>
    <ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>
     <ssv:ParameterSet version="1.0" name="tilted"><ssv:Parameters>
      <ssv:Parameter name="pend_angle_0"><ssv:Real value="0.1"/></ssv:Parameter>
     </ssv:Parameters></ssv:ParameterSet>
    </ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>
   </ssd:Component>
   <ssd:Component name="control" source="resources/control.fmu">
    <ssd:Connectors>{connectors([(b, "input") for _, b in pairs] + [("V", "output")])}</ssd:Connectors>
   </ssd:Component>
   <ssd:Component name="lag" source="resources/lag.fmu">
    <ssd:Connectors>{connectors([("u", "input"), ("y", "output")])}</ssd:Connectors>
   </ssd:Component>
  </ssd:Elements>
  <ssd:Connections>
   {"".join(f'<ssd:Connection startElement="pendulum" startConnector="{a}" endElement="control" endConnector="{b}"/>'
            for a, b in pairs)}
   <ssd:Connection startElement="control" startConnector="V" endElement="pendulum" endConnector="voltage"/>
   <ssd:Connection startElement="pendulum" startConnector="pend_angle" endElement="lag" endConnector="u"/>
  </ssd:Connections>
 </ssd:System>
 <ssd:DefaultExperiment startTime="0" stopTime="2"><ssd:Annotations>
  <ssc:Annotation type="com.opensimulationplatform"><osp:Algorithm>
   <osp:FixedStepAlgorithm baseStepSize="0.002"/></osp:Algorithm></ssc:Annotation>
 </ssd:Annotations></ssd:DefaultExperiment>
</ssd:SystemStructureDescription>
"""
    path = folder / "foreign.ssp"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", ssd)
        archive.write(pendulum, "resources/pendulum.fmu")
        archive.write(controller, "resources/control.fmu")
        archive.write(folder / "MixedTypes.fmu", "resources/lag.fmu")
    return path


def _fmpy_jacobi(folder: Path, connections, starts: dict, steps: int, h: float) -> dict:
    """The same wiring stepped by a Jacobi master written here over fmpy's own FMU2Slave."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    slaves, refs = {}, {}
    for name in ("pendulum", "control", "lag"):
        fmu = folder / "x" / f"{name}.fmu"
        md = read_model_description(str(fmu))
        slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        refs[name] = {v.name: v.valueReference for v in md.modelVariables}
        for variable, value in starts.get(name, {}).items():
            slave.setReal([refs[name][variable]], [value])
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slaves[name] = slave
    read = {(e, c) for (e, c), _ in connections} | {("lag", "y")}
    value = {key: slaves[key[0]].getReal([refs[key[0]][key[1]]])[0] for key in read}
    rows = {key: [value[key]] for key in read}
    for k in range(steps):
        for (e, c), (f, d) in connections:
            slaves[f].setReal([refs[f][d]], [value[(e, c)]])
        for name, slave in slaves.items():
            slave.doStep(k * h, h)
        value = {key: slaves[key[0]].getReal([refs[key[0]][key[1]]])[0] for key in read}
        for key in read:
            rows[key].append(value[key])
    for slave in slaves.values():
        slave.terminate()
        slave.freeInstance()
    return {f"{e}.{c}": np.array(v) for (e, c), v in rows.items()}


@pytest.mark.slow
def test_another_tools_three_fmus_run_as_an_independent_master_runs_them(tmp_path, foreign_fmu):
    path = _foreign_system(tmp_path, foreign_fmu)
    system = load_system(path, folder=tmp_path / "x")
    assert list(system.parts) == ["pendulum", "control", "lag"] and system.parts["pendulum"].set_name == "tilted"
    run = run_system(system)
    mine = _fmpy_jacobi(tmp_path, system.connections, {"pendulum": {"pend_angle_0": 0.1}}, system.steps, system.step)
    for name in ("pendulum.arm_angle", "pendulum.pend_angle", "control.V", "lag.y"):
        assert np.max(np.abs(run[name] - mine[name])) <= 1e-12, name
    assert run["pendulum.pend_angle"][0] == 0.1 and abs(run["pendulum.pend_angle"][-1]) < 0.01   # caught
    assert np.max(np.abs(run["lag.y"])) > 0.01                                                     # the lag ran


def test_a_component_that_gives_nan_stops_the_run_naming_it(tmp_path, capsys, loop, monkeypatch):
    from furuta_cosim.fmu.session import PlantSession

    original = PlantSession.step

    def poisoned(self, inputs, h):
        values = original(self, inputs, h)
        if self.time > 0.5 and "theta1" in self.outputs:
            values[self.outputs.index("theta1")] = float("nan")
        return values

    monkeypatch.setattr(PlantSession, "step", poisoned)
    with pytest.raises(SystemFailed, match=r"plant.theta1 is nan at t = 0.502 s"):
        run_system(load_system(loop[0]))
    code, out, _ = run_cli(capsys, "simulate", str(loop[0]), "-o", str(tmp_path / "o"))
    assert code == 1 and out.startswith("FAIL") and "plant.theta1 is nan" in out
