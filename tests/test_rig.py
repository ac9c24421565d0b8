"""The loop to the rig on the virtual board (and the Quanser adapter on a fake of its API): a
swing-up caught and balanced, every trip of the supervisor, every way a run ends leaving the
board at 0 V with the amplifier off, the logs every command reads."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.rig.board import BOARDS, board_for
from furuta_cosim.rig.runner import run_rig
from furuta_cosim.rig.supervisor import Limits
from furuta_cosim.rig.virtual import VirtualBoard, read_board_log

from helpers import one_line, run_cli

CLI = [sys.executable, "-m", "furuta_cosim.cli"]
FAKE = Path(__file__).parent / "fake_quanser"
QUBE = load_plant("qube-servo-3")


def _board(tmp_path, plant=QUBE, **options):
    return VirtualBoard(plant, paced=False, log=tmp_path / "run" / "board.csv", **options)


def _left_safe(folder: Path) -> None:
    """The board's own log: the last voltage it applied is 0 and the amplifier is off."""
    board = read_board_log(folder / "board.csv")
    assert board["V_applied"][-1] == 0.0 and board["enabled"][-1] == 0.0


def test_a_swing_up_is_caught_and_balanced_and_every_file_is_written(tmp_path, capsys):
    out = tmp_path / "run"
    code, stdout, err = run_cli(capsys, "rig", "run", "swingup-qube", "--board", "virtual:fast",
                                "--duration", "3", "-o", str(out), "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["status"] == "finished" and summary["samples"] == 1500
    assert 0.3 < summary["swingup"]["caught_at"] < 1.0 and summary["swingup"]["upright_at"] < 1.5
    assert summary["swingup"]["falls"] == 0 and summary["peaks"]["theta0"] < 2.0
    assert summary["peaks"]["V"] <= 10.0  # the plant file's limit
    assert sorted(summary["files"]) == ["board.csv", "controllers", "experiment.yaml", "log.csv",
                                        "summary.json", "summary.md"]
    _left_safe(out)
    # the log is an experiment file every command reads; the applied voltage is its input
    from furuta_cosim.identify.experiment import load_experiment

    experiment = load_experiment(out / "experiment.yaml")
    assert experiment.samples == 1500 and set(experiment.outputs) == {"theta0", "theta1", "i"}
    log = np.loadtxt(out / "log.csv", delimiter=",", skiprows=1)
    assert np.allclose(experiment.inputs["V"], log[:, 5])
    # the hardware saw what the runner wrote, a millisecond later (the transport delay)
    board = read_board_log(out / "board.csv")
    assert np.max(np.abs(board["V_applied"])) == pytest.approx(summary["peaks"]["V"], rel=1e-12)
    # the controller files it ran are in the folder, and run again as they ran
    code, _, err = run_cli(capsys, "rig", "run", str(out / "controllers" / "swingup-qube.yaml"),
                           "--board", "virtual:fast", "--duration", "3", "-o", str(tmp_path / "again"))
    assert code == 0, err
    assert np.array_equal(np.loadtxt(tmp_path / "again" / "log.csv", delimiter=",", skiprows=1)[:, 5], log[:, 5])


def _holding(folder: Path) -> tuple[Path, Path]:
    """A controller that holds the arm at 0.5 rad against the encoder cable (a steady 0.2 V or
    so, never near a limit), and a 20 s scenario that asks it to: what a run killed midway was
    driving."""
    controller = folder / "hold-arm.yaml"
    controller.write_text("name: hold-arm\ntype: static\ntime: discrete\nperiod: 0.002\n"
                          "K: [2.0, 0.2, 0.0, 0.0, 0.0]\nprefilter: {output: theta0, F: 2.0}\n")
    scenario = folder / "hold.yaml"
    scenario.write_text("name: hold\nplant: {model: qube-servo-3, initial: {theta1: pi}}\n"
                        "timing: {duration: 20.0, control_period: 0.002}\n"
                        "reference: {output: theta0, signal: {type: constant, value: 0.5}}\n"
                        "controllers: [hold-arm.yaml]\n")
    return controller, scenario


@pytest.mark.slow
def test_in_real_time_every_sample_is_logged_with_its_timing(tmp_path):
    """On the board's own process, in real time. On a loaded machine a sample may start late
    (and the supervisor stop the run for it): whatever happens, every sample run is logged with
    when its reading was sampled (the board's own instant: its process, held up too, may have
    last stepped before the deadline) and how long from there to its write, and the rig is left
    safe."""
    controller, scenario = _holding(tmp_path)
    summary = run_rig(controller, VirtualBoard(QUBE, log=tmp_path / "run" / "board.csv"), QUBE,
                      tmp_path / "run", scenario=scenario.with_name("hold.yaml"))
    assert summary["status"] in ("finished", "tripped"), summary["reason"]
    log = np.loadtxt(tmp_path / "run" / "log.csv", delimiter=",", skiprows=1)
    assert len(log) == summary["samples"] and np.all(log[:, 1] >= -0.2) and np.all(log[:, 2] >= 0)
    assert np.all(np.diff(log[:, 0] + log[:, 1]) >= -1e-9)   # the readings' instants never go back
    assert np.all(log[:, 1] + log[:, 2] >= 0)   # a command is written after its sample's deadline
    assert summary["timing"]["late_ms"]["max"] >= 0.0   # the machine's: when the loop woke
    if summary["status"] == "finished":
        assert 0.3 < log[-1, 6] < 0.6  # it held the arm near where it was asked to (the cable pulls back)
    _left_safe(tmp_path / "run")


@pytest.mark.parametrize("limits, limit, words", [
    ({"theta0": 0.2}, "theta0", "the arm reached"),
    ({"current": 0.05}, "current", "the motor current reached"),
])
def test_a_broken_limit_trips_the_run_and_leaves_the_rig_safe(tmp_path, limits, limit, words):
    lines = []
    summary = run_rig("swingup-qube", _board(tmp_path), QUBE, tmp_path / "run", duration=3.0,
                      limits=Limits(voltage=10.0, **limits), log=lines.append)
    assert summary["status"] == "tripped" and summary["code"] == 1 and words in summary["reason"]
    assert summary["samples"] < 1500 and any(line.startswith("stopped: " + words) for line in lines)
    log = np.loadtxt(tmp_path / "run" / "log.csv", delimiter=",", skiprows=1)
    assert len(log) == summary["samples"]  # the log is complete up to the tripping sample
    _left_safe(tmp_path / "run")


def test_a_stalled_motor_trips_the_run(tmp_path):
    blocked = tmp_path / "blocked.yaml"
    blocked.write_text("model: furuta\nextends: qube-servo-3\nparameters: {I_a: 1000.0}\n")
    plant = load_plant(blocked)
    summary = run_rig("swingup-qube", _board(tmp_path, plant), plant, tmp_path / "run", duration=3.0,
                      limits=Limits(voltage=10.0, stall_voltage=0.2, stall_seconds=0.5))
    assert summary["status"] == "tripped" and "a stalled motor" in summary["reason"]
    assert summary["seconds"] == pytest.approx(0.5, abs=0.02)
    _left_safe(tmp_path / "run")


class _LateOnce(VirtualBoard):
    """A board whose clock wakes 20 ms late at one sample (a loop preempted)."""

    def clock(self):
        inner = super().clock()

        class Late:
            calls = 0

            def now(self):
                return inner.now()

            def wait_until(self, deadline):
                Late.calls += 1
                return inner.wait_until(deadline + (0.02 if Late.calls == 100 else 0.0))

        return Late()


def test_a_missed_deadline_trips_the_run(tmp_path):
    board = _LateOnce(QUBE, paced=False, log=tmp_path / "run" / "board.csv")
    summary = run_rig("swingup-qube", board, QUBE, tmp_path / "run", duration=3.0)
    assert summary["status"] == "tripped" and "ms late" in summary["reason"] and summary["samples"] == 100
    _left_safe(tmp_path / "run")


class _Unplugged(VirtualBoard):
    """A board whose read fails at sample 300 with ``error``."""

    error: BaseException = OSError(5, "the USB device went away")

    def read(self):
        self.reads = getattr(self, "reads", 0) + 1
        if self.reads == 300:
            raise self.error
        return super().read()


@pytest.mark.parametrize("error, status", [(OSError(5, "the USB device went away"), "failed"),
                                           (KeyboardInterrupt(), "interrupted")])
def test_an_exception_or_ctrl_c_leaves_the_rig_safe_with_its_log(tmp_path, error, status):
    board = _Unplugged(QUBE, paced=False, log=tmp_path / "run" / "board.csv")
    board.error = error
    with pytest.raises(type(error)):
        run_rig("swingup-qube", board, QUBE, tmp_path / "run", duration=3.0)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == status and summary["samples"] == 299
    assert len(np.loadtxt(tmp_path / "run" / "log.csv", delimiter=",", skiprows=1)) == 299
    _left_safe(tmp_path / "run")


@pytest.mark.slow
def test_sigterm_stops_the_run_safely_with_exit_143(tmp_path):
    """As fast as the virtual board can (a real-time run on a loaded machine may trip on a late
    sample first): a 600 s run takes longer than the 4 s before the signal."""
    controller, _ = _holding(tmp_path)
    out = tmp_path / "run"
    process = subprocess.Popen(CLI + ["rig", "run", str(controller), "--duration", "600", "--board", "virtual:fast",
                                      "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    assert "stopped: SIGTERM at t = " in err and "the rig is at 0 V with the amplifier off" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "terminated" and summary["code"] == 143
    _left_safe(out)


@pytest.mark.slow
def test_a_runner_killed_with_minus_9_is_stopped_by_the_boards_watchdog(tmp_path):
    """Nothing of the runner is left to stop the motor: the board's watchdog drives it to 0 V
    within its timeout of the last reload, as a real board's does."""
    controller, scenario = _holding(tmp_path)
    # on a loaded machine a late sample may trip the run before the kill (its supervisor then
    # stops the motor itself): the kill must find the runner driving, so up to three tries
    for attempt in range(3):
        out = tmp_path / f"run-{attempt}"
        process = subprocess.Popen(CLI + ["rig", "run", str(controller), "--scenario", str(scenario), "-o",
                                          str(out), "--watchdog", "0.1"],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(4.0)
        driving = process.poll() is None and not (out / "summary.json").exists()
        process.kill()
        process.wait()
        if driving:
            break
    assert driving, "the run stopped on its own before the kill, three times"
    deadline = time.monotonic() + 60
    while not (out / "board.csv").exists() and time.monotonic() < deadline:
        time.sleep(0.1)  # the board process writes its log once it has held 0 V a while
    board = read_board_log(out / "board.csv")
    t, applied = board["t"], board["V_applied"]
    # the last reload, as the board logged it: the last change of V_written is not it (a runner
    # whose counts do not move writes the same command again, and each write reloads; read
    # that way, the motor was still driven 'after the timeout' on a loaded machine)
    last_reload = board["reloaded"][-1]
    assert last_reload > 1.0 and abs(applied[t <= last_reload + 0.1][-1]) > 0.05  # driving when killed
    after = t > last_reload + 0.1 + 0.0005  # the timeout, one plant step
    assert np.all(applied[after] == 0.0) and np.all(board["watchdog_expired"][after] == 1.0)
    assert np.any(after)
    assert not (out / "summary.json").exists()  # the runner never got to write it


def test_the_quanser_board_drives_the_hil_api_as_its_documentation_says(tmp_path, monkeypatch):
    sys.path.insert(0, str(FAKE))
    try:
        from quanser import hardware
    finally:
        sys.path.remove(str(FAKE))
    hardware.CALLS.clear()
    board = board_for("quanser:qube_servo3_usb@0", QUBE, module=hardware)
    # the calls are what is checked, not real time: the fake QUBE's time advances as the runner
    # waits (as the virtual board's does, run fast), so a loaded machine cannot trip the run late
    from furuta_cosim.rig.virtual import _SimulatedClock

    monkeypatch.setattr(hardware.HIL, "paced", False)
    monkeypatch.setattr(board, "clock", lambda: _SimulatedClock(board.card.rig))
    summary = run_rig("swingup-qube", board, QUBE, tmp_path / "run", duration=2.0)
    assert summary["status"] == "finished" and summary["swingup"]["upright_at"] < 1.5
    names = [call[0] for call in hardware.CALLS]
    # the output at 0 V and the amplifier off before anything, the watchdog told to bring them
    # there, the counts zeroed, the watchdog started before the amplifier is enabled
    assert names[:6] == ["open", "write_analog", "write_digital", "watchdog_set_analog_expiration_state",
                         "watchdog_set_digital_expiration_state", "set_encoder_counts"]
    assert hardware.CALLS[1][1:] == ([0], 1, [0.0]) and hardware.CALLS[2][1:] == ([0], 1, [0])
    assert hardware.CALLS[3][3] == [0.0] and hardware.CALLS[4][3] == [0]
    start, enable = names.index("watchdog_start"), names.index("write_digital", 3)
    assert start < enable and hardware.CALLS[enable][3] == [1]
    # the end: 0 V, the amplifier off, the watchdog stopped, the board closed
    assert names[-4:] == ["write_analog", "write_digital", "watchdog_stop", "close"]
    assert hardware.CALLS[-4][3] == [0.0] and hardware.CALLS[-3][3] == [0]


def test_a_quanser_board_that_cannot_be_opened_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(FAKE))
    from quanser import hardware

    monkeypatch.setattr(hardware.HIL, "fail_open", -1073)
    line = one_line(capsys, "rig", "run", "swingup-qube", "--board", "quanser", "--duration", "1",
                    "-o", str(tmp_path / "run"))
    assert line == "error: --board: quanser qube_servo3_usb@0: open: no such board is connected"
    assert not (tmp_path / "run").exists()  # nothing ran: no run folder


def test_without_the_sdk_the_quanser_board_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "quanser", None)  # not installed
    line = one_line(capsys, "rig", "run", "swingup-qube", "--board", "quanser", "--duration", "1",
                    "-o", str(tmp_path / "run"))
    assert "Quanser's Python HIL API is not installed" in line


@pytest.mark.parametrize("argv, expected", [
    (["--board", "arduino"], "board: expected one of"),
    (["--board", "virtual:turbo"], "'turbo': expected fast, delay=SECONDS"),
    (["--board", "virtual:fast,delay=nan"], "'delay=nan': expected fast"),
    (["--board", "quanser:qube_servo9_usb"], "expected a board type of qube_servo3_usb"),
    (["--duration", "-1"], "duration: expected seconds in (0, 3600]"),
    (["--duration", "1", "--watchdog", "0"], "watchdog: expected a number in [0.005, 10]"),
])
def test_bad_rig_options_are_one_line(tmp_path, capsys, argv, expected):
    argv = argv if "--duration" in argv else argv + ["--duration", "1"]
    line = one_line(capsys, "rig", "run", "swingup-qube", *argv, "-o", str(tmp_path / "run"))
    assert expected in line and "--" in line or expected in line, line
    assert not (tmp_path / "run").exists()


def test_every_board_is_registered_with_a_description():
    assert {"virtual", "quanser"} <= set(BOARDS)
    assert all(board.description for board in BOARDS.values())


def test_a_rig_log_is_a_regression_baseline_of_the_model(tmp_path, capsys):
    out = tmp_path / "run"
    run_rig("swingup-qube", _board(tmp_path), QUBE, out, duration=1.0)
    check = tmp_path / "check.yaml"
    check.write_text("rig_check: swingup-log\nexperiment: run/experiment.yaml\nplant: qube-servo-3\n"
                     "seconds: 0.5\ntolerances: {theta0: 0.05, theta1: 0.1}\n")
    code, out_text, err = run_cli(capsys, "regress", str(check))
    assert code == 0 and "swingup-log" in out_text and "pass" in out_text, out_text + err
    # a model that no longer predicts the rig: another pendulum inertia
    other = tmp_path / "heavier.yaml"
    other.write_text("model: furuta\nextends: qube-servo-3\nparameters: {I_p: 6.6e-5}\n")
    check.write_text(check.read_text().replace("plant: qube-servo-3", f"plant: {other}"))
    code, out_text, _ = run_cli(capsys, "regress", str(check))
    assert code == 1 and "REGRESSION swingup-log / replay: theta1 RMS: expected <= 0.1" in out_text


def test_a_rig_run_refuses_a_folder_that_holds_files(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "mine.txt").write_text("x")
    line = one_line(capsys, "rig", "run", "swingup-qube", "--board", "virtual:fast", "--duration", "1",
                    "-o", str(tmp_path / "run"))
    assert "holds files already" in line


@pytest.mark.parametrize("theta1, theta0", [(math.pi - 1.0, 0.5), (0.3, 0.0)])
def test_homing_brings_a_swinging_rig_to_rest(tmp_path, theta1, theta0):
    """From the pendulum 1 rad off hanging with the arm at 0.5 rad, or falling from 0.3 rad off
    upright: at rest (the pendulum hanging still, the arm home) within 5 s, at 2 V at most."""
    from furuta_cosim.rig.runner import home

    board = VirtualBoard(QUBE, paced=False, log=tmp_path / "home" / "board.csv",
                         overrides={"theta1_start": theta1, "theta0_start": theta0})
    summary = home(board, QUBE, tmp_path / "home", timeout=10.0)
    assert summary["status"] == "finished" and summary["seconds"] < 5.0 and summary["peaks"]["V"] <= 2.0
    log = np.loadtxt(tmp_path / "home" / "log.csv", delimiter=",", skiprows=1)
    assert abs(log[-1, 6]) < 0.05 and abs(log[-1, 7] - math.pi) < 0.05
    _left_safe(tmp_path / "home")


def test_identify_fits_a_rig_run_log(tmp_path, capsys):
    """A rig whose motor is not the model's (R_a 9.5 ohm against 7.5): its swing-up log, the
    voltage applied as the input, fitted as any log is."""
    rig = tmp_path / "rig.yaml"
    rig.write_text("model: furuta\nextends: qube-servo-3\nparameters: {R_a: 9.5}\n")
    true = load_plant(rig)
    run_rig("swingup-qube", VirtualBoard(true, paced=False), QUBE, tmp_path / "run", duration=0.5)
    spec = tmp_path / "fit.yaml"
    spec.write_text("plant: qube-servo-3\nexperiments: [run/experiment.yaml]\nfree:\n"
                    "  R_a: {bounds: [1.0, 30.0]}\n")
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--workers", "1")
    assert code == 0, err
    fitted = json.loads((tmp_path / "fit" / "fit.json").read_text())["parameters"]["R_a"]
    lo, hi = fitted["interval"]
    assert lo <= 9.5 <= hi and abs(fitted["value"] - 9.5) < 0.2, fitted


@pytest.mark.slow
def test_a_paced_run_on_a_busy_machine_logs_the_loop_as_the_board_ran_it(tmp_path):
    """The paced board's process is held up too on a busy machine (two spinning processes
    beside it here): its readings are of its last step, and it takes each write from when it
    was made. The log says both, so the replay on the same plant applies each command exactly
    where the board's own record does, reads what the board read, and follows it."""
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import closed_loop, open_session, target_for

    controller, scenario = _holding(tmp_path)
    short = tmp_path / "short.yaml"
    short.write_text(scenario.read_text().replace("duration: 20.0", "duration: 2.0"))
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        run_rig(controller, VirtualBoard(QUBE, log=tmp_path / "run" / "board.csv"), QUBE, tmp_path / "run",
                scenario=short)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    experiment = load_experiment(tmp_path / "run" / "experiment.yaml")
    board = read_board_log(tmp_path / "run" / "board.csv")
    starts = board["t"]
    ends = np.append(starts[1:], starts[-1] + 0.0005)   # each row: the state at the end of its step
    read = experiment.read_at
    q = 2 * math.pi / 2048
    # the log's time and the board's differ by a constant (the run's start on the board's
    # clock): of the shifts that put every reading at a row's end, the one where the board's
    # counts are the log's
    def rows_at(offset):
        row = np.minimum(np.searchsorted(ends, read + offset - 1e-9), len(ends) - 1)
        return row if np.all(np.abs(ends[row] - (read + offset)) < 1e-9) else None

    def apart(offset):
        row = rows_at(offset)
        counted = np.round(board["theta0"][row] / q) * q if row is not None else None
        return math.inf if row is None else int(np.sum(np.abs(counted - experiment.outputs["theta0"].values) > 1e-9))

    offset = min((e - read[0] for e in ends if 0.0 <= e - read[0] < 1.0), key=apart)
    row = rows_at(offset)
    # what the board read at each instant is what the log holds, to the count
    assert apart(offset) == 0
    # each command reaches the motor where the board applied it: its reading, its compute, the delay
    compute = experiment.loop.compute if experiment.loop.compute is not None else np.zeros(len(read))
    arrive = np.maximum.accumulate(read + compute + experiment.loop.delay) + offset
    j = np.searchsorted(arrive, starts + 1e-9, side="right") - 1
    inside = (starts > offset + 0.01) & (starts < offset + experiment.t[-1] - 0.01)
    expected = np.where(j >= 0, experiment.inputs["V"][np.maximum(j, 0)], 0.0)
    np.testing.assert_array_equal(expected[inside], board["V_applied"][inside])
    # and the replay follows the board's own state: the same commands, the arm within a hundredth
    # of a count (a held arm: no count flips apart)
    target = target_for(plant="qube-servo-3")
    with open_session(target) as session:
        simulated, volts = closed_loop(session, target, experiment)
    np.testing.assert_allclose(volts, experiment.inputs["V"], rtol=0, atol=1e-9)
    assert np.max(np.abs(simulated["theta0"] - board["theta0"][row])) < 0.01 * q
