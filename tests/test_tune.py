"""Tuning: specs validated strictly, the paper's spectral setup, the run directory, seeds."""

import json
import shutil

import numpy as np

import pytest

from furuta_cosim import paths
from furuta_cosim.errors import ConfigError
from furuta_cosim.tuning.objective import Evaluator
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

from helpers import run_cli

SPEC = paths.scenarios() / "tuning" / "paper-spectral.yaml"


def history(folder):
    return [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_paper_spectral_finds_a_stable_controller(tmp_path, capsys):
    code, out, err = run_cli(capsys, "tune", "paper-spectral", "--n-calls", "15", "-o",
                             str(tmp_path / "run"), "--json")
    assert code == 0, err
    document = json.loads(out)
    assert document["best"] and document["n_calls"] == 15
    assert {"lqr-paper", "bo-paper"} <= set(document["baselines"])
    records = history(tmp_path / "run")
    assert [r["index"] for r in records] == list(range(15))
    assert set(records[0]) == history_keys()
    best = min((r for r in records if r["feasible"]), key=lambda r: r["objective"])
    assert best["objective"] == pytest.approx(document["best"]["objective"])
    for name in ("spec.yaml", "best.yaml", "summary.json", "summary.md", "convergence.png",
                 "convergence.svg"):
        assert (tmp_path / "run" / name).stat().st_size > 0
    # best.yaml is a controller file that analyze accepts as it is, and it is stable
    code, out, _ = run_cli(capsys, "analyze", str(tmp_path / "run" / "best.yaml"), "--model", "paper-printed")
    assert code == 0 and "The closed loop is stable" in out
    assert "fastest mode, not the slowest" in (tmp_path / "run" / "summary.md").read_text()


def strip(records):
    """A history without what may differ between two runs of one seed (wall time, worker)."""
    return [{k: v for k, v in r.items() if k not in ("wall_time", "worker")} for r in records]


@pytest.mark.slow
def test_the_same_seed_gives_the_same_history(tmp_path):
    spec = load_spec("paper-spectral")
    for name in ("a", "b"):
        tune(spec, tmp_path / name, n_calls=12, seed=3)
    assert strip(history(tmp_path / "a")) == strip(history(tmp_path / "b"))
    tune(spec, tmp_path / "c", n_calls=12, seed=4)
    assert strip(history(tmp_path / "c")) != strip(history(tmp_path / "a"))


@pytest.mark.slow
def test_random_search_writes_the_same_history_format(tmp_path):
    spec = load_spec("paper-spectral")
    document = tune(spec, tmp_path / "r", method="random", n_calls=8)
    records = history(tmp_path / "r")
    assert document["method"] == "random" and [r["index"] for r in records] == list(range(8))
    bo = tune(spec, tmp_path / "b", n_calls=2)
    assert bo["method"] == "bo"
    # every line has the keys a bo line has, and the same kinds of values
    assert all(set(r) == history_keys() == set(history(tmp_path / "b")[0]) for r in records)
    assert {r["origin"] for r in records} == {"random"}
    bounds = Evaluator(spec).space.bounds
    assert all(len(r["x"]) == len(bounds) and all(lo <= v <= hi for v, (lo, hi) in zip(r["x"], bounds))
               and isinstance(r["feasible"], bool) and isinstance(r["objective"], float) for r in records)


@pytest.mark.slow
def test_a_run_directory_is_never_overwritten(tmp_path, capsys):
    tune(load_spec("paper-spectral"), tmp_path / "run", n_calls=3)
    code, _, err = run_cli(capsys, "tune", "paper-spectral", "-o", str(tmp_path / "run"))
    assert code == 2 and "holds a tuning run already" in err


SCENARIOS_SPEC = """\
name: effort-small
controller: {n_xc: 1, time: continuous, period: 0.002, model: paper-printed}
parameters:
  Ac: {log: [-1, 2], sign: -1}
  Bc: {box: [-1, 1]}
  Cc: {fixed: [[1.0]]}
  Dc: {lqr: [-2, 3], R: 10}
objective:
  type: scenarios
  scenarios: [paper-step]
  terms: [{metric: error.ISE, weight: 1.0}, {metric: u.rms, weight: 0.1}]
constraints: {stability_margin: 0.01, max_abs: {theta1: 0.5, u: 50}, requirements: false}
optimizer: {n_calls: 6, n_initial_points: 3}
variants: [{}, {C1: 1.0e-4}]
baselines: [lqr-paper]
"""


@pytest.mark.slow
def test_a_scenarios_objective_over_plant_variants(tmp_path):
    path = tmp_path / "effort.yaml"
    path.write_text(SCENARIOS_SPEC)
    document = tune(load_spec(path), tmp_path / "run")
    records = history(tmp_path / "run")
    feasible = [r for r in records if r["feasible"]]
    assert feasible, [r["constraints"] for r in records]
    for record in feasible:
        # every candidate ran on both plant variants, and its score is the worst of them
        assert set(record["metrics"]) == {"paper-step[0]", "paper-step[1]"}
        scores = [m["error.ISE"] + 0.1 * m["u.rms"] for m in record["metrics"].values()]
        assert record["objective"] == pytest.approx(max(scores), rel=1e-12)
        assert all(record["constraints"][f"paper-step[{k}].theta1.max_abs"] <= 0.5 for k in (0, 1))
    assert document["baselines"]["lqr-paper"]["feasible"]


def test_a_bound_on_a_signal_no_scenario_records_is_one_line(tmp_path, capsys):
    path = tmp_path / "effort.yaml"
    path.write_text(SCENARIOS_SPEC.replace("theta1: 0.5", "zeta: 0.5"))
    code, _, err = run_cli(capsys, "tune", str(path), "-o", str(tmp_path / "run"))
    assert code == 2 and f"{path}: constraints.max_abs.zeta: scenario paper-step records no zeta" in err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_a_killed_run_resumes_to_exactly_n_calls(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    run = tmp_path / "run"
    command = [sys.executable, "-m", "furuta_cosim.cli", "tune", "paper-spectral", "--n-calls", "40",
               "--workers", "1", "-o", str(run)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if (run / "history.jsonl").exists() and len((run / "history.jsonl").read_text().splitlines()) >= 15:
            break
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    done = len(history(run))
    assert 15 <= done < 40, "the run was not killed in the middle"
    result = subprocess.run(command + ["--resume"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    records = history(run)
    assert [r["index"] for r in records] == list(range(40))          # none lost, none twice
    assert len({tuple(r["x"]) for r in records}) == 40
    assert json.loads((run / "summary.json").read_text())["evaluations"] == 40
    # and the history is the uninterrupted run's
    whole = tmp_path / "whole"
    subprocess.run(command[:-1] + [str(whole)], check=True, capture_output=True)
    assert strip(records) == strip(history(whole))


@pytest.mark.slow
def test_a_worker_that_raises_or_dies_fails_only_its_evaluation(tmp_path, monkeypatch):
    import os

    from furuta_cosim.tuning import objective

    real = objective.Evaluator.__call__

    def faulty(self, x, order=None):
        if x[1] > 0.6:        # Bc[0][0]: a candidate whose evaluation raises
            raise ValueError("injected fault")
        if x[1] < -0.7:       # and one whose worker process dies
            os._exit(3)
        return real(self, x, order)

    monkeypatch.setattr(objective.Evaluator, "__call__", faulty)  # the forked workers inherit it
    document = tune(load_spec("paper-spectral"), tmp_path / "run", method="random", n_calls=16,
                    workers=2)
    records = history(tmp_path / "run")
    assert [r["index"] for r in records] == list(range(16))
    raised = [r for r in records if r["error"] and "injected fault" in r["error"]]
    died = [r for r in records if r["error"] == "the worker process died during this evaluation"]
    assert raised and died, [r["x"][1] for r in records]
    assert all(r["x"][1] > 0.6 for r in raised) and all(r["x"][1] < -0.7 for r in died)
    healthy = [r for r in records if -0.7 <= r["x"][1] <= 0.6]
    assert all(r["error"] is None for r in healthy)
    assert document["failed"] == len(raised) + len(died) and document["best"]


@pytest.mark.slow
def test_a_campaign_on_a_local_dask_cluster(tmp_path):
    document = tune(load_spec("paper-spectral"), tmp_path / "run", method="random", n_calls=6,
                    dask="local", workers=2)
    records = history(tmp_path / "run")
    assert [r["index"] for r in records] == list(range(6)) and document["evaluations"] == 6
    import dataclasses

    spec = load_spec("paper-spectral")
    in_pairs = dataclasses.replace(spec, optimizer=dataclasses.replace(spec.optimizer, batch=2))
    serial = tune(in_pairs, tmp_path / "serial", method="random", n_calls=6)
    # the same asks (batches of two) give the same results wherever they are evaluated
    assert [r["objective"] for r in records] == [r["objective"] for r in history(tmp_path / "serial")]
    assert serial["best"] == document["best"]
    # the worker that evaluated: a Dask worker's process, never this coordinating one
    import os

    assert all(isinstance(r["worker"], int) and r["worker"] != os.getpid() for r in records)
    assert {r["worker"] for r in history(tmp_path / "serial")} == {os.getpid()}


def test_differential_evolution_keeps_the_budget_and_the_history_format(tmp_path):
    document = tune(load_spec("paper-spectral"), tmp_path / "de", method="de", n_calls=30)
    records = history(tmp_path / "de")
    assert [r["index"] for r in records] == list(range(30)) and document["method"] == "de"
    assert set(records[0]) == set(history_keys())


def history_keys():
    return {"index", "x", "parameters", "objective", "feasible", "value", "margin", "constraints",
            "metrics", "violated", "stopped", "skipped", "known", "origin", "surrogate", "wall_time",
            "worker", "error"}


@pytest.mark.slow
def test_effort_says_plainly_whether_it_beat_the_lqr(tmp_path):
    document = tune(load_spec("effort"), tmp_path / "run", n_calls=10, workers=2)
    summary = (tmp_path / "run" / "summary.md").read_text()
    lqr = document["baselines"]["lqr-paper"]
    assert lqr["feasible"]  # the LQR meets its own tracking by construction
    best = document["best"]
    assert best is not None  # the LQR is in the initial design, and feasible
    # the tuned controller's matrices and the plant FMU's hash are in the summary
    assert "- Dc = [" in summary and "- Ac = [" in summary
    from furuta_cosim.fmu.exporter import build_fmu

    fmu = build_fmu("furuta")
    import hashlib

    assert document["fmus"] == {fmu.name: hashlib.sha256(fmu.read_bytes()).hexdigest()}
    assert f"plant FMU {fmu.name}: sha256 {document['fmus'][fmu.name]}" in summary
    for label in ("paper-tracking", "sine-follow", "noise"):
        ise = best["metrics"][label]["error.ISE"] / lqr["metrics"][label]["error.ISE"]
        assert ise <= 1.05 * (1 + 1e-12), (label, ise)  # tracking no worse than +5 %
    # run by run, where it uses less voltage than the LQR and where not, in so many words
    lower = next(line for line in summary.splitlines() if line.startswith("  - lower than lqr-paper"))
    higher = next(line for line in summary.splitlines() if line.startswith("  - not lower on:"))
    for label in ("paper-tracking", "sine-follow", "noise"):
        ratios = [best["metrics"][label][m] / lqr["metrics"][label][m] for m in ("u.rms", "u.peak_abs")]
        assert label in (lower if max(ratios) < 1 else higher), (label, ratios)
        assert f"u.rms {(ratios[0] - 1) * 100:+.1f} %" in (lower if max(ratios) < 1 else higher)
    if best["objective"] < lqr["objective"]:
        assert "the tuned controller scores better" in summary
    else:
        missed = (best["objective"] / lqr["objective"] - 1) * 100
        assert f"does NOT beat it (worse by {missed:.1f} %)" in summary
    # the result shown: per scenario the tuned response beside the baseline's, and the best
    # loop's margins (of the sampled loop that runs) with its Bode, Nyquist and |S|, |T| plots
    for label in ("paper-tracking", "sine-follow", "noise"):
        assert document["responses"][label] == f"responses/{label}.png"
        assert (tmp_path / "run" / "responses" / f"{label}.png").stat().st_size > 5000
        assert f"](responses/{label}.png)" in summary
    for name in ("bode", "nyquist", "sensitivity"):
        assert (tmp_path / "run" / "loop" / f"{name}.png").stat().st_size > 5000
    from furuta_cosim.lqr_file import analyze_file

    again = analyze_file(tmp_path / "run" / "best.yaml").analysis
    assert "sampled loop" in document["loop"]["margins_of"]
    assert document["loop"]["margins"]["gain"] == pytest.approx(again.running_margins.as_dict()["gain"])
    assert "Margins of the loop that runs" in summary


@pytest.mark.slow
def test_robust_effort_is_stable_on_every_plant_variant(tmp_path):
    document = tune(load_spec("robust-effort"), tmp_path / "run", n_calls=8, workers=2)
    assert document["best"], "no feasible controller in 8 calls"
    metrics = document["best"]["metrics"]
    assert set(metrics) == {f"{s}[{k}]" for s in ("paper-tracking", "sine-follow", "noise") for k in (0, 1)}
    for values in metrics.values():
        assert values["theta1.max_abs"] <= 0.3  # bounded in co-simulation on both plants


@pytest.mark.slow
def test_resume_refuses_another_spec_method_or_seed(tmp_path, capsys):
    tune(load_spec("paper-spectral"), tmp_path / "run", n_calls=3)
    other = tmp_path / "other.yaml"
    other.write_text(SPEC.read_text().replace("seed: 0", "seed: 0\n  batch: 1"))
    for argv, expected in ((["paper-spectral", "--seed", "5"], "--seed 5 differs from the run's 0"),
                           (["paper-spectral", "--optimizer", "random"], "--optimizer random differs"),
                           ([str(other)], "the spec differs from the one")):
        code, _, err = run_cli(capsys, "tune", *argv, "-o", str(tmp_path / "run"), "--resume",
                               "--n-calls", "6", "--workers", "1")
        assert code == 2 and expected in err, err
    assert len(history(tmp_path / "run")) == 3  # nothing was added
    # with spec.yaml deleted, the other spec once continued the history; run.json's hash says
    (tmp_path / "run" / "spec.yaml").rename(tmp_path / "kept.yaml")
    code, _, err = run_cli(capsys, "tune", str(other), "-o", str(tmp_path / "run"), "--resume",
                           "--n-calls", "6", "--workers", "1")
    assert code == 2 and "the spec differs from the one" in err and len(history(tmp_path / "run")) == 3, err
    code, _, err = run_cli(capsys, "tune", "paper-spectral", "-o", str(tmp_path / "run"), "--resume",
                           "--n-calls", "6", "--workers", "1")
    assert code == 0 and len(history(tmp_path / "run")) == 6


def batched(tmp_path, batch=3):
    """paper-spectral with batches of ``batch`` and a short initial design."""
    path = tmp_path / f"spectral-batch{batch}.yaml"
    path.write_text(SPEC.read_text().replace("seed: 0", f"seed: 0\n  batch: {batch}")
                    .replace("n_initial_points: 10", "n_initial_points: 5"))
    return load_spec(path)


@pytest.mark.parametrize("method", ["bo", "random", "de"])
@pytest.mark.slow
def test_the_history_depends_on_neither_the_workers_nor_an_interruption(tmp_path, method):
    """Workers change only the speed: one history for 1 and 2 workers; a run cut after any
    evaluation (in the design, in the middle of a batch, at a batch's end) and resumed writes
    the uninterrupted run's history."""
    spec = batched(tmp_path)
    assert "batch: 3" in spec.path.read_text()
    one = tune(spec, tmp_path / "one", method=method, n_calls=20, workers=1)
    two = tune(spec, tmp_path / "two", method=method, n_calls=20, workers=2)
    whole = strip(history(tmp_path / "one"))
    assert whole == strip(history(tmp_path / "two"))
    assert one["best"] == two["best"]
    lines = (tmp_path / "one" / "history.jsonl").read_text().splitlines(keepends=True)
    for cut in (3, 7, 9, 13):   # design; batch 0's middle; batch 1's start; batch 2's middle
        folder = tmp_path / f"cut{cut}"
        shutil.copytree(tmp_path / "one", folder)
        for name in ("summary.json", "summary.md", "best.yaml"):
            (folder / name).unlink(missing_ok=True)  # none when nothing was feasible
        # what a kill -9 leaves: the lines so far, the next one torn
        (folder / "history.jsonl").write_text("".join(lines[:cut]) + lines[cut][:25])
        tune(spec, folder, method=method, n_calls=20, workers=1, resume=True)
        assert strip(history(folder)) == whole, cut


@pytest.mark.slow
def test_a_resumed_history_from_another_optimizer_is_refused(tmp_path):
    """--resume proposes again the design and the batch it continues: a history that is not
    this run's there is refused, and nothing is changed."""
    spec = batched(tmp_path)
    tune(spec, tmp_path / "run", n_calls=12, workers=1)
    path = tmp_path / "run" / "history.jsonl"
    records = history(tmp_path / "run")
    design = sum(1 for r in records if not r["origin"].startswith("bo"))
    records = records[:design + 2]   # the design, and 2 of batch 0's 3
    last = design + 1
    records[last]["x"][0] = records[last]["x"][0] * 0.5 + 0.1   # not the point this run proposes
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    with pytest.raises(ConfigError, match=f"evaluation {last} of the history is not the point"):
        tune(spec, tmp_path / "run", n_calls=12, workers=1, resume=True)
    assert len(history(tmp_path / "run")) == design + 2


@pytest.mark.slow
def test_baselines_and_initial_controllers_start_the_search(tmp_path):
    """lqr-paper enters the design of effort as its design point (continuous here), bo-paper
    (Cc fixed to another matrix) is named with the reason, and the best is never worse than
    the baseline's point."""
    path = tmp_path / "effort-initial.yaml"
    path.write_text((paths.scenarios() / "tuning" / "effort.yaml").read_text()
                    .replace("  seed: 0\n", "  seed: 0\n  initial: [bo-paper]\n"))
    lines = []
    document = tune(load_spec(path), tmp_path / "run", n_calls=3, workers=1, log=lines.append)
    records = history(tmp_path / "run")
    assert records[0]["origin"] == "baseline lqr-paper"
    # a budget this small starts around the baseline (tuning/bayesopt.py STARTS)
    assert [r["origin"] for r in records[1:]] == ["initial design around lqr-paper"] * 2
    assert "start: around the first baseline, in small trust regions (a budget of 3 evaluations: at most " \
           "100 start at the baseline)" in lines
    assert any(line.startswith("baseline lqr-paper: in the initial design, as its design (the same "
                               "Q and R on paper-printed, continuous here): gain within") for line in lines)
    assert "initial bo-paper: not in the initial design: Cc: fixed in the search to another matrix" in lines
    assert records[0]["parameters"]["Dc.q2"] == pytest.approx(2.0)     # log10 100
    assert records[0]["parameters"]["Bc[0][2]"] == 0.0
    # the state it leaves free starts at the slowest of Ac's range (log10 |Ac| from -1 to 2)
    assert records[0]["x"][0] == -1.0
    assert document["best"]["objective"] <= records[0]["objective"]
    summary = (tmp_path / "run" / "summary.md").read_text()
    assert f"from {document['best']['origin']} (best.yaml, prefilter F = " in summary


def test_the_start_follows_the_budget_and_a_resumed_run_keeps_its_own(tmp_path):
    from furuta_cosim.tuning.bayesopt import BOX_SIDE, FEW_EVALUATIONS
    from furuta_cosim.tuning.methods import initial_design, start_of

    spec = load_spec("effort")
    assert start_of(spec, 30) == "baseline" and start_of(spec, FEW_EVALUATIONS) == "baseline"
    assert start_of(spec, FEW_EVALUATIONS + 1) == "space" and start_of(spec, 150) == "space"
    # a run begun with one start and extended past the threshold (or cut to below it) keeps it
    assert start_of(spec, 150, [{"origin": "baseline lqr-paper"},
                                {"origin": "initial design around lqr-paper"}]) == "baseline"
    assert start_of(spec, 30, [{"origin": "baseline lqr-paper"}, {"origin": "initial design"}]) == "space"
    path = tmp_path / "effort-space.yaml"
    path.write_text(spec.path.read_text().replace("  seed: 0\n", "  seed: 0\n  start: space\n"))
    assert start_of(load_spec(path), 30) == "space"
    evaluator = Evaluator(spec)
    design = initial_design(spec, evaluator, 3, start="baseline")
    low, high = (np.array(b) for b in zip(*evaluator.space.bounds))
    center = (np.array(design[0][0]) - low) / (high - low)
    for x, origin in design[1:]:
        assert origin == "initial design around lqr-paper"
        assert np.all(np.abs((np.array(x) - low) / (high - low) - center) <= BOX_SIDE / 2 + 1e-12)
    assert len(initial_design(spec, evaluator, 3, start="space")) == spec.optimizer.n_initial_points


@pytest.mark.slow
def test_the_best_file_reruns_to_its_recorded_metrics(tmp_path, capsys):
    """best.yaml carries everything the scoring used, the prefilter included: simulate of each
    scenario of the spec reproduces the metrics recorded for that evaluation (1e-9)."""
    document = tune(load_spec("effort"), tmp_path / "run", n_calls=4, workers=1)
    best = document["best"]
    assert best and best["prefilter"]["output"] == "theta0" and best["prefilter"]["F"] < 0
    for scenario in ("paper-tracking", "sine-follow", "noise"):
        code, out, err = run_cli(capsys, "simulate", scenario, "--controller",
                                 str(tmp_path / "run" / "best.yaml"), "-o", str(tmp_path / scenario),
                                 "--no-trace", "--json")
        assert code in (0, 1), err
        metrics = json.loads(out)["controllers"]["effort-best"]["metrics"]
        recorded = best["metrics"][scenario]
        assert set(recorded) <= set(metrics)
        for key, value in recorded.items():
            if value is None:
                assert metrics[key] is None, key
            else:
                assert metrics[key] == pytest.approx(value, rel=1e-9, abs=1e-12), (scenario, key)
    # the reference moves the arm: a wrong-signed prefilter could not reproduce error.ISE
    assert best["metrics"]["paper-tracking"]["error.ISE"] < 3.0


def test_a_box_around_the_lqr_holds_the_published_controller(tmp_path, capsys):
    """paper-spectral searches Dc as offsets from the LQR's gains, wide enough for the
    published Dc: bo-paper is a point of the space, exactly; the search starts from the LQR
    only (warm_start: false), and the published controller is scored alike."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.tuning.objective import Evaluator
    from furuta_cosim.tuning.methods import initial_design

    spec = load_spec("paper-spectral")
    evaluator = Evaluator(spec)
    published = load_controller("bo-paper")
    x, how = evaluator.space.point_of(published)
    assert x is not None and how == "exactly"
    built = evaluator.space.controller(x)
    for key in ("Ac", "Bc", "Cc", "Dc"):
        assert getattr(built, key) == pytest.approx(getattr(published.controller, key), rel=1e-12, abs=1e-12)
    lqr = load_controller("lqr-paper").controller
    x, how = evaluator.space.point_of(load_controller("lqr-paper"))
    assert how == "exactly" and evaluator.space.controller(x).Dc == pytest.approx(lqr.Dc, abs=1e-12)
    lines = []
    design = initial_design(spec, evaluator, 0, lines.append)
    assert [origin for _, origin in design][:1] == ["initial lqr-paper"]
    assert not any("bo-paper" in line for line in lines) and len(design) == 10
    assert evaluator.score(published.controller).objective == pytest.approx(371.02, abs=0.01)


@pytest.mark.slow
def test_the_summary_says_what_its_headline_number_does_not(tmp_path):
    """A headline of one objective hid a +47 % peak voltage and an 80 s mode: the summary
    notes every metric worse than the baseline, a slow mode and a parameter at its edge."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.design.analysis import analyze

    # the space-filling start: its 12-call best is worse than the LQR somewhere (the start at
    # the baseline's is better on every metric of the summary)
    path = tmp_path / "effort-space.yaml"
    path.write_text(load_spec("effort").path.read_text().replace("  seed: 0\n", "  seed: 0\n  start: space\n"))
    spec = load_spec(path)
    document = tune(spec, tmp_path / "run", n_calls=12, seed=0)
    best, lqr = document["best"], document["baselines"]["lqr-paper"]
    flags = document["flags"]
    worse = [(label, key) for label, values in best["metrics"].items() for key, value in values.items()
             if key in ("u.peak_abs", "u.rms", "error.ISE", "theta1.max_abs")
             and value > 1.01 * lqr["metrics"][label][key]]
    assert worse, "the 12-call run is worse than the LQR somewhere (its peak voltage, measured)"
    for label, key in worse:
        assert any(f.startswith(f"worse than lqr-paper on {label} {key}:") for f in flags), (label, key, flags)
    evaluator = Evaluator(spec)
    cfile = load_controller(tmp_path / "run" / "best.yaml")
    slowest = analyze(evaluator.model, cfile.controller).dominant.settling_time
    shortest = min(prepared.scenario.duration for _, prepared, _ in evaluator.runs())
    assert (slowest > shortest) == any("slowest mode" in f for f in flags), (slowest, shortest, flags)
    text = (tmp_path / "run" / "summary.md").read_text()
    assert all(f"- note: {f}" in text for f in flags)
