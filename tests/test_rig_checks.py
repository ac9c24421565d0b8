"""rig check-signs: the sensors read with the amplifier off, each sign judged from a motion a
person makes (a turn of the arm, a swing of the pendulum); a check without its motion is
unsure, never a pass."""

import math

import numpy as np
import pytest

from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.rig.checks import judge

from helpers import run_cli

QUBE = load_plant("qube-servo-3")
PERIOD = 0.002


def _free_swing(seconds: float = 4.0) -> np.ndarray:
    """The QUBE model's pendulum let go 0.6 rad from hanging, the arm free, 0 V: (theta0, theta1)."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.fmu.session import PlantSession

    session = PlantSession.open(build_fmu(QUBE))
    try:
        session.reset({**dict(QUBE.parameters), "theta1_start": math.pi + 0.6})
        session.set_io(["V"], ["theta0", "theta1"])
        rows = [session.get(["theta0", "theta1"])]
        for _ in range(int(round(seconds / PERIOD)) - 1):
            rows.append(session.step([0.0], PERIOD))
    finally:
        session.close()
    return np.asarray(rows)


def _session(arm_sign: float, pendulum_sign: float) -> np.ndarray:
    """What a rig whose encoders count with these signs reads (as the plant file with signs +1
    takes them): 3 s of the arm turned by hand to +0.5 rad and back, then a free swing."""
    t = np.arange(0, 3.0, PERIOD)
    turn = 0.5 * np.clip(np.minimum(t, 3.0 - t) / 0.5, 0, 1)   # up in 0.5 s, held, back
    hand = np.column_stack([turn, np.full_like(t, math.pi), np.zeros_like(t)])
    swing = _free_swing()
    swing = np.column_stack([swing, np.zeros(len(swing))])
    rows = np.vstack([hand, swing])
    rows[:, 0] *= arm_sign
    rows[:, 1] = math.pi + pendulum_sign * (rows[:, 1] - math.pi)
    return rows


@pytest.mark.parametrize("arm, pendulum, expected", [
    (1, 1, {"arm": "ok", "pendulum": "ok"}),
    (-1, 1, {"arm": "wrong", "pendulum": "ok"}),      # the pendulum judged with the arm's sign corrected
    (1, -1, {"arm": "ok", "pendulum": "wrong"}),
    (-1, -1, {"arm": "wrong", "pendulum": "wrong"}),
])
def test_each_wrong_sign_is_named_from_the_motions(arm, pendulum, expected):
    found = judge(_session(arm, pendulum), PERIOD, QUBE, (1.0, 1.0))["checks"]
    assert {k: found[k]["verdict"] for k in ("arm", "pendulum")} == expected, found
    if arm < 0:
        assert "set sensors.arm_sign: -1 in the plant file" in found["arm"]["says"]
    if pendulum < 0:
        assert "set sensors.pendulum_sign: -1 in the plant file" in found["pendulum"]["says"]


def test_a_check_without_its_motion_is_unsure():
    still = np.column_stack([np.zeros(2000), np.full(2000, math.pi), np.random.default_rng(0).normal(0, 0.004, 2000)])
    found = judge(still, PERIOD, QUBE, (1.0, 1.0))["checks"]
    assert found["arm"]["verdict"] == "unsure" and "turn it by hand" in found["arm"]["says"]
    assert found["pendulum"]["verdict"] == "unsure" and "let it swing" in found["pendulum"]["says"]
    assert found["current"]["verdict"] == "ok"
    offset = still.copy()
    offset[:, 2] += 0.05
    assert judge(offset, PERIOD, QUBE, (1.0, 1.0))["checks"]["current"]["verdict"] == "wrong"


def test_check_signs_on_the_virtual_board_never_enables_the_amplifier(tmp_path, capsys):
    # the virtual board's pendulum held 1 rad from hanging and let go (its counts kept): the
    # swing is judged, the arm (never turned) is unsure, so the exit code is 1; the board's own
    # log shows the amplifier off and 0 V throughout
    code, out, err = run_cli(capsys, "rig", "check-signs", "--board", "virtual:fast,pendulum=1.0", "--keep-zero",
                             "--seconds", "5")
    assert code == 1, err
    assert "OK      pendulum: the swinging pendulum moves the arm as the model's does" in out
    assert "UNSURE  arm: the arm was not turned" in out
    flipped = tmp_path / "flipped.yaml"
    flipped.write_text("model: furuta\nextends: qube-servo-3\nsensors: {pendulum_sign: -1}\n")
    code, out, err = run_cli(capsys, "rig", "check-signs", "--board", "virtual:fast,pendulum=1.0", "--keep-zero",
                             "--seconds", "5", "--plant", str(flipped), "--rig", "qube-servo-3")
    assert code == 1 and "WRONG   pendulum" in out and "one of sensors.arm_sign and sensors.pendulum_sign" in out
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.checks import check_signs

    board = board_for("virtual:fast,pendulum=1.0", QUBE, log=tmp_path / "board.csv")
    check_signs(board, QUBE, seconds=2, zero=False)
    log = np.genfromtxt(tmp_path / "board.csv", delimiter=",", names=True)
    assert len(log) > 3000 and not log["enabled"].any() and not np.abs(log["V_applied"]).any()
