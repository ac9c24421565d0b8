"""design-experiment: candidate excitations within the rig's limits, ranked by the information
they add; the best written as a table `rig run --input` plays and a spec identify reads; on the
virtual board a designed experiment separates what another free swing cannot."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import one_line, run_cli, synthetic_log

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("text, expected", [
    ("time,V\n0,1\n0.002,1\n", "line 1: expected the header `t,V`"),
    ("t,V\n0,1\n0.002,nan\n", "line 3: expected finite numbers"),
    ("t,V\n0,1\n0.002,1,3\n", "line 3: expected two numbers"),
    ("t,V\n0,1\n", "fewer than two rows"),
    ("t,V\n0,1\n0.002,1\n0.005,1\n", "column t: expected times from 0 at a uniform period"),
    ("t,V\n1,1\n1.002,1\n", "column t: expected times from 0"),
    ("t,V\n0,1\n0.002,1e400\n", "line 3: expected finite numbers"),
])
def test_a_bad_input_table_is_one_line(tmp_path, capsys, text, expected):
    table = tmp_path / "input.csv"
    table.write_text(text)
    line = one_line(capsys, "rig", "run", "--input", str(table), "--board", "virtual:fast",
                    "-o", str(tmp_path / "run"))
    assert str(table) in line and expected in line, line
    assert not (tmp_path / "run").exists()


def test_an_input_table_is_played_as_written_and_a_controller_with_it_is_refused(tmp_path, capsys):
    table = tmp_path / "input.csv"
    volts = [0.0] + [1.5] * 100 + [-0.5] * 99
    table.write_text("t,V\n" + "".join(f"{0.002 * k:.3f},{v}\n" for k, v in enumerate(volts)))
    code, out, err = run_cli(capsys, "rig", "run", "--input", str(table), "--board", "virtual:fast",
                             "-o", str(tmp_path / "run"))
    assert code == 0, err
    log = np.genfromtxt(tmp_path / "run" / "log.csv", delimiter=",", names=True)
    assert len(log) == 200 and np.array_equal(log["V"], volts)
    board = np.genfromtxt(tmp_path / "run" / "board.csv", delimiter=",", names=True)
    assert set(np.round(board["V_applied"], 9)) == {0.0, 1.5, -0.5}  # what the "hardware" applied
    assert yaml.safe_load((tmp_path / "run" / "experiment.yaml").read_text())["name"] == "run"  # its folder
    line = one_line(capsys, "rig", "run", "lqr", "--input", str(table), "-o", str(tmp_path / "other"))
    assert "--input: plays its table open loop" in line


def test_a_free_swing_on_the_virtual_board_keeps_the_counts(tmp_path, capsys):
    table = tmp_path / "zero.csv"
    table.write_text("t,V\n" + "".join(f"{0.002 * k:.3f},0\n" for k in range(500)))
    code, _, err = run_cli(capsys, "rig", "run", "--input", str(table), "--board", "virtual:fast,pendulum=1.0",
                           "--keep-zero", "-o", str(tmp_path / "swing"))
    assert code == 0, err
    log = np.genfromtxt(tmp_path / "swing" / "log.csv", delimiter=",", names=True)
    assert log["theta1"][0] == pytest.approx(math.pi + 1.0, abs=2 * math.pi / 2048)
    assert np.min(log["theta1"]) < math.pi  # it swings through hanging
    line = one_line(capsys, "rig", "run", "--input", str(table), "--board", "virtual:fast,pendulum=4",
                    "-o", str(tmp_path / "x"))
    assert "pendulum=RAD (-3 to 3)" in line


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("design")
    spec = synthetic_log(folder)
    from furuta_cosim.identify.run import identify

    identify(spec, folder / "fit", profiles=False)
    return spec, folder / "fit"


def test_candidates_stay_within_the_limits_and_information_only_narrows(fitted, tmp_path, capsys):
    spec, fit = fitted
    out = tmp_path / "design"
    code, text, err = run_cli(capsys, "design-experiment", str(spec), "--fit", str(fit), "-o", str(out),
                              "--duration", "2", "--voltage", "4", "--arm", "1.5")
    assert code == 0, err
    found = json.loads((out / "design.json").read_text())
    assert len(found["candidates"]) >= 5
    widest = [c["widest"] for c in found["candidates"]]
    assert widest == sorted(widest)
    for c in found["candidates"]:
        assert c["amplitude"] <= 4.0 + 1e-9 and c["peaks"]["V"] <= 4.0 + 1e-9
        assert c["peaks"]["theta0"] <= 0.6 * 1.5 + 1e-9
        assert all(0.0 < f <= 1.0 + 1e-9 for f in c["factor"].values()), c  # data never widen an interval
    table = np.genfromtxt(out / "input.csv", delimiter=",", names=True)
    assert len(table) == 1001 and np.max(np.abs(table["V"])) <= 4.0 + 1e-9
    assert found["chosen"] == found["candidates"][0]["name"] and found["chosen"] in text
    nxt = yaml.safe_load((out / "next.yaml").read_text())
    assert nxt["experiments"][-1] == "rig/experiment.yaml" and not Path(nxt["plant"]).is_absolute()
    assert f"rig run --input {out / 'input.csv'}" in text


def test_design_experiment_refuses_what_it_cannot_use(fitted, tmp_path, capsys):
    spec, fit = fitted
    line = one_line(capsys, "design-experiment", str(spec), "--fit", str(tmp_path), "-o", str(tmp_path / "o"))
    assert "not a run folder of identify" in line
    line = one_line(capsys, "design-experiment", str(spec), "--fit", str(fit), "--focus", "M_f,K_c",
                    "-o", str(tmp_path / "o"))
    assert "focus: K_c not a free parameter of synthetic" in line
    line = one_line(capsys, "design-experiment", str(spec), "--fit", str(fit), "--duration", "1e9",
                    "-o", str(tmp_path / "o"))
    assert "duration: expected seconds from 1 to 120" in line


@pytest.mark.slow
def test_a_designed_experiment_separates_what_another_free_swing_cannot(tmp_path):
    """On the virtual board (the worn QUBE): after a free swing and a weak motor run, M_f, C0
    and I_a correlate above 0.9. Adding the designed experiment brings the largest correlation
    among them below 0.9 and at least halves their widest relative interval; another free swing
    of the same length does neither."""
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_next_experiment.py"), "--json",
                           "--out", str(tmp_path / "bench")], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout.strip().splitlines()[-1])
    first, swing = results["first two logs"], results["+ another free swing"]
    [designed] = [v for k, v in results.items() if k.startswith("+ designed")]
    assert first["largest_correlation"] > 0.9 and swing["largest_correlation"] > 0.9
    assert designed["largest_correlation"] < 0.9
    assert designed["widest_focus"]["half_width"] <= 0.5 * swing["widest_focus"]["half_width"]
    assert designed["widest_focus"]["half_width"] <= 0.5 * first["widest_focus"]["half_width"]
