"""A closed-loop log whose clock jitters, replayed at the instants it ran: its law stepped over
each logged interval, its angles estimated over each interval, its fit beside the same loop's
on a uniform clock (synthetic logs of known truth: furuta_cosim/identify/foreign.py, whose
controller and delay are written out by hand)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from furuta_cosim.config import Checker
from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.estimate import estimated_noise, start_covariance, with_estimate
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.foreign import pd_log
from furuta_cosim.identify.laws import read_law
from furuta_cosim.identify.replay import closed_loop, open_session, rebuilt_command, target_for

QUANTUM = 2 * math.pi / 2048


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The same lab's PD, 5 ms late inside its loop, on a uniform and on a jittered clock."""
    folder = tmp_path_factory.mktemp("jitter")
    return {jitter: pd_log(folder / str(jitter), seed=3, delay=0.005, jitter=jitter) for jitter in (False, True)}


def test_a_jittered_closed_loop_log_loads_at_its_instants(logs):
    experiment = load_experiment(logs[True])
    steps = np.diff(experiment.t)
    assert experiment.jittered and experiment.period == pytest.approx(0.002, abs=1e-12)
    assert steps.min() == pytest.approx(0.0015, abs=1e-12) and steps.max() == pytest.approx(0.00475, abs=1e-12)
    # the lab's PD, its derivative over the time since its last run (a hand-written recursion),
    # rebuilt by the law stepped over each logged interval
    np.testing.assert_allclose(rebuilt_command(experiment), experiment.inputs["V"], rtol=0, atol=1e-9)
    # the law at the period instead gives another command: the check would have caught it
    uniform = replace(experiment, loop=replace(experiment.loop, linear=replace(experiment.loop.linear, varying=None)))
    assert np.max(np.abs(rebuilt_command(uniform) - experiment.inputs["V"])) > 0.05


@pytest.mark.parametrize("method, cutoff, integral", [("backward", 50.0, "backward"), ("forward", 80.0, "forward"),
                                                      ("bilinear", 30.0, "bilinear"), ("backward", None, "forward"),
                                                      ("bilinear", None, "backward")])
def test_the_law_over_each_interval_is_python_control_s_on_a_uniform_clock(method, cutoff, integral):
    # the form a jittered log steps (its own coordinates, an interval per sample) against the
    # law python-control discretizes at the period, on the same uniform clock
    rng = np.random.default_rng(7)
    n, period = 400, 0.002
    table = {"t": np.arange(n) * period, "a": rng.normal(size=n), "b": rng.normal(size=n), "r": rng.normal(size=n),
             "\0line": np.arange(n) + 2}
    derivative = {"on": "error", "method": method} | ({"cutoff": cutoff} if cutoff else {})
    entry = {"terms": {"theta0": {"reference": "r", "kp": 1.3, "ki": 0.7, "kd": 0.2},
                       "theta1": {"kp": -20.0, "kd": -1.5}},
             "derivative": derivative, "integral": {"method": integral}}
    outputs = {"theta0": ("a", 1.0, 0.0), "theta1": ("b", 1.0, 0.0)}
    keep = slice(100, n)   # the state at the window's start from the rows before it, both ways
    made = [read_law(Checker(Path("law.yaml")), entry, period, table, list(table)[:4], keep, outputs, (1.0, 0.0),
                     None, None, "log.csv", table["\0line"], times=times) for times in (None, table["t"])]
    assert made[0].varying is None and made[1].varying is not None
    rows = made[0].logged
    u0, _ = made[0].respond(rows, made[0].x0)
    u1, _ = made[1].respond(rows, made[1].x0, made[1].dt)
    np.testing.assert_allclose(u1, u0, rtol=1e-9, atol=1e-9 * np.max(np.abs(u0)))


def test_the_smoother_over_each_interval_is_the_uniform_one_on_a_uniform_clock(logs):
    # the estimate of a jittered log (the plant sampled over each interval, the voltage switched
    # where each command arrived inside it) on a uniform log with a delay of 2.5 samples,
    # against the smoother at the period with its command split over the sample
    target = target_for(plant="qube-servo-3")
    experiment = load_experiment(logs[False])
    varying = replace(experiment, jittered=True)
    for a, b in zip(estimated_noise(experiment, target, {}), estimated_noise(varying, target, {})):
        assert np.max(np.abs(a - b)) < 1e-6 * QUANTUM
    a, b = start_covariance(experiment, target, {})[1], start_covariance(varying, target, {})[1]
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-9 * np.max(np.abs(a)))


def test_a_jittered_loop_replays_at_the_truth_as_the_uniform_one_does(logs):
    target = target_for(plant="qube-servo-3")
    found = {}
    with open_session(target) as session:
        for jitter, path in logs.items():
            experiment = with_estimate(load_experiment(path), target)
            simulated, _ = closed_loop(session, target, experiment)
            found[jitter] = {n: float(np.sqrt(np.mean((simulated[n] - experiment.outputs[n].values) ** 2))) / QUANTUM
                             for n in ("theta0", "theta1")}
    # measured: arm 3.43 / 4.37 quanta RMS (uniform / jittered), pendulum 0.47 / 0.53: the
    # replay at the truth on the logged instants is about as close as the uniform log's
    for name in ("theta0", "theta1"):
        assert found[True][name] < 1.5 * found[False][name] + 0.25, found
    assert found[True]["theta1"] < 1.0, found


def _stated(path: Path, tmp_path: Path, change) -> Path:
    data = yaml.safe_load(path.read_text())
    change(data)
    (tmp_path / "pd.csv").write_bytes((path.parent / "pd.csv").read_bytes())
    target = tmp_path / "changed.yaml"
    target.write_text(yaml.safe_dump(data, sort_keys=False))
    return target


def test_a_closed_loop_log_is_not_resampled(logs, tmp_path):
    path = _stated(logs[True], tmp_path, lambda d: d.update(resample={"period": 0.002}))
    with pytest.raises(ConfigError, match="resample: the log has a loop: a closed loop is replayed at the instants"):
        load_experiment(path)


def _rows(path: Path) -> list[str]:
    return path.read_text().splitlines()


@pytest.mark.parametrize("edit, expected", [
    (lambda rows: rows.__setitem__(301, rows[300]), r"time: .*line 302: time does not increase"),
    (lambda rows: rows.__delitem__(slice(300, 340)), r"time: .*line 301: 0\.1[0-9]* s after the row before, more than "
                                                     r"10 typical steps"),
])
def test_a_jittered_loop_s_clock_is_checked(logs, tmp_path, edit, expected):
    rows = _rows(logs[True].parent / "pd.csv")
    edit(rows)
    (tmp_path / "pd.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "pd.yaml").write_text(logs[True].read_text())
    with pytest.raises(ConfigError, match=expected):
        load_experiment(tmp_path / "pd.yaml")


@pytest.mark.slow
def test_a_jittered_pd_log_fits_as_its_uniform_clock_does(logs, tmp_path):
    from furuta_cosim.identify.run import identify
    from furuta_cosim.identify.synthetic import truth

    true = truth()
    fitted = {}
    for jitter, path in logs.items():
        folder = tmp_path / str(jitter)
        spec = folder / "spec.yaml"
        folder.mkdir()
        spec.write_text(yaml.safe_dump({"name": "pd", "plant": "qube-servo-3", "experiments": [str(path)],
                                        "free": {"R_a": {"start": true["R_a"] * 1.2, "bounds": [1.0, 30.0]},
                                                 "M_f": {"start": true["M_f"] * 1.2, "bounds": [0.005, 0.2]}}}))
        identify(spec, folder / "fit", profiles=False)
        fitted[jitter] = json.loads((folder / "fit" / "fit.json").read_text())["parameters"]
    for name in ("R_a", "M_f"):
        low, high = fitted[True][name]["interval"]
        assert low <= true[name] <= high, (name, fitted[True][name])
        # measured on this seed: 1.0 % (R_a) and 2.6 % (M_f) apart (tools/bench_loop.py: 10 seeds)
        assert fitted[True][name]["value"] == pytest.approx(fitted[False][name]["value"], rel=0.03), name


def test_a_jittered_loop_replayed_open_loop_steps_its_logged_intervals(logs):
    # a closed-loop log that identify replays open loop (a swing-up: its logged command, after
    # the loop's delay): the plant steps over each logged interval, the command held from its
    # row's time plus the delay. The first 0.3 s of the balancing log, before the upright
    # pendulum driven open loop parts from it
    from furuta_cosim.identify.replay import simulate
    from furuta_cosim.identify.split import delayed

    target = target_for(plant="qube-servo-3")
    experiment = delayed(load_experiment(logs[True]).truncated(0.3))
    assert experiment.loop is None and experiment.jittered
    with open_session(target) as session:
        found = simulate(session, target, experiment)
        stretched = simulate(session, target, replace(experiment, jittered=False))   # stepped at the period
    rms = {n: float(np.sqrt(np.mean((found[n] - experiment.outputs[n].values) ** 2))) / QUANTUM for n in found}
    off = {n: float(np.sqrt(np.mean((stretched[n] - experiment.outputs[n].values) ** 2))) / QUANTUM for n in found}
    # measured: 0.29 / 0.30 quanta RMS (arm / pendulum) at the logged intervals, 0.93 / 1.35 at the period
    assert rms["theta0"] < 1.0 and rms["theta1"] < 1.0, rms
    assert off["theta1"] > 3 * rms["theta1"], (rms, off)


def test_a_window_cut_mid_run_of_a_jittered_loop_starts_the_law_where_the_log_left_it(logs, tmp_path):
    # the law's state at the window's start from the logged rows before it, each over its own
    # interval; the replay's lead-in the rows before (a jittered clock's steps are taken)
    def cut(data):
        data["window"] = [1.0, 5.0]
        data["start"] = {"theta0": "data", "theta1": "data", "i": "data",
                         "dtheta0": {"free": [-1.0, 1.0]}, "dtheta1": {"free": [-1.0, 1.0]}}

    experiment = load_experiment(_stated(logs[True], tmp_path, cut))
    assert experiment.jittered and experiment.t[0] >= 1.0
    assert experiment.loop.lead_in is not None and len(experiment.loop.lead_in.current) > 400
    np.testing.assert_allclose(rebuilt_command(experiment), experiment.inputs["V"], rtol=0, atol=1e-9)


def test_a_loop_that_ran_on_a_uniform_clock_stamped_with_jitter_is_named_the_clock(logs, tmp_path):
    # the uniform loop's rows stamped 0 to 1.5 ms late (a logger that stamps each row when it
    # writes it): the law over the stamped intervals is not what ran, the law at the period is
    rows = _rows(logs[False].parent / "pd.csv")
    stamps = np.random.default_rng(5).uniform(0.0, 0.0015, len(rows) - 2)
    for j, late in enumerate(stamps, start=1):
        cells = rows[j].split(",")
        cells[0] = repr(float(cells[0]) + float(late))
        rows[j] = ",".join(cells)
    (tmp_path / "pd.csv").write_text("\n".join(rows) + "\n")
    data = yaml.safe_load(logs[False].read_text())
    data["window"] = [0.0, 5.9]
    (tmp_path / "pd.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=r"loop.law: pd.csv: line \d+: .*the clock: stepped at the log's typical step "
                                          r"\(0.002\d* s\) the law gives the logged output"):
        load_experiment(tmp_path / "pd.yaml")
