"""What a tuning run costs and what each optimizer finds, measured in one run.

    python tools/bench_tune.py [--seeds 5] [--calls 150] [--skip-default] [--only spectral|effort]
                               [--lever NAME=VALUE ...] [--effort-seeds N]

- paper-spectral (12 parameters), serial: wall time split into optimizer and evaluation
  time, optimizer seconds per iteration (median, last and mean), for our GP configuration and for
  scikit-optimize's defaults (gp_minimize's: GP with noise fitted, 2 restarts, lbfgs EI);
- best objective over the seeds for bo, bo with skopt's defaults, random and de at the same
  budget, and de with 2,000 evaluations;
- effort (150 calls, 3 scenarios): wall time with 1 worker and with 2, and the speed-up; and
  with 2 workers but scikit-optimize's ask(n) for the batches instead of ours; with
  --effort-seeds N, each 2-worker run over seeds 0..N-1 (wall time and best of each).

``--lever NAME=VALUE`` (repeatable) adds a row of bo with our settings but that one, measured in
the same run as ours: ``gp_restarts`` (random starts of each GP refit, instead of the spec's
optimizer.gp_restarts), ``ei_starts`` (L-BFGS starts maximizing EI) and ``blas_threads`` (the
optimizer's BLAS threads; paper-spectral only, where no worker would inherit the patch).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import tempfile
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

from furuta_cosim.tuning import optimizers
from furuta_cosim.tuning import run as tuning
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

optimizers_make = optimizers.make
LEVERS = ("gp_restarts", "ei_starts", "blas_threads")


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


@contextmanager
def lever(name: str, value: int):
    """tuning runs with our settings except ``name`` = ``value``."""
    if name == "gp_restarts":
        with patched(lambda *args, **settings: optimizers_make(*args, **{**settings, "gp_restarts": value})):
            yield
    elif name == "ei_starts":
        before = optimizers.ACQUISITION["n_restarts_optimizer"]
        optimizers.ACQUISITION["n_restarts_optimizer"] = value
        try:
            yield
        finally:
            optimizers.ACQUISITION["n_restarts_optimizer"] = before
    else:                                   # blas_threads: run.py's threadpool_limits(1), widened
        import threadpoolctl

        original = threadpoolctl.threadpool_limits
        threadpoolctl.threadpool_limits = lambda limits=None, user_api=None: original(value, user_api)
        try:
            yield
        finally:
            threadpoolctl.threadpool_limits = original


def slug(label: str) -> str:
    """``label`` as a folder name."""
    return re.sub(r"[^A-Za-z0-9=_-]+", "-", label).strip("-")


def parse_lever(text: str) -> tuple[str, int]:
    name, _, value = text.partition("=")
    if name not in LEVERS or not value.isdigit():
        raise argparse.ArgumentTypeError(f"expected NAME=INTEGER with NAME one of {', '.join(LEVERS)}, "
                                         f"got {text!r}")
    return name, int(value)


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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=150)
    parser.add_argument("--skip-default", action="store_true", help="leave out skopt's defaults (slow)")
    parser.add_argument("--only", choices=("spectral", "effort"), help="run one of the two parts")
    parser.add_argument("--lever", type=parse_lever, action="append", default=[], metavar="NAME=VALUE",
                        help=f"a row of bo with this one setting changed ({', '.join(LEVERS)})")
    parser.add_argument("--effort-seeds", type=int, default=1, help="seeds of each 2-worker effort run")
    args = parser.parse_args()
    print(f"our settings: gp_restarts as each spec, EI {optimizers.ACQUISITION}, optimizer BLAS threads 1")
    work = Path(tempfile.mkdtemp(prefix="bench-tune-"))
    if args.only != "effort":
        spectral_part(args, work)
    if args.only != "spectral":
        effort_part(args, work)
    print(json.dumps({"work": str(work)}), file=sys.stderr)
    return 0


def spectral_part(args, work: Path) -> None:
    spectral = load_spec("paper-spectral")
    # (label, method, context factory)
    runs = [("bo", "bo", nullcontext), ("random", "random", nullcontext), ("de", "de", nullcontext)]
    if not args.skip_default:
        runs.append(("bo-skopt-defaults", "bo", lambda: patched(SkoptDefaults)))
    runs += [(f"bo, {name}={value}", "bo", lambda name=name, value=value: lever(name, value))
             for name, value in args.lever]
    rows, best = [], {}
    for label, method, context in runs:
        for seed in range(args.seeds):
            with context():
                document, per, wall = timed_run(spectral, work / slug(f"{label}-{seed}"),
                                                method=method, n_calls=args.calls, seed=seed)
            best.setdefault(label, []).append(document["best"]["objective"] if document["best"] else None)
            if seed == 0:
                nan = float("nan")
                rows.append((label, wall, document["optimizer_seconds"], document["evaluation_seconds"],
                             statistics.median(per) if per else nan, per[-1] if per else nan,
                             statistics.mean(per) if per else nan))
            print(f"  {label} seed {seed}: best {best[label][-1]}, {wall:.1f} s", file=sys.stderr, flush=True)
    de_long, _, de_wall = timed_run(spectral, work / "de-2000", method="de", n_calls=2000, seed=0)

    print(f"paper-spectral, {args.calls} calls, serial (seed 0)")
    print(f"{'method':24s} {'wall s':>8s} {'optimizer s':>12s} {'evaluation s':>13s} {'s/iter median':>14s} "
          f"{'s/iter last':>12s} {'s/iter mean':>12s} {'mean vs bo':>11s}")
    ours_mean = rows[0][6]
    for label, wall, optimizer_s, evaluation_s, median, last, mean in rows:
        print(f"{label:24s} {wall:8.1f} {optimizer_s:12.1f} {evaluation_s:13.2f} {median:14.3f} {last:12.3f} "
              f"{mean:12.3f} {mean / ours_mean:10.2f}x")
    print(f"\nbest objective over seeds 0..{args.seeds - 1} (lower is better; the paper's objective)")
    for label, values in best.items():
        found = [v for v in values if v is not None]
        print(f"{label:24s} " + " ".join(f"{v:9.3f}" if v is not None else "     none" for v in values)
              + (f"   median {statistics.median(found):.3f}, worst {max(found):.3f}" if found else ""))
    print(f"{'de, 2000 evaluations':24s} {de_long['best']['objective']:9.3f}   ({de_wall:.1f} s)")


def effort_part(args, work: Path) -> None:
    effort = load_spec("effort")
    one_doc, _, one = timed_run(effort, work / "effort-1", n_calls=args.calls, workers=1)
    runs = [("2 workers", nullcontext), ("2 workers, skopt's ask(n) batches", lambda: patched(skopt_batches))]
    runs += [(f"2 workers, {name}={value}", lambda name=name, value=value: lever(name, value))
             for name, value in args.lever if name != "blas_threads"]
    results = {}                            # label -> [(wall, document)] over the seeds
    for label, context in runs:
        for seed in range(args.effort_seeds):
            with context():
                document, _, wall = timed_run(effort, work / slug(f"effort-{label}-{seed}"),
                                              n_calls=args.calls, workers=2, seed=seed)
            results.setdefault(label, []).append((wall, document))
            print(f"  effort {label} seed {seed}: {wall:.1f} s", file=sys.stderr, flush=True)

    def best_of(document):
        return document["best"]["objective"] if document["best"] else float("nan")

    print(f"\neffort, {args.calls} calls (seed 0)")
    print(f"{'run':36s} {'wall s':>8s} {'optimizer s':>12s} {'waiting s':>10s} {'vs 1 worker':>12s} {'best':>9s}")
    for label, (wall, document) in [("1 worker", (one, one_doc))] + [(k, v[0]) for k, v in results.items()]:
        print(f"{label:36s} {wall:8.1f} {document['optimizer_seconds']:12.1f} "
              f"{document['evaluation_seconds']:10.1f} {one / wall:11.2f}x {best_of(document):9.4f}")
    if args.effort_seeds > 1:
        print(f"\neffort, {args.calls} calls, 2 workers, seeds 0..{args.effort_seeds - 1}: wall s and best")
        for label, found in results.items():
            walls = [wall for wall, _ in found]
            bests = [best_of(document) for _, document in found]
            print(f"{label:36s} " + " ".join(f"{w:5.1f}" for w in walls)
                  + "  |  " + " ".join(f"{b:.4f}" for b in bests)
                  + f"  |  median {statistics.median(walls):.1f} s, best {statistics.median(bests):.4f}")


if __name__ == "__main__":
    sys.exit(main())
