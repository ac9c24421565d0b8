"""Tuning with the rig in the loop, on the virtual board: a trial is an evaluation scored from its
log, a trial the supervisor stops is a failed evaluation with its data, the safe method proposes
only what its model says is safe, a killed tuning resumes to the same history, and an external
rig answers through files (played by tools/external_rig.py) that are read as hostile."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.tuning.rig import RigEvaluator, tune_on_rig
from furuta_cosim.tuning.spec import load_spec
from furuta_cosim.tuning.trials import BoardTrials, ExternalTrials, TrialScenario, read_result

from helpers import ROOT, one_line, run_cli

QUBE = load_plant("qube-servo-3")


def _spec(folder: Path, trials: int = 4, **rig) -> Path:
    """effort-qube on a small budget: 16 simulations, ``trials`` rig trials."""
    spec = yaml.safe_load((ROOT / "scenarios" / "tuning" / "effort-qube.yaml").read_text())
    spec["name"] = "effort-small"
    spec["optimizer"].update(n_calls=16, n_initial_points=8)
    spec["rig"] = {"n_trials": trials, "reset": "swingup-qube", "simulations": 16, **rig}
    path = folder / "effort-small.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _trials(seed: int = 0, board: str = "virtual:fast") -> BoardTrials:
    return BoardTrials(board, QUBE, str(ROOT / "scenarios" / "controllers" / "swingup-qube.yaml"), 0.5, seed)


def _tuned(tmp_path, name: str, trials: int = 4, **options) -> dict:
    spec = load_spec(_spec(tmp_path, trials))
    board = _trials()
    return tune_on_rig(spec, tmp_path / name, board, **options)


def _history(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_a_rig_tuning_scores_each_trial_from_its_log_and_keeps_every_trial(tmp_path):
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.rig.runner import COLUMNS

    document = _tuned(tmp_path, "run")
    folder = tmp_path / "run"
    records = _history(folder)
    assert len(records) == 4 and document["trials"] == 4 and document["evaluator"] == "board"
    # the first is the safe seed: the baseline's own trial, scored against itself
    assert records[0]["origin"].startswith("safe seed") and records[0]["feasible"]
    assert records[0]["objective"] == pytest.approx(1.1, abs=1e-12)  # u.rms + 0.1 u.peak_abs, each / itself
    assert records[0]["trial"]["folder"] == "trials/baseline-lqr-qube-on-qube-servo-3"
    for r in records[1:]:
        trial = folder / r["trial"]["folder"]
        assert r["trial"]["folder"] == f"trials/{r['index']:04d}" and r["trial"]["status"] == "finished"
        # its log is an experiment file, and the metrics of its scenarios come from it
        experiment = load_experiment(trial / "run" / "experiment.yaml")
        log = np.loadtxt(trial / "run" / "log.csv", delimiter=",", skiprows=1)
        phase = log[:, COLUMNS.index("phase")]
        for k, label in enumerate(("qube-step", "qube-sine")):
            rows = log[phase == k]
            assert len(rows) == 4000  # the scenario's 8 s at 2 ms, all of it the candidate's
            # the candidate took over with the pendulum upright and the arm home
            assert abs(rows[0, COLUMNS.index("theta0")]) < 0.05
            volts = rows[:, COLUMNS.index("V")]
            assert r["metrics"][label]["u.rms"] == pytest.approx(float(np.sqrt(np.mean(volts ** 2))), rel=1e-9)
        assert experiment.samples == len(log)
        # each trial also records the same candidate simulated: the residual the safe method learns
        assert math.isfinite(r["simulation"]["value"]) and set(r["slacks"]) == set(r["simulation"]["slacks"])
        assert (trial / "candidate.yaml").is_file() and (trial / "trial.json").is_file()
    summary = (folder / "summary.md").read_text()
    assert "Tuning effort-small on the rig" in summary and (folder / "best.yaml").is_file()
    # the rig's score beside the simulation's of the same controller, and why they differ: the
    # gap (rig minus simulation) over the trials, as the safe method models it
    gaps = [r["value"] - r["simulation"]["value"] for r in records
            if math.isfinite(r.get("value", math.nan)) and math.isfinite(r["simulation"].get("value", math.nan))]
    gap = document["gap"]
    assert gap["trials"] == len(gaps) and gap["median"] == pytest.approx(float(np.median(gaps)), rel=1e-12)
    assert gap["min"] <= gap["best"] <= gap["max"]
    assert f"{gap['median']:+.4g} (median; from {gap['min']:+.4g} to {gap['max']:+.4g})" in summary
    assert (folder / "simulation" / "history.jsonl").is_file()  # the simulated fidelity, a run of its own


@pytest.mark.slow
def test_a_resumed_rig_tuning_repeats_no_finished_trial_and_ends_as_the_uninterrupted_one(tmp_path, monkeypatch):
    from furuta_cosim.rig.trial import TrialRuntime

    _tuned(tmp_path, "whole")
    whole = _history(tmp_path / "whole")
    original, seen = TrialRuntime.control, {"samples": 0}

    def interrupted(self, x, rbar):
        if self.phase >= 0:
            seen["samples"] += 1
            # the baseline's and trial 1's 8000 samples each, then 500 into trial 2: Ctrl-C
            if seen["samples"] == 2 * 8000 + 500:
                raise KeyboardInterrupt
        return original(self, x, rbar)

    monkeypatch.setattr(TrialRuntime, "control", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _tuned(tmp_path, "cut")
    monkeypatch.setattr(TrialRuntime, "control", original)
    cut = tmp_path / "cut"
    assert len(_history(cut)) == 2  # the trial cut short is not in the history ...
    kept = cut / "trials" / "0002" / "run" / "log.csv"
    assert kept.is_file()  # ... and its data is kept
    _tuned(tmp_path, "cut", resume=True)
    resumed = _history(cut)
    assert (cut / "trials" / "0002.interrupted" / "run" / "log.csv").is_file()
    assert [r["x"] for r in resumed] == [r["x"] for r in whole]
    assert [r["objective"] for r in resumed] == [r["objective"] for r in whole]
    # the baseline's trial was read back, not run again
    assert not (cut / "trials" / "baseline-lqr-qube-on-qube-servo-3.interrupted").exists()


@pytest.mark.slow
def test_a_trial_the_supervisor_stops_is_a_failed_evaluation_with_its_data(tmp_path):
    """A candidate that drives the arm into its limit: the supervisor trips, the trial's log is
    kept, the evaluation fails (no value), and the next trial starts by bringing the rig to rest."""
    from furuta_cosim.cosim import compile_controller
    from furuta_cosim.tuning.rig import Fidelity

    class Runaway:
        """Full voltage one way: the arm runs into the supervisor's 2 rad."""

        def reset(self):
            pass

        def control(self, x, rbar):
            return 10.0

    spec = load_spec(_spec(tmp_path))
    evaluator = RigEvaluator(spec, _trials(), tmp_path / "run", Fidelity(spec, []))
    evaluator.check_references()
    scenarios = []
    for label, prepared, _ in evaluator.runs():
        compiled = compile_controller(prepared, "lqr-qube")
        scenarios.append(TrialScenario(label, prepared, compiled.cfile, Runaway()))
    result, metrics, info = evaluator.run_trial("0001", scenarios)
    assert result.status == "tripped" and "the arm reached" in result.reason
    assert "qube-step" in result.failures and "qube-sine" in result.failures
    outcome = evaluator._judged(result, metrics, info, {}, [])
    assert not outcome.feasible and outcome.value is None and outcome.margin == 1.0
    assert outcome.error.startswith("tripped:") and outcome.trial["status"] == "tripped"
    log = np.loadtxt(tmp_path / "run" / "trials" / "0001" / "run" / "log.csv", delimiter=",", skiprows=1)
    assert len(log) > 0
    # the rig was not left at rest: the next trial homes it first
    evaluator.run_trial("0002", [TrialScenario(s.label, s.prepared, s.cfile,
                                               compile_controller(s.prepared, "lqr-qube").runtime)
                                 for s in scenarios])
    home = json.loads((tmp_path / "run" / "trials" / "0002" / "home" / "summary.json").read_text())
    assert home["status"] == "finished"


def test_a_candidate_that_lets_the_pendulum_fall_fails_its_scenario_and_the_trial_recovers(tmp_path):
    from furuta_cosim.cosim import compile_controller
    from furuta_cosim.tuning.rig import Fidelity

    class Limp:
        """0 V: the pendulum falls from upright within a second."""

        def reset(self):
            pass

        def control(self, x, rbar):
            return 0.0

    spec = load_spec(_spec(tmp_path))
    evaluator = RigEvaluator(spec, _trials(), tmp_path / "run", Fidelity(spec, []))
    evaluator.check_references()
    scenarios = [TrialScenario(label, prepared, compile_controller(prepared, "lqr-qube").cfile, Limp())
                 for label, prepared, _ in evaluator.runs()]
    result, metrics, info = evaluator.run_trial("0001", scenarios)
    assert result.status == "finished" and result.at_rest  # caught again, then damped down
    assert "fell beyond 0.5 rad" in result.failures["qube-step"]
    assert "qube-sine" in result.failures  # never reached: the trial ended after the recovery
    assert metrics["qube-step"]["theta1.max_abs"] > 0.5  # what it did before it fell is kept
    outcome = evaluator._judged(result, metrics, info, {}, [])
    assert not outcome.feasible and outcome.slacks["qube-step.theta1.max_abs"] == 1.0


def test_the_safe_method_proposes_only_what_its_model_says_is_safe():
    """A problem where the truth is known: f = (x - 0.8)^2, the constraint g = x - 0.6 <= 0 on
    the rig, the simulation's g 0.15 lower (it believes x up to 0.75 safe). From the safe seed at
    x = 0.1 no proposal may break the rig's constraint, and the best found nears 0.6."""
    from furuta_cosim.tuning.safe import SafeBO

    def simulated(x):
        return {"value": (x - 0.8) ** 2, "slacks": {"run.g": x - 0.75}, "feasible": x <= 0.75, "known": False}

    class Fidelity:
        records = [{"x": [float(x)], **simulated(float(x)), "margin": float(x) - 0.75, "objective": 0.0,
                    "index": k} for k, x in enumerate(np.linspace(0, 1, 21))]

        @staticmethod
        def exact(x):
            return simulated(float(x[0]))

    def trial(index, x):
        g = x - 0.6
        return {"index": index, "x": [x], "value": (x - 0.8) ** 2, "objective": (x - 0.8) ** 2,
                "feasible": g <= 0, "margin": g, "slacks": {"run.g": g}, "trial": {"folder": "t"},
                "simulation": simulated(x)}

    proposer = SafeBO([(0.0, 1.0)], 0, Fidelity, beta=2.0)
    records = [trial(0, 0.1)]
    for number in range(1, 12):
        x = proposer.propose(records, number).x[0]
        records.append(trial(number, x))
    xs = [r["x"][0] for r in records]
    assert max(xs) <= 0.6, xs
    assert max(xs) > 0.45, xs  # it learned the gap and went toward the boundary


def test_a_new_trials_spread_takes_the_upper_bound_of_the_noise_its_trials_give():
    """The gap's noise fitted from n trials is uncertain: a new trial is predicted with its upper
    95 % bound (the fitted variance times n / chi2_0.05(n)), tighter as trials come; before
    three trials the noise stays at its floor."""
    from scipy.stats import chi2

    from furuta_cosim.tuning.safe import GAP, SafeBO

    rng = np.random.default_rng(3)
    far = np.array([[0.5, 0.5]])
    ratios = []
    for n in (6, 24):
        X = np.repeat(rng.random((n // 2, 2)), 2, axis=0)   # each point twice: the noise shows
        gap = SafeBO._gap(X, 0.1 + rng.normal(0.0, 0.15, n), np.array([0.3, 0.3]))
        fitted, upper = gap.noise_variances
        assert fitted > GAP["noise"] ** 2   # this rig is noisier than the floor: fitted upward
        assert upper == pytest.approx(fitted * n / chi2.ppf(0.05, n), rel=1e-12)
        _, plain = gap.predict(far, return_std=True)
        _, widened = SafeBO._predict(gap, far)
        assert widened[0] ** 2 == pytest.approx(plain[0] ** 2 + upper - fitted, rel=1e-9)
        ratios.append(upper / fitted)
    assert ratios[0] > 3.0 and 1.0 < ratios[1] < 2.0   # 3.7 after 6 trials, 1.7 after 24
    few = SafeBO._gap(rng.random((2, 2)), [0.3, -0.2], np.array([0.3, 0.3]))
    assert few.noise_variances == (GAP["noise"] ** 2, GAP["noise"] ** 2)


@pytest.mark.slow
def test_an_external_rig_tunes_through_files(tmp_path, capsys):
    exchange = tmp_path / "exchange"
    rig = subprocess.Popen([sys.executable, str(ROOT / "tools" / "external_rig.py"), str(exchange),
                            "--trials", "3", "--timeout", "300"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    try:
        code, stdout, err = run_cli(capsys, "tune", str(_spec(tmp_path, trials=3)), "--evaluator", "external",
                                    str(exchange), "-o", str(tmp_path / "run"), "--wait", "300")
    finally:
        out, rig_err = rig.communicate(timeout=300)
    assert code == 0, err + rig_err
    assert "answered 0002" in out
    records = _history(tmp_path / "run")
    assert len(records) == 3 and all(r["trial"]["status"] == "finished" for r in records)
    # what the rig sent back is in the run directory, and the metrics were computed from it
    copied = tmp_path / "run" / "trials" / "0001" / "external"
    assert {"request.json", "result.json", "scenario-qube-step.yaml", "scenario-qube-step.csv"} <= \
        {p.name for p in copied.iterdir()}
    request = json.loads((exchange / "0001" / "request.json").read_text())
    assert request["protocol"] == 1 and (exchange / "0001" / "candidate.fmu").is_file()
    assert sorted(request["metrics"]) == ["error.IAE", "theta1.max_abs", "u.peak_abs", "u.rms"]
    assert "on an external rig" in stdout


def _external_request(tmp_path):
    """A request folder of one trial, and its scenarios (the rig's answer is written by the test)."""
    from furuta_cosim.tuning.rig import Fidelity

    spec = load_spec(_spec(tmp_path))
    evaluator = RigEvaluator(spec, _trials(), tmp_path / "run", Fidelity(spec, []))
    from furuta_cosim.cosim import compile_controller

    scenarios = []
    for label, prepared, _ in evaluator.runs():
        compiled = compile_controller(prepared, "lqr-qube")
        scenarios.append(TrialScenario(label, prepared, compiled.cfile, compiled.runtime))
    request = tmp_path / "exchange" / "0001"
    request.mkdir(parents=True)
    return request, scenarios


def _experiment(request: Path, name: str, rows: int = 4000, period: float = 0.002, value="0.1",
                inputs=True) -> None:
    lines = ["t,V,theta0,theta1"] + [f"{k * period!r},{value},0.0,0.0" for k in range(rows)]
    (request / f"{name}.csv").write_text("\n".join(lines) + "\n")
    experiment = {"data": f"{name}.csv", "columns": ["t", "V", "theta0", "theta1"], "time": "t",
                  "outputs": {"theta0": {"column": "theta0", "unit": "rad"},
                              "theta1": {"column": "theta1", "unit": "rad"}}}
    if inputs:
        experiment["inputs"] = {"V": {"column": "V", "unit": "V"}}
    (request / f"{name}.yaml").write_text(yaml.safe_dump(experiment))


METRICS = {"u.rms": 0.5, "u.peak_abs": 1.0, "error.IAE": 0.4, "theta1.max_abs": 0.01}


@pytest.mark.parametrize("result, expected", [
    ("not json", "not JSON"),
    ('{"status": "fine"}', "status: expected one of finished, tripped, failed"),
    ('{"status": "finished", "extra": 1}', "unknown key(s) 'extra'"),
    ('{"status": "finished", "seconds": NaN}', "not JSON"),
    ('{"status": "finished", "scenarios": {"qube-walk": {"metrics": {}}}}', "'qube-walk' not in the request"),
    ('{"status": "finished", "scenarios": {"qube-step": {"metrics": {"u.rms": 1}}}}', "missing error.IAE"),
    ('{"status": "finished", "scenarios": {"qube-step": {"metrics": {"u.rms": 1e999, "u.peak_abs": 1, '
     '"error.IAE": 1, "theta1.max_abs": 0.1}}}}', "u.rms: expected a finite number"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "../../escape.yaml"}}}',
     "is not a file inside"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "/etc/passwd"}}}', "is not a file inside"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "link.yaml"}}}', "is not a file inside"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "slow.yaml"}}}',
     "its samples are 0.004 s apart; the scenario runs at 0.002 s"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "no-input.yaml"}}}', "inputs: needs V"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "nan.yaml"}}}', "nan.csv"),
    ('{"status": "finished", "scenarios": {"qube-step": {"what": 1}}}', 'expected {"experiment": FILE}'),
    # a norm below 0 is no measurement: it made a feasible best of objective -78.8
    ('{"status": "finished", "scenarios": {"qube-step": {"metrics": {"u.rms": -50, "u.peak_abs": 1, '
     '"error.IAE": -1, "theta1.max_abs": 0.1}}}}', "u.rms: -50 is below 0, the least rms can be"),
    ('{"status": "failed", "status": "finished"}', "the key 'status' is given twice"),
    ("[" * 100_000 + "]" * 100_000, "nested deeper than 32 levels"),
    ('{"status": "finished", "scenarios": {"qube-step": {"experiment": "outside.yaml"}}}',
     "its loop.controller"),
])
def test_an_external_rigs_result_is_read_as_hostile(tmp_path, result, expected):
    request, scenarios = _external_request(tmp_path)
    (tmp_path / "exchange" / "escape.yaml").write_text("x: 1\n")
    (request / "link.yaml").symlink_to(tmp_path / "exchange" / "escape.yaml")
    _experiment(request, "slow", period=0.004)
    _experiment(request, "no-input", inputs=False)
    _experiment(request, "nan", value="nan")
    _experiment(request, "outside")   # its loop names a controller outside the request
    outside = yaml.safe_load((request / "outside.yaml").read_text())
    (tmp_path / "exchange" / "ctrl.yaml").write_text((ROOT / "scenarios" / "controllers" / "lqr-qube.yaml").read_text())
    outside["loop"] = {"controller": str(tmp_path / "exchange" / "ctrl.yaml")}
    (request / "outside.yaml").write_text(yaml.safe_dump(outside))
    (request / "result.json").write_text(result)
    with pytest.raises(ConfigError) as caught:
        read_result(request, scenarios, sorted(METRICS))
    assert expected in str(caught.value) and str(request / "result.json") in str(caught.value)


def test_an_external_rigs_good_result_gives_traces_and_metrics(tmp_path):
    request, scenarios = _external_request(tmp_path)
    _experiment(request, "step", rows=3000)
    (request / "result.json").write_text(json.dumps({
        "status": "tripped", "reason": "the arm reached its limit", "seconds": 12.5,
        "scenarios": {"qube-step": {"experiment": "step.yaml"}, "qube-sine": {"metrics": METRICS}},
        "failures": {"qube-step": "stopped by the rig's supervisor"}}))
    found = read_result(request, scenarios, sorted(METRICS))
    trace = found["traces"]["qube-step"]
    assert found["status"] == "tripped" and len(trace.t) == 3000 and "ran 3000 of" in trace.failure
    assert np.allclose(trace.u, 0.1) and np.array_equal(trace.r, scenarios[0].prepared.rbar[:3000])
    assert found["metrics"]["qube-sine"] == METRICS and found["seconds"] == 12.5


def test_an_external_rig_that_never_answers_stops_the_tuning_resumably(tmp_path):
    from furuta_cosim.errors import RunStopped

    request, scenarios = _external_request(tmp_path)
    trials = ExternalTrials(tmp_path / "exchange", wait=0.3, metrics=sorted(METRICS), poll=0.1)
    with pytest.raises(RunStopped, match="no result for trial 0002 in 0.3 s"):
        trials.run(tmp_path / "run" / "trials" / "0002", "0002", scenarios)
    assert (tmp_path / "exchange" / "0002" / "request.json").is_file()
    del request


@pytest.mark.parametrize("argv, expected", [
    (["--optimizer", "safe"], "--optimizer: safe (safe Bayesian optimization on a rig, the simulation its "
                              "prior) tunes on a rig"),
    (["--n-trials", "5"], "--n-trials: tunes with a rig in the loop"),
    (["--board", "virtual:fast", "--n-calls", "5"], "--n-calls: a tuning on the rig runs one trial at a time"),
    (["--board", "virtual:fast", "--evaluator", "external", "x"], "not both"),
    (["--evaluator", "internal", "x"], "--evaluator: expected external DIR"),
    (["--board", "virtual:fast", "--n-trials", "1"], "--n-trials: expected a whole number from 2"),
    (["--board", "virtual:fast", "--wait", "5"], "--wait: how long to wait for an external rig"),
])
def test_bad_rig_tuning_options_are_one_line(tmp_path, capsys, argv, expected):
    line = one_line(capsys, "tune", "effort-qube", *argv, "-o", str(tmp_path / "run"))
    assert expected in line, line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("rig, expected", [
    ({"n_trials": 1}, "rig.n_trials: must be >= 2, got 1"),
    ({"reset": "lqr-qube"}, "rig.reset: "),
    ({"fall": -1}, "rig.fall: must be > 0"),
    ({"beta": "wide"}, "rig.beta: expected a number"),
    ({"surprise": 1}, "rig.surprise: unknown key"),
])
def test_bad_rig_sections_of_a_spec_are_named(tmp_path, rig, expected):
    spec = yaml.safe_load(_spec(tmp_path).read_text())
    spec["rig"] = rig
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(spec))
    with pytest.raises(ConfigError) as caught:
        load_spec(path)
    assert expected in str(caught.value) and str(path) in str(caught.value)


def test_a_rig_without_a_reset_file_is_refused_before_anything_is_written(tmp_path):
    spec = yaml.safe_load(_spec(tmp_path).read_text())
    del spec["rig"]["reset"]
    path = tmp_path / "noreset.yaml"
    path.write_text(yaml.safe_dump(spec))
    with pytest.raises(ConfigError, match="rig.reset: missing"):
        tune_on_rig(load_spec(path), tmp_path / "run", _trials())
    assert not (tmp_path / "run").exists()


def test_a_result_there_before_its_request_is_not_taken(tmp_path):
    """Planted before the request was written, it was taken as that trial's result."""
    request, scenarios = _external_request(tmp_path)
    exchange = request.parent
    (request / "result.json").write_text('{"status": "finished"}')
    trials = ExternalTrials(exchange, metrics=sorted(METRICS), wait=0.2, poll=0.05)
    with pytest.raises(ConfigError) as caught:
        trials.run(tmp_path / "run" / "0001", "0001", scenarios)
    assert "there before its request was written" in str(caught.value)
    assert not (exchange / "0001" / "request.json").exists()


def test_a_request_folder_that_is_a_link_is_not_written_through(tmp_path):
    """A planted link NNNN -> a user's folder had the user's candidate.yaml overwritten."""
    request, scenarios = _external_request(tmp_path)
    users = tmp_path / "users"
    users.mkdir()
    (users / "candidate.yaml").write_text("mine\n")
    request.rmdir()
    request.symlink_to(users, target_is_directory=True)
    trials = ExternalTrials(request.parent, metrics=sorted(METRICS), wait=0.2, poll=0.05)
    with pytest.raises(ConfigError):
        trials.run(tmp_path / "run" / "0001", "0001", scenarios)
    assert (users / "candidate.yaml").read_text() == "mine\n" and sorted(p.name for p in users.iterdir()) == ["candidate.yaml"]


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_a_result_that_is_not_a_plain_file_is_refused_at_once(tmp_path, kind):
    """A result.json that was a folder or a FIFO waited the whole --wait (an hour by default)."""
    from furuta_cosim.errors import RunStopped

    request, scenarios = _external_request(tmp_path)
    trials = ExternalTrials(request.parent, metrics=sorted(METRICS), wait=0.1, poll=0.05)
    with pytest.raises(RunStopped):   # the request written, no result yet
        trials.run(tmp_path / "run" / "0001", "0001", scenarios)
    result = request / "result.json"
    result.mkdir() if kind == "folder" else os.mkfifo(result)
    # waiting would end in RunStopped after --wait; a result that never can be is refused first
    trials = ExternalTrials(request.parent, metrics=sorted(METRICS), wait=3600, poll=0.05)
    with pytest.raises(ConfigError) as caught:
        trials.run(tmp_path / "run" / "0001", "0001", scenarios)
    assert f"result.json: not a plain file (a {'folder' if kind == 'folder' else 'FIFO'})" in str(caught.value)


def test_a_board_that_cannot_be_opened_stops_the_tuning_before_its_simulated_prior(tmp_path, capsys, monkeypatch):
    # the board is opened and read (amplifier off) before the run folder and the 150-evaluation
    # prior: without the SDK, or with no board connected, one line and nothing written
    from helpers import run_cli

    monkeypatch.setitem(sys.modules, "quanser", None)  # the SDK not installed
    code, out, err = run_cli(capsys, "tune", str(_spec(tmp_path)), "--board", "quanser", "-o", str(tmp_path / "run"))
    assert code == 2 and "Quanser's Python HIL API is not installed" in err, err
    assert len(err.strip().splitlines()) == 1 and "simulat" not in err and not (tmp_path / "run").exists()
    monkeypatch.delitem(sys.modules, "quanser")
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "fake_quanser"))
    from quanser import hardware

    monkeypatch.setattr(hardware.HIL, "fail_open", -1073)
    code, out, err = run_cli(capsys, "tune", str(_spec(tmp_path)), "--board", "quanser", "-o", str(tmp_path / "run"))
    assert code == 2 and "open: no such board is connected" in err and not (tmp_path / "run").exists(), err


def test_a_reset_file_that_cannot_swing_up_is_refused_before_the_run(tmp_path):
    with pytest.raises(ConfigError, match="rig.reset: .*lqr-qube.*not a swing-up-and-balance file"):
        BoardTrials("virtual:fast", QUBE, "lqr-qube", 0.5, 0)


@pytest.mark.slow
def test_a_rig_whose_cable_pulls_the_arm_off_home_is_reset_with_the_arm_home(tmp_path):
    """qube-servo-3-offset: under lqr-qube alone the arm balances about 0.1 rad off home and the
    reset never held it home (every trial stopped at the baseline's); the reset's integral moves
    the arm's reference until it stands home, and the trial says by how much."""
    from furuta_cosim.cosim import compile_controller
    from furuta_cosim.tuning.rig import Fidelity

    spec = load_spec(_spec(tmp_path))
    rig = BoardTrials("virtual:fast", load_plant("qube-servo-3-offset"),
                      str(ROOT / "scenarios" / "controllers" / "swingup-qube.yaml"), 0.5, 0, {"delay": 0.002})
    evaluator = RigEvaluator(spec, rig, tmp_path / "run", Fidelity(spec, []))
    evaluator.check_references()
    lines = []
    evaluator.log = lines.append
    scenarios = [TrialScenario(label, prepared, compile_controller(prepared, "lqr-qube").cfile,
                               compile_controller(prepared, "lqr-qube").runtime)
                 for label, prepared, _ in evaluator.runs()]
    result, metrics, info = evaluator.run_trial("0001", scenarios)
    assert result.status == "finished" and "reset" not in result.failures, result.failures
    assert set(metrics) == {"qube-step", "qube-sine"}
    # the cable pulls the arm toward +3 degrees: the reference that holds it home is beyond
    # the other side (0.19 rad measured), and the trial says it
    assert 0.05 < result.hold_offset < 0.5
    recorded = json.loads((tmp_path / "run" / "trials" / "0001" / "trial.json").read_text())
    assert recorded["hold_offset"] == pytest.approx(result.hold_offset)
    assert any("held the arm home with its reference +0." in line for line in lines)
    # the log's reference in the reset is that integral, and the candidate started with the arm home
    log = np.genfromtxt(tmp_path / "run" / "trials" / "0001" / "run" / "log.csv", delimiter=",", names=True)
    reset = log["phase"] == -1
    assert abs(log["r"][reset][-1] - result.hold_offset) < 0.05
    first = np.flatnonzero(log["phase"] == 0)[0]
    assert abs(log["theta0"][first]) < 0.05


def test_the_resets_integral_rests_near_home_and_starts_over_with_a_swing_up():
    from furuta_cosim.rig.trial import HOLD_RATE, TrialRuntime
    from furuta_cosim.swingup import BALANCE, SWINGUP

    class Safe:
        mode, switches = BALANCE, []

        def reset(self):
            pass

        def control(self, x, rbar):
            self.rbar = rbar
            return 0.0

    runtime = TrialRuntime(Safe(), [], None, 0.002, hold_gain=0.25, hold_limit=0.5, reset_timeout=1e9)
    upright = [0.1, 0.0, 0.0, 0.0]
    for _ in range(1000):  # 2 s with the arm still 0.1 rad off, the pendulum upright
        runtime.control(upright, 0.0)
    assert runtime.hold_offset == pytest.approx(-0.25 * 2.0 * 0.1, rel=1e-9)
    assert runtime.safe.rbar == runtime.hold_offset == runtime.reference
    held = runtime.hold_offset
    runtime.control([0.02, 0.0, 0.0, 0.0], 0.0)          # within half of home: it rests
    runtime.control([0.1, 2 * HOLD_RATE, 0.0, 0.0], 0.0)  # the arm moving: it rests
    runtime.control([0.1, 0.0, 0.2, 0.0], 0.0)            # the pendulum not upright: it rests
    assert runtime.hold_offset == held
    for _ in range(20000):  # it never passes its limit
        runtime.control([0.2, 0.0, 0.0, 0.0], 0.0)
    assert runtime.hold_offset == -0.5
    runtime.safe.mode = SWINGUP  # a fall: the swing-up again, the integral starts over
    runtime.control([0.2, 0.0, 3.0, 0.0], 0.0)
    assert runtime.hold_offset == 0.0
