"""What ``regress`` over every shipped scenario costs, against the bare co-simulations.

    python tools/bench_regress.py [--repeat 3]

Measured in one run: the sum of the bare runs (each controller of each scenario evaluated on
an open session, nothing else: no preparation, no baseline, no comparison), then ``regress``
with 1 worker and with 2 (best of ``--repeat``), and the ratios.
"""

from __future__ import annotations

import argparse
import sys
import time

from furuta_cosim import paths
from furuta_cosim.cosim.evaluation import evaluate, scenario_controllers
from furuta_cosim.cosim.master import prepare
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.regression import regress
from furuta_cosim.scenario import load_scenario


def bare_seconds() -> tuple[float, int]:
    total, count = 0.0, 0
    for path in sorted(paths.scenarios().glob("*.yaml")):
        prepared = prepare(load_scenario(path))
        compiled = scenario_controllers(prepared)
        with PlantSession.open(prepared.fmu) as session:
            for c in compiled:
                started = time.perf_counter()
                evaluate(prepared, session, c)
                total += time.perf_counter() - started
                count += 1
    return total, count


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    regress(workers=1)  # warm: FMUs built, modules imported
    bare, count = min(bare_seconds() for _ in range(args.repeat))
    walls = {}
    for workers in (1, 2):
        best = float("inf")
        for _ in range(args.repeat):
            started = time.perf_counter()
            report = regress(workers=workers)
            best = min(best, time.perf_counter() - started)
            assert not report.failed, [c.lines() for c in report.failed]
        walls[workers] = best
    print(f"regress over {count} runs of the shipped scenarios (best of {args.repeat}):")
    print(f"  bare co-simulations, summed: {bare:.2f} s")
    for workers, wall in walls.items():
        print(f"  regress, {workers} worker(s): {wall:.2f} s  ({wall / bare:.2f}x the bare runs)")
    print(f"  speed-up with 2 workers: {walls[1] / walls[2]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
