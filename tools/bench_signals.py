"""Signals to the whole process group, as a terminal (a burst of Ctrl-C) and a job scheduler
(SIGTERM) send them, during an identify fit on two worker processes (its fit and profiles) and
a tuning on two (its trials): each run must end within 10 s of the signal, with no traceback,
its files complete (the checkpoint or history a resume reads), and ``--resume`` must give the
uninterrupted result (where its last line says --resume continues it; a run stopped before it
wrote anything says nothing of the kind, and the same command is run again).

Each run is started in a session of its own and signalled after a delay spread over the work
(the i-th of N at i/N of the uninterrupted run's length); every ``--resume-every``-th run is
resumed and its result compared with the uninterrupted one.

    python3 tools/bench_signals.py [--runs 20] [--resume-every 5] [--parts identify,tune]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
CLI = [sys.executable, "-m", "furuta_cosim"]
LIMIT = 10.0   # s from the signal to the end of the run


def _identify_spec(folder: Path) -> Path:
    from bench_loop import FREE

    from furuta_cosim.identify.foreign import pd_log
    from furuta_cosim.identify.synthetic import truth

    true = truth()
    path = pd_log(folder, seed=0)
    lines = ["name: pd", "plant: qube-servo-3", f"experiments: [{path.name}]", "free:"]
    lines += [f"  {k}: {{start: {true[k] * 1.2!r}, bounds: [{lo!r}, {hi!r}]}}" for k, (lo, hi) in FREE.items()]
    spec = folder / "spec.yaml"
    spec.write_text("\n".join(lines) + "\n")
    return spec


def _commands(part: str, folder: Path):
    """(the command writing into OUT, how to read its result) of a part."""
    if part == "identify":
        spec = _identify_spec(folder)

        def result(out: Path):
            document = json.loads((out / "fit.json").read_text())
            return {k: (p["value"], p.get("interval")) for k, p in document["parameters"].items()}
        return lambda out: CLI + ["identify", str(spec), "-o", str(out), "--workers", "2"], result

    def outcome(out: Path):   # each evaluation's point and score (not its wall time or worker)
        records = [json.loads(line) for line in (out / "history.jsonl").read_text().splitlines()]
        return [(r["index"], r["x"], r["objective"], r["feasible"]) for r in records]
    return (lambda out: CLI + ["tune", "effort", "--n-calls", "24", "--seed", "3", "-o", str(out), "--workers", "2"],
            outcome)


def as_from_a_terminal() -> None:
    """In the child, before it runs: Ctrl-C as a terminal's command gets it. A benchmark or a
    test suite started in the background (``cmd &`` in a script, a CI runner) passes SIGINT on
    ignored, and a command that inherits it ignored rightly keeps ignoring it (nohup's rule):
    the burst would measure nothing but the run's own end."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _one(command, out: Path, delay: float, number: int, burst: int) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    process = subprocess.Popen(command(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True, preexec_fn=as_from_a_terminal)
    time.sleep(delay)
    sent = time.monotonic()
    alive = process.poll() is None
    if alive:
        for _ in range(burst):
            try:
                os.killpg(process.pid, number)
            except ProcessLookupError:
                break
            time.sleep(0.01)
    try:
        _, err = process.communicate(timeout=120)
        ended = time.monotonic() - sent
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        _, err = process.communicate()
        ended = float("inf")
    return {"signalled": alive, "seconds": ended, "code": process.returncode, "traceback": "Traceback" in err,
            "last": err.strip().splitlines()[-1] if err.strip() else "",
            "pools": [line for line in err.splitlines() if line.startswith("ended the ")]}


def _readable(result, out: Path):
    try:
        return result(out)
    except (OSError, ValueError, KeyError):
        return None


def run(part: str, runs: int, resume_every: int) -> bool:
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        command, result = _commands(part, folder)
        started = time.monotonic()
        done = subprocess.run(command(folder / "whole"), capture_output=True, text=True)
        length = time.monotonic() - started
        if done.returncode != 0:
            print(f"{part}: the uninterrupted run failed: {done.stderr.strip().splitlines()[-1]}")
            return False
        whole = result(folder / "whole")
        print(f"{part}: uninterrupted {length:.1f} s; {runs} runs per signal, signalled at i/{runs} of that")
        ok = True
        for name, number, burst in (("a terminal's Ctrl-C burst (5 SIGINT)", signal.SIGINT, 5),
                                    ("a scheduler's SIGTERM", signal.SIGTERM, 1)):
            times, bad, resumed, same = [], [], 0, 0
            for i in range(runs):
                out = folder / f"cut-{i}"
                found = _one(command, out, length * (i + 0.5) / runs, number, burst)
                if not found["signalled"]:
                    continue
                times.append(found["seconds"])
                # killed by the default handler (-2, -15): the signal came as the process exited, after
                # it had written everything (it said so); good only if its result is the whole one
                after = found["code"] in (-2, -15) and _readable(result, out) == whole
                if found["seconds"] > LIMIT or found["traceback"] or (found["code"] not in (130, 143, 0) and not after):
                    bad.append((i, found))
                if resume_every and i % resume_every == 0 and found["code"] != 0:
                    # as its last line says: --resume where it started, else the same command again
                    # (a run stopped before its first file has nothing to resume)
                    again = subprocess.run(command(out) + (["--resume"] if "--resume" in found["last"] else []),
                                           capture_output=True, text=True)
                    resumed += 1
                    same += again.returncode == 0 and result(out) == whole
            ok = ok and not bad and same == resumed
            print(f"  {name}: {len(times)} signalled; ended {statistics.median(times):.2f} s median, "
                  f"{max(times):.2f} s worst after the signal (at most {LIMIT:g}); {len(bad)} bad; "
                  f"{same} of {resumed} resumed runs equal the uninterrupted one")
            for i, found in bad:
                print(f"    run {i}: {found}")
        return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--resume-every", type=int, default=5)
    parser.add_argument("--parts", default="identify,tune")
    args = parser.parse_args()
    results = [run(part, args.runs, args.resume_every) for part in args.parts.split(",")]
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main())
