"""How closely other engines run an exported SSP: each loop exported by ``export_ssp``, run in
Ecos, in libcosim and by ``simulate LOOP.ssp`` (its system, stepped by our Jacobi master), and
compared with our master run of the same scenario with its
one-sample delay (``timing.delay: 1``), sample for sample.

Loops, each FMI 2.0 and 3.0 (libcosim: 2.0 only; it refuses 3.0, which the suite checks):
``paper-step`` under ``lqr-paper``, ``bo-paper`` and a generalized controller whose state sees
the plant; ``qube-step`` held at 0.3 rad from the start with a 0.13 V actuator limit that its
first commands reach (the plant's ``V_max`` in the SSP); ``qube-step`` itself (its reference
steps at 0.5 s: the source FMU) and ``qube-sine`` with two parameter sets (each chosen by name;
libcosim takes no set name); ``noise`` (seeded measurement and process noise) and
``disturbance`` (a pulse) through the source. Then the swing-up's refusal and the hostile
archives the system check refuses, each with its line. Per loop and engine: the largest difference of each angle (rad) and of
the command the plant applied (V), and the export's time. For ``paper-step`` under ``lqr-paper``
also our system stepped Gauss-Seidel (one component after the other), plant first and controller
first: the exchange order the controller's one-sample hold does not make irrelevant.

    python3 tools/bench_ssp.py
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from helpers import DYNAMIC  # noqa: E402  the suite's generalized controller, one definition

LIMIT = 0.13   # V: the QUBE loop's actuator limit


def master(scenario, controller, plant=None):
    from furuta_cosim.cosim import evaluate, prepare
    from furuta_cosim.cosim.master import on_plant
    from furuta_cosim.fmu.session import PlantSession
    from furuta_cosim.scenario import load_scenario

    loaded = replace(load_scenario(scenario), delay=1)
    prepared = prepare(on_plant(loaded, plant) if plant else loaded)
    with PlantSession.open(prepared.fmu) as session:
        trace = evaluate(prepared, session, controller).trace
    return np.column_stack([trace["theta0"], trace["theta1"], trace.u])


def ecos(path: Path, found: dict, parameter_set: str | None = None) -> np.ndarray:
    from ecospy import EcosSimulation

    rows = []
    with EcosSimulation(step_size=found["step"], ssp_path=str(path)) as simulation:
        simulation.init(parameter_set=parameter_set or found["sets"][0])
        for _ in range(round(found["stop"] / found["step"])):
            rows.append([simulation.get_real(n) for n in ("plant::theta0", "plant::theta1", "plant::V")])
            simulation.step()
        simulation.terminate()
    return np.array(rows)


def libcosim(path: Path, found: dict) -> np.ndarray | None:
    """The rows aligned with the master's (the observer reads after each step: the angles of
    the next sample, the command that step ran with; the first sample's angles are not read);
    None when libcosim refuses the archive."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    try:
        execution = CosimExecution.from_ssp_file(str(path), step_size=round(found["step"] * 1e9))
    except AssertionError:
        return None
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    plant = {s.name.decode(): s.index for s in execution.slave_infos()}["plant"]
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(plant)}
    rows = []
    for _ in range(round(found["stop"] / found["step"])):
        execution.step()
        rows.append(observer.last_real_values(plant, [refs["theta0"], refs["theta1"], refs["V"]]))
    rows = np.array(rows)
    aligned = np.full_like(rows, np.nan)
    aligned[1:, :2] = rows[:-1, :2]
    aligned[:, 2] = rows[:, 2]
    return aligned


@contextlib.contextmanager
def quiet():
    """The engines' own lines on the C stdout (Ecos says how it loads an FMI 3.0 FMU) kept out
    of the table."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def ours(path: Path, found: dict, order=None, parameter_set: str | None = None) -> np.ndarray:
    """``simulate LOOP.ssp``'s run (furuta_cosim/ssp/system.py): Jacobi, or Gauss-Seidel in
    ``order``; the rows before each step, as the Ecos rows."""
    from furuta_cosim.ssp.system import load_system, run_system

    run = run_system(load_system(path, parameter_set), order=order)
    n = int(round(found["stop"] / found["step"]))
    return np.column_stack([run["plant.theta0"][:n], run["plant.theta1"][:n], run["plant.V"][:n]])


def hostile(folder: Path) -> None:
    """The archives the system check refuses (the suite's list), each with its line."""
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.ssp import export_ssp
    from furuta_cosim.ssp.system import load_system
    from test_ssp import _rewritten
    from test_ssp_system import BROKEN

    export_ssp("paper-step", "lqr-paper", folder / "loop.ssp")
    print("\nHostile archives (paper-step under lqr-paper, one entry changed), each refused before it runs:\n")
    for k, (change, _) in enumerate(BROKEN):
        bad = _rewritten(folder / "loop.ssp", folder / f"bad-{k}.ssp", change)
        try:
            load_system(bad)
            print(f"- bad-{k}.ssp: RAN (not refused)")
        except ConfigError as error:
            print(f"- {str(error).replace(str(folder) + '/', '')}")


def main() -> int:
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.ssp import export_ssp

    print("| loop | set | FMI | engine | theta0 (rad) | theta1 (rad) | applied V | export |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        (folder / "dynamic.yaml").write_text(DYNAMIC)
        hold = folder / "qube-hold.yaml"
        hold.write_text((ROOT / "scenarios" / "qube-step.yaml").read_text()
                        .replace("points: [[0.0, 0.0], [0.5, 0.3]]", "points: [[0.0, 0.3]]")
                        .replace("name: qube-step", "name: qube-hold") + f"actuator: {{limit: {LIMIT}}}\n")
        two = ["qube-servo-3", "qube-servo-3-worn"]
        loops = [("paper-step", "lqr-paper", "lqr-paper", ()), ("paper-step", "bo-paper", "bo-paper", ()),
                 ("paper-step", str(folder / "dynamic.yaml"), "generalized", ()),
                 (str(hold), "lqr-qube", "lqr-qube", ()), ("qube-step", "lqr-qube", "lqr-qube", ()),
                 ("qube-sine", "lqr-qube", "lqr-qube", two), ("noise", "lqr-paper", "lqr-paper", ()),
                 ("disturbance", "lqr-paper", "lqr-paper", ())]
        for scenario, controller, label, plants in loops:
            name = Path(scenario).stem
            for version in ("2.0", "3.0"):
                path = folder / f"{name}-{label}-{version}.ssp"
                started = time.perf_counter()
                found = export_ssp(scenario, controller, path, plants=plants, fmi_version=version)
                seconds = time.perf_counter() - started
                limit = LIMIT if name == "qube-hold" else np.inf
                for k, set_name in enumerate(found["sets"]):
                    expected = master(scenario, controller, plants[k] if plants else None)
                    engines = [("Ecos", lambda p, f, s=set_name: ecos(p, f, s)),
                               ("libcosim", libcosim),
                               ("simulate LOOP.ssp", lambda p, f, s=set_name: ours(p, f, parameter_set=s))]
                    if label == "lqr-paper" and name == "paper-step" and version == "2.0":   # the exchange order
                        engines += [(f"Gauss-Seidel, {first} first", lambda p, f, o=order: ours(p, f, o))
                                    for first, order in (("plant", ["plant", "controller"]),
                                                         ("controller", ["controller", "plant"]))]
                    row = f"| {name}, {label} | {set_name} | {version} |"
                    for engine, run in engines:
                        if engine == "libcosim" and version == "3.0":  # it refuses (tests/test_ssp.py)
                            print(f"{row} {engine} | not run: libcosimpy reads FMI 2.0 only | | | {seconds:.2f} s |")
                            continue
                        if engine == "libcosim" and k > 0:
                            print(f"{row} {engine} | not run: libcosimpy applies each component's first set "
                                  f"(it takes no set name) | | | {seconds:.2f} s |")
                            continue
                        with quiet():
                            rows = run(path, found)
                        if rows is None:
                            print(f"{row} {engine} | refused | | | {seconds:.2f} s |")
                            continue
                        rows[:, 2] = np.clip(rows[:, 2], -limit, limit)
                        worst = np.nanmax(np.abs(rows - expected), axis=0)
                        print(f"{row} {engine} | {worst[0]:.2g} | {worst[1]:.2g} | {worst[2]:.2g} | {seconds:.2f} s |",
                              flush=True)
        try:
            export_ssp("swingup-qube", None, folder / "swingup.ssp")
            print("| swingup-qube | | | | EXPORTED (not refused) | | | |")
        except ConfigError as error:
            print(f"\nThe swing-up: {str(error).replace(str(ROOT) + '/', '')}")
        hostile(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
