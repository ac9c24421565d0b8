"""The smoother a balancing fit runs once per simulation (furuta_cosim/identify/estimate.py):
its pass (the Kalman filter forward, the smoother's gains back) against the same pass one
sample at a time, on a synthetic 10 s balancing log at 500 Hz on the plant linearized at its
truth, on one BLAS thread as identify's worker processes run it, from a diffuse start (gains that settle over hundreds of samples: a window cut mid-run)
and from a settled one (a whole log). Best of ``--repeat``; the largest difference between
the two, relative to each state's largest value.

    python tools/bench_smoother.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def pass_by_sample(Ad, C, gains, smoothers, start, y, known):
    """The baseline: the Kalman filter and the smoother's gains back, one sample at a time in
    Python, as the pass is defined (tests/test_balancing.py checks the pass against it)."""
    N, n = len(y), Ad.shape[0]
    predicted, filtered = np.zeros((N, n)), np.zeros((N, n))
    x = start
    for k in range(N):
        predicted[k] = x
        filtered[k] = x + gains[min(k, len(gains) - 1)] @ (y[k] - C @ x)
        x = Ad @ filtered[k] + known[k]
    smoothed = filtered.copy()
    for k in range(N - 2, -1, -1):
        smoothed[k] = filtered[k] + smoothers[min(k, len(smoothers) - 1)] @ (smoothed[k + 1] - predicted[k + 1])
    return smoothed


def _best(run, repeat: int) -> tuple[float, np.ndarray]:
    times = []
    for _ in range(repeat):
        clock = time.perf_counter()
        out = run()
        times.append(time.perf_counter() - clock)
    return min(times), out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()

    from threadpoolctl import threadpool_limits

    from furuta_cosim.identify.estimate import _gains, _pass, _setup
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.identify.synthetic import balancing_log

    with tempfile.TemporaryDirectory() as scratch:
        experiment = load_experiment(balancing_log(Path(scratch) / "log", seed=0))
        m = _setup(experiment, target_for(plant="qube-servo-3"), {})
    Ad, C, y, N = m["Ad"], m["C"], m["y"], m["N"]
    known = np.random.default_rng(0).standard_normal((N, Ad.shape[0])) * 1e-3
    start = np.linalg.lstsq(C, y[0], rcond=None)[0]
    threadpool_limits(1)   # as in the fit's workers (furuta_cosim/cosim/worker.py)
    print(f"smoother pass over {N} samples, {Ad.shape[0]} states, best of {args.repeat}")
    for name, diffuse in (("diffuse start", True), ("settled start", False)):
        gains, smoothers = _gains(Ad, C, m["Q"], m["R"], m["steady"], N, diffuse=diffuse)
        base, slow = _best(lambda: pass_by_sample(Ad, C, gains, smoothers, start, y, known), args.repeat)
        took, fast = _best(lambda: _pass(Ad, C, gains, smoothers, start, y, known), args.repeat)
        apart = float(np.max(np.abs(fast - slow) / (np.max(np.abs(slow), axis=0) + 1e-12)))
        print(f"{name}: {len(gains)} samples with gains of their own; one sample at a time "
              f"{base * 1e3:.1f} ms, the pass {took * 1e3:.1f} ms ({base / took:.1f}x faster); "
              f"apart {apart:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
