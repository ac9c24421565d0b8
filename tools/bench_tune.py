"""What a tuning run costs and what each optimizer finds, measured in one run.

    python tools/bench_tune.py [--seeds 5] [--calls 150] [--skip-default] [--only spectral|effort]
                               [--gp-restarts N] [--ei-starts N] [--blas-threads N] [--effort-seeds N]

- paper-spectral (12 parameters), serial: wall time split into optimizer and evaluation
  time, optimizer seconds per iteration (median, last and mean), for our GP configuration and for
  scikit-optimize's defaults (gp_minimize's: GP with noise fitted, 2 restarts, lbfgs EI);
- best objective over the seeds for bo, bo with skopt's defaults, random and de at the same
  budget, and de with 2,000 evaluations;
- effort (150 calls, 3 scenarios): wall time with 1 worker and with 2, and the speed-up; and
  with 2 workers but scikit-optimize's ask(n) for the batches instead of ours; with
  --effort-seeds N, the 2-worker run over seeds 0..N-1 (wall time and best of each).

The levers, one at a time, against our settings: --gp-restarts (random starts of the GP's
refits, instead of each spec's optimizer.gp_restarts), --ei-starts (L-BFGS starts maximizing
EI), --blas-threads (the optimizer's BLAS threads in the serial paper-spectral runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from furuta_cosim.tuning import optimizers
from furuta_cosim.tuning import run as tuning
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

optimizers_make = optimizers.make


class SkoptDefaults:
    """scikit-optimize's own GP set-up (and its ask(n) for batches), for comparison."""

    def __init__(self, dimensions, method, seed, *, xi, n_initial_points, **ours):
        from skopt import Optimizer

        self.optimizer = Optimizer(dimensions, base_estimator="GP", acq_func="EI",
                                   acq_func_kwargs={"xi": xi}, n_initial_points=n_initial_points,
                                   random_state=seed)

    def batch(self, count):
        yield from self.optimizer.ask(count) if count > 1 else [self.optimizer.ask()]

    def tell(self, xs, ys):
        self.optimizer.tell(xs, ys)

    replay = tell


def skopt_batches(dimensions, method, seed, **settings):
    """Our GP, with scikit-optimize's ask(n) for batches (a copy of the optimizer, refitted,
    then one fit per point): what the batch strategy of BayesOptimizer saves."""
    from skopt import Optimizer

    optimizer = optimizers_make(dimensions, method, seed, **settings)

    def batch(count):
        yield from Optimizer.ask(optimizer, count)

    optimizer.batch = batch
    return optimizer


@contextmanager
def patched(make):
    """tuning runs with optimizers made by ``make``."""
    optimizers.make = make
    try:
        yield
    finally:
        optimizers.make = optimizers_make


def timed_run(spec, folder, **options) -> tuple[dict, list[float], float]:
    """A run, its summary, the optimizer's seconds per iteration, and its wall time."""
    per_iteration = []
    original = tuning._ask_tell

    def measured(spec_, evaluator, executor, history, n_calls, seed, method, batch, clock, progress):
        last = [clock["optimizer"]]

        def report(*args):
            per_iteration.append(clock["optimizer"] - last[0])
            last[0] = clock["optimizer"]

        return original(spec_, evaluator, executor, history, n_calls, seed, method, batch, clock, report)

    tuning._ask_tell = measured
    try:
        started = time.perf_counter()
        document = tune(spec, folder, **options)
        return document, per_iteration, time.perf_counter() - started
    finally:
        tuning._ask_tell = original


@contextmanager
def blas_threads(count: int | None):
    """tuning runs whose optimizer uses ``count`` BLAS threads instead of one (serial runs only:
    the patch would reach forked workers too)."""
    import threadpoolctl

    original = threadpoolctl.threadpool_limits
    if count is not None:
        threadpoolctl.threadpool_limits = lambda limits=None, user_api=None: original(count, user_api)
    try:
        yield
    finally:
        threadpoolctl.threadpool_limits = original


def with_restarts(spec, restarts: int | None):
    """``spec`` with ``restarts`` random starts of the GP's refits (None: as the spec says)."""
    if restarts is None:
        return spec
    return dataclasses.replace(spec, optimizer=dataclasses.replace(spec.optimizer, gp_restarts=restarts))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=150)
    parser.add_argument("--skip-default", action="store_true", help="leave out skopt's defaults (slow)")
    parser.add_argument("--only", choices=("spectral", "effort"), help="run one of the two parts")
    parser.add_argument("--gp-restarts", type=int, help="random starts of each GP refit (default: the spec's)")
    parser.add_argument("--ei-starts", type=int, help="L-BFGS starts maximizing EI (default: "
                        f"{optimizers.ACQUISITION['n_restarts_optimizer']})")
    parser.add_argument("--blas-threads", type=int, help="the optimizer's BLAS threads in paper-spectral (default 1)")
    parser.add_argument("--effort-seeds", type=int, default=1, help="seeds of the 2-worker effort run")
    args = parser.parse_args()
    if args.ei_starts is not None:
        optimizers.ACQUISITION["n_restarts_optimizer"] = args.ei_starts
    print(f"settings: gp_restarts {args.gp_restarts if args.gp_restarts is not None else 'as each spec'}, "
          f"EI {optimizers.ACQUISITION}, optimizer BLAS threads {args.blas_threads or 1}")
    work = Path(tempfile.mkdtemp(prefix="bench-tune-"))
    if args.only != "effort":
        with blas_threads(args.blas_threads):
            spectral_part(args, with_restarts(load_spec("paper-spectral"), args.gp_restarts), work)
    if args.only != "spectral":
        effort_part(args, with_restarts(load_spec("effort"), args.gp_restarts), work)
    print(json.dumps({"work": str(work)}), file=sys.stderr)
    return 0


def spectral_part(args, spectral, work: Path) -> None:
    rows, best = [], {}
    methods = ["bo", "random", "de"] + ([] if args.skip_default else ["bo-skopt-defaults"])
    for method in methods:
        for seed in range(args.seeds):
            folder = work / f"{method}-{seed}"
            if method == "bo-skopt-defaults":
                with patched(SkoptDefaults):
                    document, per, wall = timed_run(spectral, folder, method="bo", n_calls=args.calls, seed=seed)
            else:
                document, per, wall = timed_run(spectral, folder, method=method, n_calls=args.calls, seed=seed)
            best.setdefault(method, []).append(document["best"]["objective"] if document["best"] else None)
            if seed == 0:
                rows.append((method, wall, document["optimizer_seconds"], document["evaluation_seconds"],
                             statistics.median(per) if per else float("nan"), per[-1] if per else float("nan"),
                             statistics.mean(per) if per else float("nan")))
            print(f"  {method} seed {seed}: best {best[method][-1]}, {wall:.1f} s", file=sys.stderr, flush=True)
    de_long, _, de_wall = timed_run(spectral, work / "de-2000", method="de", n_calls=2000, seed=0)

    print(f"paper-spectral, {args.calls} calls, serial (seed 0)")
    print(f"{'method':20s} {'wall s':>8s} {'optimizer s':>12s} {'evaluation s':>13s} {'s/iter median':>14s} "
          f"{'s/iter last':>12s} {'s/iter mean':>12s}")
    for method, wall, optimizer_s, evaluation_s, median, last, mean in rows:
        print(f"{method:20s} {wall:8.1f} {optimizer_s:12.1f} {evaluation_s:13.2f} {median:14.3f} {last:12.3f} "
              f"{mean:12.3f}")
    print(f"\nbest objective over seeds 0..{args.seeds - 1} (lower is better; the paper's objective)")
    for method, values in best.items():
        found = [v for v in values if v is not None]
        print(f"{method:20s} " + " ".join(f"{v:9.3f}" if v is not None else "     none" for v in values)
              + (f"   median {statistics.median(found):.3f}" if found else ""))
    print(f"{'de, 2000 evaluations':20s} {de_long['best']['objective']:9.3f}   ({de_wall:.1f} s)")


def effort_part(args, effort, work: Path) -> None:
    one_doc, _, one = timed_run(effort, work / "effort-1", n_calls=args.calls, workers=1)
    two_doc, _, two = timed_run(effort, work / "effort-2", n_calls=args.calls, workers=2)
    with patched(skopt_batches):
        ask_doc, _, ask = timed_run(effort, work / "effort-2-skopt-ask", n_calls=args.calls, workers=2)
    print(f"\neffort, {args.calls} calls (seed 0)")
    print(f"{'run':36s} {'wall s':>8s} {'optimizer s':>12s} {'waiting s':>10s} {'vs 1 worker':>12s} {'best':>9s}")
    for label, document, wall in (("1 worker", one_doc, one), ("2 workers", two_doc, two),
                                  ("2 workers, skopt's ask(n) batches", ask_doc, ask)):
        found = document["best"]["objective"] if document["best"] else float("nan")
        print(f"{label:36s} {wall:8.1f} {document['optimizer_seconds']:12.1f} "
              f"{document['evaluation_seconds']:10.1f} {one / wall:11.2f}x {found:9.4f}")
    if args.effort_seeds > 1:
        print(f"\neffort, {args.calls} calls, 2 workers, seeds 0..{args.effort_seeds - 1}")
        results = []
        for seed in range(args.effort_seeds):
            document, _, wall = (two_doc, None, two) if seed == 0 else timed_run(
                effort, work / f"effort-2-{seed}", n_calls=args.calls, workers=2, seed=seed)
            results.append(document["best"]["objective"] if document["best"] else float("nan"))
            print(f"seed {seed}: {wall:6.1f} s, best {results[-1]:.4f}", flush=True)
        print(f"median best {statistics.median(results):.4f}")


if __name__ == "__main__":
    sys.exit(main())
