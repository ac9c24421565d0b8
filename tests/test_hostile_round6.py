"""The sixth hostile round's corpus: each case on the newest surfaces is one clear line (exit 2)
or the documented verdict, never a traceback, a hang or a silent wrong answer."""

from __future__ import annotations

import os

import pytest

from furuta_cosim.errors import ConfigError

from helpers import one_line, run_cli


def _as_from_a_terminal() -> None:
    """Ctrl-C as a terminal's command gets it, though the suite runs in the background (which
    passes SIGINT on ignored: tools/bench_signals.py as_from_a_terminal)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


# -- a plant file's parent (extends:) is named from the file that extends it ----------------------

def _child(tmp_path, parent: str) -> str:
    path = tmp_path / "child.yaml"
    path.write_text(f"model: furuta\nextends: {parent}\ndescription: extends a parent\n")
    return str(path)


@pytest.mark.parametrize("parent,expected", [
    ("nosuch.yaml", "nosuch.yaml: file not found"),
    ("folder.yaml", "folder.yaml: a folder, not a file"),
    ("notplant.yaml", "notplant.yaml: model: missing"),
    ("la.yaml", "'la.yaml': a loop of symbolic links"),
    ('"a\\0b.yaml"', "b.yaml': a loop of symbolic links or not a usable file name"),
])
def test_a_parent_that_is_not_a_plant_is_named_from_its_child(tmp_path, capsys, parent, expected):
    (tmp_path / "folder.yaml").mkdir()
    (tmp_path / "notplant.yaml").write_text("description: no model\n")
    os.symlink(tmp_path / "lb.yaml", tmp_path / "la.yaml")
    os.symlink(tmp_path / "la.yaml", tmp_path / "lb.yaml")
    line = one_line(capsys, "simulate", "paper-step", "--plant", _child(tmp_path, parent), "-o", str(tmp_path / "o"))
    assert line.startswith(f"error: {tmp_path / 'child.yaml'}: extends: ") and line.endswith(expected) or \
        expected in line, line
    assert line.startswith(f"error: {tmp_path / 'child.yaml'}: extends: "), line


# -- the rig's commands on a plant that is not a Furuta pendulum ----------------------------------

@pytest.mark.parametrize("argv", [["rig", "home", "--board", "virtual:fast", "--plant", "toy"],
                                  ["rig", "check-signs", "--board", "virtual:fast", "--plant", "toy"],
                                  ["rig", "run", "lqr-qube", "--board", "virtual:fast", "--plant", "toy",
                                   "--duration", "1"]])
def test_a_rig_command_on_another_models_plant_is_one_line(tmp_path, capsys, argv):
    line = one_line(capsys, *argv, *(["-o", str(tmp_path / "o")] if argv[1] != "check-signs" else []))
    assert "--plant toy: a linear plant; the boards here run a Furuta pendulum" in line
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_rig_homes_timeout_names_itself(tmp_path, capsys):
    line = one_line(capsys, "rig", "home", "--board", "virtual:fast", "--timeout", "0.001", "-o", str(tmp_path / "o"))
    assert "--timeout: 0.001 s is shorter than one sample of the homing loop" in line


# -- export-ssp of a controller of another model, or of a loop that is unstable as exported -------

def test_export_ssp_of_another_models_controller_is_one_line(tmp_path, capsys):
    line = one_line(capsys, "export-ssp", "qube-step", "--controller", "toy-classical", "-o", str(tmp_path / "t.ssp"))
    assert "controller: " in line and "K: expected 5 values per row" in line
    assert not (tmp_path / "t.ssp").exists()


def test_export_ssp_says_when_the_loop_it_writes_is_unstable(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "export-ssp", "paper-step", "--controller", "lqr-qube", "-o", str(tmp_path / "u.ssp"))
    assert code == 0 and "WARNING controller lqr-qube on plant furuta: the loop this archive holds is UNSTABLE" in out
    assert "largest eigenvalue 1.004" in out
    code, out, _ = run_cli(capsys, "export-ssp", "paper-step", "--controller", "lqr-paper", "-o", str(tmp_path / "s.ssp"))
    assert code == 0 and "WARNING" not in out


# -- an external rig's result that is not UTF-8 is the rig side's, in one line --------------------

def test_a_result_that_is_not_utf8_is_refused_naming_the_file(tmp_path):
    from furuta_cosim.tuning.trials import read_result

    (tmp_path / "request.json").write_text("{}\n")
    (tmp_path / "result.json").write_bytes(b'{"status": "ok", "reason": "\xff\xfe"}\n')
    with pytest.raises(ConfigError, match=r"result.json: not UTF-8 text \(byte 28\): the rig side wrote it so"):
        read_result(tmp_path, [], ["u.rms"])


# -- a closed-loop log's law and resampling: the cause named, not the plant's step size ---------

@pytest.fixture(scope="module")
def pd(tmp_path_factory):
    from furuta_cosim.identify.foreign import pd_log

    folder = tmp_path_factory.mktemp("pd")
    return pd_log(folder, seed=0)


def _variant(pd, tmp_path, text: str):
    path = pd.parent / f"{tmp_path.name}.yaml"
    path.write_text(text)
    return path


def test_a_law_whose_filter_is_unstable_at_the_period_is_named(pd, tmp_path):
    from furuta_cosim.identify.experiment import load_experiment

    text = pd.read_text().replace("cutoff: 50.0\n      method: backward", "cutoff: 1500.0\n      method: forward")
    with pytest.raises(ConfigError) as refused:
        load_experiment(_variant(pd, tmp_path, text))
    line = str(refused.value)
    assert "loop.law.derivative: the law's filter is unstable at the log's period" in line
    assert "w T = 3; forward Euler is stable for w T < 2 only" in line and "n_substeps" not in line


@pytest.mark.parametrize("resample,key", [("{period: 1.0e-9, gap: 1}", "resample.period: 1e-09 s over the window's"),
                                          ("{period: 1.0e-9}", "resample.period: 1e-09 s over the window's"),
                                          ("{period: 0.0001}", "resample: pd.csv: line 3: 0.002 s without")])
def test_a_resample_period_typed_wrong_is_named_and_allocates_nothing(pd, tmp_path, resample, key):
    from furuta_cosim.identify.experiment import load_experiment

    text = pd.read_text()
    text = text[:text.index("loop:")] + f"resample: {resample}\n"
    with pytest.raises(ConfigError) as refused:
        load_experiment(_variant(pd, tmp_path, text))
    assert key in str(refused.value) and "resample.gap" not in str(refused.value)


def test_analyze_plot_of_a_loop_unstable_when_sampled_says_so(tmp_path, capsys):
    from helpers import ROOT

    text = (ROOT / "scenarios" / "controllers" / "lqr-paper.yaml").read_text()
    text = text.replace("time: discrete\nperiod: 0.002", "time: continuous\nperiod: 0.2").replace("name: lqr-paper",
                                                                                                   "name: slow")
    (tmp_path / "slow.yaml").write_text(text)
    code, _, err = run_cli(capsys, "analyze", str(tmp_path / "slow.yaml"), "--plot", str(tmp_path / "plots"))
    assert code != 0
    assert "no plots: the loop that runs (sampled at 0.2) is unstable" in err


# -- a rig's result that cannot be true is not learned from -------------------------------------

GOOD = {"u.rms": 0.5, "u.peak_abs": 1.0, "error.IAE": 0.4, "theta1.max_abs": 0.01}


@pytest.fixture(scope="module")
def qube_step():
    from furuta_cosim.cosim import prepare
    from furuta_cosim.scenario import load_scenario

    return prepare(load_scenario("qube-step"))


@pytest.mark.parametrize("change,expected", [
    ({"u.rms": 1e308}, "u.rms: 1e+308 V is above the amplifier's limit (10 V)"),
    ({"u.rms": 5e-324}, "u.rms: 4.941e-324 V: a trial that held the pendulum needs a command"),
    ({"u.rms": 1e-300}, "u.rms: 1e-300 V: a trial that held the pendulum needs a command"),
    ({"error.IAE": 1e308}, "error.IAE: 1e+308 is more than the arm's range and the reference allow"),
    ({"u.peak_abs": 0.2}, "u.peak_abs: 0.2 is below u.rms (0.5): no signal's peak is below its RMS"),
    ({"theta1.max_abs": 100.0}, "theta1.max_abs: 100 rad: the pendulum's angle, wrapped, is within pi"),
    ({"theta0.max_abs": 3.0}, "theta0.max_abs: 3 rad is beyond the supervisor's 2 rad"),
    ({k: 0.0 for k in GOOD}, "every metric is 0"),
])
def test_an_absurd_rig_result_is_named_field_by_field(qube_step, change, expected):
    from furuta_cosim.tuning.plausible import implausible

    assert implausible(GOOD, qube_step) == []
    problems = implausible({**GOOD, **change}, qube_step)
    assert problems and expected in problems[0], problems


def test_a_trial_the_supervisor_tripped_may_pass_the_arms_limit_but_is_never_feasible(tmp_path, qube_step):
    from furuta_cosim.tuning.plausible import implausible

    assert implausible({**GOOD, "theta0.max_abs": 2.01}, qube_step, finished=False) == []


def test_the_tuning_stops_on_an_absurd_result_naming_the_file_and_field(tmp_path, qube_step):
    from furuta_cosim.errors import RunStopped
    from furuta_cosim.tuning.rig import _believable
    from furuta_cosim.tuning.trials import TrialScenario

    scenarios = [TrialScenario("qube-step", qube_step, None, None)]
    with pytest.raises(RunStopped) as stopped:
        _believable(tmp_path, {"qube-step": {**GOOD, "u.rms": 1e308}}, scenarios, {}, {"qube-step"})
    assert f"{tmp_path / 'result.json'}: scenarios.qube-step.metrics: u.rms: 1e+308 V" in str(stopped.value)
    assert "is not learned from" in str(stopped.value)


@pytest.mark.parametrize("field", ["metrics", "seconds"])
def test_a_four_hundred_digit_number_is_refused_in_one_line(tmp_path, field):
    from test_rig_tuning import METRICS, _external_request
    from furuta_cosim.tuning.trials import read_result

    request, scenarios = _external_request(tmp_path)
    huge = "9" * 400
    metrics = ", ".join(f'"{k}": {huge if k == "u.rms" and field == "metrics" else v}' for k, v in METRICS.items())
    seconds = huge if field == "seconds" else "1"
    (request / "result.json").write_text('{"status": "finished", "seconds": ' + seconds +
                                         ', "scenarios": {"qube-step": {"metrics": {' + metrics + '}}}}')
    with pytest.raises(ConfigError) as refused:
        read_result(request, scenarios, sorted(METRICS))
    assert ("u.rms: expected a finite number" if field == "metrics" else "seconds: expected a finite number") \
        in str(refused.value)


def test_the_rig_sides_reason_reaches_the_terminal_escaped(tmp_path):
    from test_rig_tuning import METRICS, _external_request
    from furuta_cosim.tuning.trials import read_result

    request, scenarios = _external_request(tmp_path)
    (request / "result.json").write_text('{"status": "tripped", "reason": "\\u001b[2J\\u001b]0;owned\\u0007 fell", '
                                         '"scenarios": {"qube-step": {"metrics": ' + __import__("json").dumps(METRICS)
                                         + '}}}')
    found = read_result(request, scenarios, sorted(METRICS))
    assert "\x1b" not in found["reason"] and "\x07" not in found["reason"]
    assert found["reason"] == "\\x1b[2J\\x1b]0;owned\\x07 fell"


def test_a_tripped_trial_with_metrics_is_not_feasible(tmp_path):
    from test_rig_tuning import _spec, _trials
    from furuta_cosim.tuning.rig import Fidelity, RigEvaluator
    from furuta_cosim.tuning.spec import load_spec
    from furuta_cosim.tuning.trials import TrialResult

    spec = load_spec(_spec(tmp_path))
    evaluator = RigEvaluator(spec, _trials(), tmp_path / "run", Fidelity(spec, []))
    labels = [label for label, _, _ in evaluator.runs()]
    result = TrialResult("tripped", "the arm reached its limit", {}, {}, {}, 1.0)
    outcome = evaluator._judged(result, {label: dict(GOOD) for label in labels}, {}, {}, [])
    assert not outcome.feasible and outcome.constraints["trial"] == "tripped: the arm reached its limit"


# -- the paced virual board stands in for hardware: a group's signal leaves it safe, recorded ---

@pytest.mark.slow
@pytest.mark.parametrize("sent", ["SIGINT", "SIGINT burst", "SIGTERM"])
def test_a_group_signal_leaves_the_paced_board_at_0_v_with_its_record(tmp_path, sent):
    import signal
    import subprocess
    import sys
    import time

    import numpy as np

    from furuta_cosim.rig.virtual import read_board_log

    out = tmp_path / "run"
    process = subprocess.Popen([sys.executable, "-m", "furuta_cosim", "rig", "run", "swingup-qube", "--board", "virtual",
                                "--duration", "30", "-o", str(out)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=_as_from_a_terminal)
    lines = []
    for line in process.stderr:   # its progress: the board is running and the motor driven
        lines.append(line)
        if line.strip().startswith("rig:"):
            break
    assert process.poll() is None, "".join(lines)
    number = signal.SIGTERM if sent == "SIGTERM" else signal.SIGINT
    for _ in range(5 if sent == "SIGINT burst" else 1):
        os.killpg(process.pid, number)
        time.sleep(0.02)
    started = time.monotonic()
    _, err = process.communicate(timeout=60)
    err = "".join(lines) + err
    assert time.monotonic() - started < 15
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "ran its 30 s" not in err      # it was stopped
    board = read_board_log(out / "board.csv")
    assert board["enabled"][-1] == 0.0 and board["V_applied"][-1] == 0.0
    assert len(board["t"]) > 100 and np.all(np.isfinite(board["theta1"]))


# -- a group's signals during a fit's and a tuning's worker processes ------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("part", ["identify", "tune"])
def test_a_group_signal_during_workers_ends_the_run_cleanly_and_resume_gives_the_whole(tmp_path, part):
    """The group's burst of Ctrl-C and a SIGTERM at half the run (tools/bench_signals.py does
    it 20 times each): the run ends within 10 s, no traceback, and what it says to do next
    (--resume, or the same command) gives the uninterrupted result."""
    import signal
    import sys

    from helpers import ROOT

    sys.path.insert(0, str(ROOT / "tools"))
    import bench_signals

    command, result = bench_signals._commands(part, tmp_path)
    import subprocess
    import time

    started = time.monotonic()
    assert subprocess.run(command(tmp_path / "whole"), capture_output=True).returncode == 0
    length = time.monotonic() - started
    whole = result(tmp_path / "whole")
    for number, burst in ((signal.SIGINT, 5), (signal.SIGTERM, 1)):
        out = tmp_path / f"cut-{number}"
        found = bench_signals._one(command, out, length / 2, number, burst)
        assert found["signalled"] and found["code"] in (130, 143), found
        assert found["seconds"] < bench_signals.LIMIT and not found["traceback"], found
        # a pool ended on the way out is said, in bounded time (none if the signal fell outside it)
        for line in found["pools"]:
            assert line.startswith("ended the 2 worker processes in ") and "killed after" not in line, found
        again = subprocess.run(command(out) + (["--resume"] if "--resume" in found["last"] else []),
                               capture_output=True, text=True)
        assert again.returncode == 0, again.stderr
        assert result(out) == whole


def _nap(seconds: float) -> float:
    import time

    time.sleep(seconds)
    return seconds


@pytest.mark.parametrize("stuck", [False, True])
def test_a_pool_ended_by_an_interrupt_is_said_with_its_workers_and_time(stuck):
    """The main process ends its pool within the grace and says so: how many workers, how long,
    how many it had to kill (a worker stuck in its task past the grace is killed)."""
    import time

    from furuta_cosim.cosim.worker import start_pool, stop_pool, stopped_pools

    stopped_pools()
    pool = start_pool(2)
    futures = [pool.submit(_nap, 30.0 if stuck else 0.05) for _ in range(6)]
    futures[0].result(timeout=60) if not stuck else time.sleep(1.0)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        try:
            raise KeyboardInterrupt
        finally:
            killed = stop_pool(pool, grace=1.0)
    assert time.monotonic() - started < 5.0
    [line] = stopped_pools()
    assert line.startswith("ended the 2 worker processes in "), line
    assert killed == (2 if stuck else 0)
    assert ("2 killed after the" in line) == stuck, line
    assert stopped_pools() == []               # said once


def test_a_pool_ended_normally_is_not_said():
    from furuta_cosim.cosim.worker import start_pool, stop_pool, stopped_pools

    stopped_pools()
    pool = start_pool(2)
    assert pool.submit(_nap, 0.0).result(timeout=60) == 0.0
    assert stop_pool(pool) == 0
    assert stopped_pools() == []


def test_the_command_says_what_it_ended_before_how_to_go_on(monkeypatch, capsys):
    from furuta_cosim import cli
    from furuta_cosim.cosim.worker import start_pool, stop_pool

    def fitting(_args):
        pool = start_pool(2)
        pool.submit(_nap, 0.0).result(timeout=60)
        try:
            raise KeyboardInterrupt
        finally:
            stop_pool(pool)

    monkeypatch.setattr(cli, "cmd_simulate", fitting)
    assert cli.main(["simulate", "paper-step"]) == 130
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-2].startswith("ended the 2 worker processes in ") and lines[-1].startswith("interrupted:"), lines


# -- an SSP's parameter value its FMU refuses is named by the archive and its entry ---------------

@pytest.mark.parametrize("argv", [["simulate", "paper-step", "--plant"], ["simulate"]])
def test_a_set_value_the_fmu_refuses_names_the_archive_entry(tmp_path, capsys, argv):
    from furuta_cosim.ssp import export_ssp
    from test_ssp import _replace, _rewritten

    export_ssp("paper-step", "lqr-paper", tmp_path / "loop.ssp")
    bad = _rewritten(tmp_path / "loop.ssp", tmp_path / "bad.ssp",
                     _replace("resources/paper-calibrated.ssv", b'value="8.0" unit="Ohm"', b'value="-8.0" unit="Ohm"'))
    line = one_line(capsys, *argv, str(bad), "-o", str(tmp_path / "o"))
    assert f"{bad} (resources/paper-calibrated.ssv): parameter set 'paper-calibrated': the FMU of component plant " \
           "refuses it" in line and "R_a = -8 must be > 0" in line
    assert ".cache" not in line and "furuta-cosim/ssp/" not in line


def test_a_ctrl_c_during_an_import_is_an_interrupt_not_a_traceback(monkeypatch, capsys):
    """Python wraps a KeyboardInterrupt raised while a class is made (a dataclass's field, in an
    import the command does lazily) as "RuntimeError: Error calling __set_name__": once in 20
    runs of tools/bench_signals.py, a Ctrl-C burst ended identify with that traceback."""
    from furuta_cosim import cli

    def importing(_args):
        class Field:
            def __set_name__(self, owner, name):
                raise KeyboardInterrupt()

        class Prepared:   # noqa: F841 - the class being made when the interrupt lands
            key = Field()
        return 0

    monkeypatch.setattr(cli, "cmd_list", importing)
    code, _, err = run_cli(capsys, "list")
    assert code == 130 and err.strip() == "interrupted: no file was left half-written"


@pytest.mark.slow
def test_a_rig_tuning_stopped_in_its_simulated_prior_resumes_to_the_whole(tmp_path):
    """A Ctrl-C while the spec is tuned in simulation, before the first trial: the command says
    --resume continues it, and it does, to the uninterrupted run's trials."""
    import json
    import signal
    import subprocess
    import sys

    from test_rig_tuning import _spec

    spec = str(_spec(tmp_path, trials=3, simulations=60))
    command = [sys.executable, "-m", "furuta_cosim", "tune", spec, "--board", "virtual:fast"]
    assert subprocess.run(command + ["-o", str(tmp_path / "whole")], capture_output=True).returncode == 0
    process = subprocess.Popen(command + ["-o", str(tmp_path / "cut")], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=_as_from_a_terminal)
    seen = []
    for line in process.stderr:
        seen.append(line)
        if line.startswith("start:"):   # the simulated fidelity's design is under way
            break
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130 and "--resume' continues it" in err, "".join(seen) + err
    assert not (tmp_path / "cut" / "history.jsonl").exists()
    again = subprocess.run(command + ["-o", str(tmp_path / "cut"), "--resume"], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr

    def trials(folder):
        return [(r["index"], r["x"], r["objective"], r["feasible"])
                for r in map(json.loads, (folder / "history.jsonl").read_text().splitlines())]
    assert trials(tmp_path / "cut") == trials(tmp_path / "whole") and len(trials(tmp_path / "whole")) == 3


def test_a_command_column_scaled_wrong_is_named_not_blamed_on_the_step_size(tmp_path, capsys):
    from helpers import synthetic_log

    spec = synthetic_log(tmp_path)
    experiment = tmp_path / "prbs.yaml"
    experiment.write_text(experiment.read_text().replace("inputs: {V: {column: V, unit: V}}",
                                                         "inputs: {V: {column: V, scale: 1000}}"))
    code, _, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"))
    line = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err
    assert "prbs.yaml: inputs.V: reads 3000 V at t = 0 s, 300 times the amplifier's limit (10 V" in line
    assert "n_substeps" not in line


def test_an_interrupt_before_anything_was_recorded_does_not_offer_resume(tmp_path):
    """Found by tools/bench_signals.py (1 run in 20): a Ctrl-C before a tuning's first history
    line said --resume continues it, and --resume then refused the folder."""
    from types import SimpleNamespace

    from furuta_cosim.cli import _resume_hint

    args = SimpleNamespace(resume_with=f"furuta-cosim tune effort -o {tmp_path} --resume",
                           resume_from=tmp_path / "history.jsonl")
    assert _resume_hint(args) == f"; nothing was recorded yet: 'furuta-cosim tune effort -o {tmp_path}' starts it again"
    (tmp_path / "history.jsonl").write_text("")
    assert _resume_hint(args) == f"; 'furuta-cosim tune effort -o {tmp_path} --resume' continues it"


def test_a_nan_in_the_laws_own_output_column_is_named_not_skipped(pd, tmp_path):
    """One empty cell in the law's own output column inside the window (the command the plant
    took logged in another column) once skipped the law check: a law with the pendulum's sign
    wrong then reached the replay. It is refused at load, naming the column and the line."""
    from furuta_cosim.identify.experiment import load_experiment

    lines = (pd.parent / "pd.csv").read_text().splitlines()
    rows = [lines[0] + ",u_law"] + [line + "," + ("" if k == 499 else line.split(",")[6])
                                     for k, line in enumerate(lines[1:])]
    (pd.parent / f"{tmp_path.name}.csv").write_text("\n".join(rows) + "\n")
    text = (pd.read_text().replace("data: pd.csv", f"data: {tmp_path.name}.csv").replace("- u\n", "- u\n- u_law\n")
            .replace("    output: u\n", "    output: u_law\n").replace("kp: -34.0", "kp: 34.0"))
    with pytest.raises(ConfigError) as refused:
        load_experiment(_variant(pd, tmp_path, text))
    assert "loop.law.output" in str(refused.value) and "line 501: u_law holds 'nan' inside the window" \
        in str(refused.value)
