"""Run a benchmark and record what it printed for the docs: ``docs/benchmarks/NAME.txt``,
headed by the command, the commit it ran at and the paths whose change makes it stale; then
the pages that show it are written again (tools/docs_hooks.py: the figures where a page shows
them, the commit and, on the built site, a staleness warning on the Performance page).

    python tools/record.py [--measures PATH ...] -- NAME python tools/bench_fmu.py [ARGS]

The working tree must be clean in the measured paths (a figure of uncommitted code has no
commit to name). The output goes to the terminal as well; the file is written only when the
command succeeds, atomically.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", help="the record's name: docs/benchmarks/NAME.txt")
    parser.add_argument("--measures", nargs="+", default=["furuta_cosim", "fmu_src", "tools"],
                        help="paths whose change makes the figures stale (default: the code)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- the benchmark command")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not re.fullmatch(r"[a-z0-9][a-z0-9-]*", args.name) or not command:
        parser.error("give a plain NAME (a-z, 0-9, -) and, after --, the command")
    dirty = subprocess.run(["git", "status", "--porcelain", "--", *args.measures], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.strip()
    if dirty:
        print(f"error: uncommitted changes in {' '.join(args.measures)}:\n{dirty}", file=sys.stderr)
        return 2
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True, check=True).stdout.strip()
    done = subprocess.run(command, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    sys.stdout.write(done.stdout)
    if done.returncode != 0:
        print(f"error: the benchmark exited {done.returncode}; nothing recorded", file=sys.stderr)
        return done.returncode
    head = (f"command: {shlex.join(command)}\ncommit: {commit}\nmeasures: {' '.join(args.measures)}\n")
    target = ROOT / "docs" / "benchmarks" / f"{args.name}.txt"
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, partial = tempfile.mkstemp(dir=target.parent, prefix=f".{args.name}-")
    with os.fdopen(handle, "w") as out:
        out.write(head + "\n" + done.stdout)
    os.replace(partial, target)
    print(f"recorded in {target.relative_to(ROOT)} at {commit}", file=sys.stderr)
    sys.path.insert(0, str(ROOT / "tools"))
    import docs_hooks  # the pages that show the record, and the Performance page's table

    for page in docs_hooks.write_pages():
        print(f"written: docs/pages/{page}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
