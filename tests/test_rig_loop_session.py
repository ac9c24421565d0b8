"""The docs' "Running on the rig" page, its lab session run as written on the virtual board:
identify, design, simulate the swing-up, run it on the rig, home, regress the model against the
run's log. Every file one command leaves is taken by the next."""

import re
import shlex

import pytest

from furuta_cosim.cli import main

from helpers import page, section


@pytest.mark.slow
def test_the_lab_session_runs_as_written(tmp_path, monkeypatch, capsys):
    text = section(page("rig-loop.md"), "A lab's session")
    commands = re.search(r"```sh\n(.*?)```", text, re.S).group(1).strip().splitlines()
    files = dict(zip(re.findall(r"^`(lab/[^`]+\.yaml)`", text, re.M), re.findall(r"```yaml\n(.*?)```", text, re.S)))
    assert set(files) == {"lab/controllers/swingup-lab.yaml", "lab/scenarios/swingup-lab.yaml",
                          "lab/checks/swingup.yaml"}
    monkeypatch.chdir(tmp_path)
    for name, content in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(content)
    for command in commands:
        argv = shlex.split(command)
        assert argv[0] == "furuta-cosim"
        # the board in real time, as written, can trip a run late on a loaded machine (the
        # supervisor's deadline check, tests/test_rig.py): here it runs as fast as it can, the
        # same rig sample for sample
        argv = ["virtual:fast" if a == "virtual" else a for a in argv]
        code = main(argv[1:])
        out, err = capsys.readouterr()
        assert code == 0, (command, out[-2000:], err[-2000:])
        if argv[1:3] == ["rig", "run"]:
            assert "Swing-up: caught at" in out and "0 fall(s)" in out
        if argv[1] == "simulate":
            assert "FAIL" not in out
        if argv[1] == "regress":
            assert "1 pass" in out, out
    written = "".join(p.read_text() for p in (tmp_path / "lab").rglob("*.yaml"))
    assert str(tmp_path) not in written  # every file names the others relatively
