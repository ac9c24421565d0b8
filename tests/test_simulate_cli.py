"""simulate for a user: long runs, thinned traces, diverging runs in the figure, the README's
every-key example."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np

from furuta_cosim.progress import Progress
from furuta_cosim.cosim import evaluate, prepare, simulate
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.report.figures import figure_of_runs
from furuta_cosim.scenario import load_scenario

from helpers import run_cli

ROOT = Path(__file__).resolve().parent.parent


def test_long_runs_report_progress_in_chunks():
    scenario = dataclasses.replace(load_scenario("paper-step"), duration=200.0, requirements=())
    prepared = prepare(scenario)
    calls = []
    with PlantSession.open(prepared.fmu) as session:
        result = evaluate(prepared, session, "lqr-paper", progress=lambda k, n: calls.append((k, n)))
    assert calls == [(50_000, 100_000), (100_000, 100_000)]
    assert len(result.trace.t) == 100_000 and result.failure is None


def test_progress_lines_when_the_output_is_not_a_terminal(capsys):
    progress = Progress(delay=0.0, every=0.0)
    progress("lqr", 50, 100)
    progress("lqr", 100, 100)
    assert capsys.readouterr().err.splitlines() == ["  lqr: 50/100 steps (50%)", "  lqr: 100/100 steps (100%)"]


def test_traces_can_be_thinned_or_left_out(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "all"), "--json")
    full = json.loads(out)
    code, out, _ = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "thin"),
                           "--every", "10", "--json")
    thin = json.loads(out)
    assert code == 0 and thin["trace_every"] == 10
    lines = (tmp_path / "thin" / "lqr-paper.csv").read_text().splitlines()
    assert len(lines) == 1 + 500
    # the metrics still use every sample
    assert thin["controllers"]["lqr-paper"]["metrics"] == full["controllers"]["lqr-paper"]["metrics"]
    code, out, _ = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "none"),
                           "--no-trace", "--json")
    document = json.loads(out)
    assert code == 0 and not list((tmp_path / "none").glob("*.csv"))
    assert document["files"] == ["metrics.json", "paper-step.png", "paper-step.svg"]
    code, _, err = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "x"), "--every", "0")
    assert code == 2 and "--every: must be a whole number >= 1, got 0" in err


def test_a_diverging_run_does_not_flatten_the_others_in_the_figure():
    results = simulate(prepare(load_scenario("noise-kalman")))
    bo = results["bo-paper"].trace
    assert bo.failure and np.max(np.abs(bo.u)) > 1e4  # it did diverge
    figure = figure_of_runs({name: r.trace for name, r in results.items()})
    theta0, theta1, u = figure.axes
    lqr = results["lqr-paper"].trace
    for axis, values in ((theta1, lqr["theta1"]), (u, lqr.u)):
        low, high = axis.get_ylim()
        span = np.max(values) - np.min(values)
        assert low <= np.min(values) and high >= np.max(values)
        assert high - low <= 1.3 * span  # scaled to the LQR run, not to the diverging one
        notes = [text.get_text() for text in axis.texts]
        assert any(n.startswith("bo-paper leaves the plot at ") for n in notes), notes


def test_the_readme_every_key_example_runs_cleanly(tmp_path, capsys):
    from helpers import page

    text = page("scenarios.md")
    section = text[text.index("Every key of a scenario file"):]
    example = re.search(r"```yaml\n(.*?)```", section, re.S).group(1)
    path = tmp_path / "my-scenario.yaml"
    path.write_text(example)
    code, out, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 0, out + err
    assert "FAIL" not in out and "SKIP" not in out and "error" not in err


def test_simulate_names_a_run_that_never_settles_and_keeps_its_exit_code(capsys, tmp_path):
    """The published BO controller oscillates on the calibrated plant (68.6 V): no requirement
    concerns it, so the exit code stays 0, but the run is named, with its size."""
    code, out, err = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "out"))
    assert code == 0, err
    warned = [line for line in out.splitlines() if line.startswith("WARN")]
    assert len(warned) == 1 and warned[0].startswith("WARN  bo-paper: theta1 does not settle by the end of the run (peak |theta1| 0.6")
    assert "peak |u| 68.5" in warned[0]
    document = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert document["controllers"]["lqr-paper"]["warnings"] == []


def test_the_exit_code_policy_is_in_the_help():
    from furuta_cosim.cli import build_parser

    text = " ".join(build_parser().format_help().split())
    assert "exit codes: 0 success; 1 a check failed" in text and "2 bad input" in text


def test_a_controller_designed_for_another_plant_warns_and_its_divergence_exits_1(tmp_path, capsys):
    # lqr-qube is designed on the QUBE's linearization; paper-step runs the paper's plant, where
    # it drives the pendulum over (to 2.06 rad from upright at 21,600 V): one warning line
    # before the run, a FAIL after it, exit 1
    code, out, err = run_cli(capsys, "simulate", "paper-step", "--controller", "lqr-qube", "-o", str(tmp_path / "a"))
    assert code == 1, err
    warnings = [line for line in err.splitlines() if line.startswith("warning: lqr-qube:")]
    assert len(warnings) == 1 and "designed on qube-servo-3" in warnings[0] and "on paper-calibrated" in warnings[0]
    assert "FAIL  lqr-qube: diverged: the pendulum fell" in out
    document = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert document["passed"] is False and document["controllers"]["lqr-qube"]["diverged"].startswith("the pendulum fell")
    # on its own plant: no warning, no divergence
    code, out, err = run_cli(capsys, "simulate", "qube-step", "-o", str(tmp_path / "b"))
    assert code == 0 and "warning" not in err and "diverged" not in out, (out, err)
