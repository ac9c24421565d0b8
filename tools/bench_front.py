"""Multi-objective tuning measured: the hypervolume of each method's Pareto front over 10 seeds
at the same budget, against a reference front from a long run, in one run.

    python tools/bench_front.py [--specs tradeoff tradeoff-static] [--seeds 10] [--calls 150]
                                [--workers 2] [--methods ours,parego,global,random]
                                [--reference 600] [--kernel NAME] [-o FOLDER]

Rows, per spec (every run ``tune`` of the spec with ``--seed S --n-calls CALLS``):

- ``ours``: ``bo`` as shipped (expected hypervolume improvement on the constrained BO);
- ``parego``: ``optimizer.front: parego`` (ParEGO scalarizations, trust region), the search
  before expected hypervolume improvement;
- ``global``: ParEGO with ``optimizer.region: global``;
- ``random``: random search, same budget.

The reference front is the non-dominated set of every point of every run above and of one
``bo`` run with ``--reference`` evaluations (seed 0). Hypervolumes are taken against one
reference point per spec: the worst value of each criterion on the reference front, times 1.1.
For each row: the hypervolume per seed as a fraction of the reference front's, median and
worst, and for each feasible baseline the lowest value of the first criterion a seed's front
reaches at the baseline's other criteria (median and spread over the seeds: what
``furuta-cosim fronts`` says for one run of each family). Every run's folder stays under ``-o``
(default: a new temporary folder) with bench.json.

``--kernel NAME`` runs the ``ours`` rows again under OPENBLAS_CORETYPE=NAME (a child process,
its runs under ``kernel-NAME``) and prints the spread of each seed's hypervolume between the two
BLAS kernels, both against this run's reference front and point.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from blas import check_kernel  # tools/blas.py: run as a script, tools/ is on the path
from furuta_cosim.errors import ConfigError
from furuta_cosim.tuning import pareto
from furuta_cosim.tuning.front import reach
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

METHODS = ("ours", "parego", "global", "random")


def run(spec, folder: Path, method: str, seed: int, calls: int, workers: int) -> list[dict]:
    if method in ("parego", "global"):
        region = "trust" if method == "parego" else "global"
        spec = replace(spec, optimizer=replace(spec.optimizer, region=region, front="parego"))
    if not (folder / "front.json").exists():
        tune(spec, folder, method="random" if method == "random" else "bo", n_calls=calls,
             seed=seed, workers=workers)
    return [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines()]


def measure(args, work: Path) -> dict:
    results = {}
    for name in args.specs:
        spec = load_spec(name)
        names = [c.name for c in spec.objective.criteria]
        fronts: dict[str, list] = {}
        everything = []
        for method in args.methods:
            for seed in range(args.seeds):
                started = time.perf_counter()
                records = run(spec, work / name / method / f"seed-{seed}", method, seed,
                              args.calls, args.workers)
                rows = [pareto.criteria_of(records[k], names) for k in pareto.front_of(records, names)]
                fronts.setdefault(method, []).append(rows)
                everything += rows
                print(f"  {name} {method} seed {seed}: {len(rows)} front points, "
                      f"{time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
        if args.reference:
            started = time.perf_counter()
            records = run(spec, work / name / "reference", "ours", 0, args.reference, args.workers)
            everything += [pareto.criteria_of(records[k], names) for k in pareto.front_of(records, names)]
            print(f"  {name} reference ({args.reference} evaluations): "
                  f"{time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
        reference_front = [everything[k] for k in pareto.nondominated(everything)]
        point = (1.1 * np.max(np.array(reference_front), axis=0)).tolist()
        best = pareto.hypervolume(reference_front, point)
        summary = json.loads((work / name / args.methods[0] / "seed-0" / "summary.json").read_text())
        baselines = {n: {c: b["criteria"][c] for c in names} for n, b in summary["baselines"].items()
                     if b["feasible"] and b.get("criteria")}
        rows = {}
        for method, per_seed in fronts.items():
            ratios = [pareto.hypervolume(front, point) / best for front in per_seed]
            reached = {}
            for baseline, criteria in baselines.items():
                values = []
                for front in per_seed:
                    points = [{"criteria": dict(zip(names, row)), "index": k, "file": ""}
                              for k, row in enumerate(front)]
                    found = reach(points, names, criteria).get(names[0])
                    values.append(found["value"] if found else None)
                reached[baseline] = values
            # the stricter measure: the volume that dominates the first baseline (the region
            # "better than the LQR in every criterion"), against the reference front's there
            beyond = None
            if baselines:
                corner = list(next(iter(baselines.values())).values())
                top = pareto.hypervolume(reference_front, corner)
                beyond = [pareto.hypervolume(front, corner) / top if top > 0 else None
                          for front in per_seed]
            rows[method] = {"hypervolume": ratios, "beyond_baseline": beyond, "reached": reached}
        results[name] = {"criteria": names, "reference_point": point, "reference_hypervolume": best,
                         "reference_front": reference_front, "baselines": baselines, "rows": rows,
                         "reference_evaluations": args.reference}
    return results


def table(results: dict, args) -> list[str]:
    lines = []
    for name, data in results.items():
        names = data["criteria"]
        lines += ["", f"{name}: hypervolume after {args.calls} calls over seeds 0-{args.seeds - 1}, as a "
                      f"fraction of the reference front's ({len(data['reference_front'])} points: every run"
                      + (f" and a {data['reference_evaluations']}-evaluation bo run"
                         if data["reference_evaluations"] else "") + "), reference point "
                      + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, data["reference_point"])), "",
                  "| method | median | worst | per seed | beyond the first baseline: median | worst |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for method, row in data["rows"].items():
            ratios, beyond = row["hypervolume"], [v for v in row["beyond_baseline"] or [] if v is not None]
            lines.append(f"| {method} | {statistics.median(ratios):.3f} | {min(ratios):.3f} | "
                         + " ".join(f"{r:.3f}" for r in ratios) + " | "
                         + (f"{statistics.median(beyond):.3f} | {min(beyond):.3f} |" if beyond else "- | - |"))
        lines += ["", "beyond the first baseline: the hypervolume of the region that dominates it, as a "
                      "fraction of the reference front's there (0 when nothing found dominates it)"]
        for baseline, criteria in data["baselines"].items():
            others = " and ".join(n for n in names[1:])
            lines += ["", f"{name}: the lowest {names[0]} a front reaches at {baseline}'s {others} "
                          f"or better ({baseline}: " + ", ".join(f"{n} {criteria[n]:.4g}" for n in names) + ")",
                      "", "| method | median | best | worst | per seed |", "| --- | --- | --- | --- | --- |"]
            for method, row in data["rows"].items():
                values = row["reached"][baseline]
                found = [v for v in values if v is not None]
                shown = " ".join("none" if v is None else f"{v:.4f}" for v in values)
                if found:
                    lines.append(f"| {method} | {statistics.median(found):.4f} | {min(found):.4f} | "
                                 + (f"{max(found):.4f}" if len(found) == len(values) else "none on some seed")
                                 + f" | {shown} |")
                else:
                    lines.append(f"| {method} | none | none | none | {shown} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--specs", nargs="+", default=["tradeoff", "tradeoff-static"])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--calls", type=int, default=150)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", default=",".join(METHODS),
                        type=lambda text: [m for m in text.split(",") if m])
    parser.add_argument("--reference", type=int, default=600,
                        help="evaluations of the long bo run (0: the reference front is the runs' own)")
    parser.add_argument("--kernel", help="rerun 'ours' under OPENBLAS_CORETYPE=KERNEL and compare")
    parser.add_argument("-o", "--output", help="folder of the runs (default: a new temporary one); "
                                               "runs already finished there are reused")
    args = parser.parse_args()
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown or not args.methods:
        parser.error(f"--methods: expected some of {', '.join(METHODS)}")
    if args.kernel and "ours" not in args.methods:
        parser.error("--kernel compares the ours rows: --methods must include ours")
    kernel = check_kernel(args.kernel) if args.kernel else None  # before any long work
    work = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="bench-front-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"runs in {work}", file=sys.stderr)
    try:
        results = measure(args, work)
    except ConfigError as error:
        print("\n".join(error.problems), file=sys.stderr)
        return 2
    (work / "bench.json").write_text(json.dumps(results, indent=1) + "\n")
    print("\n".join(table(results, args)))
    if args.kernel:
        print("\n".join(kernel_spread(args, work, results, kernel)))
    return 0


def kernel_spread(args, work: Path, results: dict, kernel: str) -> list[str]:
    """The ``ours`` runs again under another BLAS kernel, measured against this run's reference."""
    child = work / f"kernel-{args.kernel}"
    command = [sys.executable, __file__, "--specs", *args.specs, "--seeds", str(args.seeds),
               "--calls", str(args.calls), "--workers", str(args.workers), "--methods", "ours",
               "--reference", "0", "-o", str(child)]
    subprocess.run(command, env={**os.environ, "OPENBLAS_CORETYPE": args.kernel}, check=True,
                   stdout=subprocess.DEVNULL)
    lines = ["", f"ours under OPENBLAS_CORETYPE={args.kernel} ({kernel}) against the default kernel "
                 "(hypervolume fractions against the reference front above):"]
    for name, data in results.items():
        names, point, best = data["criteria"], data["reference_point"], data["reference_hypervolume"]
        mine = data["rows"]["ours"]["hypervolume"]
        theirs = []
        for seed in range(args.seeds):
            records = [json.loads(line) for line in
                       (child / name / "ours" / f"seed-{seed}" / "history.jsonl").read_text().splitlines()]
            front = [pareto.criteria_of(records[k], names) for k in pareto.front_of(records, names)]
            theirs.append(pareto.hypervolume(front, point) / best)
        same = sum(1 for a, b in zip(mine, theirs) if a == b)
        spread = max(abs(a - b) for a, b in zip(mine, theirs))
        lines.append(f"  {name}: {same}/{len(mine)} seeds identical; largest change of a seed's fraction "
                     f"{spread:.3f}; median {statistics.median(theirs):.3f} against {statistics.median(mine):.3f}, "
                     f"worst {min(theirs):.3f} against {min(mine):.3f}; per seed " + " ".join(f"{v:.3f}" for v in theirs))
        for method, row in data["rows"].items():
            if method != "ours":
                other = statistics.median(row["hypervolume"])
                before, after = statistics.median(mine) > other, statistics.median(theirs) > other
                lines.append(f"    ours' median ahead of {method}'s ({other:.3f}): {before} under the default "
                             f"kernel, {after} under {args.kernel}")
    return lines


if __name__ == "__main__":
    sys.exit(main())
