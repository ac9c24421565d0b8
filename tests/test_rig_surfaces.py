"""The surfaces a real rig brings in, tried as a hostile user would: resumes that could mix
runs, identify runs that run out of budget or are killed, parameters the data cannot see, a fit
applied to another plant, roles and units that do not fit, numbers and files at their limits.
Each case is a result that is right, or one line naming the file and the key (exit 2)."""

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from furuta_cosim import paths
from furuta_cosim.errors import ConfigError

from helpers import fit_folder, one_line, run_cli

SHIPPED = paths.scenarios()
RIG = SHIPPED / "rigs" / "qube-servo-3"
CLI = [sys.executable, "-m", "furuta_cosim.cli"]


def _fit(folder: Path, **change) -> Path:
    parameters = {"R_a": {"value": 7.6, "stderr": 0.05, "bounds": [1.0, 30.0]},
                  "M_f": {"value": 0.042, "stderr": 0.001, "bounds": [0.005, 0.2]}}
    correlation = {"names": ["R_a", "M_f"], "matrix": [[1.0, 0.5], [0.5, 1.0]]}
    parameters.update(change.pop("extra", {}))
    if "names" in change:
        correlation = {"names": change.pop("names"), "matrix": change.pop("matrix")}
    return fit_folder(folder, parameters, correlation, **change)


def _robust_spec(folder: Path, fit: Path, samples: int = 1, seed: int = 0) -> Path:
    """The effort spec with variants from ``fit`` (its scenarios and LQR copied beside it)."""
    (folder / "controllers").mkdir(exist_ok=True)
    shutil.copy(SHIPPED / "controllers" / "lqr-paper.yaml", folder / "controllers")
    spec = folder / "robust.yaml"
    spec.write_text((SHIPPED / "tuning" / "effort.yaml").read_text()
                    + f"variants: {{from_fit: {fit.name}, samples: {samples}, seed: {seed}}}\n")
    return spec


# -- 1. a resume cannot mix runs ---------------------------------------------------------------


@pytest.mark.slow
def test_resume_refuses_other_variants_fit_or_plant_content(tmp_path, capsys):
    fit = _fit(tmp_path)
    run = tmp_path / "run"
    base = ["tune", "effort", "--plant", str(tmp_path / "plant.yaml"), "-o", str(run),
            "--workers", "1", "--from-fit", str(fit)]
    code, _, err = run_cli(capsys, *base, "--samples", "1", "--n-calls", "2")
    assert code in (0, 1), err
    lines = len((run / "history.jsonl").read_text().splitlines())
    for extra, expected in ((["--samples", "2"], "--samples 2 differs from the run's 1"),
                            (["--samples", "1", "--variants-seed", "3"], "--variants-seed 3 differs from the run's 0")):
        line = one_line(capsys, *base, *extra, "--resume", "--n-calls", "4")
        assert expected in line and "plant variants would differ" in line, line
    # the same path, other content: the fit's numbers changed
    document = json.loads(fit.read_text())
    document["parameters"]["R_a"]["stderr"] = 0.5
    fit.write_text(json.dumps(document))
    line = one_line(capsys, *base, "--samples", "1", "--resume", "--n-calls", "4")
    assert "is not the one the run drew its variants from" in line and "content differs" in line, line
    assert len((run / "history.jsonl").read_text().splitlines()) == lines  # nothing was added


@pytest.mark.slow
def test_resume_refuses_a_plant_file_whose_values_changed(tmp_path, capsys):
    plant = tmp_path / "rig.yaml"
    plant.write_text("model: furuta\nextends: paper-calibrated\nparameters: {C1: 2.0e-3}\n")
    run = tmp_path / "run"
    code, _, err = run_cli(capsys, "tune", "paper-spectral", "--plant", str(plant), "-o", str(run),
                           "--n-calls", "2", "--workers", "1")
    assert code in (0, 1), err
    plant.write_text("model: furuta\nextends: paper-calibrated\nparameters: {C1: 3.0e-3}\n")
    line = one_line(capsys, "tune", "paper-spectral", "--plant", str(plant), "-o", str(run),
                    "--n-calls", "4", "--workers", "1", "--resume")
    assert f"the plant file {plant} has changed since the run started" in line, line


@pytest.mark.slow
def test_the_printed_resume_line_continues_the_run_it_stopped(tmp_path):
    """A 16-call run cut at 2 and continued with the printed line once ended at the spec's
    count instead; the line now carries every option that shapes the run."""
    run = tmp_path / "run"
    process = subprocess.Popen(CLI + ["tune", "paper-spectral", "-o", str(run), "--workers", "1",
                                      "--n-calls", "16", "--seed", "3"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.default_int_handler))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (
            (run / "history.jsonl").exists() and len((run / "history.jsonl").read_bytes().splitlines()) >= 2):
        time.sleep(0.02)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    line = err.split("'")[1]
    assert "--n-calls 16" in line and "--seed 3" in line and line.endswith("--resume"), err
    done = subprocess.run(line.replace("furuta-cosim", f"{sys.executable} -m furuta_cosim.cli", 1).split()
                          + ["--workers", "1"], capture_output=True, text=True, timeout=300)
    assert done.returncode in (0, 1), done.stderr
    assert len((run / "history.jsonl").read_text().splitlines()) == 16


@pytest.mark.slow
def test_a_resume_without_n_calls_keeps_the_runs_budget(tmp_path):
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import load_spec

    spec = load_spec("paper-spectral")
    tune(spec, tmp_path / "run", n_calls=12, workers=1)
    lines = (tmp_path / "run" / "history.jsonl").read_text().splitlines()
    (tmp_path / "run" / "history.jsonl").write_text("\n".join(lines[:5]) + "\n")
    tune(spec, tmp_path / "run", workers=1, resume=True)
    assert len((tmp_path / "run" / "history.jsonl").read_text().splitlines()) == 12


# -- 2. identify finishes and resumes --------------------------------------------------------------


def _shipped_spec(folder: Path, **change) -> Path:
    """The shipped QUBE identify spec, with its experiments named by absolute paths."""
    data = yaml.safe_load((SHIPPED / "identify" / "qube-servo-3.yaml").read_text())
    data["experiments"] = [str(RIG / "free-swing.yaml"), str(RIG / "motor-7V.yaml")]
    data.update(change)
    path = folder / "qube.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.slow
def test_a_budget_that_runs_out_at_the_end_of_a_stage_gives_the_fit_so_far(tmp_path, capsys):
    """A budget spent exactly as stage 1 ends: stage 2 evaluates nothing. This was
    `min() arg is an empty sequence` after all the work. Where stage 1 ends (it moves with the
    library releases: 285, 288 and 322 simulations seen) is read from a run stopped in stage 2."""
    probe = _shipped_spec(tmp_path, max_simulations=400)
    run_cli(capsys, "identify", "--no-profiles", str(probe), "-o", str(tmp_path / "probe"), "--workers", "1")
    probed = json.loads((tmp_path / "probe" / "fit.json").read_text())
    assert len(probed["stages"]) >= 2, probed["stages"]
    budget = probed["stages"][0]["simulations"]
    spec = _shipped_spec(tmp_path, max_simulations=budget)
    code, out, err = run_cli(capsys, "identify", "--no-profiles", str(spec), "-o", str(tmp_path / "fit"), "--workers", "1")
    # a fit its budget stopped is not trusted: exit 1, the reason in its last line
    assert code == 1, err
    assert "the budget was spent before it began" in err
    assert f"note: stopped at max_simulations ({budget}) in stage 2/5" in out
    assert out.splitlines()[-1].startswith("verdict: NOT trusted") and "max_simulations" in out.splitlines()[-1]
    document = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert document["message"].startswith(f"stopped at max_simulations ({budget})")
    assert all(math.isfinite(p["value"]) for p in document["parameters"].values())


@pytest.mark.slow
def test_a_killed_identify_resumes_to_the_uninterrupted_fit(tmp_path):
    spec = _shipped_spec(tmp_path)
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    done = subprocess.run(CLI + ["identify", "--no-profiles", str(spec), "-o", str(whole), "--workers", "2"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    process = subprocess.Popen(CLI + ["identify", "--no-profiles", str(spec), "-o", str(stopped), "--workers", "2"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checkpoint = stopped / "identify-checkpoint.json"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        try:
            if json.loads(checkpoint.read_text())["stage"] >= 2:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.05)
    process.kill()
    process.wait()
    assert not (stopped / "fit.json").exists()
    done = subprocess.run(CLI + ["identify", "--no-profiles", str(spec), "-o", str(stopped), "--resume", "--workers", "1"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "resumed after stage" in done.stderr
    a, b = (json.loads((folder / "fit.json").read_text()) for folder in (whole, stopped))
    for name in a["parameters"]:  # the same fit, on 2 workers or 1, stopped or not
        assert b["parameters"][name]["value"] == pytest.approx(a["parameters"][name]["value"], rel=1e-9)
    assert b["simulations"] == a["simulations"]
    assert not checkpoint.exists()


def test_resume_refuses_a_run_of_other_data_or_nothing_to_resume(tmp_path, capsys):
    spec = _shipped_spec(tmp_path)
    out = tmp_path / "fit"
    out.mkdir()
    line = one_line(capsys, "identify", "--no-profiles", str(spec), "-o", str(out), "--resume")
    assert "nothing to resume" in line
    identity = {"spec": "qube-servo-3", "spec_sha256": "0" * 64, "data": {}, "plant_sha256": None,
                "fmu_sha256": "", "fmi_version": "2.0"}
    (out / "identify-checkpoint.json").write_text(json.dumps(
        {"identity": identity, "stage": 1, "x": [0.0], "record": [], "simulations": 3}))
    line = one_line(capsys, "identify", "--no-profiles", str(spec), "-o", str(out), "--resume")
    assert "the spec's content differ from the stopped run's" in line, line


@pytest.mark.slow
def test_identify_refuses_a_folder_that_is_not_its_run_and_leaves_nothing_stale(tmp_path, capsys):
    spec = _shipped_spec(tmp_path, max_simulations=40)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    line = one_line(capsys, "identify", "--no-profiles", str(spec), "-o", str(other), "--workers", "1")
    assert "holds files that are not a run of identify qube-servo-3" in line
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]
    out = tmp_path / "fit"
    assert run_cli(capsys, "identify", "--no-profiles", str(spec), "-o", str(out), "--workers", "1", "--accept")[0] == 0
    (out / "old-overlay.png").write_text("a figure of an experiment the spec no longer has")
    (out / ".fit.json.0123456789abcdef.partial").write_text("left by a killed write")
    first = sorted(p.name for p in out.iterdir())
    assert run_cli(capsys, "identify", "--no-profiles", str(spec), "-o", str(out), "--workers", "1", "--accept")[0] == 0
    after = sorted(p.name for p in out.iterdir())
    assert "old-overlay.png" not in after and not [n for n in after if n.endswith(".partial")]
    assert set(after) == set(first) - {"old-overlay.png", ".fit.json.0123456789abcdef.partial"}
    assert json.loads((out / "fit.json").read_text())["files"] == sorted(after)


@pytest.mark.slow
def test_identify_on_workers_leaves_no_folder_in_the_temporary_directory(tmp_path):
    spec = _shipped_spec(tmp_path, max_simulations=60)
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    done = subprocess.run(CLI + ["identify", "--no-profiles", str(spec), "-o", str(tmp_path / "fit"), "--workers", "2",
                                 "--accept"],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "TMPDIR": str(temporary)})
    assert done.returncode == 0, done.stderr
    assert list(temporary.iterdir()) == []


@pytest.mark.slow
def test_the_fit_is_written_before_the_figures(tmp_path, monkeypatch):
    """A full disk (here: a figure that cannot be drawn) keeps plant.yaml and fit.json."""
    import furuta_cosim.identify.pipeline as pipeline
    import furuta_cosim.identify.run as run

    def broken(*_args, **_kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pipeline, "draw_figures", broken)
    spec = _shipped_spec(tmp_path, max_simulations=30)
    with pytest.raises(OSError):
        run.identify(spec, tmp_path / "fit", profiles=False)
    assert (tmp_path / "fit" / "fit.json").is_file() and (tmp_path / "fit" / "plant.yaml").is_file()
    assert not (tmp_path / "fit" / "identify-checkpoint.json").exists()


# -- 3. what the data cannot see -----------------------------------------------------------------


def test_a_parameter_the_data_do_not_see_is_reported_without_an_interval(tmp_path, capsys):
    """The motor log ends before the arm meets its stop: K_stop moved from 1 to 13.7 and
    carried an interval of zero width."""
    spec = tmp_path / "stop.yaml"
    spec.write_text(f"plant: qube-servo-3\nexperiments: [{RIG / 'motor-7V.yaml'}]\nfree:\n"
                    "  R_a: {bounds: [1.0, 30.0]}\n  K_stop: {start: 1.0, bounds: [0.0, 100.0]}\n"
                    "max_simulations: 200\n")
    # R_a alone cannot fit the 7 V run's arm (the verdict refuses it); what K_stop shows stands
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--workers", "1", "--accept")
    assert code == 0, err
    stop = json.loads((tmp_path / "fit" / "fit.json").read_text())["parameters"]["K_stop"]
    assert stop["identifiable"] is False and stop["interval"] is None and stop["stderr"] is None
    assert stop["value"] == 1.0  # kept at its start: the data said nothing
    assert "K_stop" in out and "structurally not identifiable" in out
    assert "the data do not depend on it" in json.dumps(stop["verdict"])
    assert yaml.safe_load((tmp_path / "fit" / "plant.yaml").read_text())["parameters"]["K_stop"] == 1.0
    r_a = json.loads((tmp_path / "fit" / "fit.json").read_text())["parameters"]["R_a"]
    assert r_a["identifiable"] is True and r_a["interval"][0] < r_a["value"] < r_a["interval"][1]


def test_a_tuning_holds_what_the_fit_could_not_identify_and_says_so(tmp_path):
    from furuta_cosim.tuning.spec import load_spec

    fit = _fit(tmp_path, extra={"K_stop": {"value": 1.0, "identifiable": False, "stderr": None,
                                           "interval": None, "bounds": [0.0, 100.0]}},
               names=["R_a", "M_f", "K_stop"], matrix=[[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])
    spec = load_spec(_robust_spec(tmp_path, fit, samples=4))
    assert all(dict(v).get("K_stop") == 1.0 for v in spec.variants[1:])
    assert len({dict(v)["R_a"] for v in spec.variants[1:]}) == 4  # the others are drawn
    assert any("K_stop is not identifiable from the fit's data: held at 1" in note for note in spec.notes)


@pytest.mark.parametrize("free, expected", [
    ("V: {bounds: [0, 10]}", "free.V: only a plant parameter can be fitted (V is an input"),
    ("n_substeps: {bounds: [1, 100]}", "free.n_substeps: a Integer setting of qube-servo-3"),
    ("theta1_start: {bounds: [3, 3.3]}", "free.theta1_start: "),
    ("R_a: {bounds: [-5, 30]}", "free.R_a.bounds: R_a must be > 0 (its physical range), the bounds' lo is -5"),
])
def test_only_physical_values_can_be_free(tmp_path, capsys, free, expected):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"plant: qube-servo-3\nexperiments: [{RIG / 'motor-7V.yaml'}]\nfree:\n  {free}\n")
    line = one_line(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--workers", "1")
    assert f"{spec}: " in line and expected in line, line
    assert not (tmp_path / "fit").exists()


# -- 4. a fit belongs to its plant ----------------------------------------------------------------


def test_a_fit_is_refused_on_another_plant(tmp_path, capsys):
    fit = _fit(tmp_path)
    line = one_line(capsys, "tune", "effort", "--plant", "qube-servo-3", "--from-fit", str(fit),
                    "-o", str(tmp_path / "run"))
    assert "is not the plant" in line and str(fit) in line and "qube-servo-3.yaml" in line, line
    spec = _robust_spec(tmp_path, fit)
    spec.write_text(spec.read_text() + "plant: paper-calibrated\n")
    line = one_line(capsys, "tune", str(spec), "-o", str(tmp_path / "run"))
    assert "plant:" in line and "is not the plant" in line, line


def test_a_plant_beside_the_fit_that_is_not_the_fitted_one_is_refused(tmp_path, capsys):
    fit = _fit(tmp_path)
    (tmp_path / "plant.yaml").write_text("model: furuta\nextends: qube-servo-3\nparameters: {R_a: 9.9, M_f: 0.042}\n")
    line = one_line(capsys, "tune", "effort", "--from-fit", str(fit), "-o", str(tmp_path / "run"))
    assert "plant.yaml: is not the plant fit.json was fitted to" in line, line


def test_a_variant_outside_the_physical_range_is_refused_when_drawn(tmp_path):
    from furuta_cosim.identify.variants import variants_from_fit

    fit = _fit(tmp_path, extra={"C0": {"value": 1e-4, "stderr": 1e-3, "bounds": [-1.0, 1.0]}},
               names=["R_a", "M_f", "C0"], matrix=[[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ConfigError, match=r"fit.json: variant \d+ draws C0 = -[0-9.e-]+, outside its "
                                          r"physical range \(>= 0\)"):
        variants_from_fit(fit, 16, 0)


@pytest.mark.parametrize("names, matrix, expected", [
    (["R_a", "R_a"], [[1.0, 0.0], [0.0, 1.0]], "correlation.names: expected unique names"),
    (["R_a", "M_f"], [[2.0, 0.0], [0.0, 2.0]], "not a correlation matrix"),
    (["R_a", "M_f"], [[1.0, 0.0], [0.0, 0.5]], "unit diagonal"),
])
def test_a_correlation_that_is_no_correlation_is_refused(tmp_path, names, matrix, expected):
    from furuta_cosim.identify.variants import read_fit

    with pytest.raises(ConfigError, match=expected):
        read_fit(_fit(tmp_path, names=names, matrix=matrix))


def test_a_correlation_that_is_not_positive_semidefinite_is_refused(tmp_path):
    from furuta_cosim.identify.variants import read_fit

    fit = _fit(tmp_path, extra={"C0": {"value": 1e-4, "stderr": 1e-5, "bounds": [0.0, 1.0]}},
               names=["R_a", "M_f", "C0"], matrix=[[1.0, 0.9, -0.9], [0.9, 1.0, 0.9], [-0.9, 0.9, 1.0]])
    with pytest.raises(ConfigError, match="positive semi-definite"):
        read_fit(fit)


def test_a_list_of_variants_has_a_limit(tmp_path, capsys):
    spec = tmp_path / "many.yaml"
    data = yaml.safe_load((SHIPPED / "tuning" / "effort.yaml").read_text())
    data["variants"] = [{}] * 5000
    (tmp_path / "controllers").mkdir()
    shutil.copy(SHIPPED / "controllers" / "lqr-paper.yaml", tmp_path / "controllers")
    spec.write_text(yaml.safe_dump(data))
    started = time.monotonic()
    line = one_line(capsys, "tune", str(spec), "-o", str(tmp_path / "run"))
    assert "variants: 5000 variants; at most 65" in line
    assert time.monotonic() - started < 60  # it hung before


# -- 5. roles and dimensions ------------------------------------------------------------------------


def _experiment(folder: Path, outputs: str, **extra) -> Path:
    (folder / "log.csv").write_text("t,v,y\n" + "".join(f"{0.002 * k!r},1,{0.001 * k!r}\n" for k in range(50)))
    text = (f"data: log.csv\ncolumns: [t, v, y]\ntime: t\ninputs: {{V: {{column: v, unit: V}}}}\n"
            f"outputs: {outputs}\nstart: {{theta1: 3.141592653589793}}\n")
    text += "".join(f"{k}: {v}\n" for k, v in extra.items())
    path = folder / "e.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("outputs, extra, expected", [
    ("{V: {column: y, unit: V}}", {}, "outputs.V: V is an input of qube-servo-3, not an output it computes"),
    ("{R_a: {column: y, scale: 1}}", {}, "outputs.R_a: R_a is an parameter"),
    ("{theta0: {column: y, unit: A}}", {}, "outputs.theta0.unit: A is a unit of a current, but theta0 is in rad"),
    ("{i: {column: y, unit: deg}}", {}, "outputs.i.unit: deg is a unit of an angle, but i is in A"),
    ("{theta0: {column: y, unit: rad}}", {"parameters": "{theta1_start: 0.3}"},
     "parameters.theta1_start: sets the start of theta1, which start.theta1 sets too"),
])
def test_an_experiments_roles_and_units_must_fit_the_plant(tmp_path, capsys, outputs, extra, expected):
    path = _experiment(tmp_path, outputs, **extra)
    line = one_line(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert f"{path}: " in line and expected.replace("an parameter", "a parameter") in line.replace(
        "an parameter", "a parameter"), line


def test_variants_may_not_set_a_start_the_scenario_sets(tmp_path, capsys):
    scenario = yaml.safe_load((SHIPPED / "paper-step.yaml").read_text())
    assert "theta1" in scenario["plant"]["initial"]
    data = yaml.safe_load((SHIPPED / "tuning" / "effort.yaml").read_text())
    data["objective"]["scenarios"] = ["paper-step"]
    data["variants"] = [{}, {"theta1_start": 0.3}]
    (tmp_path / "controllers").mkdir()
    shutil.copy(SHIPPED / "controllers" / "lqr-paper.yaml", tmp_path / "controllers")
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(data))
    code, _, err = run_cli(capsys, "tune", str(spec), "-o", str(tmp_path / "run"))
    assert code == 2 and "variants[1]" in err and "plant.overrides.theta1_start: sets the start of theta1, " \
        "which plant.initial.theta1 sets too" in err, err


def test_validate_fmu_refuses_an_angle_in_millimetres_as_the_session_does(furuta_fmu, tmp_path, capsys):
    import re
    import zipfile

    with zipfile.ZipFile(furuta_fmu) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    text = files["modelDescription.xml"].decode()
    text = text.replace("<UnitDefinitions>", '<UnitDefinitions>\n<Unit name="mm"><BaseUnit m="1" '
                        'factor="0.001"/></Unit>', 1)
    text, count = re.subn(r'(<ScalarVariable name="theta1"[^>]*>\s*<Real[^>]*?)unit="rad"', r'\1unit="mm"', text)
    assert count == 1
    files["modelDescription.xml"] = text.encode()
    bad = tmp_path / "Furuta.fmu"
    with zipfile.ZipFile(bad, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    code, out, _ = run_cli(capsys, "validate-fmu", str(bad))
    assert code == 1 and re.search(r"^FAIL +units .*theta1 is in 'mm', not a unit of rad", out, re.M), out
    code, _, err = run_cli(capsys, "simulate", "paper-step", "--fmu", str(bad), "-o", str(tmp_path / "out"))
    assert code == 2 and "theta1 is in 'mm', not a unit of rad" in err, err


# -- 6. numbers and files at their limits ----------------------------------------------------------


@pytest.mark.parametrize("outputs, expected", [
    ("{theta0: {column: y, unit: rad, noise: 1.0e+200}}", "outputs.theta0.noise: must be <= 1e+12"),
    ("{theta0: {column: y, unit: rad, quantum: 1.0e+300}}", "outputs.theta0.quantum: must be <= 1e+12"),
    ("{theta0: {column: y, unit: rad, bias: {free: [-1.0e+300, 1.0e+300]}}}",
     "outputs.theta0.bias.free: expected magnitudes of at most 1e+12"),
])
def test_huge_numbers_in_an_experiment_are_one_line(tmp_path, capsys, outputs, expected):
    path = _experiment(tmp_path, outputs)
    line = one_line(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert f"{path}: " in line and expected in line, line


def test_huge_bounds_in_an_identify_spec_are_one_line(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"plant: qube-servo-3\nexperiments: [{RIG / 'motor-7V.yaml'}]\nfree:\n"
                    "  C0: {bounds: [0, 1.0e+300]}\n")
    line = one_line(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"))
    assert f"{spec}: free.C0.bounds: expected magnitudes of at most 1e+12" in line, line


def test_a_fit_with_a_huge_stderr_or_nested_deep_is_one_line(tmp_path, capsys):
    fit = _fit(tmp_path)
    document = json.loads(fit.read_text())
    document["parameters"]["R_a"]["stderr"] = 1e200
    fit.write_text(json.dumps(document))
    line = one_line(capsys, "tune", "effort", "--from-fit", str(fit), "-o", str(tmp_path / "run"))
    assert "fit.json: parameters.R_a.stderr: 1e+200 is beyond any spread its bounds allow" in line, line
    fit.write_text("[" * 100_000 + "]" * 100_000)
    line = one_line(capsys, "tune", "effort", "--from-fit", str(fit), "-o", str(tmp_path / "run"))
    assert "fit.json: nested more than 64 levels deep" in line, line


def test_a_long_extends_chain_is_one_line(tmp_path, capsys):
    (tmp_path / "p0.yaml").write_text("model: furuta\nextends: paper-calibrated\n")
    for k in range(1, 3000):
        (tmp_path / f"p{k}.yaml").write_text(f"model: furuta\nextends: p{k - 1}.yaml\n")
    line = one_line(capsys, "simulate", "paper-step", "--plant", str(tmp_path / "p2999.yaml"),
                    "-o", str(tmp_path / "out"))
    assert "extends: a chain of more than 32 plant files" in line, line


@pytest.mark.parametrize("cell", ["7_000", "\u0661\u0662", "\uff11", "0x10", "1,5e"])
def test_a_cell_is_an_ascii_decimal_number(tmp_path, capsys, cell):
    (tmp_path / "log.csv").write_text(f"t;v;y\n0;1;0\n0.002;{cell};0\n0.004;1;0\n", encoding="utf-8")
    path = tmp_path / "e.yaml"
    path.write_text("data: log.csv\ndelimiter: ';'\ncolumns: [t, v, y]\ntime: t\ninputs: {V: {column: v, unit: V}}\n"
                    "outputs: {theta0: {column: y, unit: rad}}\n")
    line = one_line(capsys, "replay", str(path), "--plant", "qube-servo-3")
    assert "log.csv: line 3, column v: not a number" in line and "ASCII decimal" in line, line


@pytest.mark.slow
def test_a_million_row_log_is_read_in_bounded_memory(tmp_path):
    """The reader once held every row as Python floats: 629 MB to replay 10^6 rows."""
    n = 1_000_000
    t = np.arange(n) * 0.002
    with open(tmp_path / "log.csv", "w") as handle:
        handle.write("t,v,y\n")
        np.savetxt(handle, np.column_stack([t, np.zeros(n), np.zeros(n)]), delimiter=",", fmt="%.9g")
    (tmp_path / "e.yaml").write_text("data: log.csv\ncolumns: [t, v, y]\ntime: t\ninputs: {V: {column: v, unit: V}}\n"
                                     "outputs: {theta0: {column: y, unit: rad}}\n")
    # the peak of this process's own memory (VmHWM; ru_maxrss carries the parent's over a fork)
    program = ("import re; from furuta_cosim.identify.experiment import load_experiment; "
               f"e = load_experiment({str(tmp_path / 'e.yaml')!r}); "
               "print(e.samples, re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read()).group(1))")
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=300)
    samples, peak_kb = map(int, done.stdout.split())
    assert samples == n
    size = (tmp_path / "log.csv").stat().st_size
    assert peak_kb * 1024 < 150e6 + 3 * size, (peak_kb, size)  # the interpreter and 3x the file at most
