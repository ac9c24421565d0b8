"""A loop that is not the one that ran is named at load, in seconds, with the cause its rebuilt
command shows (a factor, the sign, a shift of samples, a column read another way, another
loop): identify/mismatch.py, the law check of identify/laws.py, and identify's refusal."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.foreign import pd_log
from furuta_cosim.identify.mismatch import MISMATCH, apart, cause
from furuta_cosim.identify.precheck import wrong_loop
from furuta_cosim.identify.replay import rebuilt_command

from helpers import ROOT, run_cli

PERIOD = 0.002


def _command(seed: int = 0, n: int = 2000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    return np.sin(2 * np.pi * 1.3 * t) + 0.4 * np.sin(2 * np.pi * 7.1 * t + 1.0) + 0.05 * rng.standard_normal(n)


@pytest.mark.parametrize("make, words", [
    (lambda u: 0.5 * u, "a constant factor: the logged command is 0.5 times the rebuilt one"),
    (lambda u: 1000.0 * u, "a constant factor: the logged command is 1000 times the rebuilt one"),
    (lambda u: -u, "the sign: the logged command is the rebuilt one negated"),
    (lambda u: np.concatenate([np.zeros(3), u[:-3]]), "a shift of 3 sample(s): the logged command is the rebuilt one 3 sample(s) (6 ms) later"),
    (lambda u: np.concatenate([u[2:], np.zeros(2)]), "a shift of 2 sample(s): the logged command is the rebuilt one 2 sample(s) (4 ms) earlier"),
    (lambda u: u[::-1], ""),   # another command altogether
])
def test_the_cause_a_difference_shows_is_named(make, words):
    rebuilt = _command()
    logged = make(rebuilt)
    assert apart(rebuilt, logged) > MISMATCH
    found = cause(rebuilt, logged, PERIOD)
    assert found.startswith(words) if words else found == ""


def test_a_command_that_is_not_a_number_is_apart_and_has_no_cause():
    rebuilt = _command()
    logged = rebuilt.copy()
    logged[10] = np.nan
    assert apart(rebuilt, logged) == np.inf and cause(rebuilt, logged, PERIOD) == ""


@pytest.fixture(scope="module")
def balancing(tmp_path_factory):
    """lqr-qube balancing on the fast virtual board, 2 s from 0.05 rad off upright."""
    from furuta_cosim.cli import main

    out = tmp_path_factory.mktemp("balancing") / "run"
    assert main(["rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.05", "--duration", "2",
                 "-o", str(out)]) == 0
    return out


def _variant(run, tmp_path, name: str, change=None, column=None):
    """The run's experiment file with its loop or its logged command changed."""
    folder = tmp_path / name
    shutil.copytree(run, folder)
    data = yaml.safe_load((folder / "experiment.yaml").read_text())
    data["name"] = name
    if change is not None:
        change(data, folder)
    if column is not None:
        lines = (folder / "log.csv").read_text().splitlines()
        k = lines[0].split(",").index("V")
        values = np.array([float(line.split(",")[k]) for line in lines[1:]])
        changed = column(values)
        rows = [line.split(",") for line in lines[1:]]
        for row, value in zip(rows, changed):
            row[k] = repr(float(value))
        (folder / "log.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    path = folder / "experiment.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _stated(controller: str):
    def change(data, folder):
        shutil.copy(ROOT / "scenarios" / "controllers" / controller, folder / "controllers" / controller)
        data["loop"]["controller"] = f"controllers/{controller}"
    return change


def test_the_project_s_own_logs_rebuild_their_command(balancing):
    experiment = load_experiment(balancing / "experiment.yaml")
    assert apart(rebuilt_command(experiment), experiment.input_at("V")) == 0.0
    assert wrong_loop(experiment) is None


@pytest.mark.parametrize("name, change, column, words", [
    ("wrong-controller", _stated("lqr-paper.yaml"), None,
     "the command lqr-paper.yaml computes from the logged data is"),
    ("halved", None, lambda v: 0.5 * v, "a constant factor: the logged command is 0.5 times"),
    ("negated", None, lambda v: -v, "the sign"),
    ("shifted", None, lambda v: np.concatenate([np.zeros(2), v[:-2]]), "a shift of 2 sample(s)"),
])
def test_a_loop_that_did_not_run_is_named_with_its_cause(balancing, tmp_path, name, change, column, words):
    line = wrong_loop(load_experiment(_variant(balancing, tmp_path, name, change, column)))
    assert line is not None and words in line, line
    assert "from t = 0 s" in line
    if name == "wrong-controller":
        # lqr-paper's command is about twice the logged one away: not a factor, a sign or a shift
        assert "another loop than the one that ran" in line and "at most 10%" in line


def test_identify_refuses_a_wrong_controller_before_any_simulation(balancing, tmp_path, capsys):
    experiment = _variant(balancing, tmp_path, "stated", _stated("lqr-paper.yaml"))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({"name": "wrong", "plant": "qube-servo-3", "experiments": [str(experiment)],
                                    "free": {"R_a": {"start": 9.0, "bounds": [1.0, 30.0]}}}))
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"))
    assert code == 2, (out, err)
    first = next(line for line in err.splitlines() if line.startswith("error:"))
    assert str(experiment) in first and "lqr-paper.yaml computes" in first, err
    assert "the fit stopped before it began" in err and "--force" in err
    assert not (tmp_path / "fit" / "fit.json").exists()


@pytest.fixture(scope="module")
def pd(tmp_path_factory):
    return pd_log(tmp_path_factory.mktemp("pd"), seed=2)


def _with_feedforward(pd, tmp_path, nan_at: int | None = None):
    """The lab's log with a feedforward added to the applied voltage and clipped at 4 V: its
    `u` column stays the law's own output, the new `V` column what reached the plant."""
    lines = (pd.parent / "pd.csv").read_text().splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:]]
    u = header.index("u")
    out = [",".join(header + ["ff", "V"])]
    for k, row in enumerate(rows):
        if row[0] == "nan":
            out.append(",".join(row + ["nan", "nan"]))
            continue
        ff = 0.3 * float(np.sin(2.0 * float(row[0])))
        applied = float(np.clip(float(row[u]) + ff, -4.0, 4.0))
        if nan_at is not None and k == nan_at:
            row[u] = "nan"
        out.append(",".join(row + [repr(ff), repr(applied)]))
    (tmp_path / "ff.csv").write_text("\n".join(out) + "\n")
    data = yaml.safe_load(pd.read_text())
    data.update(data="ff.csv", name="ff", columns=header + ["ff", "V"])
    data["inputs"]["V"]["column"] = "V"
    data["loop"].update(feedforward="ff", voltage=4.0)
    path = tmp_path / "ff.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_law_s_own_output_and_the_applied_input_are_each_checked(pd, tmp_path):
    experiment = load_experiment(_with_feedforward(pd, tmp_path))
    logged = experiment.input_at("V")
    assert np.max(np.abs(logged)) == pytest.approx(4.0)   # the limit is reached: clipped
    assert wrong_loop(experiment) is None   # law + feedforward, clipped: the applied column


def test_a_nan_in_the_law_s_output_is_named_not_skipped(pd, tmp_path):
    with pytest.raises(ConfigError) as error:
        load_experiment(_with_feedforward(pd, tmp_path, nan_at=100))
    assert "loop.law.output: ff.csv: line 102: u holds 'nan' inside the window" in str(error.value)
