"""Scenario-driven regression: baselines, tolerances, JUnit, other FMUs, bad input."""

import json
import math
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from furuta_cosim import paths
from furuta_cosim.regression import regress

from helpers import run_cli

# the top-level scenarios and those of each example tree (a folder with its own baselines)
TOP = sorted(p.stem for p in paths.scenarios().glob("*.yaml"))     # the Furuta's and the toy's
SHIPPED = TOP + sorted(p.stem for p in (paths.scenarios() / "cart-pole").glob("*.yaml"))


def runs_of(names) -> int:
    """How many runs the scenarios named make: one per controller of each."""
    from furuta_cosim.scenario import load_scenario

    trees = [paths.scenarios(), paths.scenarios() / "cart-pole"]
    return sum(len(load_scenario(next(t / f"{n}.yaml" for t in trees if (t / f"{n}.yaml").is_file())).controllers)
               for n in names)
MAPPING = """\
control_input: voltage
states: {theta0: arm_angle, dtheta0: arm_rate, theta1: pend_angle, dtheta1: pend_rate, i: current}
disturbances: {tau0: arm_torque, tau1: pend_torque}
initial: {theta1: pend_angle_0}
"""


def test_every_shipped_scenario_matches_its_baseline_and_junit_says_so(tmp_path, capsys):
    junit = tmp_path / "regress.xml"
    code, out, err = run_cli(capsys, "regress", "--workers", "2", "--junit", str(junit))
    assert code == 0, out + err
    root = ET.parse(junit).getroot()
    cases = root.findall("./testsuite/testcase")
    # every controller of every shipped scenario, none failed, each compared on something
    assert {s.get("name") for s in root.findall("testsuite")} == set(SHIPPED)
    assert len(cases) == runs_of(SHIPPED) and root.get("failures") == "0"
    assert not root.findall(".//failure")
    checked = [int(c.find("properties/property[@name='checked']").get("value")) for c in cases]
    assert min(checked) >= 10


def test_a_changed_plant_parameter_is_a_regression_naming_what_moved(capsys):
    code, out, _ = run_cli(capsys, "regress", "paper-step", "--params", "C1=1e-4", "--workers", "1")
    assert code == 1
    lines = [line for line in out.splitlines() if line.startswith("REGRESSION paper-step / lqr-paper: ")]
    assert lines, out
    metric = [line for line in lines if ": u.rms: expected " in line]
    assert metric and ", got " in metric[0], lines


def _own_scenario(tmp_path) -> Path:
    """paper-step with its own copy of lqr-paper, beside it in tmp_path."""
    controller = (paths.scenarios() / "controllers" / "lqr-paper.yaml").read_text()
    (tmp_path / "mine.yaml").write_text(controller.replace("name: lqr-paper", "name: mine"))
    text = (paths.scenarios() / "paper-step.yaml").read_text()
    text = text.replace("controllers: [lqr-paper, bo-paper]", "controllers: [mine.yaml]")
    text = text.replace("controllers: [lqr-paper]}", "controllers: [mine]}")
    (tmp_path / "step.yaml").write_text(text.replace("name: paper-step", "name: step"))
    return tmp_path / "step.yaml"


def test_a_perturbed_controller_is_a_regression_and_update_says_what_changed(tmp_path, capsys):
    scenario = _own_scenario(tmp_path)
    code, out, _ = run_cli(capsys, "regress", str(scenario), "--update")
    assert code == 0 and "step  " in out and " new" in out
    baseline = tmp_path / "baselines" / "step" / "mine.yaml"
    assert baseline.is_file()
    code, out, _ = run_cli(capsys, "regress", str(scenario))
    assert code == 0, out
    controller = tmp_path / "mine.yaml"
    text = controller.read_text()
    perturbed = text.replace("K: [-0.3105225402877734,", "K: [-0.32,")  # the arm gain, 3 %
    assert perturbed != text
    controller.write_text(perturbed)
    code, out, _ = run_cli(capsys, "regress", str(scenario), "--json")
    assert code == 1
    case = json.loads(out)["cases"][0]
    assert case["status"] == "fail" and case["controller"] == "mine"
    assert any(d["kind"] == "metric" and d["name"] == "error.ISE" for d in case["differences"])
    assert case["notes"] and "changed since the baseline" in case["notes"][0]
    before = baseline.read_text()
    code, out, _ = run_cli(capsys, "regress", str(scenario), "--update")
    assert code == 0 and "updated" in out and "changed    step / mine: error.ISE: expected" in out
    assert baseline.read_text() != before
    code, _, _ = run_cli(capsys, "regress", str(scenario))
    assert code == 0


def test_a_missing_baseline_fails_and_says_how_to_make_it(tmp_path, capsys):
    scenario = _own_scenario(tmp_path)
    code, out, _ = run_cli(capsys, "regress", str(scenario))
    assert code == 1 and "REGRESSION step / mine: no baseline at" in out and "--update" in out


@pytest.mark.slow
def test_the_fmu_rebuilt_by_fmpy_compile_passes(tmp_path, furuta_fmu, capsys):
    rebuilt = tmp_path / "Furuta.fmu"
    shutil.copy(furuta_fmu, rebuilt)
    done = subprocess.run([sys.executable, "-m", "fmpy.cli", "compile", str(rebuilt)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert rebuilt.read_bytes() != furuta_fmu.read_bytes()  # a binary of its own
    names = [n for n in TOP if not n.startswith("toy")]
    code, out, err = run_cli(capsys, "regress", *names, "--fmu", str(rebuilt), "--workers", "1")
    assert code == 0, out + err
    assert f"{runs_of(names)} run(s)" in out and f": {runs_of(names)} pass" in out


def test_another_exporters_fmu_passes_through_a_mapping(tmp_path, foreign_fmu, capsys):
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING)
    report = regress(["paper-step"], fmu=foreign_fmu, mapping=mapping, workers=1)
    assert [c.status for c in report.cases] == ["pass", "pass"], [c.lines() for c in report.cases]
    assert min(c.checked for c in report.cases) >= 10


def _one_line_exit_2(capsys, *argv) -> str:
    code, out, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, (code, out, err)
    return lines[0]


@pytest.fixture
def corrupt(tmp_path):
    scenario = _own_scenario(tmp_path)
    target = tmp_path / "baselines" / "step" / "mine.yaml"
    target.parent.mkdir(parents=True)
    return scenario, target


@pytest.mark.parametrize("text, key", [
    ("format: 1\nscenario: [", "line"),                      # not YAML
    ("just text", "expected a mapping"),
    ("format: 2\nscenario: {name: step, sha256: x}\ncontroller: {name: mine, sha256: x}\n"
     "metrics: {}\ntrace: {every: 1, columns: [t], rows: []}\n", "format: expected 1"),
    ("format: 1\nscenario: {name: step, sha256: x}\ncontroller: {name: mine, sha256: x}\n"
     "metrics: {a.b: yes}\ntrace: {every: 1, columns: [t, u], rows: [[0, 1]]}\n", "metrics.a.b"),
    ("format: 1\nscenario: {name: step, sha256: x}\ncontroller: {name: mine, sha256: x}\n"
     "metrics: {}\ntrace: {every: 1, columns: [t, u], rows: [[0, 1], [1]]}\n", "trace.rows[1]"),
    ("format: 1\nscenario: {name: step, sha256: x}\ncontroller: {name: mine, sha256: x}\n"
     "metrics: {}\ntrace: {every: 1, columns: [t, u], rows: [[1, 1], [0, 1]]}\n", "trace.rows: the times"),
])
def test_a_corrupt_baseline_is_one_line_and_never_overwritten(corrupt, capsys, text, key):
    scenario, target = corrupt
    target.write_text(text)
    line = _one_line_exit_2(capsys, "regress", str(scenario))
    assert line.startswith(f"error: {target}") and key in line, line
    code, out, err = run_cli(capsys, "regress", str(scenario), "--update")
    assert code == 2 and "refusing to overwrite" in err
    assert target.read_text() == text


def test_a_baseline_of_another_scenario_version_is_refused(tmp_path, capsys):
    scenario = _own_scenario(tmp_path)
    run_cli(capsys, "regress", str(scenario), "--update")
    scenario.write_text(scenario.read_text().replace("duration: 10.0", "duration: 9.0"))
    line = _one_line_exit_2(capsys, "regress", str(scenario))
    assert "scenario.sha256: made from another version of" in line and "--update" in line


@pytest.mark.parametrize("argv, expected", [
    (["paper-step", "--fmu", "missing.fmu"], "--fmu missing.fmu: no such FMU file"),
    (["--fmu", "x.fmu"], "--fmu: name the scenarios"),
    (["paper-step", "--fmu", "x.fmu", "--mapping", "missing.yaml"], "--mapping missing.yaml: no such file"),
    (["paper-step", "--params", "C1=abc"], "--params C1=abc: expected NAME=NUMBER"),
    (["paper-step", "--params", "nosuchset"], "nosuchset"),
    (["paper-step", "--update", "--params", "C1=1e-4"], "--update: writes the baselines"),
    (["nosuchscenario"], "nosuchscenario"),
])
def test_bad_arguments_are_one_line(capsys, argv, expected):
    line = _one_line_exit_2(capsys, "regress", *argv)
    assert expected in line, line


def test_an_fmu_that_does_not_fit_the_mapping_is_one_line(tmp_path, foreign_fmu, capsys):
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(MAPPING.replace("pend_angle,", "pendulum_angle,"))
    line = _one_line_exit_2(capsys, "regress", "paper-step", "--fmu", str(foreign_fmu),
                            "--mapping", str(mapping))
    # the mapping file is at fault, not the scenario: the line names that file and its key
    assert line.startswith(f"error: {mapping}: states.theta1: ForeignPendulum has no Real output "
                           "'pendulum_angle'"), line


@pytest.mark.parametrize("text, key", [
    ("states: 3\n", "states: expected a mapping"),
    ("states: {theta0: 5}\n", "states.theta0: expected a non-empty string"),
    ("control_input: ''\n", "control_input: expected a non-empty string"),
    ("extra: 1\n", "extra"),
])
def test_a_bad_mapping_file_is_one_line_naming_its_key(tmp_path, foreign_fmu, capsys, text, key):
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(text)
    line = _one_line_exit_2(capsys, "regress", "paper-step", "--fmu", str(foreign_fmu),
                            "--mapping", str(mapping))
    assert line.startswith(f"error: {mapping}: ") and key in line, line


@pytest.mark.parametrize("damage, expected", [
    ("column all NaN", 2), ("column all inf", 2), ("a NaN in one row", 2), ("rows: []", 2),
    ("rows cut short", 2), ("a column missing", 1), ("columns: [t] only", 1),
    ("wrong at 198 of 200 points, one value 1e300", 1),
])
def test_a_damaged_baseline_never_passes(tmp_path, capsys, damage, expected):
    """The trace of a baseline is validated (finite, complete, every signal), and one wild
    value cannot widen the band to everything."""
    import yaml

    from furuta_cosim.regression import baseline_text

    scenario = _own_scenario(tmp_path)
    assert run_cli(capsys, "regress", str(scenario), "--update")[0] == 0
    target = tmp_path / "baselines" / "step" / "mine.yaml"
    document = yaml.safe_load(target.read_text())
    trace = document["trace"]
    columns, rows = trace["columns"], trace["rows"]
    u = columns.index("theta1")
    if damage == "column all NaN":
        rows = [[*r[:u], None, *r[u + 1:]] for r in rows]
    elif damage == "column all inf":
        rows = [[*r[:u], math.inf, *r[u + 1:]] for r in rows]
    elif damage == "a NaN in one row":
        rows[100][u] = None
    elif damage == "rows: []":
        rows = []
    elif damage == "rows cut short":
        rows = rows[:120]
    elif damage == "a column missing":
        columns = [c for k, c in enumerate(columns) if k != u]
        rows = [[v for k, v in enumerate(r) if k != u] for r in rows]
    elif damage == "columns: [t] only":
        columns, rows = ["t"], [[r[0]] for r in rows]
    else:
        assert len(rows) >= 200
        rows = [[*r[:u], r[u] + 0.05, *r[u + 1:]] for r in rows]
        rows[50][u] = 1e300
        rows[0][u] -= 0.05
        rows[-1][u] -= 0.05
    document["trace"] = {"every": trace["every"], "columns": columns, "rows": rows}
    target.write_text(baseline_text(document))
    code, out, err = run_cli(capsys, "regress", str(scenario))
    assert code == expected, (damage, out, err)
    if expected == 2:
        assert err.startswith(f"error: {target}: trace.rows"), err
    else:
        assert "REGRESSION step / mine: theta1" in out, out


@pytest.mark.slow
def test_regress_passes_under_other_blas_kernels():
    """The shipped baselines do not rest on rounding: the same regress under two OpenBLAS
    kernels (each rounds its reductions its own way, and each differs from the default one)
    passes, the diverging bo-paper run on noise-kalman included."""
    import platform

    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if platform.machine() in ("x86_64", "AMD64"):
        candidates = ["Prescott"] + (["Haswell"] if " avx2" in flags else []) + ["Nehalem"]
    else:
        candidates = ["ARMV8"] + (["NEOVERSEN1"] if " asimddp" in flags else []) + ["CORTEXA57"]
    # OpenBLAS keeps its default for a name it does not take (nothing would be tested): two
    # kernels that differ from the default and from each other
    probe = ("import numpy, threadpoolctl; print([i.get('architecture') for i in "
             "threadpoolctl.threadpool_info() if i.get('user_api') == 'blas'])")

    def in_effect(env):
        return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                              check=True).stdout.strip()

    seen, kernels = {in_effect(dict(os.environ))}, []
    for kernel in candidates:
        runs = in_effect({**os.environ, "OPENBLAS_CORETYPE": kernel})
        if runs not in seen and len(kernels) < 2:
            seen.add(runs)
            kernels.append(kernel)
    assert len(kernels) == 2, (candidates, seen)
    for kernel in kernels:
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
        done = subprocess.run([sys.executable, "-c", "import sys; from furuta_cosim.cli import main; "
                               "sys.exit(main(['regress', '--workers', '1', '--json']))"],
                              env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, (kernel, done.stdout[-3000:], done.stderr[-3000:])
        cases = json.loads(done.stdout)["cases"]
        assert len(cases) == runs_of(SHIPPED) and {c["status"] for c in cases} == {"pass"}
        diverging = [c for c in cases if c["scenario"] == "noise-kalman" and c["controller"] == "bo-paper"]
        assert diverging and diverging[0]["checked"] >= 10, diverging


@pytest.mark.slow
def test_a_new_metric_fails_no_shipped_baseline_and_update_adds_only_its_lines(tmp_path, capsys, monkeypatch):
    """Open-world baselines: a metric added to the code (here error.ITSE) is a note on every
    baseline that lacks it, and --update adds its line to each of them, nothing else."""
    import difflib

    from furuta_cosim import metrics

    copy = tmp_path / "scenarios"
    shutil.copytree(paths.scenarios(), copy)
    regress([str(p) for p in sorted(copy.glob("*.yaml"))], update=True)  # up to this code's metrics
    before = {p: p.read_text() for p in sorted((copy / "baselines").rglob("*.yaml"))}
    # a new metric is one registry entry (furuta_cosim/metrics.py), registered by being defined
    monkeypatch.setattr(metrics, "METRICS", dict(metrics.METRICS))

    class ITSE(metrics.Sum):
        name, of, description = "ITSE", "error", "integral of t e^2"

        def term(self, s):
            return s.t * s.x ** 2

    report = regress([str(p) for p in sorted(copy.glob("*.yaml"))])
    assert not report.failed and len(report.cases) == runs_of(TOP)
    noted = [c for c in report.cases if any("metric error.ITSE" in n for n in c.notes)]
    # every run to its end holds the new metric (a run that stopped early stores none)
    finished = [p for p, text in before.items() if "failure: null" in text]
    assert len(noted) == len(finished) >= 15
    report = regress([str(p) for p in sorted(copy.glob("*.yaml"))], update=True)
    added, removed = [], []
    for path, text in before.items():
        for line in difflib.unified_diff(text.splitlines(), path.read_text().splitlines(), lineterm="", n=0):
            if line.startswith(("+++", "---", "@@")):
                continue
            (added if line.startswith("+") else removed).append((path.name, line))
    assert removed == [] and len(added) == len(finished)
    assert all(line.startswith("+  error.ITSE: ") for _, line in added), added[:3]
    # and the updated baselines pass as they are
    assert not regress([str(p) for p in sorted(copy.glob("*.yaml"))]).failed


def test_update_leaves_a_baseline_that_still_passes_byte_for_byte(tmp_path, capsys):
    """What the run reproduces within tolerance is kept as stored (here every value after a
    perturbation far below the tolerances), so an update on another machine changes nothing."""
    copy = tmp_path / "scenarios"
    shutil.copytree(paths.scenarios(), copy)
    # first brought up to the metrics this code computes (a metric added since the shipped
    # baseline was written is one line an update adds, not a change of what it holds)
    regress([str(copy / "paper-step.yaml")], update=True)
    target = copy / "baselines" / "paper-step" / "lqr-paper.yaml"
    text = target.read_text()
    nudged = text.replace("error.ISE: 0.5176796916", "error.ISE: 0.5176796917")
    assert nudged != text
    target.write_text(nudged)
    report = regress([str(copy / "paper-step.yaml")], update=True)
    assert {c.status for c in report.cases} == {"unchanged"}
    assert target.read_text() == nudged


def test_a_signal_the_baseline_lacks_is_a_note_unless_it_is_the_runs_core(tmp_path, capsys):
    import yaml

    from furuta_cosim.regression import baseline_text

    scenario = _own_scenario(tmp_path)
    assert run_cli(capsys, "regress", str(scenario), "--update")[0] == 0
    target = tmp_path / "baselines" / "step" / "mine.yaml"
    document = yaml.safe_load(target.read_text())
    columns, rows = document["trace"]["columns"], document["trace"]["rows"]
    for name, code in (("i", 0), ("u", 1)):
        k = columns.index(name)
        document["trace"] = {"every": document["trace"]["every"], "columns": columns[:k] + columns[k + 1:],
                             "rows": [r[:k] + r[k + 1:] for r in rows]}
        target.write_text(baseline_text(document))
        got, out, err = run_cli(capsys, "regress", str(scenario), "--json")
        case = json.loads(out)["cases"][0]
        assert got == code, (name, out, err)
        if code == 0:
            assert "not in the baseline (regress with `update` adds it): signal i" in case["notes"]
        else:
            assert case["differences"][0]["name"] == "u" and "missing from the baseline" in case["differences"][0]["got"]


@pytest.mark.slow
def test_worker_processes_leave_nothing_in_the_temporary_directory(tmp_path):
    """Each worker extracts the FMU into a folder of its own; the folder goes when the worker
    does, on a normal end too (a pool's workers never run atexit handlers)."""
    folder = tmp_path / "tmpdir"
    folder.mkdir()
    done = subprocess.run([sys.executable, "-m", "furuta_cosim", "regress", "paper-step", "sine",
                           "noise", "--workers", "2"], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "TMPDIR": str(folder)})
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in folder.iterdir()) == []


@pytest.mark.slow
def test_update_never_writes_a_baseline_that_regress_would_refuse(tmp_path, capsys):
    """--update once wrote a 6 MB baseline that every later regress refused as too large."""
    text = (paths.scenarios() / "paper-step.yaml").read_text()
    path = tmp_path / "long-step.yaml"
    path.write_text(text.replace("name: paper-step", "name: long-step")
                    .replace("controllers: [lqr-paper, bo-paper]", "controllers: [lqr-paper]")
                    + "\nregression: {points: 100000}\n")
    data = yaml.safe_load(path.read_text())
    data["timing"]["duration"] = 100.0
    path.write_text(yaml.safe_dump(data))
    code, out, err = run_cli(capsys, "regress", str(path), "--update", "--workers", "1")
    assert code == 1 and "not written: regress reads no file over 1 MB" in out + err, out + err
    assert not (tmp_path / "baselines" / "long-step" / "lqr-paper.yaml").exists()


@pytest.mark.parametrize("name", ["", "peak", ".x", "u."])
def test_a_baseline_metric_without_a_signal_is_refused(tmp_path, name):
    """Found by tests/test_fuzz.py: a metric named '' was read as a metric."""
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.regression import read_baseline

    data = yaml.safe_load((paths.scenarios() / "baselines" / "paper-step" / "lqr-paper.yaml").read_text())
    data["metrics"][name] = 1.0
    path = tmp_path / "lqr-paper.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="expected a metric name <signal>.<metric>"):
        read_baseline(path)
