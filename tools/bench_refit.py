"""What the GP fits' second start costs the optimizer: one ``bo`` run of a spec, then its
history replayed through the optimizer's proposals twice, with the fits climbing from the
batch before's hyperparameters alone and from those and the kernel's defaults (as shipped).

    python tools/bench_refit.py [--spec effort] [--seed 0] [--repeat 3] [-o FOLDER]

Each replay asks every batch's proposal of the recorded history (its surrogates fitted or
conditioned, then its points), so both replays see the same data; they differ in the
hyperparameters they find, which is what the second start is for. Printed: the seconds of the
batches that refit and of the others, best of ``--repeat`` passes each, and the ratio shipped
/ one start. The optimizer runs on one BLAS thread, as in ``tune``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from furuta_cosim.errors import ConfigError
from furuta_cosim.tuning import bayesopt, gp
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec


def replay(records, bounds, seed: int, xi: float, n_initial: int, batch: int, one_start: bool) -> tuple[float, float]:
    """Seconds of the refitting batches' proposals and of the others over ``records``."""
    shipped = gp._starts
    if one_start:
        gp._starts = lambda theta, d: [theta]
    try:
        bo = bayesopt.ConstrainedBO(bounds, seed, xi=xi, n_initial_points=n_initial, batch=batch)
        refit = other = 0.0
        for number, first, count in bayesopt.batches(n_initial, batch, len(records)):
            started = time.perf_counter()
            list(bo.propose(records[:first], n_initial, number).points(count))
            spent = time.perf_counter() - started
            if number % bayesopt.REFIT_EVERY == 0:
                refit += spent
            else:
                other += spent
        return refit, other
    finally:
        gp._starts = shipped


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default="effort")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat: expected a whole number of at least 1")
    try:
        spec = load_spec(args.spec)
    except ConfigError as error:
        print(error, file=sys.stderr)
        return 2
    from threadpoolctl import threadpool_limits

    folder = args.output or Path(tempfile.mkdtemp(prefix="bench-refit-"))
    run_dir = folder / f"{spec.name}-{args.seed}"
    tune(spec, run_dir, method="bo", seed=args.seed, workers=2)
    records = [json.loads(line) for line in (run_dir / "history.jsonl").read_text().splitlines()]
    bounds = [b for block in spec.blocks for b in block.bounds()]
    n_initial = sum(1 for r in records if not str(r.get("origin", "")).startswith("bo"))
    times = {}
    with threadpool_limits(1):
        for name, one in (("one start", True), ("two starts (shipped)", False)):
            passes = [replay(records, bounds, args.seed, spec.optimizer.xi, n_initial, spec.optimizer.batch, one)
                      for _ in range(args.repeat)]
            times[name] = (min(p[0] for p in passes), min(p[1] for p in passes))
    print(f"{spec.name} seed {args.seed}: {len(records)} evaluations replayed, best of {args.repeat} "
          f"(run in {run_dir})")
    for name, (refit, other) in times.items():
        print(f"  {name}: refitting batches {refit:.2f} s, other batches {other:.2f} s")
    (one_refit, one_other), (two_refit, two_other) = times.values()
    print(f"  two / one: refitting batches {two_refit / one_refit:.3f}, "
          f"all batches {(two_refit + two_other) / (one_refit + one_other):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
