"""rig run refuses what simulate refuses, before a board is opened; seeds are checked before
anything starts (they were tracebacks)."""

import yaml

from helpers import ROOT, run_cli

QUBE = ROOT / "scenarios" / "plants" / "qube-servo-3.yaml"


def _slow_lqr(folder):
    data = yaml.safe_load((ROOT / "scenarios" / "controllers" / "lqr-qube.yaml").read_text())
    data.update(name="slow", period=0.01)
    data.pop("provenance", None)
    path = folder / "slow.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_controller_slower_than_the_plant_integrates_is_refused_before_the_board(tmp_path, capsys):
    code, out, err = run_cli(capsys, "rig", "run", str(_slow_lqr(tmp_path)), "--board", "virtual:fast",
                             "--duration", "1", "-o", str(tmp_path / "run"))
    assert code == 2 and "limits.control_period.max: 0.004 s" in err and "every 0.01 s" in err, err
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())


def test_encoder_counts_are_a_whole_number(tmp_path, capsys):
    plant = tmp_path / "plant.yaml"
    plant.write_text("model: furuta\nextends: qube-servo-3\nsensors: {encoder_counts: 3.5}\n")
    code, out, err = run_cli(capsys, "rig", "run", "lqr-qube", "--plant", str(plant), "--board", "virtual:fast",
                             "--duration", "1", "-o", str(tmp_path / "run"))
    assert code == 2 and "sensors.encoder_counts" in err and "Traceback" not in err, err


def test_a_negative_seed_is_refused_before_anything_starts(tmp_path, capsys):
    for argv in (["rig", "run", "lqr-qube", "--board", "virtual:fast", "-o", str(tmp_path / "a")],
                 ["rig", "home", "--board", "virtual:fast", "-o", str(tmp_path / "b")],
                 ["tune", "effort-qube", "--board", "virtual:fast", "-o", str(tmp_path / "c")]):
        code, out, err = run_cli(capsys, *argv, "--seed", "-1")
        assert code == 2 and "--seed: expected a whole number from 0 to 2^32 - 1" in err, (argv, err)
        assert len(err.strip().splitlines()) == 1
        assert not (tmp_path / argv[-1]).exists()


def _scenario(folder, **changes):
    data = yaml.safe_load((ROOT / "scenarios" / "qube-step.yaml").read_text())
    data.update(changes)
    path = folder / "scenario.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _one_line(code, err, *words):
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert all(w in err for w in words), err


# the unclear cases: each one line naming the file or flag, the key and what was expected
def test_rig_home_with_no_time_names_its_own_flag(tmp_path, capsys):
    code, out, err = run_cli(capsys, "rig", "home", "--board", "virtual:fast", "--timeout", "0",
                             "-o", str(tmp_path / "home"))
    _one_line(code, err, "--timeout: expected seconds in (0, 3600], got 0")
    assert not (tmp_path / "home").exists()


def test_an_external_evaluator_that_is_a_file_is_named(tmp_path, capsys):
    (tmp_path / "exchange").write_text("not a folder\n")
    code, out, err = run_cli(capsys, "tune", "effort-qube", "--evaluator", "external", str(tmp_path / "exchange"),
                             "-o", str(tmp_path / "run"))
    _one_line(code, err, "--evaluator external: ", "exchange: expected the folder", "got a file")


def test_a_requirement_no_value_can_meet_is_refused_before_it_runs(tmp_path, capsys):
    scenario = _scenario(tmp_path, requirements=[{"metric": "theta0.max_abs", "min": 1.0, "max": 0.1}])
    code, out, err = run_cli(capsys, "simulate", str(scenario), "-o", str(tmp_path / "out"))
    _one_line(code, err, "scenario.yaml: requirements[0]: min 1 is above max 0.1")
    assert not (tmp_path / "out").exists()


def test_a_requirement_on_a_controller_state_the_controller_lacks_is_refused(tmp_path, capsys):
    scenario = _scenario(tmp_path, requirements=[{"metric": "xc3.max_abs", "max": 1.0}])
    code, out, err = run_cli(capsys, "simulate", str(scenario), "-o", str(tmp_path / "out"))
    _one_line(code, err, "requirements[0].metric: lqr-qube has no controller states (a static gain): no xc3")


def test_a_plant_file_named_as_the_loop_s_controller_names_the_experiment_and_key(tmp_path, capsys):
    from furuta_cosim.identify.synthetic import balancing_log

    experiment = balancing_log(tmp_path / "log", seed=0, duration=0.5)
    text = experiment.read_text()
    controller = yaml.safe_load(text)["loop"]["controller"]
    experiment.write_text(text.replace(f"controller: {controller}", f"controller: {QUBE}"))
    code, out, err = run_cli(capsys, "replay", str(experiment), "--plant", "qube-servo-3")
    _one_line(code, err, "experiment.yaml: loop.controller: ", "qube-servo-3.yaml: not a controller file")


def test_a_balance_controller_on_a_hanging_pendulum_is_refused_before_anything_moves(tmp_path, capsys):
    # lqr-qube balances near upright; the virtual board starts hanging, as a rig at rest does:
    # refused in one line, the amplifier never enabled, no run folder (not even the board's log)
    code, out, err = run_cli(capsys, "rig", "run", "lqr-qube", "--board", "virtual:fast", "--duration", "1",
                             "-o", str(tmp_path / "run"))
    assert code == 2, err
    assert "the pendulum reads 3.14 rad from upright" in err and "within 0.3 rad" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


def test_a_balance_only_run_starts_with_the_pendulum_held_upright(tmp_path, capsys):
    # the virtual board can start near upright (held there, its encoder zeroed hanging): the
    # balance controller takes over at once and keeps it up; a catch narrower than the start refuses
    code, out, err = run_cli(capsys, "rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.05",
                             "--duration", "2", "-o", str(tmp_path / "run"))
    assert code == 0, err
    import numpy as np

    from furuta_cosim.rig.runner import COLUMNS
    from furuta_cosim.swingup import wrap

    log = np.loadtxt(tmp_path / "run" / "log.csv", delimiter=",", skiprows=1)
    pendulum = np.array([wrap(v) for v in log[:, COLUMNS.index("theta1")]])
    assert abs(pendulum[0] - 0.05) < 0.01 and np.max(np.abs(pendulum)) < 0.1
    code, out, err = run_cli(capsys, "rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.2",
                             "--catch", "0.1", "--duration", "1", "-o", str(tmp_path / "narrow"))
    assert code == 2 and "reads 0.199 rad from upright" in err and "within 0.1 rad" in err, err
    code, out, err = run_cli(capsys, "rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.7",
                             "--duration", "1", "-o", str(tmp_path / "far"))
    assert code == 2 and "upright=RAD (-0.5 to 0.5)" in err, err
