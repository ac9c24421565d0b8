"""Run some tests many times in a row on a loaded machine and count how often they pass.

A test must pass every time, loaded or not: this finds the one failure in ten (or in sixty)
that a single suite run hides. The load is ``--burners`` busy processes (one per core loads
the machine fully); each repetition is a fresh pytest process.

    python3 tools/repeat_tests.py --runs 20 --burners 2 -- tests/test_rig_signals.py

prints one line per run and, at the end, the passes out of the runs; exit 1 if any failed
(the failed runs' output is kept in ``--keep``, by default a temporary folder it names).
"""

from __future__ import annotations

import argparse
import multiprocessing
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _burn() -> None:
    while True:
        pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="repetitions (default 20)")
    parser.add_argument("--burners", type=int, default=2, help="busy processes loading the machine (default 2)")
    parser.add_argument("--keep", type=Path, default=None, help="folder for the failed runs' output")
    parser.add_argument("tests", nargs="+", help="what pytest is given (after --)")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.burners < 0:
        parser.error("--runs must be at least 1 and --burners at least 0")
    keep = args.keep or Path(tempfile.mkdtemp(prefix="repeat-tests-"))
    keep.mkdir(parents=True, exist_ok=True)
    burners = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(args.burners)]
    for b in burners:
        b.start()
    passed = 0
    try:
        for k in range(1, args.runs + 1):
            started = time.monotonic()
            done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args.tests],
                                  capture_output=True, text=True)
            last = (done.stdout.strip().splitlines() or [""])[-1]
            if done.returncode == 0:
                passed += 1
            else:
                (keep / f"run-{k}.txt").write_text(done.stdout + done.stderr)
            print(f"run {k}/{args.runs}: {'pass' if done.returncode == 0 else 'FAIL'} "
                  f"({time.monotonic() - started:.0f} s) {last}", flush=True)
    finally:
        for b in burners:
            b.terminate()
    print(f"{passed} of {args.runs} runs passed with {args.burners} burner(s)"
          + ("" if passed == args.runs else f"; failed runs' output in {keep}"))
    return 0 if passed == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
