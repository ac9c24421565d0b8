"""Microseconds per closed-loop control step of a plant FMU, three ways, in one run: the
Furuta pendulum's; the cart-pole example's (a plant folder) beside it; and the Furuta written
in Python and exported by pythonfmu (what a user who writes only Python equations gets).

    python tools/bench_fmu.py [--steps 5000] [--repeats 7] [--plants furuta cart-pole furuta-pythonfmu]

- floor:    a C program that dlopens the same FMU binary and runs the same loop;
- session:  furuta_cosim's PlantSession (cffi, prepared buffers);
- fmpy:     fmpy's FMU2Slave wrapper (setReal / doStep / getReal with Python lists).

The loop: read the states, u = -K x with plain floats, set V, doStep 1 ms with 10 RK4
substeps; released from the pendulum 0.1 rad off upright. The Furuta: its 5 states and the
paper's printed LQR gain; the cart-pole (scenarios/cart-pole): its 4 states and lqr-ip02's
gain. Best of the repeats.
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

from fmpy.fmi2 import FMU2Slave

from furuta_cosim.fmu.compiler import compiler
from furuta_cosim.fmu.exporter import build_fmu, fmi_headers
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.fmu.session import FmuBinary, PlantSession

H = 1e-3
ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Loop:
    """One plant's benchmark loop: its FMU, the fed-back states, their gain and the start
    parameter that releases the pendulum."""

    fmu: Path
    states: list
    K: list
    start: str
    input: str = "V"
    native: bool = True        # a C binary a C program can dlopen (not a pythonfmu one)


def furuta() -> Loop:
    return Loop(build_fmu("furuta"), ["theta0", "dtheta0", "theta1", "dtheta1", "i"],
                [-0.31, -5.26, 70.74, 8.92, 0.17], "theta1_start")


def cart_pole() -> Loop:
    import yaml

    example = ROOT / "scenarios" / "cart-pole"
    plant = load_plant(example / "plants" / "ip02.yaml")
    plant = replace(plant, parameters={**plant.parameters, "n_substeps": 10})   # as the Furuta's
    K = yaml.safe_load((example / "controllers" / "lqr-ip02.yaml").read_text())["K"]
    return Loop(build_fmu(plant), ["x_c", "dx_c", "alpha", "dalpha"], K, "alpha_start")


def pythonfmu_furuta() -> Loop:
    """The Furuta pendulum written in Python and exported by pythonfmu (the tests' foreign
    FMU, tests/foreign/pendulum_fmu.py: RK4 with 20 substeps per doStep, in Python)."""
    foreign = ROOT / "tests" / "foreign"
    work = Path(tempfile.mkdtemp(prefix="bench-fmu-"))
    atexit.register(shutil.rmtree, work, True)
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(foreign / "pendulum_fmu.py"),
                    str(foreign / "pendulum_physics.py"), "-d", str(work)], check=True, capture_output=True,
                   env={**os.environ, "PYTHONPATH": str(foreign)})
    return Loop(next(work.glob("*.fmu")), ["arm_angle", "arm_rate", "pend_angle", "pend_rate", "current"],
                [-0.31, -5.26, 70.74, 8.92, 0.17], "pend_angle_0", input="voltage", native=False)


PLANTS = {"furuta": furuta, "cart-pole": cart_pole, "furuta-pythonfmu": pythonfmu_furuta}

FLOOR_C = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                   fmi2String m, ...) { (void)e; (void)n; (void)s; (void)c; fprintf(stderr, "%s\n", m); }
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(int argc, char **argv) {
    void *lib = dlopen(argv[1], RTLD_NOW);
    int steps = atoi(argv[3]), repeats = atoi(argv[4]), r, k, j;
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)dlsym(lib, "fmi2Instantiate");
    fmi2ResetTYPE *reset = (fmi2ResetTYPE *)dlsym(lib, "fmi2Reset");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)dlsym(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)dlsym(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *leave = (fmi2ExitInitializationModeTYPE *)dlsym(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)dlsym(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)dlsym(lib, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)dlsym(lib, "fmi2DoStep");
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("floor", fmi2CoSimulation, argv[2], "", &callbacks, 0, 0);
    const fmi2ValueReference out[N] = {VR_OUT}, in = VR_V, start = VR_START;
    const double K[N] = {GAIN}, released = 0.1;
    double x[N], u, best = 1e9, t0;
    for (r = 0; r < repeats; r++) {
        reset(c); setup(c, 0, 0.0, 0.0, 0, 0.0); enter(c);
        set_real(c, &start, 1, &released); leave(c);
        t0 = now();
        for (k = 0; k < steps; k++) {
            get_real(c, out, N, x);
            u = 0.0;
            for (j = 0; j < N; j++) u -= K[j] * x[j];
            set_real(c, &in, 1, &u);
            if (do_step(c, k * H, H, fmi2True) != fmi2OK) return 1;
        }
        if (now() - t0 < best) best = now() - t0;
    }
    printf("%.6f\n", best / steps * 1e6);
    return 0;
}
"""


def floor(loop: Loop, steps: int, repeats: int) -> float:
    with FmuBinary(loop.fmu) as binary, tempfile.TemporaryDirectory() as work:
        vr = {name: binary.variable(name).valueReference for name in loop.states + ["V", loop.start]}
        source = Path(work) / "floor.c"
        source.write_text(FLOOR_C)
        program = Path(work) / "floor"
        defines = [f"-DN={len(loop.states)}", f"-DVR_OUT={','.join(str(vr[s]) for s in loop.states)}",
                   f"-DVR_V={vr['V']}", f"-DVR_START={vr[loop.start]}",
                   f"-DGAIN={','.join(map(str, loop.K))}", f"-DH={H}"]
        subprocess.run([compiler(), "-O2", "-std=c99", "-D_POSIX_C_SOURCE=199309L",
                        f"-I{fmi_headers()}", *defines, str(source), "-o", str(program), "-ldl"],
                       check=True)
        library = binary.directory / "binaries" / "linux64" / f"{binary.identifier}.so"
        result = subprocess.run([str(program), str(library), binary.model_description.guid,
                                 str(steps), str(repeats)], check=True, capture_output=True, text=True)
        return float(result.stdout)


def session(loop: Loop, steps: int, repeats: int) -> float:
    best = float("inf")
    with PlantSession.open(loop.fmu) as plant:
        plant.set_io([loop.input], loop.states)
        gains = list(zip(loop.K, range(len(loop.states))))
        for _ in range(repeats):
            plant.reset({loop.start: 0.1})
            x = plant.get(loop.states)
            step = plant.step
            start = time.perf_counter()
            for _ in range(steps):
                u = 0.0
                for g, j in gains:
                    u -= g * x[j]
                x = step([u], H)
            best = min(best, time.perf_counter() - start)
    return best / steps * 1e6


def fmpy_wrapper(loop: Loop, steps: int, repeats: int) -> float:
    best = float("inf")
    K, STATES = loop.K, loop.states
    with FmuBinary(loop.fmu) as binary:
        md = binary.model_description
        slave = FMU2Slave(guid=md.guid, unzipDirectory=str(binary.directory),
                          modelIdentifier=binary.identifier, instanceName="fmpy")
        slave.instantiate()
        out = [binary.variable(s).valueReference for s in STATES]
        vin = [binary.variable(loop.input).valueReference]
        start_vr = [binary.variable(loop.start).valueReference]
        for r in range(repeats):
            if r:
                slave.reset()
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            slave.setReal(start_vr, [0.1])
            slave.exitInitializationMode()
            start = time.perf_counter()
            for k in range(steps):
                x = slave.getReal(out)
                slave.setReal(vin, [-sum(g * v for g, v in zip(K, x))])
                slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
            best = min(best, time.perf_counter() - start)
        slave.terminate()
        slave.freeInstance()
    return best / steps * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--plants", nargs="+", choices=tuple(PLANTS), default=list(PLANTS),
                        help="furuta-pythonfmu needs pythonfmu (the test extra)")
    args = parser.parse_args()
    ways = {"floor (C loop)": floor, "PlantSession": session, "fmpy FMU2Slave": fmpy_wrapper}
    measured = {}
    for plant in args.plants:
        loop = PLANTS[plant]()
        measured[plant] = {name: way(loop, args.steps, args.repeats) for name, way in ways.items()
                           if loop.native or way is not floor}
    first = args.plants[0]
    for plant, results in measured.items():
        base = measured[first]["floor (C loop)"]
        substeps = 20 if plant == "furuta-pythonfmu" else 10
        print(f"{plant}: closed loop, {args.steps} steps of 1 ms, {substeps} RK4 substeps, best of {args.repeats}")
        for name, us in results.items():
            beside = f"  {us / measured[first][name]:6.2f}x {first}'s" if plant != first else ""
            print(f"{name:16s} {us:8.3f} us/step  {us / base:6.2f}x {first}'s floor{beside}")
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
