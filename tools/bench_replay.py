"""A replay's closed loop in C against the Python loop, in the same run (identify/native.py).

- replay: a 10 s balancing log recorded on the virtual board (5000 samples at 500 Hz) under a
  controller file (lqr-qube) and under a PD law stated in the logger's words, replayed with its
  loop closed through its smoother's angles; per kind the best of ``--repeats`` calls of the
  whole replay (the smoother included) and of the loop alone (the replay less the smoother's
  time), in the C loop and in the Python loop, and their ratio; the largest difference of their
  outputs.
- fit: identify of that log with R_a, M_f and I_a free and profiles, on ``--workers`` worker
  processes, once with each loop (``FURUTA_COSIM_PYTHON_LOOP=1`` for the Python one): wall time
  and the ratio, and the largest relative difference of the fitted values and interval ends.
- against: the same fit, and the shipped QUBE spec's (two real logs, open loop), by this
  checkout and by revision ``--against REV`` of its history (unpacked into a temporary
  folder): wall times, and how far apart their values and interval ends are.

    python tools/bench_replay.py [--repeats 5] [--workers 2] [--parts replay,fit,against] [--against REV]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

FREE = {"R_a": (1.0, 30.0), "M_f": (0.005, 0.2), "I_a": (1.0e-6, 1.0e-2)}
LAW = ([-1.0, -1.2, 34.0, 3.0], -1.0)


def _log(folder: Path, kind: str) -> Path:
    from furuta_cosim.identify.synthetic import balancing_log

    return balancing_log(folder / kind, seed=0, duration=10.0, **({"law": LAW} if kind == "law" else {}))


def _best(call, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        times.append(time.perf_counter() - started)
    return min(times)


def replay(folder: Path, repeats: int) -> list[str]:
    from furuta_cosim.identify import native
    from furuta_cosim.identify.estimate import estimated_noise, with_estimate
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.identify.replay import closed_loop, open_session, target_for

    from furuta_cosim.fmu.session import PlantSession

    target = target_for(plant="qube-servo-3")
    lines = ["replay of a 10 s balancing log (5000 samples), its loop closed through its smoother's angles; "
             f"best of {repeats}:"]
    with PlantSession.open(target.fmu) as session:   # what no loop can take away: the plant's own step
        session.set_io(inputs=["V"], outputs=["theta0", "theta1", "i"])

        def steps():
            session.reset(parameters={"theta1_start": 3.141592653589793})
            for _ in range(5000):
                session.step([0.1], 0.002)
        plant = _best(steps, repeats)
    lines.append(f"  the plant's 5000 steps alone, called from Python: {1e6 * plant / 5000:.2f} us a step")
    for kind in ("controller", "law"):
        experiment = with_estimate(load_experiment(_log(folder, kind)), target)
        smoother = _best(lambda: estimated_noise(experiment, target, dict(experiment.parameters)), repeats)
        found = {}
        with open_session(target) as session:
            for name, off in (("C", None), ("Python", "1")):
                if off:
                    os.environ[native.OFF] = off
                try:
                    found[name] = closed_loop(session, target, experiment)
                    found[name + " s"] = _best(lambda: closed_loop(session, target, experiment), repeats)
                finally:
                    os.environ.pop(native.OFF, None)
        apart = max(float(np.max(np.abs(found["C"][0][n] - found["Python"][0][n]))) for n in found["C"][0])
        apart_v = float(np.max(np.abs(found["C"][1] - found["Python"][1])))
        c_loop, py_loop = found["C s"] - smoother, found["Python s"] - smoother
        lines.append(f"  {kind:10s}: whole replay {1000 * found['C s']:.1f} ms (C) vs {1000 * found['Python s']:.1f} ms "
                     f"(Python), {found['Python s'] / found['C s']:.1f} times faster; the loop alone "
                     f"{1e6 * c_loop / experiment.samples:.2f} vs {1e6 * py_loop / experiment.samples:.2f} us a sample, "
                     f"{py_loop / c_loop:.1f} times; the smoother {1000 * smoother:.1f} ms; outputs apart "
                     f"{apart:.1e}, command {apart_v:.1e} V")
    return lines


def _fit(spec, out: Path, workers: int, python_loop: bool, root: Path = ROOT) -> tuple[float, dict]:
    import json

    env = {**os.environ, "PYTHONPATH": str(root)}
    if python_loop:
        env["FURUTA_COSIM_PYTHON_LOOP"] = "1"
    else:
        env.pop("FURUTA_COSIM_PYTHON_LOOP", None)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "furuta_cosim", "identify", str(spec), "-o", str(out),
                           "--workers", str(workers)], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode not in (0, 1):
        raise SystemExit(f"identify failed: {done.stderr.strip().splitlines()[-1:]}")
    return seconds, json.loads((out / "fit.json").read_text())


def _apart(c_fit: dict, py_fit: dict, names) -> float:
    """The largest relative difference of two fits' values and interval ends."""
    apart = 0.0
    for name in names:
        a, b = c_fit["parameters"][name], py_fit["parameters"][name]
        pairs = [(a["value"], b["value"])] + [(x, y) for key in ("interval", "interval_profile")
                                              for x, y in zip(a.get(key) or [], b.get(key) or [])
                                              if x is not None and y is not None]
        apart = max([apart] + [abs(x - y) / max(abs(y), 1e-300) for x, y in pairs])
    return apart


def _balancing_spec(folder: Path) -> Path:
    import yaml

    spec = folder / "spec.yaml"
    if not spec.exists():
        experiment = _log(folder, "fit")
        spec.write_text(yaml.safe_dump({"name": "balancing", "plant": "qube-servo-3", "experiments": [str(experiment)],
                                        "free": {n: {"bounds": list(b)} for n, b in FREE.items()}}))
    return spec


def fit(folder: Path, workers: int) -> list[str]:
    spec = _balancing_spec(folder)
    c_seconds, c_fit = _fit(spec, folder / "fit-c", workers, False)
    py_seconds, py_fit = _fit(spec, folder / "fit-python", workers, True)
    apart = _apart(c_fit, py_fit, FREE)
    values = ", ".join(f"{n} {c_fit['parameters'][n]['value']:.4g} {c_fit['parameters'][n].get('interval_profile')}"
                       for n in FREE)
    return [f"fit of the 10 s balancing log, {', '.join(FREE)} free, with profiles, {workers} workers:",
            f"  C loop {c_seconds:.1f} s, Python loop {py_seconds:.1f} s: {py_seconds / c_seconds:.1f} times faster; "
            f"values and interval ends apart at most {apart:.1e} (relative); trusted "
            f"{c_fit['verdict']['trusted']} / {py_fit['verdict']['trusted']}",
            f"  {values}"]


def against(folder: Path, workers: int, revision: str) -> list[str]:
    """This checkout's fits against revision ``revision``'s: the balancing log and the shipped
    QUBE spec."""
    other = folder / "revision"
    subprocess.run(["git", "worktree", "add", "--detach", "-q", str(other), revision], cwd=ROOT, check=True)
    try:
        lines = [f"the same fits by this checkout and by {revision} ({workers} workers):"]
        for name, spec, free in (("balancing log", _balancing_spec(folder), list(FREE)),
                                 ("qube-servo-3 (real logs)", "qube-servo-3", None)):
            here_s, here = _fit(spec, folder / f"here-{len(lines)}", workers, False)
            there_s, there = _fit(spec, folder / f"there-{len(lines)}", workers, False, root=other)
            names = free or [n for n in here["parameters"] if "." not in n]
            lines.append(f"  {name}: {here_s:.1f} s here, {there_s:.1f} s at {revision}; values and interval ends "
                         f"apart at most {_apart(here, there, names):.1e} (relative); verdicts "
                         f"{'the same' if here['verdict'] == there['verdict'] else 'differ'}")
        return lines
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT, check=False)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--parts", default="replay,fit", type=lambda text: text.split(","))
    parser.add_argument("--against", metavar="REV", help="with the part against: the revision to compare with")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-replay-") as folder:
        lines = []
        if "replay" in args.parts:
            lines += replay(Path(folder), args.repeats)
        if "fit" in args.parts:
            lines += fit(Path(folder), args.workers)
        if "against" in args.parts:
            if not args.against:
                parser.error("--parts against needs --against REV")
            lines += against(Path(folder), args.workers, args.against)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
