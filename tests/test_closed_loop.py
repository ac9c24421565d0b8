"""A rig run's log replayed with its loop closed: the controller that ran (its file kept in the
run folder), the reference it followed, the rates' filter, the voltage limit and the board's
delay, as the experiment file's `loop:` names them; a bad `loop:` is one line."""

import json
import math

import numpy as np
import pytest
import yaml

from helpers import one_line, run_cli

QUANTUM = 2 * math.pi / 2048


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from helpers import run_cli  # noqa: F401 (the CLI as a user runs it, in-process)
    from furuta_cosim.cli import main

    out = tmp_path_factory.mktemp("loop") / "run"
    assert main(["rig", "run", "swingup-qube", "--board", "virtual:fast", "--duration", "4", "-o", str(out)]) == 0
    return out


def _replay(path):
    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.identify.run import replay

    return replay([path], target_for(plant="qube-servo-3"))


def test_a_swing_up_and_balance_log_replays_with_its_loop_closed(run):
    loop = yaml.safe_load((run / "experiment.yaml").read_text())["loop"]
    assert loop == {"controller": "controllers/swingup-qube.yaml", "reference": "r", "rate_filter": 40.0,
                    "counts": 2048, "late": "late", "compute": "compute", "mode": "mode", "voltage": 10.0,
                    "delay": 0.001}
    closed = _replay(run / "experiment.yaml")
    assert closed["experiments"]["run"]["loop"] == "closed"
    # the replay's controller catches the pendulum at the sample the log's did
    mode = closed["experiments"]["run"]["mode"]
    summary = json.loads((run / "summary.json").read_text())
    assert mode["agree"] and mode["logged"] == mode["replayed"] and mode["logged"][0][1] == 1.0
    assert mode["logged"][0][0] == pytest.approx(summary["swingup"]["caught_at"], abs=1e-9)
    rms = {o: c["rms"] for o, c in closed["experiments"]["run"]["outputs"].items()}
    # the same plant, the same controller, the same sensors: within the encoders' rounding
    assert rms["theta1"] < 3 * QUANTUM and rms["theta0"] < 5 * QUANTUM, rms
    document = yaml.safe_load((run / "experiment.yaml").read_text())
    del document["loop"]
    document["name"] = "open"
    (run / "open.yaml").write_text(yaml.safe_dump(document))
    open_loop = _replay(run / "open.yaml")["experiments"]["open"]["outputs"]
    assert open_loop["theta1"]["rms"] > 1.0  # driven by the logged voltage alone it falls


@pytest.mark.parametrize("change, expected", [
    ({"controller": "controllers/missing.yaml"}, "loop.controller: "),
    ({"reference": "nope"}, "loop.reference: 'nope' is not one of columns"),
    ({"rate_filter": -3}, "loop.rate_filter"),
    ({"counts": 2.5}, "loop.counts"),
    ({"surprise": 1}, "loop"),
])
def test_a_bad_loop_is_one_line(run, tmp_path, capsys, change, expected):
    document = yaml.safe_load((run / "experiment.yaml").read_text())
    document["loop"].update(change)
    document["data"] = str(run / "log.csv")
    if "controller" not in change:
        document["loop"]["controller"] = str(run / document["loop"]["controller"])
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document))
    line = one_line(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert str(path) in line and expected in line, line


def test_a_delay_of_whole_samples_replays_and_one_beyond_ten_is_refused(run, tmp_path, capsys):
    """A board whose command reaches the motor a sample later (0.002 s at 500 Hz) is a loop the
    replay closes (this log's board had 1 ms, so the replay says it is not reproduced); a delay
    of more than 10 samples is a typo, refused with its key."""
    document = yaml.safe_load((run / "experiment.yaml").read_text())
    document["data"] = str(run / "log.csv")
    document["loop"]["controller"] = str(run / document["loop"]["controller"])
    path = tmp_path / "late.yaml"
    document["loop"]["delay"] = 0.002
    path.write_text(yaml.safe_dump(document))
    code, out, err = run_cli(capsys, "replay", str(path), "--plant", "qube-servo-3", "--json")
    found = json.loads(out)
    # it runs with the loop closed; the board's true delay was 1 ms, and one sample too long
    # shows: the arm leaves its log by more than 20 quanta (not reproduced, exit 1)
    assert code == 1 and found["experiments"]["run"]["loop"] == "closed", (out, err)
    assert "run theta0" in found["far"] and "failure" not in found["experiments"]["run"]
    document["loop"]["delay"] = 0.03
    path.write_text(yaml.safe_dump(document))
    line = one_line(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert "loop.delay: 0.03 s is more than 10 samples of the log (0.002 s each)" in line, line


def test_a_swing_up_file_without_a_description_is_kept_readable(tmp_path):
    """rig run keeps the controller it ran; a swing-up file with no description was kept as
    `description: null`, which a replay closing its loop then refused."""
    from dataclasses import replace

    from furuta_cosim.controllers import load_controller, save_controller

    cfile = replace(load_controller("swingup-qube"), description="")
    written = save_controller(cfile, tmp_path / "kept.yaml")
    assert "description" not in yaml.safe_load(written.read_text())
    assert load_controller(written).swingup is not None


def test_a_log_whose_samples_were_read_late_replays_at_the_times_it_was_read(tmp_path):
    # the fast virtual board's clock wakes each sample up to 1.5 ms late (whole 0.5 ms steps,
    # seeded), as a busy machine does; the log's `late` column says when each sample was read.
    # Replayed at those times the swing-up is reproduced; at the nominal times it is not
    from furuta_cosim.cli import main

    out = tmp_path / "late"
    assert main(["rig", "run", "swingup-qube", "--board", "virtual:fast,late=0.0015", "--duration", "4",
                 "-o", str(out)]) == 0
    data = yaml.safe_load((out / "experiment.yaml").read_text())
    data["loop"].pop("late")
    data["name"] = "nominal"
    (out / "nominal.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    timed = _replay(out / "experiment.yaml")["experiments"]["late"]["outputs"]
    nominal = _replay(out / "nominal.yaml")["experiments"]["nominal"]["outputs"]
    assert timed["theta0"]["rms"] < 4 * QUANTUM and timed["theta1"]["rms"] < 2 * QUANTUM, timed
    assert nominal["theta0"]["rms"] > 20 * QUANTUM, nominal


def test_a_rig_log_replays_on_the_plant_it_was_recorded_on(run, capsys):
    code, out, err = run_cli(capsys, "replay", str(run / "experiment.yaml"))
    assert code == 0, err
    assert "note: replayed on qube-servo-3, the plant the rig run ran on" in err
    assert out.startswith("replay on qube-servo-3")
    code, out, err = run_cli(capsys, "replay", str(run / "experiment.yaml"), "--plant", "qube-servo-3-worn")
    assert out.startswith("replay on qube-servo-3-worn") and "note:" not in err


@pytest.mark.parametrize("values, expected", [
    ({5: "-0.5"}, "loop.late: log.csv: line 7: -0.5 s: expected seconds from -0.2 to 0.02 (10 samples)"),
    ({5: "nan"}, "log.csv: line 7, column late: not a finite number"),
    ({5: "0.5"}, "loop.late: log.csv: line 7: 0.5 s: expected seconds"),
    ({5: "0.0", 4: "0.0039"}, "loop.late: log.csv: line 7: read before the sample before it"),
])
def test_a_bad_late_column_is_one_line_naming_its_line(run, tmp_path, capsys, values, expected):
    import shutil

    folder = tmp_path / "copy"
    shutil.copytree(run, folder)
    lines = (folder / "log.csv").read_text().splitlines()
    column = lines[0].split(",").index("late")
    for row, value in values.items():
        cells = lines[row + 1].split(",")
        cells[column] = value
        lines[row + 1] = ",".join(cells)
    (folder / "log.csv").write_text("\n".join(lines) + "\n")
    line = one_line(capsys, "replay", str(folder / "experiment.yaml"))
    assert expected in line, line


def test_held_means_by_hand():
    import numpy as np

    from furuta_cosim.identify.clocks import held_means

    # 0 until 0.5, then 1 until 1.5, 2 until 2.0, then 3
    means = held_means(np.array([0.5, 1.5, 2.0]), np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 2.0]))
    assert means.tolist() == pytest.approx([0.5, 1.5, 3.0])


def test_replay_says_how_it_runs_a_log_identify_fits_in_segments(run, tmp_path, capsys):
    data = yaml.safe_load((run / "experiment.yaml").read_text())
    data["segments"] = 0.5
    data["data"] = str(run / data["data"])
    data["loop"]["controller"] = str(run / data["loop"]["controller"])
    path = tmp_path / "segmented.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code, out, err = run_cli(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert code == 0, err
    assert ("note: run: segments: 0.5 s is how identify fits it (multiple shooting, each segment from its "
            "measured state); replay runs its whole window as the log ran (its loop closed)") in err


def test_a_recorded_plant_that_is_a_path_is_refused(run, tmp_path, capsys):
    data = yaml.safe_load((run / "experiment.yaml").read_text())
    data["rig"]["plant"] = "../../elsewhere/plant.yaml"
    data["data"] = str(run / data["data"])
    data["loop"]["controller"] = str(run / data["loop"]["controller"])
    path = tmp_path / "moved.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    line = one_line(capsys, "replay", str(path))
    assert "rig.plant: '../../elsewhere/plant.yaml': expected a plant file's name" in line and "--plant" in line


def test_a_late_run_replays_each_command_when_the_board_applied_it(tmp_path):
    """Samples up to 3 ms late on the virtual board's simulated clock: a late sample's successor
    can be read at the same instant (the log's `late` makes two read times equal), which the log
    check takes; the replay switches the motor's voltage exactly where the board did (its own
    record, board.csv), and closes the loop on the same plant well within the tolerance."""
    from furuta_cosim.cli import main
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import closed_loop, open_session, target_for

    out = tmp_path / "late"
    assert main(["rig", "run", "swingup-qube", "--board", "virtual:fast,late=0.003", "--duration", "2",
                 "--seed", "3", "-o", str(out)]) == 0
    experiment = load_experiment(out / "experiment.yaml")
    read = experiment.read_at
    assert np.any(np.abs(np.diff(read)) < 1e-9) and np.all(np.diff(read) > -1e-9)
    # the command of each sample at the motor from its write plus the board's delay, the later
    # of two written at once winning: the board's own record of the voltage it applied
    arrive = np.maximum.accumulate(read + (0.0 if experiment.loop.compute is None else experiment.loop.compute) + experiment.loop.delay)
    board = np.genfromtxt(out / "board.csv", delimiter=",", names=True)
    step = float(np.diff(board["t"][:2])[0])
    # the board's row at t is the step from t, its time 2 periods before the run's first sample
    at = board["t"] - 2 * experiment.period
    inside = (at > 0.01) & (at < experiment.t[-1] - 0.01)
    j = np.searchsorted(arrive, at + 1e-9, side="right") - 1
    expected = np.where(j >= 0, experiment.inputs["V"][np.maximum(j, 0)], 0.0)
    assert step == pytest.approx(0.0005)
    np.testing.assert_array_equal(expected[inside], board["V_applied"][inside])
    target = target_for(plant="qube-servo-3")
    with open_session(target) as session:
        _, volts = closed_loop(session, target, experiment)
    # the controller sees what it saw until the swing-up's first count the replay rounds
    # otherwise: the commands agree to rounding over the first 0.3 s
    first = int(0.3 / experiment.period)
    np.testing.assert_allclose(volts[:first], experiment.inputs["V"][:first], rtol=0, atol=1e-9)


def test_a_balance_only_run_states_the_start_its_board_shows(tmp_path):
    """The virtual board lets a lifted pendulum fall for two samples before the first one: the
    experiment file states the rates and current its own record shows there (they were 0,
    3 and 6 smoothed standard deviations off), and the smoother's estimate agrees with them."""
    from furuta_cosim.cli import main
    from furuta_cosim.identify.estimate import start_estimate, with_estimate
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import target_for

    out = tmp_path / "up"
    assert main(["rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.05", "--duration", "2",
                 "-o", str(out)]) == 0
    stated = yaml.safe_load((out / "experiment.yaml").read_text())["start"]
    assert stated["theta0"] == "data" and stated["theta1"] == "data"
    board = np.genfromtxt(out / "board.csv", delimiter=",", names=True)
    # the first sample is read at 4 ms of the board's time: the row of the step that ends there
    # and the rates from the angles one step either side
    k = int(np.argmin(np.abs(board["t"] - 0.0035)))
    assert stated["dtheta1"] == pytest.approx((board["theta1"][k + 1] - board["theta1"][k - 1]) / 0.001, rel=1e-12)
    assert stated["dtheta1"] > 0.03
    target = target_for(plant="qube-servo-3")
    experiment = with_estimate(load_experiment(out / "experiment.yaml"), target)
    estimate = start_estimate(experiment, target, {})
    for name in ("dtheta0", "dtheta1"):
        value, sd = estimate[name]
        assert abs(stated[name] - value) < 3 * sd, (name, stated[name], estimate[name])


def test_a_board_without_a_record_frees_the_rates_its_counts_show_moving():
    from furuta_cosim.rig.runner import FREE_RATE, _start

    class Blind:
        def state_at(self, when):
            return None

    rows = np.zeros((3, 15))
    assert _start(Blind(), 0.0, rows)["dtheta1"] == 0.0          # at rest: 0, as it is
    rows[1, 12] = 3.0                                              # the pendulum's counts moved
    start = _start(Blind(), 0.0, rows)
    assert start["dtheta1"] == {"free": [-FREE_RATE, FREE_RATE]} and start["dtheta0"] == 0.0


def _mode_moved(run, tmp_path, samples: int = 10):
    """A copy of the run whose log's mode column is ``samples`` later."""
    import shutil

    folder = tmp_path / "moved"
    shutil.copytree(run, folder)
    lines = (folder / "log.csv").read_text().splitlines()
    k = lines[0].split(",").index("mode")
    rows = [line.split(",") for line in lines[1:]]
    modes = [row[k] for row in rows]
    for row, value in zip(rows, ["0.0"] * samples + modes[:-samples]):
        row[k] = value
    (folder / "log.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    return folder


def test_a_mode_the_replay_does_not_switch_where_the_log_did_is_named(run, tmp_path):
    # the log's mode column moved 10 samples later: the replay's catch is where it was, and
    # the comparison says from when they part
    folder = _mode_moved(run, tmp_path)
    found = _replay(folder / "experiment.yaml")["experiments"]["run"]["mode"]
    assert not found["agree"]
    assert found["logged"][0][0] == pytest.approx(found["replayed"][0][0] + 10 * 0.002, abs=1e-9)
    assert found["first_apart"] == pytest.approx(found["replayed"][0][0], abs=1e-9)


def test_the_replay_runs_in_the_logged_mode_and_keeps_its_own_rule_beside_it(run, tmp_path):
    # the log's catch moved 10 samples later: the replay's controller swings up until the log
    # says it caught (its switches are the log's, to the sample), and its own rule, which
    # catches where the run did, is kept as what it would have done
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import closed_loop, open_session, target_for

    folder = _mode_moved(run, tmp_path)
    target = target_for(plant="qube-servo-3")
    logged = load_experiment(folder / "experiment.yaml")
    original = load_experiment(run / "experiment.yaml")
    caught = int(np.argmax(np.asarray(original.loop.mode) == 1.0))
    with open_session(target) as session:
        record: dict = {}
        _, volts = closed_loop(session, target, logged, record=record)
        _, before = closed_loop(session, target, original)
    assert record["switches"][0] == (caught + 10, 1.0)
    assert record["own"][:10] == [(caught + j, 1.0) for j in range(10)]
    # until the caught sample the same commands; from it the moved replay is still swinging up
    np.testing.assert_allclose(volts[:caught], before[:caught], rtol=0, atol=1e-12)
    assert np.max(np.abs(volts[caught:caught + 10] - before[caught:caught + 10])) > 0.1
