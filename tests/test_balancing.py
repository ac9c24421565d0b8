"""Balancing logs: fitted with the loop in the replay (a controller file of ours or a law from
another tool), by multiple shooting when no controller is known, validated on held-out data,
and every fit judged before its plant file is written (identify/verdict.py)."""

import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.synthetic import balancing_log, truth
from furuta_cosim.identify.verdict import judge

from helpers import run_cli

QUANTUM = 2 * math.pi / 2048
TRUE = truth()
PD = ([-1.0, -1.2, 34.0, 3.0], -1.0)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A 6 s balancing log of the QUBE under lqr-qube (one-sample delay, 10 V limit, the arm on
    a square wave), its virtual board's own record of the true angles, and a PD-law log."""
    root = tmp_path_factory.mktemp("balancing")
    lqr = balancing_log(root / "lqr", seed=0, duration=6.0, board_log=root / "board.csv")
    pd = balancing_log(root / "pd", seed=1, duration=6.0, law=PD, amplitude=0.2, period=3.0)
    return {"lqr": lqr, "pd": pd, "board": root / "board.csv"}


def _spec(folder: Path, experiment: Path, free=("R_a", "M_f"), off: float = 0.3, **extra) -> Path:
    spec = {"name": "balancing", "plant": "qube-servo-3", "experiments": [str(experiment)],
            "free": {n: {"start": TRUE[n] * (1 + off), "bounds": [TRUE[n] / 10, TRUE[n] * 10]} for n in free}}
    spec.update(extra)
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _rewritten(experiment: Path, folder: Path, change) -> Path:
    """A copy of ``experiment`` (beside its log) with ``change(data)`` applied."""
    data = yaml.safe_load(experiment.read_text())
    change(data)
    data["data"] = str(experiment.parent / data["data"])
    if "controller" in data.get("loop", {}):
        data["loop"]["controller"] = str(experiment.parent / data["loop"]["controller"])
    path = folder / f"{experiment.parent.name}-changed.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _true_angles(experiment, board_path: Path) -> np.ndarray:
    """The virtual board's true angles at the experiment's samples (its clock starts before
    the run: its first applied volt is the run's first command, one delay after t = 0)."""
    board = np.loadtxt(board_path, delimiter=",", skiprows=1)
    first = board[np.argmax(board[:, 2] != 0.0), 0] - experiment.loop.delay
    rows = np.searchsorted(board[:, 0], experiment.t + first - 0.0005 - 1e-9)
    return board[rows][:, 5:7]


def test_the_smoother_knows_a_window_cut_mid_run_from_its_first_sample(logs, tmp_path):
    """A window cut mid-motion starts the smoother with no knowledge of its rates (a diffuse
    start, time-varying gains until they settle): over its first 50 ms its angles are within a
    fraction of a quantum of the truth (measured 0.03 and 0.07; with the settled gains from the
    first sample the pendulum's was 0.4 quanta RMS off, 1.0 over the first 25 samples of a
    window of the 10 s log)."""
    from furuta_cosim.identify.estimate import estimated_noise
    from furuta_cosim.identify.replay import target_for

    path = _rewritten(logs["lqr"], tmp_path, lambda d: (
        d.update(window=[2.0, 6.0]), d["start"].update(i="data", dtheta0="data", dtheta1="data")))
    experiment = load_experiment(path)
    assert experiment.loop.lead_in is not None
    true = _true_angles(experiment, logs["board"])
    counts = np.column_stack([experiment.outputs["theta0"].values, experiment.outputs["theta1"].values])
    estimate = counts - np.column_stack(estimated_noise(experiment, target_for(plant="qube-servo-3"), {}))
    first = slice(0, 25)
    smoothed = np.sqrt(np.mean((estimate[first] - true[first]) ** 2, axis=0)) / QUANTUM
    assert np.all(smoothed < 0.25), smoothed


def test_the_start_covariance_is_the_smoother_s_own(logs):
    """The smoothed covariance at a log's first sample (the rates a window's reach rests on) is
    the Rauch-Tung-Striebel recursion's over the whole log, taken from its settled value: the
    same to 1e-6 as the recursion run over every sample; the angles known better than a count's
    rounding, the rates to a few hundredths of a rad/s."""
    from furuta_cosim.identify import estimate
    from furuta_cosim.identify.replay import target_for

    experiment = load_experiment(logs["lqr"])
    target = target_for(plant="qube-servo-3")
    states, S = estimate.start_covariance(experiment, target, {})
    m = estimate._setup(experiment, target, {})
    Ad, C, Q, R = m["Ad"], m["C"], m["Q"], m["R"]
    P, afters, followings = estimate.DIFFUSE * m["steady"], [], []
    for _ in range(m["N"]):
        gain = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
        afters.append(P - gain @ C @ P)
        P = Ad @ afters[-1] @ Ad.T + Q
        followings.append(P)
    brute = afters[-1]
    for k in range(m["N"] - 2, -1, -1):
        G = afters[k] @ Ad.T @ np.linalg.inv(followings[k])
        brute = afters[k] + G @ (brute - followings[k]) @ G.T
    np.testing.assert_allclose(S, brute, rtol=1e-6, atol=1e-6 * np.max(np.abs(brute)))
    sigma = dict(zip(states, np.sqrt(np.diag(S))))
    assert sigma["theta0"] < QUANTUM / math.sqrt(12) and sigma["theta1"] < QUANTUM / math.sqrt(12)
    assert 1e-3 < sigma["dtheta0"] < 0.05 and 1e-3 < sigma["dtheta1"] < 0.05, sigma


@pytest.mark.slow
def test_a_balancing_log_is_fitted_with_its_loop_closed(logs, tmp_path, capsys):
    code, out, err = run_cli(capsys, "identify", str(_spec(tmp_path, logs["lqr"])), "-o", str(tmp_path / "fit"),
                             "--no-profiles", "--workers", "1", "--holdout", "0.3")
    assert code == 0, (out, err)
    assert "replayed with its loop closed" in err
    document = yaml.safe_load((tmp_path / "fit" / "fit.json").read_text())
    # started 30 % off, 4.2 s fitted: both within 5 % (measured: -2.2 % and +1.7 %; open loop
    # the same log gives errors of 40 to 110 %, tools/bench_balancing.py)
    assert document["parameters"]["R_a"]["value"] == pytest.approx(TRUE["R_a"], rel=0.05)
    assert document["parameters"]["M_f"]["value"] == pytest.approx(TRUE["M_f"], rel=0.05)
    held = document["validation"]["lqr-held-out"]
    assert held["theta0"]["rms"] < 3 * QUANTUM and held["theta1"]["rms"] < 3 * QUANTUM, held
    assert document["verdict"]["trusted"] and out.strip().splitlines()[-1].startswith("verdict: trusted")
    assert "rejected" not in yaml.safe_load((tmp_path / "fit" / "plant.yaml").read_text())


@pytest.mark.slow
def test_a_balancing_log_run_open_loop_is_not_trusted_and_leaves_no_usable_plant(logs, tmp_path, capsys):
    """The issue's case: a balancing log on its logged voltage alone (an unstable plant run
    open loop): the fit says so last, exits 1, and its plant file is refused until accepted."""
    open_loop = _rewritten(logs["lqr"], tmp_path, lambda d: d.pop("loop"))
    spec = _spec(tmp_path, open_loop, max_simulations=20)
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles",
                             "--workers", "1")
    last = out.strip().splitlines()[-1]
    assert code == 1 and last.startswith("verdict: NOT trusted: "), (code, out, err)
    assert "times its noise floor" in last and "next: " in last
    assert "stopped at max_simulations (20)" in out   # the budget's message is printed
    plant = tmp_path / "fit" / "plant.yaml"
    assert "rejected" in yaml.safe_load(plant.read_text())
    code, out, err = run_cli(capsys, "simulate", "qube-step", "--plant", str(plant))
    assert code == 2 and "untrustworthy" in err and "--accept" in err
    code, out, err = run_cli(capsys, "tune", "effort-qube", "--from-fit", str(tmp_path / "fit" / "fit.json"),
                             "-o", str(tmp_path / "tuned"))
    assert code == 2 and "untrustworthy" in err, err
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles",
                             "--workers", "1", "--accept")
    assert code == 0 and "written all the same" in out
    code, out, err = run_cli(capsys, "simulate", "qube-step", "--plant", str(plant))
    assert "untrustworthy" not in err


def test_the_verdict_names_each_reason():
    document = {"experiments": {"a": {"theta0": {"rms": 0.05, "sigma": 0.00089, "sigma_from": "quantum",
                                                 "quantum": 0.0030679}}},
                "validation": {"b": {"i": {"rms": 0.003, "sigma": 0.004, "sigma_from": "noise"}}},
                "message": "stopped at max_simulations (10) in stage 2/5 (first 1 s)",
                "parameters": {"R_a": {"value": 7.0, "interval": [-488.0, 501.0], "identifiable": True},
                               "C0": {"value": 1e-5, "interval": [-1e-5, 3e-5], "identifiable": True},
                               "a.theta1": {"value": 0.1, "interval": [-1.0, 1.0]}}}
    ranges = {"R_a": (0.0, None, True), "C0": (0.0, None, False)}
    verdict = judge(document, ranges)
    # 0.05 rad is 16.3 quanta: within the default 20; the budget and R_a's interval are not
    assert not verdict["trusted"] and len(verdict["reasons"]) == 2, verdict
    budget, bound = verdict["reasons"]
    assert verdict["outputs"]["a"]["theta0"]["floors"] == pytest.approx(0.05 / 0.0030679)
    assert "max_simulations" in budget and "R_a" in bound and "no R_a" in bound
    assert verdict["notes"] and "C0" in verdict["notes"][0]   # friction may be 0: a note only
    assert judge(document, ranges, tolerance=10)["reasons"][0].startswith("a theta0: replay RMS 0.05 rad")
    document["experiments"]["a"]["theta0"]["rms"] = 0.07   # 22.8 quanta
    reasons = judge(document, ranges)["reasons"]
    assert reasons[0].startswith("a theta0: replay RMS 0.07 rad is 22.8 times its noise floor")
    document["validation"]["b"]["i"]["rms"] = float("nan")   # a NaN replay is a failure, never a pass
    assert any(r.startswith("b (held out) i") for r in judge(document, ranges)["reasons"])


def test_a_law_from_another_tool_closes_the_loop(logs, tmp_path, capsys):
    code, out, err = run_cli(capsys, "replay", str(logs["pd"]), "--plant", "qube-servo-3", "--json")
    assert code == 0, err
    found = yaml.safe_load(out)["experiments"]["pd"]
    assert found["loop"] == "closed"
    # the PD law replays its own log within a quantum on the true plant (measured 0.55, 0.36)
    assert found["outputs"]["theta0"]["rms"] < QUANTUM and found["outputs"]["theta1"]["rms"] < QUANTUM


def test_the_smoother_sees_the_true_angles_better_than_the_counts(logs):
    from furuta_cosim.identify.estimate import estimated_noise
    from furuta_cosim.identify.replay import target_for

    experiment = load_experiment(logs["lqr"])
    true = _true_angles(experiment, logs["board"])
    noise = estimated_noise(experiment, target_for(plant="qube-servo-3"), {})
    counts = np.column_stack([experiment.outputs["theta0"].values, experiment.outputs["theta1"].values])
    estimate = counts - np.column_stack(noise)
    raw = np.sqrt(np.mean((counts - true) ** 2, axis=0)) / QUANTUM
    smoothed = np.sqrt(np.mean((estimate - true) ** 2, axis=0)) / QUANTUM
    assert np.all(raw > 0.25) and np.all(smoothed < 0.5 * raw), (raw, smoothed)   # measured 0.3 vs 0.06


@pytest.mark.parametrize("diffuse", [True, False])
@pytest.mark.parametrize("samples", [1, 2, 5, 50, 700, 3000])
def test_the_smoother_s_blocked_recursions_are_the_sample_by_sample_pass(logs, diffuse, samples):
    """On the plant's own linearization and a log's readings, the smoother in blocks gives what
    it gives one sample at a time (to rounding), from a diffuse start (gains that settle over
    over hundreds of samples: 367 here) or a settled one, on logs of a few samples to thousands."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
    try:
        from bench_smoother import pass_by_sample   # the pass as defined, one sample at a time
    finally:
        sys.path.pop(0)
    from furuta_cosim.identify.estimate import _gains, _pass, _setup
    from furuta_cosim.identify.replay import target_for

    m = _setup(load_experiment(logs["lqr"]), target_for(plant="qube-servo-3"), {})
    y, n = m["y"][:samples], m["Ad"].shape[0]
    gains, smoothers = _gains(m["Ad"], m["C"], m["Q"], m["R"], m["steady"], samples, diffuse=diffuse)
    known = np.random.default_rng(0).standard_normal((samples, n)) * 1e-3
    start = np.linalg.lstsq(m["C"], y[0], rcond=None)[0]
    fast = _pass(m["Ad"], m["C"], gains, smoothers, start, y, known)
    slow = pass_by_sample(m["Ad"], m["C"], gains, smoothers, start, y, known)
    scale = np.max(np.abs(slow), axis=0) + 1e-12
    assert fast.shape == slow.shape
    assert np.max(np.abs(fast - slow) / scale) < 1e-9


def test_the_smoother_s_own_error_is_drawn_from_its_noise_model(logs):
    """A draw of the smoother's error (what it makes of reading noise alone: the reach of a
    balancing fit adds its effect) is reproducible by its seed, another seed another draw, and
    below the counts' own rounding, as the smoother's real error is (on this log: the draws
    0.04 and 0.03 quanta RMS, the real error 0.06, the counts' 0.3)."""
    from furuta_cosim.identify.estimate import noise_draw
    from furuta_cosim.identify.replay import target_for

    experiment = load_experiment(logs["lqr"])
    target = target_for(plant="qube-servo-3")
    first, again, other = (np.column_stack(noise_draw(experiment, target, {}, seed)) for seed in (1, 1, 2))
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, other)
    for draw in (first, other):
        assert draw.shape == (experiment.samples, 2) and np.all(np.isfinite(draw))
        rms = np.sqrt(np.mean(draw ** 2, axis=0)) / QUANTUM
        assert np.all((0.003 < rms) & (rms < 0.5 / math.sqrt(12))), rms


def test_segments_start_from_the_measured_state(logs):
    from furuta_cosim.identify.split import segments, split

    experiment = load_experiment(logs["lqr"])
    parts = segments(experiment, 0.5)
    assert [p.name for p in parts[:2]] == ["lqr@1", "lqr@2"] and len(parts) == 12
    assert sum(p.samples for p in parts) == experiment.samples
    k = parts[0].samples
    assert parts[1].start["theta0"] == experiment.outputs["theta0"].values[k]
    assert all(p.loop is None for p in parts) and parts[1].alias == "lqr"
    fitted, held = split(experiment, 0.25)
    assert fitted.samples + held.samples == experiment.samples and held.name == "lqr-held-out"
    assert held.t[0] == experiment.t[fitted.samples]


@pytest.mark.slow
def test_multiple_shooting_fits_a_log_whose_controller_is_not_known(logs, tmp_path, capsys):
    def shooting(data):
        data["inputs"]["V"]["delay"] = data.pop("loop")["delay"]
        data["segments"] = 0.1
        data["window"] = [0.0, 3.0]

    spec = _spec(tmp_path, _rewritten(logs["lqr"], tmp_path, shooting), free=("R_a",))
    code, out, err = run_cli(capsys, "identify", str(spec), "-o", str(tmp_path / "fit"), "--no-profiles",
                             "--workers", "1", "--json")
    document = yaml.safe_load(out)
    assert code == 1 and document["loops"]["lqr@1"] == "segments", err
    # a fallback, less informed than the loop: within 10 % on 3 s (measured +7 %, its interval
    # too narrow: the rates at each segment's start are estimated from counts); open loop the
    # same log's whole window gives +111 %
    p = document["parameters"]["R_a"]
    assert p["value"] == pytest.approx(TRUE["R_a"], rel=0.1), p
    # every segment replays, but the log run through as `replay` runs it (open loop: the
    # pendulum falls) does not: not a plant to trust for this log
    assert not document["verdict"]["trusted"]
    assert any(r.startswith("lqr theta1: replayed whole as `replay` runs it") for r in document["verdict"]["reasons"])
    assert document["whole"]["lqr"]["theta1"]["rms"] > 0.1   # rad: fallen
    # the log read as one: its figures (the 30 segments one after the other), its verdict's
    # outputs per log with the segments' median and worst, one printed line per log and output
    assert document["figures"] == ["lqr-overlay.png", "lqr-residuals.png"]
    assert sorted(p.name for p in (tmp_path / "fit").glob("*.png")) == ["lqr-overlay.png", "lqr-residuals.png"]
    theta0 = document["verdict"]["outputs"]["lqr"]["theta0"]
    assert theta0["segments"]["count"] == 30 and theta0["segments"]["worst"] >= theta0["segments"]["median"]
    assert not any("@" in name for name in document["verdict"]["outputs"])


@pytest.mark.parametrize("change, key, words", [
    (lambda d: d["loop"].update(law={"K": [1, 2, 3, 4]}), "loop", "one of them"),
    (lambda d: d["loop"].update(law={"K": [1, 2, 3]}) or d["loop"].pop("controller"), "loop.law.K", "4 gains"),
    (lambda d: d["loop"].update(law={"K": [1, 2, 3, 4], "period": 0.001}) or d["loop"].pop("controller"),
     "loop.law.period", "0.002 s apart"),
    (lambda d: d["loop"].update(delay=1.0), "loop.delay", "more than 10 samples"),
    (lambda d: d["loop"].update(feedforward="nope"), "loop.feedforward", "not one of columns"),
    (lambda d: d.update(segments=0.001), "segments", "shorter than 3 samples"),
    (lambda d: d["inputs"]["V"].update(delay=-1), "inputs.V.delay", "is loop.delay"),
    (lambda d: d["inputs"]["V"].update(delay=0.002), "inputs.V.delay", "is loop.delay"),
    (lambda d: d["loop"].update(delay={"free": [0.0, 0.5]}), "loop.delay.free", "more than 10 samples"),
    (lambda d: d["loop"].update(delay={"free": [0.01, 0.002]}), "loop.delay.free", "0 <= lo < hi"),
    (lambda d: d["loop"].update(delay={"fixed": 0.01}), "loop.delay.fixed", "unknown key (expected one of: free)"),
])
def test_a_loop_that_cannot_be_closed_is_refused_with_its_key(logs, tmp_path, change, key, words):
    with pytest.raises(ConfigError) as caught:
        load_experiment(_rewritten(logs["lqr"], tmp_path, change))
    text = str(caught.value)
    assert f": {key}: " in text and words in text, text


@pytest.mark.parametrize("extra, key", [({"holdout": 2}, "holdout"), ({"tolerance": -1}, "tolerance"),
                                        ({"tolerance": "many"}, "tolerance")])
def test_a_spec_with_a_bad_verdict_setting_is_refused(logs, tmp_path, extra, key):
    from furuta_cosim.identify.spec import load_identify_spec

    with pytest.raises(ConfigError, match=f"spec.yaml: {key}: "):
        load_identify_spec(_spec(tmp_path, logs["lqr"], **extra))


def test_a_held_out_log_must_be_named_apart(logs, tmp_path, capsys):
    shutil.copy(logs["lqr"], tmp_path / "lqr.yaml")
    code, out, err = run_cli(capsys, "identify", str(_spec(tmp_path, logs["lqr"])), "-o", str(tmp_path / "fit"),
                             "--validate", str(logs["lqr"]))
    assert code == 2 and "two experiments are named lqr" in err, err
