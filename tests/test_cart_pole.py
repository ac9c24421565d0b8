"""The cart-pole example (scenarios/cart-pole/): every command of the toolchain on a plant
that is not the Furuta pendulum, its states named by its own declaration."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.fmu.check import validate
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.regression import regress
from furuta_cosim.scenario import load_scenario
from furuta_cosim.ssp import export_ssp
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

from helpers import ROOT, run_cli

EXAMPLE = ROOT / "scenarios" / "cart-pole"


def test_the_shipped_lqr_is_what_design_lqr_gives_on_the_plant(capsys, tmp_path):
    shipped = yaml.safe_load((EXAMPLE / "controllers" / "lqr-ip02.yaml").read_text())
    Q = [str(v) for v in np.diag(shipped["provenance"]["Q"])]
    R = str(shipped["provenance"]["R"][0][0])
    code, out, _ = run_cli(capsys, "design", "lqr", "--plant", str(EXAMPLE / "plants" / "ip02.yaml"),
                           "--Q", *Q, "--R", R, "--json")
    assert code == 0
    designed = json.loads(out)
    np.testing.assert_allclose(np.ravel(designed["K"]), shipped["K"], rtol=1e-9)
    assert designed["prefilter"]["output"] == "x_c"   # the declaration's first measured output


def _runs(name):
    scenario = load_scenario(EXAMPLE / f"{name}.yaml")
    prepared = prepare(scenario)
    with PlantSession.open(prepared.fmu) as session:
        return {c: evaluate(prepared, session, str(EXAMPLE / "controllers" / f"{c}.yaml"))
                for c in ("lqr-ip02", "effort-ip02")}, prepared


@pytest.mark.parametrize("name", ["cart-step", "cart-sine"])
def test_both_controllers_balance_the_pendulum_while_the_cart_tracks(name):
    runs, prepared = _runs(name)
    assert prepared.states == ["x_c", "dx_c", "alpha", "dalpha"] and prepared.control_input == "V"
    for controller, result in runs.items():
        trace = result.trace
        assert np.max(np.abs(trace["alpha"])) < 0.1, controller             # balanced
        error = trace["x_c"] - trace.r
        if name == "cart-step":
            assert np.max(np.abs(error[-500:])) < 0.002, controller          # settled in the last second
        else:   # follows the sine, behind it by a fraction of its size
            assert np.sqrt(np.mean(error ** 2)) < 0.5 * np.sqrt(np.mean(trace.r ** 2)), controller
    # the tuned generalized controller spends less voltage than the LQR, as tuned for
    rms = {c: float(np.sqrt(np.mean(np.square(r.trace.u)))) for c, r in runs.items()}
    assert rms["effort-ip02"] < (0.9 if name == "cart-step" else 0.99) * rms["lqr-ip02"], rms


def test_regress_of_the_example_tree_passes_against_its_baselines():
    results = regress([EXAMPLE]).cases
    assert sorted((r.scenario, r.controller) for r in results) == [
        ("cart-sine", "effort-ip02"), ("cart-sine", "lqr-ip02"),
        ("cart-step", "effort-ip02"), ("cart-step", "lqr-ip02")]
    assert all(r.status == "pass" and r.checked >= 19 for r in results), \
        [(r.scenario, r.controller, r.status, r.checked) for r in results]


@pytest.mark.slow
def test_a_30_evaluation_tuning_beats_the_lqr_and_its_best_file_reproduces_its_score(tmp_path):
    spec = load_spec(EXAMPLE / "tuning" / "effort-ip02.yaml")
    summary = tune(spec, tmp_path / "run", n_calls=30, seed=0)
    best = summary["best"]["objective"]
    assert best < 1.1 - 0.03   # the LQR scores 1.1 on this spec
    again = tune(spec, tmp_path / "again", n_calls=30, seed=0)
    assert again["best"]["objective"] == best   # a run is its seed's, to the bit
    saved = yaml.safe_load((tmp_path / "run" / "best.yaml").read_text())
    assert saved["type"] == "generalized" and len(saved["Dc"][0]) == 4


def test_the_exported_loop_runs_in_ecos_as_our_master_runs_it(tmp_path):
    from ecospy import EcosSimulation

    scenario = str(EXAMPLE / "cart-step.yaml")
    controller = str(EXAMPLE / "controllers" / "effort-ip02.yaml")
    found = export_ssp(scenario, controller, tmp_path / "loop.ssp")
    rows = []
    with EcosSimulation(step_size=found["step"], ssp_path=str(tmp_path / "loop.ssp")) as simulation:
        simulation.init(parameter_set=found["sets"][0])
        for _ in range(int(round(found["stop"] / found["step"]))):
            rows.append([simulation.get_real(n) for n in ("plant::x_c", "plant::alpha", "plant::V")])
            simulation.step()
        simulation.terminate()
    rows = np.array(rows)
    prepared = prepare(replace(load_scenario(scenario), delay=1))
    with PlantSession.open(prepared.fmu) as session:
        master = evaluate(prepared, session, controller).trace
    assert len(rows) == len(master.t)
    assert np.max(np.abs(rows[:, 0] - master["x_c"])) <= 1e-6
    assert np.max(np.abs(rows[:, 1] - master["alpha"])) <= 1e-6
    assert np.max(np.abs(rows[:, 2] - master.u)) <= 1e-6 * np.max(np.abs(master.u))
    assert np.max(master["x_c"]) > 0.09      # the cart went where the step said


def test_the_controller_exports_as_an_fmu_that_passes_every_check(capsys, tmp_path):
    code, out, _ = run_cli(capsys, "export-controller", str(EXAMPLE / "controllers" / "effort-ip02.yaml"),
                           "-o", str(tmp_path))
    assert code == 0
    fmu = out.strip().splitlines()[-1]
    findings = validate(fmu)
    assert all(f.ok for f in findings), [f for f in findings if not f.ok]
    from fmpy import read_model_description

    units = {v.name: v.unit for v in read_model_description(fmu).modelVariables}
    assert {"x_c", "dx_c", "alpha", "dalpha", "V"} <= set(units)
    # each signal as the cart-pole's declaration says it, the reference in the tracked output's unit
    assert (units["x_c"], units["dalpha"], units["r"], units["V"]) == ("m", "rad/s", "m", "V")


def test_analyze_gives_the_loop_of_the_plant_s_own_states(capsys):
    code, out, _ = run_cli(capsys, "analyze", str(EXAMPLE / "controllers" / "effort-ip02.yaml"), "--json")
    assert code == 0
    result = json.loads(out)
    assert result["stable"] is True


def _chirp_log(folder, truth):
    from furuta_cosim.identify.synthetic import open_loop_log

    t = 0.002 * np.arange(2500)    # 5 s, the pendulum hanging; a chirp of 0.3 to 5.3 Hz on the motor
    return open_loop_log(folder, EXAMPLE / "plants" / "ip02.yaml",
                         {"V": 2.0 * np.sin(2 * np.pi * (0.3 * t + 0.5 * t * t))}, period=0.002,
                         outputs={"x_c": ("m", 2.275e-5), "alpha": ("rad", 2 * np.pi / 4096)},
                         truth=truth, start={"alpha": np.pi}, name="chirp")


def test_identify_finds_the_truth_of_a_synthetic_log_within_its_intervals(tmp_path):
    from furuta_cosim.identify.run import identify

    truth = {"B_eq": 5.4, "B_p": 0.004}   # the manual's 4.3 and 0.0024 as the start
    experiment = _chirp_log(tmp_path / "logs", truth)
    spec = tmp_path / "dampings.yaml"
    spec.write_text(f"name: dampings\nplant: {EXAMPLE / 'plants' / 'ip02.yaml'}\n"
                    f"experiments: [{experiment}]\n"
                    "free:\n  B_eq: {bounds: [0.5, 20.0]}\n  B_p: {bounds: [0.0, 0.05]}\n")
    document = identify(spec, tmp_path / "fit")
    assert document["verdict"]["trusted"] is True
    for name, value in truth.items():
        found = document["parameters"][name]
        low, high = found["interval"]
        assert low <= value <= high and found["verdict"] == "identifiable", (name, found)
        assert abs(found["value"] - value) < 1e-3 * value
    fitted = yaml.safe_load((tmp_path / "fit" / "plant.yaml").read_text())
    assert fitted["parameters"]["B_eq"] == pytest.approx(5.4, rel=1e-3)


def test_a_closed_loop_log_of_another_plant_is_refused_in_one_line(tmp_path, capsys):
    from helpers import one_line

    experiment = _chirp_log(tmp_path, None)
    text = experiment.read_text() + f"loop: {{controller: {EXAMPLE / 'controllers' / 'lqr-ip02.yaml'}}}\n"
    experiment.write_text(text)
    line = one_line(capsys, "replay", str(experiment), "--plant", str(EXAMPLE / "plants" / "ip02.yaml"))
    assert "loop: a closed-loop log is replayed through the Furuta pendulum's loop" in line


def test_the_rig_says_in_one_line_that_it_runs_a_furuta_pendulum(capsys, tmp_path):
    from helpers import one_line

    line = one_line(capsys, "rig", "run", str(EXAMPLE / "controllers" / "lqr-ip02.yaml"), "--board", "virtual",
                    "--plant", str(EXAMPLE / "plants" / "ip02.yaml"), "--duration", "1", "-o", str(tmp_path / "run"))
    assert "ip02: a plant of the folder plant/; the boards here run a Furuta pendulum" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
@pytest.mark.parametrize("block", [0, 1])
def test_the_own_plant_page_s_commands_run_as_written(block, tmp_path):
    """Each command block of the Your own plant page, run by a shell in a fresh folder that
    sees the project's scenarios/ as a checkout does."""
    import os
    import re
    import subprocess
    import sys

    from helpers import page

    text = re.findall(r"```sh\n(.*?)```", page("own-plant.md"), re.S)[block]
    (tmp_path / "scenarios").symlink_to(ROOT / "scenarios")
    env = {**os.environ, "PATH": f"{os.path.dirname(sys.executable)}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", "-e", "-c", text], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, (done.stdout[-3000:], done.stderr[-3000:])
    if block == 0:
        assert (tmp_path / "my-plant" / "lqr.yaml").is_file() and "x.SettlingTime" in done.stdout
    else:
        assert (tmp_path / "effort-ip02.fmu").is_file() and (tmp_path / "cart-step.ssp").is_file()
        assert "4 run(s)" in done.stdout and ": 4 pass" in done.stdout
