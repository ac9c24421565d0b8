"""Cost of a 10 s paper-step co-simulation (5,000 control steps of 2 ms), split into parts,
what tuning pays per candidate, and command start-up.

    python tools/bench_cosim.py [--repeats 7]

Measured in one run, best of the repeats:
- bare:        PlantSession.step alone with the same inputs (the floor the loop stands on);
- loop:        the master's loop for the LQR (reset, loop, trace) on paper-step: in C
               (cosim/native.py, what runs by default) and the generated Python loop
               (FURUTA_COSIM_PYTHON_LOOP=1, what runs with an estimator or unit conversions);
- parts:       controller calls alone, the noise (noise scenario minus paper-step), recording;
- end to end:  load the scenario, prepare, evaluate one controller (the FMU already cached);
- candidate:   evaluate a new controller (its own gain) on an already prepared scenario:
               compile + run + metrics, what tuning pays per scenario per candidate; the same
               in a worker process after its first call (the prepared scenario and the result
               cross the process boundary each time);
- FMI 3.0:     bare steps of our FMI 3.0 build of the same pendulum (same inputs), against
               the FMI 2.0 build;
- foreign:     bare steps of the pythonfmu-built pendulum of the tests (when pythonfmu is
               installed), against ours;
- start-up:    ``furuta-cosim --help`` and ``list`` against ``python -c pass``.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from furuta_cosim.controllers import load_controller
from furuta_cosim.cosim import compile_controller, evaluate, prepare
from furuta_cosim.cosim import evaluation, native
from furuta_cosim.cosim.worker import evaluate_here
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def best(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def candidates(count: int, seed: int = 0):
    """LQR gains scaled entry by entry: each a new controller with its own generated code."""
    lqr = load_controller("lqr-paper")
    rng = np.random.default_rng(seed)
    for _ in range(count):
        gain = lqr.controller.Dc * np.exp(rng.uniform(-0.05, 0.05, lqr.controller.Dc.shape))
        yield dataclasses.replace(lqr, controller=dataclasses.replace(lqr.controller, Dc=gain))


def foreign_step(repeats: int, steps: int) -> float | None:
    if shutil.which("pythonfmu") is None:
        return None
    folder = Path(tempfile.mkdtemp(prefix="bench-foreign-"))
    try:
        foreign = ROOT / "tests" / "foreign"
        # the slave imports its physics, a project file of the build
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(foreign / "pendulum_fmu.py"),
                        str(foreign / "pendulum_physics.py"), "-d", str(folder)],
                       check=True, capture_output=True, env={**os.environ, "PYTHONPATH": str(foreign)})
        with PlantSession.open(folder / "ForeignPendulum.fmu") as plant:
            def bare():
                plant.reset({"pend_angle_0": 0.1})
                plant.set_io(["voltage"], ["arm_angle", "arm_rate", "pend_angle", "pend_rate", "current"])
                for _ in range(steps):
                    plant.step([0.0], 2e-3)

            return best(bare, max(1, repeats // 3))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def bare_steps(plant, prepared, applied, h: float):
    """A run of nothing but ``plant.step`` with the inputs ``applied``."""
    def bare():
        plant.reset(prepared.start)
        plant.set_io(["V"], prepared.outputs)
        step = plant.step
        for u in applied:
            step([u], h)
    return bare


def fmi3_step(prepared, applied, h: float, repeats: int) -> float:
    """Bare steps of the FMI 3.0 build with the inputs the FMI 2.0 run applied."""
    from furuta_cosim.fmu.exporter import build_fmu

    with PlantSession.open(build_fmu("furuta", fmi_version="3.0")) as plant:
        return best(bare_steps(plant, prepared, applied, h), repeats)


def startup(argv: list[str], repeats: int) -> float:
    return best(lambda: subprocess.run(argv, check=True, capture_output=True), repeats)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--candidates", type=int, default=50, help="candidates per timing")
    args = parser.parse_args()
    scenario = dataclasses.replace(load_scenario("paper-step"), controllers=("lqr-paper",))
    prepared = prepare(scenario)
    noisy = prepare(dataclasses.replace(load_scenario("noise"), controllers=("lqr-paper",)))
    steps, h = prepared.steps, prepared.communication_step
    compiled = compile_controller(prepared, "lqr-paper")
    compiled_noisy = compile_controller(noisy, "lqr-paper")

    with PlantSession.open(prepared.fmu) as plant:
        reference, _ = evaluation._run(prepared, plant, compiled, None)
        applied = reference.u.tolist()
        t_bare = best(bare_steps(plant, prepared, applied, h), args.repeats)
        t_fmi3 = fmi3_step(prepared, applied, h, args.repeats)  # right after: the same machine state
        t_run = best(lambda: evaluation._run(prepared, plant, compiled, None), args.repeats)
        os.environ[native.OFF] = "1"
        t_python_run = best(lambda: evaluation._run(prepared, plant, compiled, None), args.repeats)
        del os.environ[native.OFF]
        t_noise_run = best(lambda: evaluation._run(noisy, plant, compiled_noisy, None), args.repeats)
        pool = list(candidates(args.candidates * args.repeats))
        t_candidate = best(lambda: [evaluate(prepared, plant, pool.pop()) for _ in range(args.candidates)],
                           args.repeats) / args.candidates
    states = np.column_stack([reference[n] for n in prepared.signals]).tolist()
    rbar = prepared.rbar.tolist()

    def controller_only():
        control = compiled.runtime.control
        for x, r in zip(states, rbar):
            control(x, r)

    t_controller = best(controller_only, args.repeats)
    t_record = best(lambda: (np.array(states).T, np.array(applied)), args.repeats)

    def end_to_end():
        s = load_scenario("paper-step")
        p = prepare(s)
        with PlantSession.open(p.fmu) as session:
            evaluate(p, session, "lqr-paper")

    t_total = best(end_to_end, args.repeats)

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as workers:
        workers.submit(evaluate_here, prepared, "lqr-paper").result()  # the worker's first call
        remote = list(candidates(args.candidates * args.repeats, seed=1))
        t_worker = best(lambda: [workers.submit(evaluate_here, prepared, remote.pop()).result()
                                 for _ in range(args.candidates)], args.repeats) / args.candidates

    t_foreign = foreign_step(args.repeats, steps)
    t_pass = startup([sys.executable, "-c", "pass"], args.repeats)
    command = [sys.executable, "-m", "furuta_cosim.cli"]
    t_help = startup(command + ["--help"], args.repeats)
    t_list = startup(command + ["list"], args.repeats)

    per = lambda seconds: seconds / steps * 1e6  # noqa: E731
    print(f"paper-step, LQR, {steps} control steps of {prepared.control_period * 1e3:g} ms, "
          f"{prepared.substeps} communication step(s) each, best of {args.repeats}")
    print(f"{'part':44s} {'us/step':>8s} {'ms/run':>8s} {'vs bare':>8s}")
    rows = [("bare PlantSession.step", t_bare), ("master loop (reset, loop, trace)", t_run),
            ("Python loop (FURUTA_COSIM_PYTHON_LOOP=1)", t_python_run),
            ("  of which controller calls", t_controller), ("  of which recording (to arrays)", t_record),
            ("noise: extra per run (noise scenario)", t_noise_run - t_run),
            ("end to end (load, prepare, evaluate, metrics)", t_total),
            ("new candidate on a prepared scenario", t_candidate),
            ("  the same in a worker process", t_worker),
            ("bare step of the FMI 3.0 build", t_fmi3)]
    if t_foreign is not None:
        rows.append(("bare step of the pythonfmu pendulum", t_foreign))
    for name, seconds in rows:
        print(f"{name:44s} {per(seconds):8.3f} {seconds * 1e3:8.2f} {seconds / t_bare:8.2f}x")
    # the loop in C steps the plant without Python: it can cost less than bare Python steps
    print(f"the Python loop's overhead over bare stepping: {(t_python_run - t_bare) / t_bare * 100:.0f} %; "
          f"loop in C / Python loop: {t_run / t_python_run:.2f}")
    print(f"\n{'command start-up':44s} {'ms':>8s} {'vs python -c pass':>18s}")
    for name, seconds in (("python -c pass", t_pass), ("furuta-cosim --help", t_help),
                          ("furuta-cosim list", t_list)):
        print(f"{name:44s} {seconds * 1e3:8.1f} {seconds / t_pass:17.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
