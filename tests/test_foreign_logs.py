"""Logs as other labs record them: a foreign loop stated in its own words, a fitted input
delay, a jittered clock fitted as a uniform one (synthetic logs of known truth:
furuta_cosim/identify/foreign.py, whose controller and delay are written out by hand)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import yaml

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.foreign import CUTOFF, PD_GAINS, PERIOD, chirp_log, pd_log
from furuta_cosim.identify.replay import compare, open_session, rebuilt_command, simulate, target_for

from helpers import run_cli


@pytest.fixture(scope="module")
def pd(tmp_path_factory):
    return pd_log(tmp_path_factory.mktemp("pd"), seed=1)


def _changed(path, tmp_path, change):
    data = yaml.safe_load(path.read_text())
    change(data)
    target = path.parent / f"changed-{tmp_path.name}.yaml"
    target.write_text(yaml.safe_dump(data))
    return target


def test_a_lab_s_pd_on_two_errors_rebuilds_its_logged_output_and_replays(pd):
    experiment = load_experiment(pd)
    assert "kd -3 on pend_ref" in experiment.loop.describe()
    rebuilt = rebuilt_command(experiment)
    # the law stated in the lab's words (degrees, its pendulum sign, backward Euler) against
    # the lab's own output, computed by a separate hand-written recursion
    np.testing.assert_allclose(rebuilt, experiment.inputs["V"], rtol=0, atol=1e-9)
    target = target_for(plant="qube-servo-3")
    with open_session(target) as session:
        found = compare(experiment, simulate(session, target, experiment))
    # the loop closed again on the true plant: the angles within 2 encoder quanta RMS (the
    # rounding of the encoders drives the difference that remains)
    for name in ("theta0", "theta1"):
        assert found[name]["rms"] < 2.0 * found[name]["quantum"], (name, found[name])
    assert abs(found["theta1"]["period"]["error"]) < 0.02


def test_the_docs_law_block_loads_as_written_and_rebuilds_the_lab_s_output(pd, tmp_path):
    # the foreign-logs page's first block, as a user copies it (its `on:` key unquoted, read as
    # the word: YAML 1.1 alone would make it a boolean), beside the synthetic lab's log
    from helpers import page

    block = re.findall(r"```yaml\n(.*?)```", page("foreign-logs.md"), re.S)[0]
    assert "derivative: {on: error" in block
    (tmp_path / "pd.csv").write_bytes((pd.parent / "pd.csv").read_bytes())
    path = tmp_path / "documented.yaml"
    path.write_text("data: pd.csv\n" + block)
    experiment = load_experiment(path)
    assert "on error" in experiment.loop.describe() or "error" in experiment.loop.describe()
    # the page's gains are the lab's to 5 digits: the command agrees to well under 1 mV
    np.testing.assert_allclose(rebuilt_command(experiment), experiment.inputs["V"], rtol=0, atol=1e-3)


@pytest.mark.parametrize("change, expected", [
    (lambda d: d["loop"]["law"]["derivative"].update(method="bilinear"), r"line \d+: the law gives"),
    (lambda d: d["loop"]["law"].update(error="measurement - reference"), r"line 2: the law gives 3.6"),
    (lambda d: d["loop"]["law"]["derivative"].update(on="measurement"), r"line \d+: the law gives"),
    (lambda d: d["loop"]["law"]["terms"]["theta1"].update(kd=-2.9), r"line \d+: the law gives"),
    (lambda d: d["loop"]["law"].update(derivative={"on": "error", "method": "forward"}),
     "a forward-Euler derivative needs a filter"),
    (lambda d: d["outputs"].pop("i") and d["loop"]["law"]["terms"].update(i={"kp": 1.0}),
     "the law acts on i, which is not one of outputs"),
    (lambda d: d["loop"]["law"]["terms"]["theta0"].update(reference="ref"), r"'ref' is not one of columns"),
    (lambda d: d["loop"]["law"].update(output="volts"), r"loop.law.output: 'volts' is not one of columns"),
    (lambda d: d["loop"]["law"]["derivative"].update(method="trapezoid"), "expected one of backward, forward, bilinear"),
])
def test_a_law_that_is_not_the_one_that_ran_is_one_line(pd, tmp_path, change, expected):
    with pytest.raises(ConfigError) as error:
        load_experiment(_changed(pd, tmp_path, change))
    assert len(error.value.problems) == 1, error.value.problems
    assert "loop.law" in error.value.problems[0], error.value.problems[0]
    assert re.search(expected, error.value.problems[0]), error.value.problems[0]


def test_the_same_law_as_a_state_space_gives_the_same_command(pd, tmp_path):
    # the backward-Euler filtered derivative d_k = a (d_{k-1} + w (e_k - e_{k-1})) written by
    # hand as a state space with x = [d_{k-1}, e_{k-1}] per error, e = r - y, on
    # v = [arm_ref, pend_ref, theta0, theta1]
    a, w = 1.0 / (1.0 + CUTOFF * PERIOD), CUTOFF
    A = np.zeros((4, 4))
    B = np.zeros((4, 4))
    C = np.zeros((1, 4))
    D = np.zeros((1, 4))
    for j, (name, r, y) in enumerate((("arm", 0, 2), ("pendulum", 1, 3))):
        kp, kd = PD_GAINS[name]
        d, e = 2 * j, 2 * j + 1
        A[d, d], A[d, e] = a, -a * w                 # d_k from d_{k-1}, e_{k-1}
        B[d, r], B[d, y] = a * w, -a * w             # and e_k
        B[e, r], B[e, y] = 1.0, -1.0                 # e_k kept for the next sample
        C[0, d], C[0, e] = kd * a, -kd * a * w
        D[0, r] += kp + kd * a * w
        D[0, y] -= kp + kd * a * w

    def as_state_space(data):
        data["loop"]["law"] = {"A": A.tolist(), "B": B.tolist(), "C": C.tolist(), "D": D.tolist(),
                               "inputs": ["arm_ref", "pend_ref", "theta0", "theta1"], "output": "u"}

    experiment = load_experiment(_changed(pd, tmp_path, as_state_space))
    assert experiment.loop.describe() == "the law of 4 states on arm_ref, pend_ref, theta0, theta1"
    np.testing.assert_allclose(rebuilt_command(experiment), experiment.inputs["V"], rtol=0, atol=1e-9)


def test_a_window_cut_mid_log_starts_the_law_where_the_log_left_it(pd, tmp_path):
    def cut(data):
        data["window"] = [2.5, 6.0]
        data["start"] = {"theta0": "data", "dtheta0": 0.0, "theta1": "data", "dtheta1": 0.0, "i": 0.0}

    experiment = load_experiment(_changed(pd, tmp_path, cut))
    # the filters' state at 2.5 s is the one the law reaches on the rows before the window:
    # the output still rebuilds from the window's first sample
    np.testing.assert_allclose(rebuilt_command(experiment), experiment.inputs["V"], rtol=0, atol=1e-9)


def _spec(folder, experiment, free: dict, **extra) -> object:
    lines = [f"name: {experiment.stem}", "plant: qube-servo-3", f"experiments: [{experiment.name}]", "free:"]
    lines += [f"  {k}: {{start: {s!r}, bounds: [{lo!r}, {hi!r}]}}" for k, (s, lo, hi) in free.items()]
    lines += [f"{k}: {v}" for k, v in extra.items()]
    path = folder / f"{experiment.stem}-spec.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_an_input_s_delay_is_fitted_with_its_interval(tmp_path, capsys):
    experiment = chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=4)
    spec = _spec(tmp_path, experiment, {"R_a": (9.0, 1.0, 30.0)})
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles")
    assert code == 0, (out, err)
    assert "chirp.V.delay: starts at" in err
    found = json.loads((tmp_path / "fit" / "fit.json").read_text())["parameters"]
    delay = found["chirp.V.delay"]
    assert abs(delay["value"] - 0.012) < 0.001, delay
    assert delay["interval"][1] - delay["interval"][0] < 0.001
    assert delay["rests_on"].startswith("its sandwich interval (only plant parameters are profiled)")
    assert abs(found["R_a"]["value"] / 7.5 - 1.0) < 0.02


def test_a_delay_fitted_in_segments_is_one_unknown_of_the_log(tmp_path):
    from furuta_cosim.identify.problem import unknowns
    from furuta_cosim.identify.spec import load_identify_spec
    from furuta_cosim.identify.split import parts_of

    experiment = chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=0, duration=1.0)
    data = yaml.safe_load(experiment.read_text())
    data["segments"] = 0.2
    experiment.write_text(yaml.safe_dump(data))
    spec = parts_of(load_identify_spec(_spec(tmp_path, experiment, {"R_a": (7.0, 1.0, 30.0)})))
    assert len(spec.experiments) == 5
    names = [u.name for u in unknowns(spec, {"R_a": 7.5})]
    assert names.count("chirp.V.delay") == 1, names
    # each segment's delay brings in the log's own samples before it, not zeros
    third = spec.experiments[2]
    whole = load_experiment(experiment)
    m = len(third.delays["V"].before)
    start = 2 * 100
    np.testing.assert_array_equal(third.delays["V"].before, whole.inputs["V"][start - m:start])
    np.testing.assert_allclose(third.input_at("V", {"chirp.V.delay": 0.012}),
                               whole.input_at("V", {"chirp.V.delay": 0.012})[start:start + third.samples],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("bounds, expected", [
    ([0.02, 0.01], r"expected \[lo, hi\] with 0 <= lo < hi"),
    ([-0.001, 0.01], r"expected \[lo, hi\] with 0 <= lo < hi"),
    ([0.0, 0.05], "0.05 s is more than 10 samples"),
])
def test_a_delay_s_bounds_are_checked(tmp_path, bounds, expected):
    experiment = chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=0, duration=0.5)
    data = yaml.safe_load(experiment.read_text())
    data["inputs"]["V"]["delay"] = {"free": bounds}
    experiment.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=f"inputs.V.delay.free: {expected}"):
        load_experiment(experiment)


@pytest.mark.slow
def test_a_jittered_interleaved_log_fits_as_the_uniform_one(tmp_path):
    from furuta_cosim.identify.run import identify

    fits = {}
    for name, jitter in (("uniform", False), ("jittered", True)):
        experiment = chirp_log(tmp_path, delay=0.012, seed=2, jitter=jitter, name=name)
        spec = _spec(tmp_path, experiment, {"R_a": (9.0, 1.0, 30.0), "M_f": (0.05, 0.005, 0.2)})
        identify(spec, tmp_path / name, profiles=False)
        fits[name] = json.loads((tmp_path / name / "fit.json").read_text())["parameters"]
    assert load_experiment(tmp_path / "jittered.yaml").period == pytest.approx(PERIOD, rel=1e-9)
    for parameter in ("R_a", "M_f"):
        assert math.isclose(fits["jittered"][parameter]["value"], fits["uniform"][parameter]["value"], rel_tol=0.05)


def test_a_held_out_part_starts_the_law_where_the_fitted_part_left_it(pd):
    from furuta_cosim.identify.split import split

    fitted, held = split(load_experiment(pd), 0.4)
    # the held-out part's filters start from the state the law reaches on the logged samples
    # before it, not from zero: its command rebuilds from its first sample
    for part in (fitted, held):
        np.testing.assert_allclose(rebuilt_command(part), part.inputs["V"], rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def pd_late(tmp_path_factory):
    # the lab's PD with its command 5 ms late inside the loop (2.5 samples), the delay fitted
    return pd_log(tmp_path_factory.mktemp("pd-late"), seed=1, delay=0.005, free_delay=(0.0, 0.02))


def test_a_delay_inside_the_loop_moves_the_closed_loop_replay(pd_late):
    experiment = load_experiment(pd_late)
    assert experiment.free_starts() == {"loop.delay": experiment.loop.free_delay}
    assert experiment.loop.free_delay.bounds == (0.0, 0.02)
    target = target_for(plant="qube-servo-3")
    found = {}
    with open_session(target) as session:
        for delay in (0.0, 0.005, 0.01):
            found[delay] = compare(experiment, simulate(session, target, experiment, {"pd.loop.delay": delay}))
    # at the true delay the loop closed again (on counted angles) is within 2 quanta RMS on both
    # angles; at none or twice it, several times further off
    for name in ("theta0", "theta1"):
        assert found[0.005][name]["rms"] < 2.0 * found[0.005][name]["quantum"], found[0.005][name]
        assert found[0.0][name]["rms"] > 2.0 * found[0.005][name]["rms"], (name, found)
        assert found[0.01][name]["rms"] > 4.0 * found[0.005][name]["rms"], (name, found)


def test_a_loop_s_fitted_delay_replays_open_loop_parts_at_the_fit_s_value(pd_late):
    # a closed-loop log replayed open loop on its logged command (a swing-up's way, and a
    # segment's) carries the loop's free delay as the same unknown, loop.delay
    from furuta_cosim.identify.split import delayed

    experiment = load_experiment(pd_late)
    opened = delayed(experiment)
    assert opened.loop is None and list(opened.free_starts()) == ["loop.delay"]
    logged = experiment.inputs["V"]
    np.testing.assert_allclose(opened.input_at("V", {"pd.loop.delay": 0.004})[2:], logged[:-2], rtol=0, atol=1e-12)
    half = opened.input_at("V", {"pd.loop.delay": 0.005})
    np.testing.assert_allclose(half[3:], 0.5 * (logged[:-3] + logged[1:-2]), rtol=0, atol=1e-12)


def test_a_validation_log_shares_the_fitted_logs_delay(tmp_path):
    from furuta_cosim.identify.problem import shared_values, with_shared

    fitted = load_experiment(chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=4, name="a", duration=0.5))
    other = load_experiment(chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=5, name="b", duration=0.5))
    stated = load_experiment(chirp_log(tmp_path, delay=0.012, seed=6, name="c", duration=0.5))
    shares = shared_values([fitted], [fitted, other, stated])
    assert shares == {"b.V.delay": ["a.V.delay"]}   # a stated delay stays as stated
    assert with_shared({"a.V.delay": 0.0121, "R_a": 7.5}, shares)["b.V.delay"] == 0.0121


@pytest.mark.slow
def test_a_held_out_chirp_is_scored_at_the_fitted_delay_and_replay_uses_it(tmp_path, capsys):
    fitted = chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=4, name="a", duration=3.0)
    held = chirp_log(tmp_path, delay=0.012, free_delay=(0.0, 0.02), seed=5, name="b", duration=3.0)
    spec = _spec(tmp_path, fitted, {"R_a": (9.0, 1.0, 30.0)}, validation=f"[{held.name}]")
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles")
    assert code == 0, (out, err)
    document = json.loads((tmp_path / "fit" / "fit.json").read_text())
    delay = document["parameters"]["a.V.delay"]["value"]
    assert abs(delay - 0.012) < 0.001
    assert document["shared"] == {"b.V.delay": {"value": delay, "from": ["a.V.delay"]}}
    # scored at 12 ms, the held-out chirp is within 2 quanta on both angles (at its start, 0 ms,
    # it was tens of quanta off)
    for name in ("theta0", "theta1"):
        scored = document["validation"]["b"][name]
        assert scored["rms"] < 2.0 * scored["quantum"], scored
        assert document["at_start"]["b"][name]["rms"] > 5.0 * scored["rms"]
    # replay on the fitted plant takes the fitted delay, and says so
    code, out, err = run_cli(capsys, "replay", str(held), "--plant", str(tmp_path / "fit" / "plant.yaml"), "--json")
    replayed = json.loads(out)
    assert replayed["values"] == {"b.V.delay": pytest.approx(delay, abs=1e-15)}
    assert any("b: its V.delay at" in note and "fitted on a.V.delay" in note for note in replayed["notes"])
    assert replayed["experiments"]["b"]["outputs"]["theta0"]["rms"] == pytest.approx(
        document["validation"]["b"]["theta0"]["rms"], rel=1e-9)


def test_a_topic_that_starts_late_names_the_first_row_with_every_value(tmp_path):
    # a ROS log whose command topic's first message comes after the angles' (fill: true given):
    # the refusal names the first row where every column read has a value, not "fill: true"
    path = chirp_log(tmp_path, delay=0.0, seed=1, jitter=True, name="ros", duration=0.5)
    csv = path.parent / "ros.csv"
    lines = csv.read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    for row in rows[:7]:   # the V cells of the first rows emptied
        row[1] = ""
    first = next(k for k, row in enumerate(rows) if k >= 7 and row[1] not in ("", "nan"))
    csv.write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    text = str(error.value)
    assert "column V: no value yet" in text and "fill: true carries a value forward, never back" in text, text
    found = re.search(r"is line (\d+) \(t = ([0-9.e+-]+) s\): start the window there", text)
    assert found and int(found.group(1)) >= first + 2, (first, text)
    # and the window it names loads
    data = yaml.safe_load(path.read_text())
    data["window"] = [float(found.group(2)), 0.5]
    path.write_text(yaml.safe_dump(data))
    assert float(found.group(2)) <= load_experiment(path).t[0] < float(found.group(2)) + 0.005


def test_a_balancing_log_s_free_loop_delay_is_refused_with_why(pd_late, tmp_path, capsys):
    # its replay closes the loop through the smoother's angles, which hide the delay: the fit
    # found 3.99 ms for 5 on ten seeds with 0.04 ms intervals (tools/bench_loop.py): refused
    for name in ("pd.yaml", "pd.csv"):
        (tmp_path / name).write_bytes((pd_late.parent / name).read_bytes())
    spec = _spec(tmp_path, tmp_path / "pd.yaml", {"R_a": (9.0, 1.0, 30.0)})
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles")
    assert code == 2, (out, err)
    assert f"{tmp_path / 'pd.yaml'}: loop.delay: a balancing log is replayed through the angles its smoother estimates" in err
    assert "state the delay (a number of seconds)" in err and not (tmp_path / "fit" / "fit.json").exists()
