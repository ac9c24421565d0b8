"""How well the rig loop keeps its period on this machine.

Three loops at the same period, each for --seconds, in this order:

- sleep: time.sleep to each deadline (what a naive loop does);
- clock: the runner's clock alone (sleep, then spin the last half millisecond), no I/O;
- rig run: the whole runner on the virtual board in real time (its plant in a process of its
  own): read, estimate, control (the shipped swing-up and catch), supervise, write, reload the
  watchdog.

Each line gives how late a sample starts after its deadline (median, 99th percentile, max, in
microseconds), the period jitter (the interval between two starts minus the period), and for the
rig run how long a sample's work takes; the last lines are the rig run's lateness as a ratio of
the clock alone's, measured in the same run (how much the board and controller add).

    python tools/bench_rig.py --seconds 10
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.rig.board import Clock
from furuta_cosim.rig.runner import run_rig
from furuta_cosim.rig.virtual import VirtualBoard


def bare(period: float, seconds: float, spin: bool) -> np.ndarray:
    """Lateness of each sample of an empty loop (s)."""
    clock = Clock()
    n = int(seconds / period)
    late = np.zeros(n)
    start = time.perf_counter() + 2 * period
    for k in range(n):
        deadline = start + k * period
        if spin:
            woke = clock.wait_until(deadline)
        else:
            remaining = deadline - time.perf_counter()
            if remaining > 0:
                time.sleep(remaining)
            woke = time.perf_counter()
        late[k] = woke - deadline
    return late


def stats(microseconds: np.ndarray) -> str:
    return (f"median {np.median(microseconds):8.1f}  p99 {np.percentile(microseconds, 99):8.1f}  "
            f"max {np.max(microseconds):8.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--period", type=float, default=0.002)
    args = parser.parse_args()
    period = args.period
    results = {}
    for name, spin in (("sleep", False), ("clock", True)):
        late = bare(period, args.seconds, spin) * 1e6
        results[name] = late
        print(f"{name:8s} late (us):   {stats(late)}   jitter (us): {stats(np.abs(np.diff(late)))}")
    plant = load_plant("qube-servo-3")
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        summary = run_rig("swingup-qube", VirtualBoard(plant, log=out / "board.csv"), plant, out,
                          duration=args.seconds)
        log = np.loadtxt(out / "log.csv", delimiter=",", skiprows=1, ndmin=2)
    late, compute = log[:, 1] * 1e6, log[:, 2] * 1e6
    results["rig"] = late
    print(f"{'rig run':8s} late (us):   {stats(late)}   jitter (us): {stats(np.abs(np.diff(late)))}")
    print(f"{'':8s} work (us):   {stats(compute)}   ({summary['status']}: {summary['reason']}; "
          f"{summary['timing']['overruns']} overruns of {summary['samples']} samples)")
    clock = results["clock"]
    for what, f in (("median", np.median), ("p99", lambda v: np.percentile(v, 99)), ("max", np.max)):
        print(f"rig run / clock, lateness {what}: {f(late) / max(f(clock), 1e-3):.2f}")
    print(json.dumps({"period_ms": 1000 * period, "seconds": args.seconds,
                      **{f"{k}_late_us": {"median": float(np.median(v)), "p99": float(np.percentile(v, 99)),
                                          "max": float(np.max(v))} for k, v in results.items()},
                      "rig_work_us": {"median": float(np.median(compute)), "p99": float(np.percentile(compute, 99)),
                                      "max": float(np.max(compute))}}))


if __name__ == "__main__":
    main()
