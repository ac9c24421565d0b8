"""The whole scenario travels: a reference that changes, seeded measurement noise and
disturbances go into the SSP as a source FMU the exporter builds, so that Ecos, libcosim and
simulate LOOP.ssp run the scenario itself, each within 1e-9 of simulate SCENARIO."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from furuta_cosim.fmu.session import model_description
from furuta_cosim.ssp import export_ssp
from furuta_cosim.ssp.system import load_system, run_system

from helpers import DYNAMIC, one_line
from test_ssp import _ecos, _libcosim, _master

AGREE = 1e-9
LOOPS = [("qube-step", "lqr-qube"), ("qube-sine", "lqr-qube"), ("noise", "lqr-paper"),
         ("disturbance", "lqr-paper"), ("noise", "dynamic")]


def _controller(folder, name):
    if name == "dynamic":
        (folder / "dynamic.yaml").write_text(DYNAMIC)
        return str(folder / "dynamic.yaml")
    return name


def _agree(rows: np.ndarray, master, n: int) -> None:
    for j, name in enumerate(("theta0", "theta1")):
        assert np.max(np.abs(rows[:n, j] - master[name][:n])) <= AGREE, name
    assert np.max(np.abs(rows[:n, 2] - master.u[:n])) <= AGREE * max(1.0, np.max(np.abs(master.u)))


@pytest.mark.parametrize("scenario,controller", LOOPS)
def test_the_scenario_runs_in_ecos_and_here_as_the_master_runs_it(tmp_path, scenario, controller):
    controller = _controller(tmp_path, controller)
    found = export_ssp(scenario, controller, tmp_path / "loop.ssp")
    assert found["source"] and "come from the component source" in found["note"]
    master = _master(scenario, controller)
    run = run_system(load_system(tmp_path / "loop.ssp"))
    ours = np.column_stack([run["plant.theta0"], run["plant.theta1"], run["plant.V"]])
    n = len(master.t)
    _agree(ours, master, n)
    _agree(_ecos(tmp_path / "loop.ssp", found, found["sets"][0]), master, n)
    # the source carried something the loop felt: without it (a constant reference, no noise,
    # no pulse) the run differs
    assert np.max(np.abs(run["source.r"] - run["source.r"][0])) > 0 or scenario in ("noise", "disturbance")
    moved = {"qube-step": 0.1, "qube-sine": 0.05, "noise": 1e-4, "disturbance": 1e-3}[scenario]
    assert np.max(np.abs(master["theta0"])) > moved


@pytest.mark.parametrize("scenario", ["qube-step", "noise"])
def test_the_scenario_runs_in_libcosim_as_the_master_runs_it(tmp_path, scenario):
    controller = "lqr-qube" if scenario.startswith("qube") else "lqr-paper"
    found = export_ssp(scenario, controller, tmp_path / "loop.ssp")
    rows = _libcosim(tmp_path / "loop.ssp", found)
    master = _master(scenario, controller)
    # libcosim's observer reads after each step: the next sample's angles, this step's command
    for j, name in enumerate(("theta0", "theta1")):
        assert np.max(np.abs(rows[:-1, j] - master[name][1:])) <= AGREE, name
    assert np.max(np.abs(rows[:, 2] - master.u)) <= AGREE * max(1.0, np.max(np.abs(master.u)))


def test_an_fmi_3_source_runs_the_same(tmp_path):
    found = export_ssp("noise", "lqr-paper", tmp_path / "three.ssp", fmi_version="3.0")
    master = _master("noise", "lqr-paper")
    run = run_system(load_system(tmp_path / "three.ssp"))
    assert run.values and load_system(tmp_path / "three.ssp").parts["source"].md.fmiVersion == "3.0"
    _agree(np.column_stack([run["plant.theta0"], run["plant.theta1"], run["plant.V"]]), master, len(master.t))
    _agree(_ecos(tmp_path / "three.ssp", found, found["sets"][0]), master, len(master.t))


def test_the_source_is_a_valid_fmu_and_the_archive_the_same_bytes_twice(tmp_path):
    import zipfile

    first = export_ssp("noise", "lqr-paper", tmp_path / "a.ssp")
    export_ssp("noise", "lqr-paper", tmp_path / "b.ssp")
    assert (tmp_path / "a.ssp").read_bytes() == (tmp_path / "b.ssp").read_bytes()
    with zipfile.ZipFile(tmp_path / "a.ssp") as archive:
        (tmp_path / "source.fmu").write_bytes(archive.read("resources/source.fmu"))
    assert validate_fmu(str(tmp_path / "source.fmu")) == []
    outputs = [v.name for v in model_description(tmp_path / "source.fmu").modelVariables if v.causality == "output"]
    assert {"r", "n_theta0", "n_i", "d_tau0", "d_tau1"} <= set(outputs)
    assert "seed 7" in first["note"]


def test_a_plant_file_cannot_name_the_source_model(tmp_path, capsys):
    (tmp_path / "mine.yaml").write_text("model: source\ndescription: a source is no plant\n")
    line = one_line(capsys, "simulate", "paper-step", "--plant", str(tmp_path / "mine.yaml"), "-o", str(tmp_path / "o"))
    assert "model: expected the name of a plant model" in line and "source" not in line.split("(")[1].split(")")[0]
