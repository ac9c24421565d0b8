"""The README's two set-up commands: exactly two, CI runs the second, the first works from a
clean clone in a new virtual environment."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def setup_commands():
    text = (ROOT / "README.md").read_text()
    section = text.split("## Set-up on a fresh machine", 1)[1].split("\n## ", 1)[0]
    return [block.strip() for block in re.findall(r"```sh\n(.*?)```", section, re.S)]


def test_readme_holds_exactly_two_setup_commands():
    commands = setup_commands()
    assert len(commands) == 2 and all("\n" not in c for c in commands)
    assert "furuta-cosim" in commands[0] and "pytest" in commands[1]


def test_ci_runs_the_readme_test_command():
    assert setup_commands()[1] in (ROOT / ".ci" / "run").read_text().splitlines()


@pytest.mark.slow
def test_main_job_runs_from_a_clean_clone_in_a_new_venv(tmp_path):
    if not (ROOT / ".git").exists():
        pytest.fail("the repository's .git is needed to make a clean clone")
    clone, venv = tmp_path / "clone", tmp_path / "venv"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    # the dependencies come from this machine; the project itself installs anew
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    python = venv / "bin" / "python"
    install, main_job = setup_commands()[0].split(" && ", 1)
    assert install == "python3 -m pip install -e ."
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "-e", str(clone)],
                   check=True, capture_output=True)
    env = {**os.environ, "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}",
           "FURUTA_COSIM_CACHE": str(tmp_path / "cache"), "VIRTUAL_ENV": str(venv)}
    where = subprocess.run([str(python), "-c", "import furuta_cosim; print(furuta_cosim.__file__)"],
                           env=env, cwd=tmp_path, capture_output=True, text=True, check=True)
    assert Path(where.stdout.strip()).is_relative_to(clone)
    result = subprocess.run(main_job, shell=True, env=env, cwd=clone, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads((clone / "out" / "paper-step" / "metrics.json").read_text())
    assert report["passed"] and set(report["controllers"]) == {"lqr-paper", "bo-paper"}
    assert (clone / "out" / "paper-step" / "paper-step.png").stat().st_size > 10_000
