"""The constrained Bayesian optimizer: it learns where feasibility lies, each proposal is a
function of the history before its batch, the trust region follows TuRBO's rule, points go
out as soon as they are known, and the optimizer runs on one BLAS thread."""

import dataclasses
import math
import statistics

import numpy as np
import pytest

from furuta_cosim.tuning import bayesopt, run
from furuta_cosim.tuning.executors import Serial
from furuta_cosim.tuning.bayesopt import (ConstrainedBO, RandomSearch, batches, latin_hypercube,
                                            _region, _weights)
from furuta_cosim.tuning.spec import load_spec

BOUNDS = [(0.0, 1.0)] * 4
TARGET = np.array([0.2, 0.3, 0.5, 0.5])
OPTIMUM = 0.125  # the constrained minimum: x0 + x1 = 1 nearest to (0.2, 0.3)
PENALTY = 1000.0


def outcome(index, x, origin="", surrogate=None):
    """A made-up evaluation: f = |x - TARGET|^2 subject to x0 + x1 >= 1 (margin 1 - x0 - x1)."""
    x = [float(v) for v in x]
    value = float(np.sum((np.array(x) - TARGET) ** 2))
    margin = 1.0 - x[0] - x[1]
    feasible = margin <= 0
    return {"index": index, "x": x, "value": value, "margin": max(-1.0, min(1.0, margin)),
            "feasible": feasible, "objective": value if feasible else PENALTY + margin,
            "origin": origin, "surrogate": surrogate}


def constrained_run(seed, calls=36, batch=2, region="trust", design=10):
    bo = ConstrainedBO(BOUNDS, seed, xi=0.01, n_initial_points=design, batch=batch, region=region)
    records = [outcome(k, x) for k, x in enumerate(latin_hypercube(design, BOUNDS, seed))]
    for number, first, count in batches(design, batch, calls):
        proposal = bo.propose(records[:first], design, number)
        for x in proposal.points(count):
            records.append(outcome(len(records), x, proposal.origin, proposal.surrogate))
    return records


def best(records):
    return min((r["objective"] for r in records if r["feasible"]), default=math.inf)


@pytest.mark.slow
@pytest.mark.parametrize("region", ["trust", "global"])
def test_infeasible_points_teach_where_feasibility_lies(region):
    """Over 12 seeds: most proposals after the design are feasible on every seed, the median
    best is close to the constrained optimum on a boundary (within 5 % in the trust region,
    25 % globally: measured 2.7 % and 11 %), and the best beats random search at the same
    budget at the median and on at least 10 seeds (measured 11 and 12). A seed's own best
    rests on the GP's rounding (one trust-region seed ends 3.3x the optimum), so no single
    seed is asked to be close."""
    gaps, wins = [], 0
    for seed in range(12):
        records = constrained_run(seed, region=region)
        proposed = records[10:]
        assert sum(r["feasible"] for r in proposed) >= 0.6 * len(proposed)
        sampler = RandomSearch(BOUNDS, seed)
        randoms = [outcome(k, sampler.point(k)) for k in range(len(records))]
        gaps.append(best(records) / OPTIMUM - 1)
        wins += best(records) < best(randoms)
    assert statistics.median(gaps) <= (0.05 if region == "trust" else 0.25)
    assert wins >= 10


def test_a_proposal_depends_only_on_the_history_before_its_batch():
    records = constrained_run(0, calls=20)
    bo = ConstrainedBO(BOUNDS, 0, xi=0.01, n_initial_points=10, batch=2)
    first = bo.propose(records[:14], 10, 2)
    again = bo.propose(records[:14], 10, 2)
    assert first.surrogate == again.surrogate
    points = list(first.points(3))
    assert list(again.points(2)) == points[:2]  # the batch's size changes only its tail
    assert points[:2] == [r["x"] for r in records[14:16]]
    # the hyperparameters of the batch before are where the next refit starts: recorded
    assert records[14]["surrogate"]["feasibility"] and len(records[14]["surrogate"]["feasibility"]) == 6
    assert len(records[14]["surrogate"]["region"]) == bayesopt.LANES == 2  # each region's side


def test_the_trust_region_doubles_on_success_and_halves_on_failure():
    def record(index, value):
        return {"index": index, "x": [0.5] * 4, "feasible": True, "objective": value}

    design = [record(0, 10.0)]
    improving = design + [record(k, 10.0 - k) for k in range(1, 4)]
    assert _region(improving, 1, 1, 4)[0] == pytest.approx(2 * bayesopt.REGION_START)
    stalling = design + [record(k, 10.0) for k in range(1, 5)]  # patience max(4, d) / batch = 4
    assert _region(stalling, 1, 1, 4)[0] == pytest.approx(bayesopt.REGION_START / 2)
    length, incumbent = _region(stalling[:3], 1, 1, 4)
    assert length == bayesopt.REGION_START and incumbent["index"] == 0


def test_the_second_region_follows_its_own_points_from_the_warm_start():
    """Record k of the batches belongs to region (k - start) % 2: the first is centered on
    the best of all, the second on the best of its own points and the run's first point
    (the warm start), and each grows or shrinks on its own points' progress."""
    def record(index, value, x):
        return {"index": index, "x": [x] * 4, "feasible": True, "objective": value}

    records = [record(0, 10.0, 0.1), record(1, 9.5, 0.9)]  # the design: warm start, then another
    for k in range(3):  # region 0's points improve, region 1's do not
        records += [record(2 + 2 * k, 9.0 - k, 0.8), record(3 + 2 * k, 11.0, 0.2)]
    length, incumbent = _region(records, 2, 2, 4)
    assert incumbent["objective"] == 7.0 and length == pytest.approx(2 * bayesopt.REGION_START)
    length, own = _region(records, 2, 2, 4, 1, 2)  # patience max(4, d) / batch = 2 failures
    assert own["index"] == 0 and length == pytest.approx(bayesopt.REGION_START / 2)
    records += [record(8, 12.0, 0.8), record(9, 9.0, 0.15)]  # region 1 improves: its new center
    assert _region(records, 2, 2, 4, 1, 2)[1]["index"] == 9


def test_one_long_length_scale_stretches_the_first_region_but_not_the_second():
    """TuRBO's weights make the first region's side as long as the box along a coordinate
    the objective hardly depends on; the second region's sides are at most its length, so it
    stays around the basin it follows."""
    scales = [8.0, 0.5, 0.5, 0.5]
    first, second = _weights(scales), _weights(scales, bayesopt.OWN_WIDEST)
    assert np.prod(first) == pytest.approx(1.0) and first[0] == pytest.approx(8.0)
    assert second == pytest.approx([bayesopt.OWN_WIDEST, 0.5, 0.5, 0.5], rel=1e-12)
    bo = ConstrainedBO(BOUNDS, 0, xi=0.01, n_initial_points=4, batch=2)
    center, length = np.array([0.05, 0.5, 0.5, 0.5]), 0.4
    for weights, reach in ((first, 1.0), (second, 0.05 + 0.5 * length * bayesopt.OWN_WIDEST)):
        C = bo._candidates(center, length, weights, np.random.default_rng(1), 4096)
        assert C[:, 0].max() == pytest.approx(reach, abs=0.01) and C[:, 0].max() <= reach
        assert np.all(np.abs(C[:, 1:] - 0.5) <= 0.5 * length * 0.5 + 1e-12)


def test_the_initial_design_is_a_seeded_latin_hypercube_inside_the_bounds():
    bounds = [(-1.0, 2.0), (0.0, 10.0)]
    points = np.array(latin_hypercube(8, bounds, 5))
    assert points.shape == (8, 2) and np.array_equal(points, latin_hypercube(8, bounds, 5))
    for j, (low, high) in enumerate(bounds):
        # one point in each eighth of every dimension
        assert sorted(np.floor((points[:, j] - low) / (high - low) * 8).astype(int)) == list(range(8))
    assert not np.array_equal(points, latin_hypercube(8, bounds, 6))


@pytest.mark.slow
def test_each_point_of_a_batch_is_sent_before_the_next_is_computed(tmp_path, monkeypatch):
    events = []

    class Recording(Serial):
        def submit(self, x, order=None):
            events.append("submit")
            return super().submit(x, order)

        def gather(self, pending):
            events.append("gather")
            return super().gather(pending)

    propose = ConstrainedBO.propose

    def recorded(self, *args):
        events.append("fit")
        proposal = propose(self, *args)
        inner = proposal._next

        def next_point():
            events.append("point")
            return inner()

        proposal._next = next_point
        return proposal

    monkeypatch.setattr(ConstrainedBO, "propose", recorded)
    monkeypatch.setattr(run, "executor_for", lambda spec, evaluator, workers, dask: Recording(spec, evaluator))
    spec = load_spec("paper-spectral")
    spec = dataclasses.replace(spec, baselines=(), optimizer=dataclasses.replace(
        spec.optimizer, batch=2, n_initial_points=4))
    run.tune(spec, tmp_path / "run", n_calls=8)
    # the design (4 points) goes out at once; then each batch's first point goes out before
    # the second is computed
    assert events == ["submit"] * 4 + ["gather"] + \
        ["fit", "point", "submit", "point", "submit", "gather"] * 2


@pytest.mark.slow
def test_the_optimizer_runs_on_one_blas_thread_serial_too(tmp_path, monkeypatch):
    from threadpoolctl import threadpool_info, threadpool_limits

    seen = []
    propose = ConstrainedBO.propose

    def recorded(self, *args):
        seen.extend(pool["num_threads"] for pool in threadpool_info())
        return propose(self, *args)

    monkeypatch.setattr(ConstrainedBO, "propose", recorded)
    with threadpool_limits(2):                   # whatever the caller allows
        run.tune(load_spec("paper-spectral"), tmp_path / "run", n_calls=12)
    assert seen and set(seen) == {1}


def test_the_convergence_figure_shows_each_baselines_level(tmp_path, monkeypatch):
    from furuta_cosim.report import figures

    drawn = {}
    monkeypatch.setattr(figures, "_save", lambda figure, path, dpi: drawn.setdefault("figure", figure) and [])
    records = [{"index": k, "objective": v, "feasible": v < 100} for k, v in enumerate([3.0, 1000.5, 2.0])]
    figures.plot_convergence(records, tmp_path / "c", {"lqr-paper": 2.5})
    axis = drawn["figure"].axes[0]
    levels = [line for line in axis.get_lines() if line.get_label() == "lqr-paper (scored alike)"]
    assert len(levels) == 1 and list(levels[0].get_ydata()) == [2.5, 2.5]


def test_the_convergence_figure_is_scaled_to_the_gain_and_shows_infeasible_points_by_margin(tmp_path, monkeypatch):
    """A 2.4 % gain over the LQR fills the axis (one feasible point at 3.8 does not flatten it),
    and the infeasible points sit on an axis of their own, by how far they broke a constraint."""
    from furuta_cosim.report import figures

    drawn = {}
    monkeypatch.setattr(figures, "_save", lambda figure, path, dpi: drawn.setdefault("figure", figure) and [])
    objectives = [3.8, 1.09, 1.08, 1.0735, 1.2, 1.074]
    records = [{"index": k, "objective": v, "feasible": True, "margin": -0.1} for k, v in enumerate(objectives)]
    records += [{"index": 6, "objective": 9.0, "feasible": False, "margin": 0.4}]
    figures.plot_convergence(records, tmp_path / "c", {"lqr": 1.1})
    top, below = drawn["figure"].axes
    low, high = top.get_ylim()
    assert 1.0735 - 0.01 < low < 1.0735 and 1.1 < high < 1.2  # the gain is most of the axis
    above = [line for line in top.get_lines() if line.get_label().startswith("feasible, above")]
    assert len(above) == 1 and list(above[0].get_ydata()) == [high, high]  # 3.8 and 1.2, on the edge
    crosses = [line for line in below.get_lines() if line.get_label() == "infeasible evaluation"]
    assert list(crosses[0].get_xdata()) == [6] and list(crosses[0].get_ydata()) == [0.4]


