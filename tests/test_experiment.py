"""Experiment files: the shipped logs read as their README says, and every bad log is one line
naming the file and the row or key, exit 2, nothing written."""

import math
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.columns import estimated_noise
from furuta_cosim.identify.experiment import Free, load_experiment

from helpers import run_cli

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "scenarios" / "rigs" / "qube-servo-3"


def test_the_free_swing_reads_as_its_log_says():
    e = load_experiment(RIG / "free-swing.yaml")
    assert e.name == "free-swing" and e.period == pytest.approx(0.004, rel=1e-9)
    assert e.t[0] == pytest.approx(11.0) and e.t[-1] == pytest.approx(47.7)
    assert e.samples == round((47.7 - 11.0) / 0.004) + 1
    theta1 = e.outputs["theta1"]
    # 0 deg hanging in the log is pi in the model; the quantum is one count of 2048
    assert np.median(theta1.values) == pytest.approx(math.pi, abs=0.01)
    assert theta1.sigma == pytest.approx(math.radians(360 / 2048) / math.sqrt(12), rel=1e-12)
    assert theta1.sigma_from == "quantum" and theta1.bias is not None
    assert isinstance(e.start["theta1"], Free) and e.parameters["I_a"] == 1.0
    assert e.input_at("V").shape == (e.samples,) and not np.any(e.input_at("V"))


def test_the_motor_run_holds_7_volts_for_a_tenth_of_a_second():
    e = load_experiment(RIG / "motor-7V.yaml")
    V = e.input_at("V")
    assert set(np.unique(V)) == {0.0, 7.0}
    assert e.t[np.nonzero(V)[0][-1]] == pytest.approx(0.098)
    assert e.outputs["i"].sigma == pytest.approx(0.004) and e.outputs["i"].sigma_from == "noise"


def test_truncation_keeps_the_first_seconds():
    e = load_experiment(RIG / "free-swing.yaml").truncated(2.0)
    assert e.samples == 501 and e.outputs["theta1"].values.shape == (501,)


def test_noise_estimate_of_white_noise_on_a_smooth_signal():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 10, 5000)
    y = np.sin(t) + rng.normal(0, 0.01, t.size)
    assert estimated_noise(y) == pytest.approx(0.01, rel=0.05)


def _write(folder: Path, csv: bytes | str, **keys) -> Path:
    data = folder / "log.csv"
    data.write_bytes(csv if isinstance(csv, bytes) else csv.encode())
    spec = {"data": "log.csv", "columns": "[t, v, y]", "time": "t",
            "inputs": "{V: {column: v, unit: V}}", "outputs": "{theta0: {column: y, unit: rad}}"}
    spec.update({k: v for k, v in keys.items() if v is not None})
    for key in [k for k, v in keys.items() if v is None]:
        spec.pop(key)
    path = folder / "e.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in spec.items()))
    return path


GOOD = "t,v,y\n0,1,0\n0.01,1,0.1\n0.02,1,0.2\n0.03,1,0.3\n"


def test_a_footer_outside_the_window_is_never_read(tmp_path):
    # a logger's last row of NaN (the final state, no action): the window leaves it out
    path = _write(tmp_path, GOOD + "0.04,nan,NaN\n", window="[0, 0.03]")
    experiment = load_experiment(path)
    assert experiment.samples == 4 and np.all(np.isfinite(experiment.outputs["theta0"].values))


@pytest.mark.parametrize("csv, keys, expected", [
    ("t,v\n0,1\n0.01,1\n", {}, r"log.csv: line 2: 2 field\(s\), but columns names 3"),
    ("t,v,y\n0,1,0\n0.01,x,1\n", {}, r"log.csv: line 3, column v: not a number \('x'\)"),
    ("t,v,y\n0,1,0\n0.01,1,nan\n", {}, r"e.yaml: data: log.csv: line 3, column y: not a finite number; give a window"),
    ("t,v,y\n0,1,0\n0.01,1,inf\n", {}, r"line 3, column y: not a finite number"),
    (GOOD + "0.04,nan,0.4\n", {"window": "[0, 0.04]"}, r"e.yaml: window: log.csv: line 6, column v: not a finite number inside the window"),
    ("t,v,y\n0,1,0\n0.02,1,0\n0.01,1,0\n", {}, r"e.yaml: time: log.csv: line 4: time does not increase \(0.02 then 0.01\)"),
    ("t,v,y\n0,1,0\n0.01,1,0\n0.03,1,0\n0.04,1,0\n", {}, r"e.yaml: time: log.csv: line 4: not sampled uniformly"),
    (GOOD, {"window": "[5, 6]"}, r"e.yaml: window: \[5, 6\] s holds 0 sample\(s\) of log.csv"),
    (GOOD, {"window": "[0.02, 0.01]"}, r"e.yaml: window: expected \[start, end\] with start < end"),
    (GOOD, {"outputs": "{theta0: {column: y, unit: furlong}}"}, r"e.yaml: outputs.theta0.unit: unknown unit 'furlong'"),
    (GOOD, {"outputs": "{theta0: {column: z}}"}, r"e.yaml: outputs.theta0.column: 'z' is not one of columns"),
    (GOOD, {"outputs": "{theta0: {column: y}}"}, r"e.yaml: outputs.theta0: give the unit of column 'y' \(unit: one of rad, deg"),
    (GOOD, {"outputs": "{theta0: {column: y, unit: rad, scale: 2}}"}, r"e.yaml: outputs.theta0: give unit or scale, not both"),
    (GOOD, {"outputs": "{theta0: {column: y, unit: rad, quantum: -1}}"}, r"e.yaml: outputs.theta0.quantum: must be >= 0"),
    (GOOD, {"outputs": "{}"}, r"e.yaml: outputs: names no output"),
    (GOOD, {"time": "s"}, r"e.yaml: time: 's' is not one of columns"),
    (GOOD, {"data": "missing.csv"}, r"e.yaml: data: .*missing.csv: no such file"),
    (GOOD, {"colour": "red"}, r"e.yaml: colour: unknown key"),
    (GOOD, {"start": "{theta1: data}"}, r"e.yaml: start.theta1: 'data' takes the measured theta1"),
    (GOOD, {"start": "{theta0: {free: [1, 0]}}"}, r"e.yaml: start.theta0.free: expected \[lo, hi\] with lo < hi"),
    (GOOD, {"header": "-1"}, r"e.yaml: header: must be >= 0"),
    ("t,v,y\n", {}, r"log.csv: 1 line\(s\), all of them header"),
    (b"t,v,y\n\x00\x01\x02\n", {}, r"log.csv: not a text file"),
    (b"t,v,y\n\xff\xfe1,2,3\n", {}, r"log.csv: not a text file \(not UTF-8\)"),
])
def test_a_bad_log_is_one_line_naming_the_file_and_the_place(tmp_path, capsys, csv, keys, expected):
    import re

    path = _write(tmp_path, csv, **keys)
    with pytest.raises(ConfigError) as caught:
        load_experiment(path)
    assert len(caught.value.problems) == 1, caught.value.problems
    assert re.search(expected, caught.value.problems[0]), caught.value.problems[0]
    before = sorted(p.name for p in tmp_path.iterdir())
    code, out, err = run_cli(capsys, "replay", str(path), "--plant", "qube-servo-3", "-o", str(tmp_path / "out"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_fewer_samples_than_free_parameters_is_refused(tmp_path):
    experiment = _write(tmp_path, "t,v,y\n0,1,0\n0.01,1,0.1\n")
    spec = tmp_path / "spec.yaml"
    spec.write_text("plant: qube-servo-3\nexperiments: [e.yaml]\nfree:\n"
                    "  R_a: {bounds: [1, 30]}\n  M_f: {bounds: [0.01, 0.1]}\n  C0: {bounds: [0, 1]}\n")
    from furuta_cosim.identify.spec import load_identify_spec

    with pytest.raises(ConfigError, match=r"spec.yaml: experiments: 2 measured values for 3 free unknowns"):
        load_identify_spec(spec)
    assert experiment.is_file()


def test_names_the_plant_lacks_are_refused_before_any_simulation(tmp_path):
    from furuta_cosim.identify.replay import check_names, target_for

    path = _write(tmp_path, GOOD, inputs="{U: {column: v, unit: V}}", outputs="{phi: {column: y, unit: rad}}",
                  parameters="{mass: 1.0}")
    with pytest.raises(ConfigError) as caught:
        check_names(target_for(plant="qube-servo-3"), [load_experiment(path)])
    text = "\n".join(caught.value.problems)
    assert "e.yaml: inputs.U: qube-servo-3 has no input U" in text
    assert "e.yaml: outputs.phi: qube-servo-3 has no variable phi" in text
    assert "e.yaml: parameters.mass: not a parameter of qube-servo-3" in text


def test_the_readme_examples_are_files_that_load(tmp_path):
    import re
    import shutil

    from furuta_cosim.identify.spec import load_identify_spec

    from helpers import page, section

    text = section(page("rig.md"), "Your own rig: measured logs, replay, identify")
    experiment, spec = re.findall(r"```yaml\n(.*?)```", text, re.S)[:2]  # then a closed loop's keys
    rigs = tmp_path / "rigs" / "qube-servo-3"
    shutil.copytree(RIG, rigs)
    (rigs / "motor-7V.yaml").write_text(experiment)
    e = load_experiment(rigs / "motor-7V.yaml")
    assert e.outputs["i"].bias is not None and e.samples == 131
    (tmp_path / "identify").mkdir()
    (tmp_path / "identify" / "mine.yaml").write_text(spec)
    loaded = load_identify_spec(tmp_path / "identify" / "mine.yaml")
    assert [p.name for p in loaded.free] == ["I_p", "R_a"] and loaded.horizon == (2.0, 4.0)


def _jittered(folder, rows, extra=""):
    (folder / "log.csv").write_text("t,V,y\n" + "".join(f"{a:.6f},{b},{c}\n" for a, b, c in rows))
    path = folder / "e.yaml"
    path.write_text("name: e\ndata: log.csv\nheader: 1\ncolumns: [t, V, y]\ntime: t\n" + extra
                    + "inputs: {V: {column: V, unit: V}}\noutputs: {theta0: {column: y, unit: rad}}\n")
    return path


def test_a_jittered_clock_is_resampled_when_asked(tmp_path):
    # 2 ms nominal, 1.5 to 4.8 ms apart (seeded): refused as it is; on a 2 ms grid the output
    # interpolated (within 1e-4 of the smooth signal it samples), the input held from its last sample
    rng = np.random.default_rng(3)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0015, 0.0048, 400))])
    rows = [(a, 1.0 if math.sin(2 * math.pi * a) > 0 else -1.0, f"{0.1 * math.sin(2 * math.pi * a):.9f}") for a in t]
    with pytest.raises(ConfigError, match="not sampled uniformly.*give resample: PERIOD"):
        load_experiment(_jittered(tmp_path, rows))
    experiment = load_experiment(_jittered(tmp_path, rows, "resample: 0.002\n"))
    assert experiment.period == pytest.approx(0.002) and experiment.t[-1] <= t[-1]
    assert np.max(np.abs(experiment.outputs["theta0"].values - 0.1 * np.sin(2 * np.pi * experiment.t))) < 1e-4
    last = np.searchsorted(t, experiment.t + 1e-15, side="right") - 1
    held = np.where(np.sin(2 * np.pi * t[last]) > 0, 1.0, -1.0)
    assert np.array_equal(experiment.input_at("V"), held)


def test_a_gap_in_a_resampled_log_is_refused_with_its_time(tmp_path):
    t = [0.002 * k for k in range(50)] + [0.2 + 0.002 * k for k in range(50)]   # 0.102 s without a sample
    rows = [(a, 1.0, 0.0) for a in t]
    with pytest.raises(ConfigError, match=r"resample: log.csv: line 52: 0.102 s without a sample "
                                          r"\(from t = 0.098 s\), more than the 0.02 s a gap may last \(10 periods"):
        load_experiment(_jittered(tmp_path, rows, "resample: 0.002\n"))


def test_interleaved_topics_are_held_forward_when_asked(tmp_path):
    # each row holds one topic: the voltage's rows and the angle's rows alternate, the other
    # cell empty (nan); fill: true carries each topic's last value into the rows of the other
    rows = []
    for k in range(100):
        a = 0.001 * k
        rows.append((a, 2.0 if k % 2 == 0 else "", "nan" if k % 2 == 0 else f"{0.5 * a:.6f}"))
    rows[0] = (0.0, 2.0, 0.0)
    experiment = load_experiment(_jittered(tmp_path, rows, "resample: {period: 0.002, fill: true}\n"))
    assert np.all(experiment.input_at("V") == 2.0)
    assert np.max(np.abs(experiment.outputs["theta0"].values - 0.5 * experiment.t)) < 1e-3
    with pytest.raises(ConfigError, match="column y: not a finite number; an empty cell of a topic logged on "
                                          "other rows: resample with fill: true"):
        load_experiment(_jittered(tmp_path, rows, "resample: 0.002\n"))
