"""Fault injection: malformed files made from the shipped ones, hostile YAML, output-folder
faults and interrupted runs. Bad input is one line naming file and key, exit 2, never a
traceback; an interrupted run leaves no half-written file and no temporary folder."""

import copy
import signal
import subprocess
import sys
import time

import pytest
import yaml

from furuta_cosim import paths

from helpers import run_cli

SHIPPED = paths.scenarios()
MISSING = object()

# (path of keys, new value or MISSING, a key the error must name)
SCENARIO_CASES = [
    (("name",), 42, "name"), (("name",), [], "name"), (("name",), "../../escaped-by-name", "name"),
    (("name",), "a b", "name"), (("description",), [1], "description"),
    (("description",), {"a": 1}, "description"), (("plant",), 5, "plant"),
    (("plant",), [], "plant"), (("plant",), "furuta", "plant"), (("plant", "model"), 5, "plant.model"),
    (("plant", "model"), "segway", "plant.model"), (("plant", "model"), "", "plant.model"),
    (("plant", "initial"), [1], "plant.initial"), (("plant", "initial"), {"theta1": "a"}, "plant.initial.theta1"),
    (("plant", "initial"), {"theta1": float("nan")}, "plant.initial.theta1"),
    (("plant", "initial"), {"zeta": 0.1}, "plant.initial.zeta"),
    (("plant", "overrides"), {"mass": 1.0}, "plant.overrides.mass"),
    (("plant", "overrides"), {"n_substeps": 2.5}, "plant.overrides.n_substeps"),
    (("plant", "overrides"), {"n_substeps": 1.0e10}, "plant.overrides.n_substeps"),
    (("plant", "overrides"), {"m_p": "x"}, "plant.overrides.m_p"),
    (("plant",), {"fmu": "missing.fmu"}, "plant.fmu"), (("plant",), {"fmu": 5}, "plant.fmu"),
    (("plant", "mapping"), 5, "plant.mapping"), (("plant", "mapping"), {"states": 5}, "plant.mapping.states"),
    (("plant", "mapping"), {"states": {"theta0": 5}}, "plant.mapping.states.theta0"),
    (("plant", "mapping"), {"bogus": {}}, "plant.mapping.bogus"),
    (("plant", "control_input"), "volts", "plant.control_input"),
    (("timing",), 5, "timing"), (("timing",), {}, "timing.duration"),
    (("timing", "duration"), -1.0, "timing.duration"), (("timing", "duration"), 1.0e308, "timing.duration"),
    (("timing", "duration"), 1.0e9, "timing.duration"), (("timing", "duration"), "x", "timing.duration"),
    (("timing", "control_period"), 0.0, "timing.control_period"),
    (("timing", "control_period"), 1.0e-300, "timing.duration"),
    (("timing", "communication_step"), 0.0015, "timing.control_period"),
    (("timing", "communication_step"), 1.0e-300, "timing.communication_step"),
    (("timing", "extra"), 1, "timing.extra"), (("reference",), 5, "reference"),
    (("reference", "signal"), 5, "reference.signal"),
    (("reference", "signal"), {"type": "wave"}, "reference.signal.type"),
    (("reference", "signal"), {"type": "step", "amplitude": 1.0}, "reference.signal.time"),
    (("reference", "signal"), {"type": "sine", "amplitude": 1.0, "period": -1.0}, "reference.signal.period"),
    (("reference", "signal"), {"type": "table", "points": [[1, 0], [0, 1]]}, "reference.signal.points"),
    (("reference", "output"), "phi", "reference.output"), (("noise",), 5, "noise"),
    (("noise",), {"seed": -1}, "noise.seed"), (("noise",), {"seed": 1.5}, "noise.seed"),
    (("noise",), {"seed": 1, "process": {"tau9": 1.0}}, "noise.process.tau9"),
    (("noise",), {"seed": 1, "measurement": {"theta1": -1.0}}, "noise.measurement.theta1"),
    (("noise",), {"seed": 1, "measurement": {"zeta": 1.0}}, "noise.measurement.zeta"),
    (("disturbances",), 5, "disturbances"),
    (("disturbances",), [{"input": "tau1", "start": 0.0, "duration": 1.0}], "disturbances[0].value"),
    (("disturbances",), [{"input": "tau9", "start": 0.0, "duration": 1.0, "value": 1.0}], "disturbances[0].input"),
    (("actuator",), {"limit": 0.0}, "actuator.limit"), (("actuator",), {"limit": "x"}, "actuator.limit"),
    (("estimator",), {"type": "luenberger", "measured": ["theta0"]}, "estimator.type"),
    (("estimator",), {"type": "kalman", "measured": ["zeta"]}, "estimator.measured"),
    (("controllers",), [], "controllers"), (("controllers",), 5, "controllers"),
    (("controllers",), ["nonexistent"], "controllers[0]"), (("controllers",), [5], "controllers"),
    (("requirements",), 5, "requirements"),
    (("requirements",), [{"metric": "x", "max": 1.0}], "requirements[0].metric"),
    (("requirements",), [{"metric": "theta1.Overshoot", "max": 1.0}], "requirements[0].metric"),
    (("requirements",), [{"metric": "u.peak_abs"}], "requirements[0]"),
    (("requirements",), [{"metric": "u.peak_abs", "max": "x"}], "requirements[0].max"),
    (("requirements",), [{"metric": "u.peak_abs", "max": 1.0, "controllers": ["nobody"]}],
     "requirements[0].controllers"),
    (("metrics",), {"error_window": [5.0]}, "metrics.error_window"),
    (("metrics",), {"error_window": [5.0, 1.0]}, "metrics.error_window"),
    (("metrics",), {"error_window": [100.0, 200.0]}, "metrics.error_window"),
    (("plot",), ["zeta"], "plot"), (("plot",), 5, "plot"), (("extra",), 1, "extra"),
]
CONTROLLER_CASES = [
    (("type",), "wave", "type"), (("time",), "soon", "time"), (("period",), 0.0, "period"),
    (("period",), -1.0, "period"), (("period",), "x", "period"), (("period",), 0.001, "period"),
    (("K",), [1.0, 2.0], "K"), (("K",), "x", "K"), (("K",), [[1.0] * 5, [1.0] * 5], "K"),
    (("K",), [1.0, 2.0, float("inf"), 4.0, 5.0], "K"), (("name",), "../x", "name"),
    (("prefilter",), {"output": "zeta"}, "prefilter.output"), (("prefilter",), 5, "prefilter"),
    (("Ac",), [[-1.0]], "Ac"), (("provenance",), 5, "provenance"), (("extra",), 1, "extra"),
]
PLANT_CASES = [
    (("parameters", "m_p"), 0.0, "parameters.m_p"), (("parameters", "n_substeps"), 2.5, "parameters.n_substeps"),
    (("parameters", "n_substeps"), 0, "parameters.n_substeps"), (("parameters", "C0"), -1.0, "parameters"),
    (("parameters", "mass"), 1.0, "parameters.mass"), (("parameters",), 5, "parameters"),
    (("model",), "segway", "model"), (("description",), [1], "description"),
    (("extends",), "missing-set", "extends"), (("parameters", "g"), "x", "parameters.g"),
]


def mutate(data, keys, value):
    data = copy.deepcopy(data)
    target = data
    for key in keys[:-1]:
        target = target.setdefault(key, {}) if isinstance(target.get(key, {}), dict) else target[key]
    if value is MISSING:
        target.pop(keys[-1], None)
    else:
        target[keys[-1]] = value
    return data


def write(tmp_path, name, data):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def assert_one_line(code, out, err, path, key):
    lines = err.strip().splitlines()
    assert code == 2, (out, err)
    assert "Traceback" not in err
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, lines
    assert str(path) in errors[0] and f"{key}" in errors[0], errors[0]


@pytest.mark.parametrize("keys, value, key", SCENARIO_CASES, ids=lambda c: repr(c)[:40])
def test_malformed_scenarios(tmp_path, capsys, keys, value, key):
    data = yaml.safe_load((SHIPPED / "paper-step.yaml").read_text())
    path = write(tmp_path, "bad.yaml", mutate(data, keys, value))
    code, out, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert_one_line(code, out, err, path, key)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.parametrize("keys, value, key", CONTROLLER_CASES, ids=lambda c: repr(c)[:40])
def test_malformed_controllers(tmp_path, capsys, keys, value, key):
    data = yaml.safe_load((SHIPPED / "controllers" / "lqr-paper.yaml").read_text())
    path = write(tmp_path, "bad-controller.yaml", mutate(data, keys, value))
    code, out, err = run_cli(capsys, "simulate", "paper-step", "--controller", str(path),
                             "-o", str(tmp_path / "out"))
    assert_one_line(code, out, err, path, key)


@pytest.mark.parametrize("keys, value, key", PLANT_CASES, ids=lambda c: repr(c)[:40])
def test_malformed_plants(tmp_path, capsys, keys, value, key):
    data = yaml.safe_load((SHIPPED / "plants" / "paper-calibrated.yaml").read_text())
    path = write(tmp_path, "bad-plant.yaml", mutate(data, keys, value))
    code, out, err = run_cli(capsys, "build-fmu", str(path))
    assert_one_line(code, out, err, path, key)


@pytest.mark.parametrize("text, expected", [
    ("name: a\nname: b\n", "line 2: duplicate key 'name' (first at line 1)"),
    ("timing: {duration: 1.0}\ntiming: {duration: 0.5}\n", "line 2: duplicate key 'timing'"),
    ("a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
     "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
     "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: [*e, *e, *e, *e, *e, *e, *e, *e, *e]\n",
     "its aliases expand to"),
    ("a: [" + "[" * 5000 + "]" * 5000 + "]\n", ""),
    ("x: " + "1" * 2_000_000 + "\n", "larger than 1 MB"),
    ("\xff\xfe bad bytes", "not UTF-8"),
    ("a: [1, 2\n", "invalid YAML"),
])
def test_hostile_yaml_is_one_line(tmp_path, capsys, text, expected):
    path = tmp_path / "hostile.yaml"
    path.write_bytes(text.encode("latin-1") if text.startswith("\xff") else text.encode())
    code, out, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "out"))
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"error: {path}: ") and expected in err


def test_output_faults_are_one_line_before_any_run(tmp_path, capsys):
    existing = tmp_path / "a-file"
    existing.write_text("keep me")
    code, _, err = run_cli(capsys, "simulate", "paper-step", "-o", str(existing))
    assert code == 2 and err == f"error: -o {existing}: exists and is not a folder\n"
    code, _, err = run_cli(capsys, "simulate", "paper-step", "-o", str(existing / "below"))
    assert code == 2 and "is not a folder" in err
    folder = tmp_path / "adir"
    folder.mkdir()
    code, _, err = run_cli(capsys, "design", "lqr", "-o", str(folder))
    assert code == 2 and err == f"error: -o {folder}: is a folder; name a file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file", "adir"]  # no .partial
    assert existing.read_text() == "keep me"


def test_an_output_folder_holds_exactly_what_its_metrics_list(tmp_path, capsys):
    out = tmp_path / "out"
    assert run_cli(capsys, "simulate", "paper-step", "-o", str(out))[0] == 0
    (out / "notes.txt").write_text("mine")  # a user's own file is never touched
    assert run_cli(capsys, "simulate", "paper-step", "--controller", "lqr-paper", "-o", str(out))[0] == 0
    import json

    listed = json.loads((out / "metrics.json").read_text())["files"]
    assert sorted(p.name for p in out.iterdir()) == sorted(listed + ["notes.txt"])
    assert "bo-paper.csv" not in listed


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_run_leaves_no_half_written_file(tmp_path, sig):
    scenario = tmp_path / "long.yaml"
    data = yaml.safe_load((SHIPPED / "paper-step.yaml").read_text())
    data["timing"]["duration"] = 600.0
    data["controllers"] = ["lqr-paper"]
    data["requirements"] = []
    scenario.write_text(yaml.safe_dump(data))
    out, temporary = tmp_path / "out", tmp_path / "tmp"
    temporary.mkdir()
    import os

    # Ctrl-C as at a terminal: a test run started in the background (`cmd &` in a script)
    # inherits SIGINT ignored, and Python then never turns it into KeyboardInterrupt
    process = subprocess.Popen([sys.executable, "-m", "furuta_cosim.cli", "simulate", str(scenario),
                                "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env={**os.environ, "TMPDIR": str(temporary)},
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(out.glob(".*.partial")):
        time.sleep(0.002)  # wait until the 300,000-line trace is being written
    assert list(out.glob(".*.partial")), "the run never started writing"
    process.send_signal(sig)
    _, err = process.communicate(timeout=60)
    assert process.returncode == (130 if sig == signal.SIGINT else 143), err
    assert "no file was left half-written" in err and "Traceback" not in err
    assert list(out.iterdir()) == []        # nothing under a final name, no .partial
    assert list(temporary.iterdir()) == []  # the extracted FMU was removed


def test_a_full_disk_while_writing_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    import errno
    from contextlib import contextmanager

    from furuta_cosim.cosim import trace

    real = trace.atomic

    @contextmanager
    def disk_fills_up(path):
        with real(path) as partial:
            yield partial
            raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(trace, "atomic", disk_fills_up)
    code, _, err = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "out"))
    assert code == 2 and err.endswith(f"error: {tmp_path / 'out' / 'lqr-paper.csv'}: No space left on device\n")
    assert list((tmp_path / "out").iterdir()) == []


def test_a_full_disk_names_the_file_it_filled(tmp_path, capsys, monkeypatch):
    """The kernel's ENOSPC carries no file name: the line once read "error: No space left on
    device" alone. The writer names its target, and the history its file."""
    import errno
    import pathlib

    real = pathlib.Path.write_text

    def full(self, *args, **kwargs):
        if self.name.endswith(".partial"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "write_text", full)
    code, _, err = run_cli(capsys, "design", "lqr", "-o", str(tmp_path / "K.yaml"))
    assert code == 2 and err == f"error: {tmp_path / 'K.yaml'}: No space left on device\n", err
    monkeypatch.setattr(pathlib.Path, "write_text", real)

    from furuta_cosim.tuning import history

    def no_room(handle, record):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(history, "_append", no_room)
    code, _, err = run_cli(capsys, "tune", "paper-spectral", "--n-calls", "3", "-o", str(tmp_path / "run"))
    assert code == 2 and err.endswith(f"error: {tmp_path / 'run' / 'history.jsonl'}: No space left on device\n"), err


def test_analyze_exits_by_every_verdict_it_prints(tmp_path, capsys):
    controller = tmp_path / "fast.yaml"
    data = yaml.safe_load((SHIPPED / "controllers" / "lqr-paper.yaml").read_text())
    # sampled at 0.5 s the LQR's loop is unstable (a period of 1e-300 s is refused now)
    data.update(time="continuous", period=0.5)
    controller.write_text(yaml.safe_dump(data))
    code, out, _ = run_cli(capsys, "analyze", str(controller))
    assert "the loop is UNSTABLE" in out and code == 1
