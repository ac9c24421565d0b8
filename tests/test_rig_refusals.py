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
