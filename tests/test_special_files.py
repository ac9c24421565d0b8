"""A path a user names that is not a plain file (a FIFO, a device, a folder) is refused in one
line before anything opens it: a FIFO would hold open() for ever, a device never ends."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.inputs import read_input, regular

from helpers import ROOT

TIMEOUT = 60   # s: a refusal takes well under a second; a hang is stopped here and fails


def _cli(tmp_path, *argv) -> tuple[int, str, float]:
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "furuta_cosim", *argv], cwd=tmp_path, capture_output=True,
                          text=True, timeout=TIMEOUT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return done.returncode, done.stderr, time.perf_counter() - started


@pytest.fixture
def fifo(tmp_path):
    def make(name: str):
        path = tmp_path / name
        os.mkfifo(path)
        return path
    return make


def _plant_extending(tmp_path, parent) -> str:
    path = tmp_path / "child.yaml"
    path.write_text(f"model: furuta\nextends: {parent}\ndescription: a plant whose parent is a FIFO\n")
    return str(path)


CASES = {
    "scenario": lambda t, f: ["simulate", str(f("s.yaml"))],
    "plant": lambda t, f: ["simulate", "paper-step", "--plant", str(f("p.yaml"))],
    "extends": lambda t, f: ["simulate", "paper-step", "--plant", _plant_extending(t, f("parent.yaml"))],
    "controller": lambda t, f: ["simulate", "paper-step", "--controller", str(f("c.yaml"))],
    "ssp": lambda t, f: ["simulate", str(f("loop.ssp"))],
    "fmu": lambda t, f: ["simulate", "paper-step", "--fmu", str(f("plant.fmu"))],
    "validate": lambda t, f: ["validate-fmu", str(f("plant.fmu"))],
    "identify": lambda t, f: ["identify", str(f("spec.yaml"))],
    "rig home": lambda t, f: ["rig", "home", "--board", "virtual:fast", "--plant", str(f("p.yaml"))],
    "rig check-signs": lambda t, f: ["rig", "check-signs", "--board", "virtual:fast", "--plant",
                                     _plant_extending(t, f("parent.yaml"))],
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_fifo_is_refused_in_one_line_before_it_is_opened(tmp_path, fifo, case):
    code, err, seconds = _cli(tmp_path, *CASES[case](tmp_path, fifo))
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err, err
    assert any("a FIFO, not a file: refused before it is opened" in line for line in lines), err
    assert seconds < TIMEOUT


def test_a_device_and_a_folder_are_refused(tmp_path):
    code, err, _ = _cli(tmp_path, "simulate", "/dev/zero")
    assert code == 2 and "/dev/zero: a device, not a file" in err
    (tmp_path / "folder.yaml").mkdir()
    code, err, _ = _cli(tmp_path, "simulate", "paper-step", "--plant", str(tmp_path / "folder.yaml"))
    assert code == 2 and "a folder, not a file" in err


def test_the_reader_bounds_what_it_reads(tmp_path):
    path = tmp_path / "big.csv"
    path.write_bytes(b"1\n" * 600)
    assert read_input(path, 1200) == b"1\n" * 600
    with pytest.raises(ConfigError, match="larger than 1000 bytes: not a file this reads"):
        read_input(path, 1000)
    with pytest.raises(ConfigError, match="file not found"):
        regular(tmp_path / "none.csv")
    with pytest.raises(ConfigError, match="not a usable file name"):
        regular("a\0b")
    os.symlink(tmp_path / "loop-a", tmp_path / "loop-b")
    os.symlink(tmp_path / "loop-b", tmp_path / "loop-a")
    with pytest.raises(ConfigError, match="loop-a: (a loop of symbolic links|cannot be read)"):
        regular(tmp_path / "loop-a")
