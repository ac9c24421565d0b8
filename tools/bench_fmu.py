"""Microseconds per closed-loop control step of the Furuta FMU, three ways, in one run.

    python tools/bench_fmu.py [--steps 5000] [--repeats 7]

- floor:    a C program that dlopens the same FMU binary and runs the same loop;
- session:  furuta_cosim's PlantSession (cffi, prepared buffers);
- fmpy:     fmpy's FMU2Slave wrapper (setReal / doStep / getReal with Python lists).

The loop: read the 5 states, u = -K x with plain floats (the printed LQR gain), set V,
doStep 1 ms with 10 RK4 substeps; released from theta1 = 0.1 rad. Best of the repeats.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from fmpy.fmi2 import FMU2Slave

from furuta_cosim.fmu.compiler import compiler
from furuta_cosim.fmu.exporter import build_fmu, fmi_headers
from furuta_cosim.fmu.session import FmuBinary, PlantSession

K = [-0.31, -5.26, 70.74, 8.92, 0.17]
STATES = ["theta0", "dtheta0", "theta1", "dtheta1", "i"]
H = 1e-3

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
    const fmi2ValueReference out[5] = {VR_OUT}, in = VR_V, start = VR_START;
    const double K[5] = {GAIN}, theta1 = 0.1;
    double x[5], u, best = 1e9, t0;
    for (r = 0; r < repeats; r++) {
        reset(c); setup(c, 0, 0.0, 0.0, 0, 0.0); enter(c);
        set_real(c, &start, 1, &theta1); leave(c);
        t0 = now();
        for (k = 0; k < steps; k++) {
            get_real(c, out, 5, x);
            u = 0.0;
            for (j = 0; j < 5; j++) u -= K[j] * x[j];
            set_real(c, &in, 1, &u);
            if (do_step(c, k * H, H, fmi2True) != fmi2OK) return 1;
        }
        if (now() - t0 < best) best = now() - t0;
    }
    printf("%.6f\n", best / steps * 1e6);
    return 0;
}
"""


def floor(fmu: Path, steps: int, repeats: int) -> float:
    with FmuBinary(fmu) as binary, tempfile.TemporaryDirectory() as work:
        vr = {name: binary.variable(name).valueReference for name in STATES + ["V", "theta1_start"]}
        source = Path(work) / "floor.c"
        source.write_text(FLOOR_C)
        program = Path(work) / "floor"
        defines = [f"-DVR_OUT={','.join(str(vr[s]) for s in STATES)}", f"-DVR_V={vr['V']}",
                   f"-DVR_START={vr['theta1_start']}", f"-DGAIN={','.join(map(str, K))}", f"-DH={H}"]
        subprocess.run([compiler(), "-O2", "-std=c99", "-D_POSIX_C_SOURCE=199309L",
                        f"-I{fmi_headers()}", *defines, str(source), "-o", str(program), "-ldl"],
                       check=True)
        library = binary.directory / "binaries" / "linux64" / f"{binary.identifier}.so"
        result = subprocess.run([str(program), str(library), binary.model_description.guid,
                                 str(steps), str(repeats)], check=True, capture_output=True, text=True)
        return float(result.stdout)


def session(fmu: Path, steps: int, repeats: int) -> float:
    best = float("inf")
    with PlantSession.open(fmu) as plant:
        plant.set_io(["V"], STATES)
        k0, k1, k2, k3, k4 = K
        for _ in range(repeats):
            plant.reset({"theta1_start": 0.1})
            x = plant.get(STATES)
            step = plant.step
            start = time.perf_counter()
            for _ in range(steps):
                x = step([-(k0 * x[0] + k1 * x[1] + k2 * x[2] + k3 * x[3] + k4 * x[4])], H)
            best = min(best, time.perf_counter() - start)
    return best / steps * 1e6


def fmpy_wrapper(fmu: Path, steps: int, repeats: int) -> float:
    best = float("inf")
    with FmuBinary(fmu) as binary:
        md = binary.model_description
        slave = FMU2Slave(guid=md.guid, unzipDirectory=str(binary.directory),
                          modelIdentifier=binary.identifier, instanceName="fmpy")
        slave.instantiate()
        out = [binary.variable(s).valueReference for s in STATES]
        vin = [binary.variable("V").valueReference]
        start_vr = [binary.variable("theta1_start").valueReference]
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
    args = parser.parse_args()
    fmu = build_fmu("furuta")
    results = {"floor (C loop)": floor(fmu, args.steps, args.repeats),
               "PlantSession": session(fmu, args.steps, args.repeats),
               "fmpy FMU2Slave": fmpy_wrapper(fmu, args.steps, args.repeats)}
    base = results["floor (C loop)"]
    print(f"closed loop, {args.steps} steps of 1 ms, 10 RK4 substeps, best of {args.repeats}")
    for name, us in results.items():
        print(f"{name:16s} {us:7.3f} us/step  {us / base:5.2f}x floor")
    return 0


if __name__ == "__main__":
    sys.exit(main())
