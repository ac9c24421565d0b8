"""The README's "Tuning for your own rig" session, run as written in a fresh folder: identify,
design, robust tuning, analyze, export (FMI 2.0 and 3.0), validate, regress the rig's own
scenario. Every file one command leaves is taken by the next; the folder then moves whole."""

import re
import shlex
import shutil
from pathlib import Path

import pytest

from furuta_cosim.cli import main

ROOT = Path(__file__).resolve().parent.parent


def _section():
    from helpers import page
    from helpers import section as under

    section = under(page("rig.md"), "Tuning for your own rig")
    commands = re.search(r"```sh\n(.*?)```", section, re.S).group(1).strip().splitlines()
    scenario = re.search(r"```yaml\n(.*?)```", section, re.S).group(1)
    return commands, scenario


@pytest.mark.slow
def test_the_rig_session_runs_as_written(tmp_path, monkeypatch, capsys):
    commands, scenario = _section()
    monkeypatch.chdir(tmp_path)
    for command in commands:
        argv = shlex.split(command)
        assert argv[0] == "furuta-cosim"
        if argv[1:3] == ["regress", "rig/scenarios"] and not (tmp_path / "rig" / "scenarios").exists():
            (tmp_path / "rig" / "scenarios").mkdir(parents=True)
            (tmp_path / "rig" / "scenarios" / "rig-step.yaml").write_text(scenario)
        code = main(argv[1:])
        out, err = capsys.readouterr()
        assert code == 0, (command, out[-2000:], err[-2000:])
        if argv[1] == "regress" and "--update" not in argv:
            assert "2 pass" in out, out
        if argv[1] == "validate-fmu":
            assert "valid" in out and "FAIL" not in out, out
    written = "".join(p.read_text() for p in (tmp_path / "rig").rglob("*.yaml"))
    assert str(tmp_path) not in written  # every file names the others relatively
    moved = tmp_path / "elsewhere" / "rig"
    moved.parent.mkdir()
    shutil.move(str(tmp_path / "rig"), moved)
    monkeypatch.chdir(moved.parent)
    assert main(["regress", "rig/scenarios"]) == 0
    assert "2 pass" in capsys.readouterr().out
