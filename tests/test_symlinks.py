"""Nothing is written through a symbolic link under an output folder: for each command that
writes a folder (tune, a trade-off, simulate, regress, identify), a link is planted at every
folder and every file a normal run writes, pointing outside, and the run refuses with one line
per link before any work (exit 2); what a link points to is never touched. ``report`` writes one
file into a run directory, which is checked alike."""

import os
from pathlib import Path

import pytest

from helpers import run_cli, synthetic_log

TUNE = """\
name: small
controller: {n_xc: 1, time: continuous, period: 0.002, model: paper-printed}
parameters:
  Ac: {log: [-1, 2], sign: -1}
  Bc: {box: [-1, 1]}
  Cc: {fixed: [[1.0]]}
  Dc: {lqr: [-2, 3], R: 10}
objective: {type: scenarios, scenarios: [paper-step], terms: [{metric: u.rms}]}
constraints: {stability_margin: 0.01, requirements: false}
optimizer: {n_calls: 4, n_initial_points: 3, batch: 2}
"""
TRADEOFF = TUNE.replace(
    "objective: {type: scenarios, scenarios: [paper-step], terms: [{metric: u.rms}]}",
    "objective:\n  type: tradeoff\n  scenarios: [paper-step]\n  criteria:\n"
    "    - {name: effort, terms: [{metric: u.rms}]}\n    - {name: tracking, terms: [{metric: error.ISE}]}")


def _tune(text):
    def run(capsys, here, out):
        spec = here / "spec.yaml"
        spec.write_text(text)
        return run_cli(capsys, "tune", str(spec), "-o", str(out), "--workers", "1")
    return run


def _simulate(capsys, here, out):
    return run_cli(capsys, "simulate", "paper-step", "-o", str(out))


def _regress(capsys, here, out):
    return run_cli(capsys, "regress", "paper-step", "--workers", "1", "-o", str(out))


def _identify(capsys, here, out):
    spec = synthetic_log(here)
    text = spec.read_text().split("free:")[0] + "free:\n  R_a: {start: 6.0, bounds: [1.0, 30.0]}\n"
    spec.write_text(text)
    return run_cli(capsys, "identify", str(spec), "-o", str(out), "--workers", "1")


COMMANDS = {"tune": _tune(TUNE), "tradeoff": _tune(TRADEOFF), "simulate": _simulate,
            "regress": _regress, "identify": _identify}


def _written(root: Path):
    folders, files = [], []
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root)
        if path.name == ".lock":
            continue
        (folders if path.is_dir() else files).append(relative)
    return folders, files


def _untouched(outside: Path, before: dict) -> None:
    now = {p.relative_to(outside): p.read_bytes() for p in outside.rglob("*") if p.is_file()}
    assert now == before, "written through a link"


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS)
def test_nothing_is_written_through_a_planted_link(command, tmp_path, capsys):
    run = COMMANDS[command]
    normal = tmp_path / "normal"
    normal.mkdir()
    code, _, err = run(capsys, normal, normal / "out")
    assert code in (0, 1), err
    folders, files = _written(normal / "out")
    assert files, "the command wrote nothing to plant links in"
    cases = [("folder", f) for f in folders] + [("files", None)]
    for kind, target in cases:
        here = tmp_path / f"case-{len(list(tmp_path.iterdir()))}"
        out, outside = here / "out", here / "outside"
        outside.mkdir(parents=True)
        if kind == "folder":
            (out / target).parent.mkdir(parents=True, exist_ok=True)
            os.symlink(outside, out / target)
        else:  # every file a link to a file of its own outside, its folders real
            for folder in folders:
                (out / folder).mkdir(parents=True, exist_ok=True)
            out.mkdir(parents=True, exist_ok=True)
            for k, file in enumerate(files):
                (outside / f"{k}").write_text("theirs")
                os.symlink(outside / f"{k}", out / file)
        before = {p.relative_to(outside): p.read_bytes() for p in outside.rglob("*") if p.is_file()}
        code, _, err = run(capsys, here, out)
        assert "Traceback" not in err, err
        _untouched(outside, before)
        assert code == 2, (target, code, err)
        problems = err.strip().splitlines()
        assert problems and all("symbolic link" in line for line in problems), err
        assert len(problems) == (1 if kind == "folder" else min(len(files), 10)), err


def test_a_report_is_not_written_through_a_link(tmp_path, capsys):
    code, _, err = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "run"))
    assert code == 0, err
    (tmp_path / "theirs.html").write_text("theirs")
    os.symlink(tmp_path / "theirs.html", tmp_path / "run" / "report.html")
    code, _, err = run_cli(capsys, "report", str(tmp_path / "run"))
    assert code == 2 and "report.html is a symbolic link" in err, err
    assert (tmp_path / "theirs.html").read_text() == "theirs"
    (tmp_path / "run" / "report.html").unlink()
    code, _, err = run_cli(capsys, "report", str(tmp_path / "run"))
    assert code == 0 and (tmp_path / "run" / "report.html").stat().st_size > 1000, err


def test_a_link_planted_during_a_run_is_refused_by_the_writer(tmp_path):
    """The check before work covers what exists then; a link planted later is refused by the
    writer that would follow it, file or folder."""
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.files import folder, output_folder, write_text

    out = output_folder(tmp_path / "out")
    folder(out)
    outside = tmp_path / "outside"
    outside.mkdir()
    os.symlink(outside, out / "front")
    with pytest.raises(ConfigError, match="front: is a symbolic link"):
        write_text(out / "front" / "00.yaml", "x")
    with pytest.raises(ConfigError, match="front: is a symbolic link"):
        folder(out / "front" / "deeper")
    assert list(outside.iterdir()) == []
    # a link at a file is replaced by the file, never written through
    (outside / "theirs").write_text("theirs")
    os.symlink(outside / "theirs", out / "summary.md")
    write_text(out / "summary.md", "ours")
    assert (outside / "theirs").read_text() == "theirs" and not (out / "summary.md").is_symlink()
