"""Cost of a 10 s paper-step co-simulation (5,000 control steps of 2 ms), split into parts.

    python tools/bench_cosim.py [--repeats 7]

Measured in one run, best of the repeats:
- bare:       PlantSession.step alone with the same inputs (the floor the loop stands on);
- run:        the master's loop for the LQR (reset, loop, trace) on paper-step;
- parts:      controller calls alone, the measurement/process noise (noise scenario minus
              paper-step), and recording (lists to arrays);
- end to end: load the scenario, prepare, simulate one controller, compute its metrics
              (the FMU already built and cached).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from furuta_cosim.cosim.master import prepare, run, simulate
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.metrics import compute
from furuta_cosim.scenario import load_scenario


def best(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    scenario = dataclasses.replace(load_scenario("paper-step"), controllers=("lqr-paper",))
    prepared = prepare(scenario)
    noisy = prepare(dataclasses.replace(load_scenario("noise"), controllers=("lqr-paper",)))
    steps, h = prepared.steps, prepared.communication_step
    _, controller = prepared.controllers[0]

    with PlantSession.open(prepared.fmu) as plant:
        reference = run(prepared, plant, 0)
        applied = reference.u.tolist()

        def bare():
            plant.reset(prepared.start)
            plant.set_io(["V"], prepared.outputs)
            step = plant.step
            for u in applied:
                step([u], h)

        t_bare = best(bare, args.repeats)
        t_run = best(lambda: run(prepared, plant, 0), args.repeats)
        t_noise_run = best(lambda: run(noisy, plant, 0), args.repeats)
    states = np.column_stack([reference[n] for n in prepared.outputs]).tolist()
    rbar = prepared.rbar.tolist()

    def controller_only():
        control = controller.control
        for x, r in zip(states, rbar):
            control(x, r)

    t_controller = best(controller_only, args.repeats)
    t_record = best(lambda: (np.array(states).T, np.array(applied)), args.repeats)
    t_draw = best(lambda: np.random.default_rng(7).standard_normal((steps, 7)), args.repeats)

    def end_to_end():
        s = dataclasses.replace(load_scenario("paper-step"), controllers=("lqr-paper",))
        p = prepare(s)
        traces = simulate(p)
        compute(traces["lqr-paper"], s.reference.settles)

    t_total = best(end_to_end, args.repeats)
    per = lambda seconds: seconds / steps * 1e6  # noqa: E731
    print(f"paper-step, LQR, {steps} control steps of {prepared.control_period * 1e3:g} ms, "
          f"{int(round(prepared.control_period / h))} communication step(s) each, best of {args.repeats}")
    print(f"{'part':38s} {'us/step':>8s} {'ms/run':>8s} {'vs bare':>8s}")
    rows = [("bare PlantSession.step", t_bare), ("master loop (reset, loop, trace)", t_run),
            ("  of which controller calls", t_controller), ("  of which recording (to arrays)", t_record),
            ("noise: extra per run (noise scenario)", t_noise_run - t_run),
            ("noise: drawing the samples", t_draw), ("end to end (load, prepare, run, metrics)", t_total)]
    for name, seconds in rows:
        print(f"{name:38s} {per(seconds):8.3f} {seconds * 1e3:8.2f} {seconds / t_bare:8.2f}x")
    print(f"loop overhead over bare stepping: {(t_run - t_bare) / t_bare * 100:.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
