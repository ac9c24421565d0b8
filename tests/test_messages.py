"""A library message names what its caller has: the Python argument or the file's key. The
command line turns those names into its flags (cli.as_flags), so each message is written once
and reads right from either side."""

from __future__ import annotations

import pytest

from furuta_cosim.errors import ConfigError

from helpers import one_line, run_cli


def _refusal(call) -> str:
    with pytest.raises(ConfigError) as caught:
        call()
    [line] = caught.value.problems
    return line


def test_a_parameter_set_given_twice(tmp_path, capsys):
    from furuta_cosim.ssp import export_ssp

    line = _refusal(lambda: export_ssp("paper-step", "lqr-paper", tmp_path / "a.ssp",
                                       plants=["qube-servo-3", "qube-servo-3"]))
    assert line.startswith("plants qube-servo-3: the parameter set 'qube-servo-3' is there twice"), line
    assert "--" not in line
    line = one_line(capsys, "export-ssp", "paper-step", "--plant", "qube-servo-3", "--plant", "qube-servo-3",
                    "-o", str(tmp_path / "b.ssp"))
    assert line.startswith("error: --plant qube-servo-3: the parameter set"), line


def test_a_board_given_another_models_plant(capsys):
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.rig.board import board_for

    line = _refusal(lambda: board_for("virtual:fast", load_plant("toy")))
    assert line.startswith("plant toy: a linear plant; the boards here run a Furuta pendulum"), line
    assert "--" not in line
    line = one_line(capsys, "rig", "home", "--board", "virtual:fast", "--plant", "toy")
    assert line.startswith("error: --plant toy: a linear plant"), line


def test_a_balance_controller_started_with_the_pendulum_down(tmp_path, capsys):
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.runner import run_rig

    plant = load_plant("qube-servo-3")
    line = _refusal(lambda: run_rig("lqr-qube", board_for("virtual:fast", plant), plant,
                                    tmp_path / "api", duration=1.0))
    assert "start it with `zero=False`" in line and "widen `catch` (in rad)" in line, line
    assert "--" not in line
    line = one_line(capsys, "rig", "run", "lqr-qube", "--board", "virtual:fast", "--duration", "1",
                    "-o", str(tmp_path / "cli"))
    assert "start it with --keep-zero" in line and "widen --catch (in rad)" in line, line
    assert "nothing was driven" in line


def test_a_rig_method_in_simulation(tmp_path, capsys):
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import load_spec

    line = _refusal(lambda: tune(load_spec("effort-qube"), tmp_path / "api", method="safe"))
    assert line.endswith("tunes on a rig: give a `board`, or an external rig (`evaluator`) with the folder its "
                         "trials are exchanged in"), line
    assert "--" not in line
    line = one_line(capsys, "tune", "effort-qube", "--optimizer", "safe", "-o", str(tmp_path / "cli"))
    assert line.endswith("give a --board, or an external rig (--evaluator external) with the folder its trials "
                         "are exchanged in"), line


def test_a_rejected_fit_as_a_plant(tmp_path, capsys):
    from furuta_cosim.fmu.plants import load_plant

    path = tmp_path / "plant.yaml"
    path.write_text("rejected: the held-out logs are 9 floors off\nmodel: furuta\n")
    line = _refusal(lambda: load_plant(path))
    assert line.endswith("or run identify with `accept=True` to write it as a plant all the same"), line
    line = one_line(capsys, "simulate", "paper-step", "--plant", str(path), "-o", str(tmp_path / "o"))
    assert line.endswith("or run identify with --accept to write it as a plant all the same"), line


def test_a_fit_the_logs_cannot_separate():
    """The precheck's next step names identify()'s ``force``; the command line its --force
    (tests/test_trust.py runs the command on a log without the current)."""
    from furuta_cosim.cli import as_flags
    from furuta_cosim.identify.precheck import next_step

    said = next_step([{"names": ["R_a", "M_f"]}], {"theta0", "theta1"}, plant_has_current=True)
    assert said.endswith("`force=True` fits anyway") and "--" not in said, said
    assert as_flags(said).endswith("--force fits anyway")


def test_an_archive_of_a_scenario_without_a_controller(tmp_path):
    """Reached from Python only (a scenario file names its controllers): export_ssp's argument."""
    from dataclasses import replace

    from furuta_cosim.cli import as_flags
    from furuta_cosim.scenario import load_scenario
    from furuta_cosim.ssp import export_ssp

    scenario = replace(load_scenario("paper-step"), controllers=())
    line = _refusal(lambda: export_ssp(scenario, None, tmp_path / "a.ssp"))
    assert line.endswith("names no controller: give one (`controller=NAME`)"), line
    assert as_flags(line).endswith("give one (--controller NAME)")
    assert not (tmp_path / "a.ssp").exists()
