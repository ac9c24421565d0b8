"""The evaluation core: prepare, compile, evaluate -> RunResult; pickling and worker processes;
the metric catalogue; names that resolve where a user expects."""

import dataclasses
import json
import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from furuta_cosim.controllers import load_controller
from furuta_cosim.cosim import RunResult, compile_controller, evaluate, prepare
from furuta_cosim.cosim.trace import Trace
from furuta_cosim.cosim.worker import evaluate_here
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

from helpers import run_cli


def assert_same_trace(a: Trace, b: Trace):
    assert a.columns() == b.columns()
    for name in a.columns():
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.fixture(scope="module")
def paper_step():
    return prepare(load_scenario("paper-step"))


def test_evaluate_gives_what_simulate_writes(paper_step, tmp_path, capsys):
    code, out, _ = run_cli(capsys, "simulate", "paper-step", "--controller", "lqr-paper",
                           "-o", str(tmp_path), "--json")
    assert code == 0
    entry = json.loads(out)["controllers"]["lqr-paper"]
    with PlantSession.open(paper_step.fmu) as session:
        result = evaluate(paper_step, session, "lqr-paper")
    assert result.passed and result.failure is None
    assert json.loads(json.dumps(result.to_dict()))["metrics"] == entry["metrics"]
    assert result.requirements == {k: {**v} for k, v in entry["requirements"].items()}
    written = Trace.from_csv(tmp_path / "lqr-paper.csv", "lqr-paper", "theta0", "V")
    assert_same_trace(result.trace, written)  # bit-identical: the CSV keeps every digit


def test_run_result_round_trips_through_json_and_csv(paper_step, tmp_path):
    with PlantSession.open(paper_step.fmu) as session:
        result = evaluate(paper_step, session, "bo-paper")
    assert result.metrics["theta1.SettlingTime"] == np.inf  # unstable on the calibrated plant
    entry = json.loads(json.dumps(result.save(tmp_path), allow_nan=False))
    back = RunResult.from_dict(entry, base=tmp_path)
    assert entry["trace"] == "bo-paper.csv"  # beside the JSON, not where it was written from
    assert back.metrics == result.metrics and back.requirements == result.requirements
    assert (back.scenario, back.controller, back.failure) == (result.scenario, result.controller, None)
    assert_same_trace(back.trace, result.trace)


def test_one_session_evaluates_candidate_after_candidate(paper_step):
    lqr = load_controller("lqr-paper")
    with PlantSession.open(paper_step.fmu) as session:
        first = evaluate(paper_step, session, lqr)
        for scale in (0.9, 1.1):
            gain = dataclasses.replace(lqr.controller, Dc=lqr.controller.Dc * scale)
            evaluate(paper_step, session, dataclasses.replace(lqr, controller=gain))
        again = evaluate(paper_step, session, compile_controller(paper_step, lqr))
    assert_same_trace(first.trace, again.trace)


def test_scenarios_plant_sets_and_prepared_scenarios_pickle():
    for scenario in (load_scenario("paper-step"), load_scenario("noise-kalman")):
        assert pickle.loads(pickle.dumps(scenario)) == scenario
    plant = load_plant("paper-calibrated")
    assert pickle.loads(pickle.dumps(plant)) == plant
    prepared = prepare(load_scenario("noise-kalman"))
    assert prepared.estimator() is not None  # compiled here; shipped as matrices
    copy = pickle.loads(pickle.dumps(prepared))
    assert copy.key == prepared.key and copy.states == prepared.states
    np.testing.assert_array_equal(copy.measurement_noise, prepared.measurement_noise)
    with PlantSession.open(prepared.fmu) as session:
        here = evaluate(prepared, session, "lqr-paper")
        there = evaluate(copy, session, "lqr-paper")
    assert_same_trace(here.trace, there.trace)
    compiled = compile_controller(prepared, "lqr-paper")
    assert pickle.loads(pickle.dumps(compiled)).runtime.control([0.0] * 5, 1.0) == \
        compiled.runtime.control([0.0] * 5, 1.0)


@pytest.mark.slow
def test_a_process_pool_evaluates_as_in_process(paper_step):
    names = ["lqr-paper", "bo-paper"]
    with PlantSession.open(paper_step.fmu) as session:
        local = [evaluate(paper_step, session, n) for n in names]
    # spawn: the workers get nothing but what pickles
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        remote = list(pool.map(evaluate_here, [paper_step] * 2, names))
        again = list(pool.map(evaluate_here, [paper_step] * 2, names))
    for a, b, c in zip(local, remote, again):
        assert a.controller == b.controller and a.metrics == b.metrics == c.metrics
        assert_same_trace(a.trace, b.trace)


@pytest.mark.parametrize("metric, expected", [
    ("theta1.Overshoot", "theta1 has no metric 'Overshoot' (its metrics: max_abs, SettlingTime)"),
    ("zeta.max_abs", "no signal 'zeta' is recorded"),
    ("u.IAE", "u has no metric 'IAE'"),
])
def test_metrics_that_no_run_records_are_input_errors(tmp_path, capsys, metric, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(load_scenario("paper-step").path.read_text().replace(
        "{metric: u.peak_abs, max: 7.5, controllers: [lqr-paper]}", f"{{metric: {metric}, max: 1}}"))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{path}: requirements[1].metric: {expected}" in err


def test_every_metric_of_the_catalogue_is_computed(paper_step):
    with PlantSession.open(paper_step.fmu) as session:
        result = evaluate(paper_step, session, "lqr-paper")
    promised = {f"{s}.{m}" for s, names in paper_step.metrics.items() for m in names}
    # SettlingTime of an output exists when it starts away from 0: here theta1 only
    optional = {f"{s}.SettlingTime" for s in paper_step.signals if s != "theta1"}
    assert promised - optional <= set(result.metrics) <= promised


@pytest.mark.parametrize("edit, expected", [
    (("plot: [theta0]", "plot: [zeta]"), "plot: no signal 'zeta' is recorded"),
    (("plot: [theta0]", "metrics: {error_window: [20, 30]}"),
     "metrics.error_window: [20, 30] holds no sample of the run"),
])
def test_plot_and_error_window_are_checked_before_running(tmp_path, capsys, edit, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(load_scenario("paper-step").path.read_text() + "plot: [theta0]\n")
    path.write_text(path.read_text().replace(*edit))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 2 and expected in err and not (tmp_path / "out").exists()


def test_a_requirement_scoped_to_a_misspelt_controller_is_an_input_error(tmp_path, capsys):
    path = tmp_path / "typo.yaml"
    path.write_text(load_scenario("paper-step").path.read_text().replace(
        "max: 7.5, controllers: [lqr-paper]", "max: 7.5, controllers: [lqr-papr]"))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 2
    assert f"{path}: requirements[1].controllers: no controller 'lqr-papr' in this scenario" in err


def test_requirements_for_controllers_that_did_not_run_are_reported(tmp_path, capsys):
    mine = tmp_path / "my-lqr.yaml"
    mine.write_text(load_controller("lqr-paper").path.read_text().replace("name: lqr-paper", "name: my-lqr"))
    code, out, _ = run_cli(capsys, "simulate", "paper-step", "--controller", str(mine),
                           "-o", str(tmp_path / "out"))
    assert code == 0
    assert out.count("SKIP  ") == 3 and "applies to lqr-paper, which did not run: not checked" in out
    document = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert len(document["unchecked"]) == 3


def test_controller_files_resolve_beside_the_scenario(tmp_path, capsys, monkeypatch):
    folder = tmp_path / "project"
    (folder / "controllers").mkdir(parents=True)
    (folder / "controllers" / "mine.yaml").write_text(load_controller("lqr-paper").path.read_text())
    scenario = folder / "step.yaml"
    scenario.write_text(load_scenario("paper-step").path.read_text()
                        .replace("[lqr-paper, bo-paper]", "[controllers/mine.yaml]"))
    monkeypatch.chdir(tmp_path)  # not the scenario's folder
    code, out, err = run_cli(capsys, "simulate", str(scenario), "-o", str(tmp_path / "out"), "--json")
    assert code == 0, err
    assert list(json.loads(out)["controllers"]) == ["lqr-paper"]


def test_unknown_names_list_every_valid_name(capsys):
    with pytest.raises(ConfigError, match=r"known: .*derived.*furuta.*paper-calibrated"):
        from furuta_cosim.models import load_model

        load_model("segway")
    code, _, err = run_cli(capsys, "linearize", "--params", "segway")
    assert code == 2 and "furuta" in err and "paper-calibrated" in err


def test_list_names_everything_and_speaks_json(capsys):
    code, out, _ = run_cli(capsys, "list", "--json")
    listing = json.loads(out)
    assert code == 0
    assert {"furuta", "paper-calibrated", "toy"} <= set(listing["plants"])
    assert {"derived", "paper-printed"} <= set(listing["models"])
    assert {"lqr-paper", "bo-paper"} <= set(listing["controllers"])
    assert {"paper-step", "noise-kalman"} <= set(listing["scenarios"])
    code, out, _ = run_cli(capsys, "list")
    assert code == 0 and "derived" in out and "furuta" in out
