"""The README's two set-up commands: exactly two, CI runs the second, the first works from a
clean clone in a new virtual environment."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import page, python_blocks

ROOT = Path(__file__).resolve().parent.parent


def setup_commands():
    text = (ROOT / "README.md").read_text()
    section = text.split("## Set-up on a fresh machine", 1)[1].split("\n## ", 1)[0]
    return [block.strip() for block in re.findall(r"```sh\n(.*?)```", section, re.S)]


def test_readme_holds_exactly_two_setup_commands():
    commands = setup_commands()
    assert len(commands) == 2 and all("\n" not in c for c in commands)
    assert "furuta-cosim" in commands[0] and "pytest" in commands[1]


def test_ci_runs_the_readme_test_command_in_a_fresh_venv():
    script = (ROOT / ".ci" / "run").read_text().splitlines()
    assert setup_commands()[1] in script
    position = script.index(setup_commands()[1])
    assert any("-m venv" in line for line in script[:position])
    assert any("/bin/activate" in line for line in script[:position])


@pytest.mark.slow
def test_main_job_runs_from_a_clean_clone_in_a_new_venv(tmp_path):
    """The first command as written, in a new virtual environment that sees none of this
    machine's packages: it must install everything it needs by itself."""
    if not (ROOT / ".git").exists():
        pytest.fail("the repository's .git is needed to make a clean clone")
    clone, venv = tmp_path / "clone", tmp_path / "venv"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    env = {key: value for key, value in os.environ.items()
           if key not in ("PYTHONPATH", "PYTHONHOME", "FURUTA_COSIM_ROOT")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}", VIRTUAL_ENV=str(venv),
               FURUTA_COSIM_CACHE=str(tmp_path / "cache"), PIP_DISABLE_PIP_VERSION_CHECK="1")
    result = subprocess.run(setup_commands()[0], shell=True, env=env, cwd=clone,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    where = subprocess.run(["python3", "-c", "import furuta_cosim, sys; print(furuta_cosim.__file__, sys.prefix)"],
                           env=env, cwd=tmp_path, capture_output=True, text=True, check=True)
    module, prefix = where.stdout.split()
    assert Path(module).is_relative_to(clone) and Path(prefix) == venv
    run = clone / "runs" / "effort"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["evaluations"] == 150 and summary["best"] and "lqr-paper" in summary["baselines"]
    assert (run / "convergence.png").stat().st_size > 10_000
    assert (run / "summary.md").read_text().startswith("# Tuning effort")
    assert len((run / "history.jsonl").read_text().splitlines()) == 150


PYTHON = python_blocks()
# an example that tunes (a simulated run, or a simulated prior then rig trials) or fits (a whole
# identify pipeline, or identify itself) takes seconds
RUNS = [pytest.param(k, marks=pytest.mark.slow) if re.search(r"\btune(_on_rig)?\(|\.run\(|\bidentify\(", block) else k
        for k, (_, block) in enumerate(PYTHON)]


@pytest.mark.parametrize("index", RUNS)
def test_the_docs_python_examples_run_as_written(index, tmp_path, monkeypatch):
    where, block = PYTHON[index]
    monkeypatch.chdir(tmp_path)
    exec(compile(block, where, "exec"), {"__name__": "readme"})  # noqa: S102


@pytest.mark.slow
def test_the_readme_every_key_tuning_spec_runs(tmp_path):
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import load_spec

    text = page("tuning.md")
    section = text[text.index("Every key of a tuning spec"):]
    path = tmp_path / "my-tuning.yaml"
    path.write_text(re.search(r"```yaml\n(.*?)```", section, re.S).group(1))
    document = tune(load_spec(path), tmp_path / "run", n_calls=2)
    assert document["evaluations"] == 2 and document["baselines"]["lqr-paper"]["feasible"]


@pytest.mark.parametrize("index", range(len(PYTHON)))
def test_the_docs_python_examples_paste_into_the_interactive_prompt(index):
    """Pasted line by line at >>> (where a block ends only at a blank line), no example is a
    SyntaxError."""
    import codeop

    pending = []
    for line in PYTHON[index][1].splitlines() + [""]:
        pending.append(line)
        if codeop.compile_command("\n".join(pending), "<stdin>", "single") is not None:
            pending = []


@pytest.mark.slow
def test_the_quick_starts_next_five_commands_run_as_written(tmp_path, monkeypatch, capsys):
    """After the main job (here a short one into the same folder), each of the README's next
    five commands runs as written and succeeds."""
    import shlex

    from helpers import run_cli, section

    block = re.findall(r"```sh\n(.*?)```", section((ROOT / "README.md").read_text(), "Quick start"), re.S)[1]
    commands = [shlex.split(line.split("#", 1)[0]) for line in block.strip().splitlines()]
    assert len(commands) == 5 and all(c[0] == "furuta-cosim" for c in commands)
    monkeypatch.chdir(tmp_path)
    assert run_cli(capsys, "tune", "effort", "--n-calls", "4", "--workers", "1")[0] == 0
    for argv in commands:
        code, out, err = run_cli(capsys, *argv[1:])
        assert code == 0, (argv, out[-2000:], err[-2000:])
    assert (tmp_path / "effort.fmu").is_file()
