"""What robust tuning buys on a fitted rig: the worst case over plants the fit allows, of a
controller tuned at the fit's point estimate against one tuned over variants drawn from the
fit (``tune --from-fit``), over seeds, both scored on the same held-out variants.

    python tools/bench_robust.py --fit runs/identify/qube/fit.json [--spec effort] [--seeds 10]
                                 [--calls 150] [--samples 8] [--held-out 16] [--workers 2] [-o DIR]

For each seed: ``tune SPEC --plant FIT/../plant.yaml`` (point) and the same with
``--from-fit FIT --samples N`` (robust); then both best controllers and the spec's LQR
designed for the plant are scored on ``--held-out`` variants drawn from the fit with another
seed (variants seed 1000 + seed; none of them tuned on). Printed: per row the median and worst
over seeds of the held-out worst case, and how often a controller is infeasible on a
held-out variant (a constraint it was tuned to meet broken on a plant the fit allows).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from furuta_cosim.controllers import load_controller
from furuta_cosim.tuning.objective import Evaluator
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec


def held_out(spec_name: str, plant: Path, fit: Path, samples: int, seed: int, controllers: dict) -> dict:
    """Each controller's worst objective over the held-out variants, and its infeasible count."""
    spec = load_spec(spec_name, plant=plant, from_fit=(fit, samples, seed))
    evaluator = Evaluator(spec)
    found = {}
    for name, path in controllers.items():
        outcome = evaluator.score(load_controller(path).controller)
        scores = evaluator.by_variant(outcome.metrics)
        found[name] = {"worst": max((s for s in scores if s is not None), default=None),
                       "feasible": outcome.feasible}
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit", required=True, help="fit.json of an identify run (its plant.yaml beside it)")
    parser.add_argument("--spec", default="effort")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--calls", type=int, default=150)
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--held-out", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("-o", "--output")
    args = parser.parse_args()
    fit = Path(args.fit).resolve()
    plant = fit.parent / "plant.yaml"
    work = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="bench-robust-"))
    rows: dict[str, list] = {"point": [], "robust": [], "lqr": []}
    for seed in range(args.seeds):
        started = time.perf_counter()
        point = tune(load_spec(args.spec, plant=plant), work / f"point-{seed}", seed=seed,
                     n_calls=args.calls, workers=args.workers)
        robust = tune(load_spec(args.spec, plant=plant, from_fit=(fit, args.samples, 0)),
                      work / f"robust-{seed}", seed=seed, n_calls=args.calls, workers=args.workers)
        controllers = {"lqr": load_spec(args.spec, plant=plant).baselines[0]}
        if point["best"]:
            controllers["point"] = str(work / f"point-{seed}" / "best.yaml")
        if robust["best"]:
            controllers["robust"] = str(work / f"robust-{seed}" / "best.yaml")
        scored = held_out(args.spec, plant, fit, args.held_out, 1000 + seed, controllers)
        for name in rows:
            rows[name].append(scored.get(name))
        print(f"  seed {seed}: " + ", ".join(f"{n} worst {v['worst']:.4f} feasible {v['feasible']}"
                                             for n, v in scored.items() if v["worst"] is not None)
              + f" ({time.perf_counter() - started:.0f} s)", file=sys.stderr, flush=True)
    print(f"{args.spec} on {plant}, {args.calls} calls, {args.samples} tuning variants, "
          f"{args.held_out} held-out variants, seeds 0-{args.seeds - 1}")
    print("| controller | held-out worst, median | worst seed | seeds infeasible on a held-out variant |")
    print("| --- | --- | --- | --- |")
    for name, values in rows.items():
        worst = [v["worst"] for v in values if v and v["worst"] is not None]
        bad = sum(1 for v in values if not v or not v["feasible"])
        if worst:
            print(f"| {name} | {statistics.median(worst):.4f} | {max(worst):.4f} | {bad}/{len(values)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
