"""--plant: every command that runs or designs on the pendulum takes another plant; scenarios
of another model are not applicable, never an error about a file the user did not write; a
designed controller names its model relative to itself and travels."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli

ROOT = Path(__file__).resolve().parent.parent


def test_regress_on_another_plant_lists_the_toy_scenarios_as_not_applicable(capsys, tmp_path):
    code, out, err = run_cli(capsys, "regress", "paper-step", "toy-step", "--plant", "qube-servo-3",
                             "--json")
    report = json.loads(out)
    status = {(c["scenario"], c["controller"]): c["status"] for c in report["cases"]}
    assert status[("toy-step", "toy-classical")] == "n/a" and status[("toy-step", "toy-generalized")] == "n/a"
    # the paper's controllers on the QUBE plant: what moves is reported, as regressions
    assert status[("paper-step", "lqr-paper")] == "fail" and report["plant"] == "qube-servo-3"
    assert code == 1 and "plant.overrides" not in err
    notes = [c["notes"][0] for c in report["cases"] if c["status"] == "n/a"]
    assert all("runs the toy plant (model linear); qube-servo-3 is a furuta plant" in n for n in notes)


def test_regress_params_of_a_pendulum_set_skip_the_toy_scenarios(capsys):
    code, out, err = run_cli(capsys, "regress", "toy-step", "--params", "qube-servo-3")
    assert code == 0, err  # nothing applicable failed
    assert "2 n/a" in out and "its plant has no parameter m_p, m_c, I_p and" in out
    assert "error" not in err


def test_regress_on_its_own_plant_passes_as_without(capsys):
    code, out, err = run_cli(capsys, "regress", "paper-step", "--plant", "paper-calibrated")
    assert code == 0 and "2 pass" in out, (out, err)


def test_simulate_on_another_plant_and_on_the_wrong_model(capsys, tmp_path):
    code, out, err = run_cli(capsys, "simulate", "paper-step", "--plant", "qube-servo-3",
                             "--controller", str(ROOT / "scenarios" / "controllers" / "lqr-paper.yaml"),
                             "-o", str(tmp_path / "q"), "--json")
    assert json.loads(out)["plant"] == "qube-servo-3"
    code, out, err = run_cli(capsys, "simulate", "toy-step", "--plant", "qube-servo-3", "-o", str(tmp_path / "t"))
    assert code == 2 and err.count("\n") == 1 and "runs the toy plant" in err
    assert not (tmp_path / "t").exists()


def test_a_designed_controller_names_its_plant_relative_to_itself_and_travels(capsys, tmp_path):
    work = tmp_path / "work"
    (work / "plants").mkdir(parents=True)
    plant = work / "plants" / "rig.yaml"
    plant.write_text("model: furuta\nextends: qube-servo-3\nparameters: {R_a: 7.7}\n")
    code, out, err = run_cli(capsys, "design", "lqr", "--plant", str(plant), "-o",
                             str(work / "controllers" / "lqr-rig.yaml"), "--json")
    assert code == 0, err
    text = (work / "controllers" / "lqr-rig.yaml").read_text()
    assert "model: derived:../plants/rig.yaml" in text and str(tmp_path) not in text
    moved = tmp_path / "elsewhere"
    shutil.copytree(work, moved)
    shutil.rmtree(work)
    code, out, err = run_cli(capsys, "analyze", str(moved / "controllers" / "lqr-rig.yaml"), "--json")
    assert code == 0, err
    assert json.loads(out)["stable"] is True
    code, out, err = run_cli(capsys, "design", "lqr", "--plant", "qube-servo-3", "--model", "toy")
    assert code == 2 and "give it or --model, not both" in err


def _history(folder):
    return [{k: v for k, v in json.loads(line).items() if k not in ("wall_time", "worker")}
            for line in (folder / "history.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_tune_for_another_plant_compares_with_that_plants_lqr(capsys, tmp_path):
    from furuta_cosim.tuning.spec import load_spec

    out = tmp_path / "run"
    code, text, err = run_cli(capsys, "tune", "effort", "--plant", "qube-servo-3", "--n-calls", "4",
                              "--workers", "1", "-o", str(out), "--json")
    assert code == 0, err
    document = json.loads(text)
    assert list(document["baselines"]) == ["lqr-paper-on-qube-servo-3"]
    assert json.loads((out / "run.json").read_text())["plant"] == "qube-servo-3"
    assert "model: derived:qube-servo-3" in (out / "best.yaml").read_text()
    summary = (out / "summary.md").read_text()
    assert "On plant qube-servo-3" in summary and "designed again for qube-servo-3" in summary
    # the LQR designed for the plant is the paper's recipe on its linearization
    spec = load_spec("effort", plant="qube-servo-3")
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.lqr_file import design_lqr_file

    again = load_controller(spec.baselines[0])
    fresh = design_lqr_file("derived:qube-servo-3", Q=[1, 10, 100, 10, 1], R=[10])
    np.testing.assert_allclose(again.controller.K, fresh.cfile.controller.K, rtol=1e-12)
    # the spec's own plant key gives the same search
    copy = tmp_path / "effort-qube.yaml"
    copy.write_text((ROOT / "scenarios" / "tuning" / "effort.yaml").read_text() + "plant: qube-servo-3\n")
    (tmp_path / "controllers").mkdir()
    shutil.copy(ROOT / "scenarios" / "controllers" / "lqr-paper.yaml", tmp_path / "controllers")
    code, _, err = run_cli(capsys, "tune", str(copy), "--n-calls", "4", "--workers", "1", "-o", str(tmp_path / "keyed"))
    assert code == 0, err
    assert _history(tmp_path / "keyed") == _history(out)
    # resuming without the plant would mix two searches
    code, _, err = run_cli(capsys, "tune", "effort", "--n-calls", "6", "-o", str(out), "--resume")
    assert code == 2 and "--plant (none) differs from the run's qube-servo-3" in err


def test_tune_on_a_plant_of_another_model_names_the_scenario(capsys, tmp_path):
    spec = tmp_path / "toy-on-qube.yaml"
    # at a period the QUBE allows, so that what is refused is the scenario's model
    spec.write_text("controller: {n_xc: 0, model: toy, time: discrete, period: 0.002}\n"
                    "parameters: {Dc: {box: [-2, 2]}}\n"
                    "objective: {type: scenarios, scenarios: [toy-step], terms: [{metric: error.ISE}]}\n"
                    "plant: qube-servo-3\n")
    code, out, err = run_cli(capsys, "tune", str(spec), "-o", str(tmp_path / "run"))
    assert code == 2 and not (tmp_path / "run").exists()
    assert "objective.scenarios[0]" in err and "runs the toy plant" in err, err


@pytest.mark.slow
def test_a_run_directory_travels_with_its_plant(capsys, tmp_path):
    work = tmp_path / "lab"
    (work / "plants").mkdir(parents=True)
    (work / "plants" / "rig.yaml").write_text("model: furuta\nextends: qube-servo-3\nparameters: {R_a: 7.7}\n")
    code, text, err = run_cli(capsys, "tune", "effort", "--plant", str(work / "plants" / "rig.yaml"),
                              "--n-calls", "3", "--workers", "1", "-o", str(work / "runs" / "effort"), "--json")
    assert code == 0, err
    best = (work / "runs" / "effort" / "best.yaml").read_text()
    assert "model: derived:../../plants/rig.yaml" in best and str(tmp_path) not in best
    recorded = json.loads(text)["best"]["metrics"]["paper-tracking"]["u.rms"]
    moved = tmp_path / "moved"
    shutil.move(str(work), moved)
    code, out, err = run_cli(capsys, "analyze", str(moved / "runs" / "effort" / "best.yaml"))
    assert code in (0, 1) and "derived:rig" in out, err
    code, out, err = run_cli(capsys, "simulate", "paper-tracking", "--plant", str(moved / "plants" / "rig.yaml"),
                             "--controller", str(moved / "runs" / "effort" / "best.yaml"),
                             "-o", str(tmp_path / "sim"), "--json")
    assert json.loads(out)["controllers"]["effort-best"]["metrics"]["u.rms"] == pytest.approx(recorded, rel=1e-9)


def _plant_with_limits(tmp_path, limits: str) -> Path:
    plant = tmp_path / "rig.yaml"
    plant.write_text(f"model: furuta\nextends: qube-servo-3\nlimits: {limits}\n")
    return plant


def test_a_plant_states_the_control_periods_it_allows(capsys, tmp_path):
    from furuta_cosim.fmu.plants import load_plant

    assert load_plant("qube-servo-3").control_period == (None, 0.004)
    assert load_plant("paper-calibrated").control_period == (None, None)
    # a plant that extends another keeps the bounds it does not restate
    assert load_plant(_plant_with_limits(tmp_path, "{control_period: {min: 0.001}}")).control_period == (0.001, 0.004)
    # a scenario of that model at a period the plant refuses: one line naming both files
    code, out, err = run_cli(capsys, "simulate", "paper-step", "--plant",
                             str(_plant_with_limits(tmp_path, "{control_period: {min: 0.003}}")),
                             "-o", str(tmp_path / "out"))
    assert code == 2 and err.count("\n") == 1, err
    assert "paper-step.yaml: timing.control_period: 0.002 s is outside what the rig plant allows " \
           "(rig.yaml: limits.control_period: min 0.003 and max 0.004)" in err
    # and a tuning spec whose controller runs at that period
    code, out, err = run_cli(capsys, "tune", "effort", "--plant", str(tmp_path / "rig.yaml"),
                             "-o", str(tmp_path / "tune"))
    assert code == 2 and "effort.yaml: controller.period: 0.002 s is outside what the rig plant allows" in err
    assert not (tmp_path / "tune").exists()


@pytest.mark.parametrize("limits, message", [
    ("{control_period: {min: 0.01, max: 0.001}}", "limits.control_period: min (0.01) is above max (0.001)"),
    ("{control_period: {max: -1}}", "limits.control_period.max: must be > 0, got -1"),
    ("{period: 1}", "limits.period: unknown key (expected one of: control_period, current, stall_seconds"),
    ("[1, 2]", "limits: expected a mapping"),
])
def test_a_plants_limits_are_checked_like_the_rest_of_it(tmp_path, limits, message):
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.fmu.plants import load_plant

    with pytest.raises(ConfigError) as raised:
        load_plant(_plant_with_limits(tmp_path, limits))
    assert message in str(raised.value) and "rig.yaml" in str(raised.value)
