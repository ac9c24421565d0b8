"""Candidates that have failed stop early: a run whose running ISE or peak is past its bound
stops there with a lower bound of what the full run would give, the other runs of that
candidate are skipped, the run that fails most often goes first, and the loop's exact
constraints are checked for candidates instead of being learned."""

import dataclasses
import json
import shutil

import numpy as np
import pytest

from furuta_cosim.controllers import load_controller
from furuta_cosim.tuning.history import failing_first
from furuta_cosim.tuning.objective import Evaluator
from furuta_cosim.tuning.bayesopt import ConstrainedBO
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec


def stopping(spec, slack=0.0):
    """``spec`` with early stopping on (the shipped specs leave it off)."""
    return dataclasses.replace(spec, constraints=dataclasses.replace(spec.constraints, stop_early=slack))


@pytest.fixture(scope="module")
def effort():
    return Evaluator(stopping(load_spec("effort")))


def candidate_breaking_sine_follow(evaluator):
    """The first point along the diagonal of the effort space whose loop is stable and which
    tracks the sine worse than the LQR allows, with its outcome with every run to the end."""
    space = evaluator.space
    for scale in np.linspace(0.0, 1.0, 21):
        x = [low + scale * (high - low) for low, high in space.bounds]
        if evaluator.loop_checks(space.controller(x))[1] == 0:
            outcome = Evaluator.score(evaluator, space.controller(x))
            if not outcome.feasible and outcome.constraints.get("sine-follow.error.ISE/lqr-paper", 0) > 1.05:
                return x, outcome
    raise AssertionError("no stable point of the effort space breaks sine-follow's tracking")


@pytest.mark.slow
def test_a_failed_candidate_stops_and_skips_its_other_runs_with_a_lower_bound(effort):
    x, full = candidate_breaking_sine_follow(effort)
    early = effort(x, ["sine-follow", "paper-tracking", "noise"])
    assert not early.feasible and early.value is None
    assert early.stopped["run"] == "sine-follow" and early.stopped["metric"] == "error.ISE"
    assert early.skipped == ["paper-tracking", "noise"]
    assert "sine-follow" in early.violated and set(early.metrics) == {"sine-follow"}
    # the violation said (objective = penalty + violation) and the margin are lower bounds
    penalty = effort.spec.constraints.penalty
    assert penalty < early.objective <= full.objective
    assert early.margin <= full.margin and early.margin > 0
    ratio = early.constraints["sine-follow.error.ISE/lqr-paper"]
    assert 1.05 < ratio <= full.constraints["sine-follow.error.ISE/lqr-paper"]
    assert len(early.metrics) < len(full.metrics)  # fewer runs simulated (speed: tools/bench_tune.py)


@pytest.mark.slow
def test_a_feasible_candidate_scores_the_same_in_any_order(effort):
    lqr = effort.space.point_of(load_controller("lqr-paper"))[0]
    plain = effort(lqr)
    reordered = effort(lqr, ["noise", "sine-follow", "paper-tracking"])
    assert plain.feasible and reordered.feasible and not plain.stopped and not plain.skipped
    assert reordered.objective == plain.objective and reordered.value == plain.value
    assert reordered.margin == plain.margin
    assert {k: v for k, v in reordered.metrics.items()} == plain.metrics


def test_the_run_broken_most_often_goes_first():
    labels = ["a", "b", "c"]
    records = [{"violated": ["b"]}, {"violated": ["c", "b"]}, {"violated": []}, {},
               {"violated": ["c"]}, {"violated": ["zz"]}, {"violated": "b"}]
    assert failing_first(records, labels) == ["b", "c", "a"]
    assert failing_first([], labels) == labels  # ties keep the spec's order


def test_candidates_failing_the_exact_check_are_never_proposed_and_not_learned():
    """A screen that refuses half the cube (x0 > 0.5) is checked for every candidate the
    acquisition ranks, however many rank above the first that passes; the refused points of
    the history ('known') are left out of the feasibility GP."""
    bounds = [(0.0, 1.0)] * 3
    checked = []

    def screen(x):
        checked.append(x)
        return x[0] <= 0.5

    bo = ConstrainedBO(bounds, 0, xi=0.01, n_initial_points=6, batch=2, region="global", screen=screen)
    rng = np.random.default_rng(0)
    records = []
    for k in range(12):
        x = rng.random(3).tolist()
        known = x[0] > 0.5
        records.append({"index": k, "x": x, "feasible": not known, "known": known,
                        "objective": (1000.0 + x[0]) if known else float(np.sum(np.square(x))),
                        "value": None if known else float(np.sum(np.square(x))),
                        "margin": 1.0 if known else -0.5})
    proposal = bo.propose(records, 6, 0)
    points = list(proposal.points(2))
    assert all(p[0] <= 0.5 for p in points)
    assert any(c[0] > 0.5 for c in checked)  # ranked above them, refused, passed over
    b = bo._batch(records, 0)
    assert len(b.feasibility.y) == sum(1 for r in records if not r["known"])


def test_the_pick_checks_beyond_any_fixed_number_of_candidates():
    bo = ConstrainedBO([(0.0, 1.0)], 0, xi=0.01, n_initial_points=2, batch=1,
                       screen=lambda x: x[0] < 0.01)
    C = np.linspace(0.0, 1.0, 1001)[:, None]
    top, score = bo._pick(C, C[:, 0].copy())  # the best by score are the refused ones
    assert top[0] < 0.01 and score == pytest.approx(top[0])


@pytest.mark.slow
def test_an_early_stopping_run_resumes_to_the_uninterrupted_history(tmp_path):
    spec = stopping(load_spec("effort"))
    spec = dataclasses.replace(spec, optimizer=dataclasses.replace(spec.optimizer, n_initial_points=6))
    document = tune(spec, tmp_path / "whole", n_calls=14, workers=1)
    lines = (tmp_path / "whole" / "history.jsonl").read_text().splitlines(keepends=True)
    records = [json.loads(line) for line in lines]
    assert any(r.get("stopped") for r in records) and any(r.get("skipped") for r in records)
    # the summary counts what was cut short, in numbers and in words
    early = document["early"]
    assert early["stopped"] == sum(1 for r in records if r["stopped"]) > 0
    assert early["runs_skipped"] == sum(len(r["skipped"]) for r in records) > 0
    assert f"cut short: {early['cut_short']} infeasible candidates" in \
        (tmp_path / "whole" / "summary.md").read_text()
    for r in records:
        if r.get("stopped"):
            assert r["value"] is None and not r["feasible"] and r["stopped"]["run"] in r["violated"]
    folder = tmp_path / "cut"
    shutil.copytree(tmp_path / "whole", folder)
    for name in ("summary.json", "summary.md", "best.yaml"):
        (folder / name).unlink(missing_ok=True)
    (folder / "history.jsonl").write_text("".join(lines[:9]) + lines[9][:30])  # a batch's middle
    tune(spec, folder, n_calls=14, workers=2, resume=True)

    def strip(text):
        return [{k: v for k, v in json.loads(line).items() if k not in ("wall_time", "worker")}
                for line in text.splitlines()]

    assert strip((folder / "history.jsonl").read_text()) == strip("".join(lines))


def test_stop_early_is_a_slack_or_false(tmp_path):
    source = (load_spec("effort").path).read_text()
    assert load_spec("effort").constraints.stop_early is None  # off unless a spec asks
    for text, expected in (("0.25", 0.25), ("false", None), ("0", 0.0), ("null", None)):
        path = tmp_path / f"stop-{text}.yaml"
        path.write_text(source.replace("  requirements: false\n", f"  requirements: false\n  stop_early: {text}\n"))
        assert load_spec(path).constraints.stop_early == expected


@pytest.mark.slow
def test_stop_early_false_runs_every_run_of_a_failed_candidate_to_its_end(effort):
    x, full = candidate_breaking_sine_follow(effort)
    spec = load_spec("effort")
    never = Evaluator(dataclasses.replace(spec, constraints=dataclasses.replace(spec.constraints, stop_early=None)))
    outcome = never(x, ["sine-follow", "paper-tracking", "noise"])
    assert outcome.stopped is None and outcome.skipped == [] and outcome.value == full.value
    assert outcome.objective == full.objective and set(outcome.metrics) == set(full.metrics)
