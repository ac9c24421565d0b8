"""A replay's closed loop in C equals the Python loop, which stays the reference, within 1e-12
on every kind of log it takes (a controller file's law, a law in the logger's words, a delay of
whole samples and of a part of one, a window cut mid-run, the encoders' rounding or a balancing
log's smoother, a voltage limit); every other kind runs the Python loop."""

from __future__ import annotations

import numpy as np
import pytest

from furuta_cosim.identify.estimate import with_estimate
from furuta_cosim.identify.experiment import load_experiment
from furuta_cosim.identify.replay import closed_loop, open_session, target_for

TOLERANCE = 1e-12


@pytest.fixture(scope="module")
def target():
    return target_for(plant="qube-servo-3")


def _both(target, experiment, monkeypatch, values=None, phase=0.0):
    """(the C loop's outputs and volts, the Python loop's), and whether C ran."""
    from furuta_cosim.identify import native

    ran = []
    real = native.replay_in_c

    def spy(*args, **kwargs):
        found = real(*args, **kwargs)
        ran.append(found is not None)
        return found

    monkeypatch.setattr(native, "replay_in_c", spy)
    with open_session(target) as session:
        fast = closed_loop(session, target, experiment, values, phase=phase)
        monkeypatch.setenv(native.OFF, "1")
        slow = closed_loop(session, target, experiment, values, phase=phase)
        monkeypatch.delenv(native.OFF)
    return fast, slow, ran[0]


def _same(fast, slow) -> None:
    (outputs, volts), (reference, reference_volts) = fast, slow
    assert outputs.keys() == reference.keys()
    for name in outputs:
        scale = max(float(np.max(np.abs(reference[name]))), 1e-9)
        assert np.max(np.abs(outputs[name] - reference[name])) <= TOLERANCE * scale, name
    assert np.max(np.abs(volts - reference_volts)) <= TOLERANCE * max(float(np.max(np.abs(reference_volts))), 1e-9)


@pytest.mark.parametrize("case", ["controller", "law", "window", "late delay"])
def test_the_c_loop_is_the_python_loop_on_a_balancing_log(tmp_path, target, monkeypatch, case):
    from furuta_cosim.identify.synthetic import balancing_log

    import yaml

    options = {"controller": {}, "law": {"law": ([-1.0, -1.2, 34.0, 3.0], -1.0)},
               "window": {}, "late delay": {"delay": 0.0033}}[case]
    path = balancing_log(tmp_path / "log", seed=2, duration=6.0, **options)
    if case == "window":   # cut mid-run: the loop runs over the rows before it first (its lead-in)
        document = yaml.safe_load(path.read_text())
        document["window"] = [2.0, 5.0]
        document["start"].update(i="data", dtheta0="data", dtheta1="data")
        path.write_text(yaml.safe_dump(document))
    experiment = with_estimate(load_experiment(path), target)
    assert (experiment.loop.lead_in is not None) == (case == "window")
    fast, slow, ran = _both(target, experiment, monkeypatch)
    assert ran, case
    _same(fast, slow)
    assert np.all(np.isfinite(fast[1])) and np.max(np.abs(fast[1])) > 0.01   # a loop that moved


def test_the_c_loop_is_the_python_loop_through_the_encoders_and_a_limit(tmp_path, target, monkeypatch):
    """A log whose angles are not estimated: the controller sees the simulated angles rounded
    to counts (at two phases of the encoders' zero), its command clipped."""
    from dataclasses import replace

    from furuta_cosim.identify.synthetic import balancing_log

    experiment = load_experiment(balancing_log(tmp_path / "log", seed=4, duration=4.0))
    experiment = replace(experiment, loop=replace(experiment.loop, estimate=False, voltage=0.5))
    for phase in (0.0, 0.5):
        fast, slow, ran = _both(target, experiment, monkeypatch, phase=phase)
        assert ran
        _same(fast, slow)
        assert np.max(np.abs(fast[1])) == pytest.approx(0.5)                 # the limit was reached


def test_a_free_delay_at_a_fitted_value_and_a_lab_s_pd(tmp_path, target, monkeypatch):
    """A lab's errors-PD in its own words (a law with its derivative's state), its loop delay
    free and replayed where a fit would put it (a part of a sample)."""
    from furuta_cosim.identify.foreign import pd_log

    experiment = with_estimate(load_experiment(pd_log(tmp_path / "pd", duration=4.0, delay=0.005,
                                                      free_delay=(0.0, 0.01))), target)
    for seconds in (0.0, 0.0047, 0.008):
        fast, slow, ran = _both(target, experiment, monkeypatch, values={"pd.loop.delay": seconds})
        assert ran
        _same(fast, slow)


def test_a_jittered_clock_and_a_rig_s_late_samples(tmp_path, target, monkeypatch):
    """The loop as it ran: a PD logged on a jittered clock (1.5 to 4.8 ms), and a balancing run
    on the virtual board whose samples wake up to 2 ms late (its late and compute columns): the
    plant stepped to each reading, each command switched in when it arrived."""
    from furuta_cosim.cli import main
    from furuta_cosim.identify.foreign import pd_log

    jittered = with_estimate(load_experiment(pd_log(tmp_path / "pd", duration=3.0, jitter=True)), target)
    assert jittered.jittered
    out = tmp_path / "late"
    assert main(["rig", "run", "lqr-qube", "--board", "virtual:fast,upright=0.05,late=0.002", "--duration", "3",
                 "-o", str(out)]) == 0
    late = with_estimate(load_experiment(out / "experiment.yaml"), target)
    assert late.late is not None and np.max(late.late) > 0.0005
    for experiment in (jittered, late):
        fast, slow, ran = _both(target, experiment, monkeypatch)
        assert ran, experiment.name
        _same(fast, slow)


def test_a_swing_up_runs_the_python_loop(tmp_path, target, monkeypatch):
    """A swing-up switches between its modes (a rule, not a matrix): the Python loop, with the
    same result as with the C loop switched off."""
    from furuta_cosim.cli import main

    out = tmp_path / "swing"
    assert main(["rig", "run", "swingup-qube", "--board", "virtual:fast", "--duration", "3", "-o", str(out)]) in (0, 1)
    experiment = load_experiment(out / "experiment.yaml")
    fast, slow, ran = _both(target, experiment, monkeypatch)
    assert not ran
    assert all(np.array_equal(fast[0][n], slow[0][n]) for n in fast[0]) and np.array_equal(fast[1], slow[1])
