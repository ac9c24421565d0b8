"""Fitting balancing logs: a synthetic balancing rig of known parameters (the virtual board's
QUBE-Servo 3 with 2048-count encoders, a noisy 12-bit current sensor, a one-sample delay and a
10 V limit; furuta_cosim/identify/synthetic.py), under an LQR and under a PD law logged as
another tool would log it, the arm following a square wave. Per seed: a 10 s log fitted
(R_a, M_f, C0, I_a freed, starting 20 to 60 % off) and a second 10 s log of the same session
held out. Three ways to fit, on the same logs:

- loop: the controller closed in the replay, the angles the encoders rounded estimated;
- shooting: multiple shooting, 0.2 s segments from the measured state, no controller known
  (under the LQR only: it is the slow one);
- open: the logged voltage alone, open loop (what identify did before the loop).

    python tools/bench_balancing.py [--seeds 10] [--workers 2] [--ways loop,shooting,open] [--shooting-laws lqr]

With ``--cases``, what identify *says* instead, on the loop way under the LQR, profiles on
(the verdict a rig owner acts on), per seed and case:

- ``good``: the log as recorded;
- ``window``: a window cut at 2 s that keeps the run's start (rates and current 0);
- ``window-freed``: the same window with its rates freed and its current read from the log;
- ``no-current``: the log without its current;
- ``deg``: the arm's column in rad declared ``deg``;
- ``mA``: the current in A declared ``mA``.

    python tools/bench_balancing.py --cases good,window,window-freed,no-current,deg,mA --seeds 10

Per case: how many seeds were refused (before the fit, with its reason, or by the verdict),
how many were trusted, how many trusted fits hold the truth within every interval (the
profile's, else the sandwich's), and the time to the verdict (median and worst).

Per way and law: how many seeds hold each true value within its 95 % interval, the median
and worst error, the held-out replay RMS in encoder quanta, how many fits the verdict
trusted, and the wall time of a fit. Then the shipped QUBE-Servo 3 fit, for comparison with
its record (nothing of it may get worse).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

FREE = ("R_a", "M_f", "C0", "I_a")
BOUNDS = {"R_a": (1.0, 30.0), "M_f": (0.005, 0.2), "C0": (0.0, 1e-2), "I_a": (1e-6, 1e-2)}
LAWS = {"lqr": None, "pd": ([-1.0, -1.2, 34.0, 3.0], -1.0)}
QUANTUM = 2 * math.pi / 2048


CASES = ("good", "window", "window-freed", "no-current", "deg", "mA")


def _case(data: dict, case: str, fitted: bool) -> None:
    """The experiment's keys as a user of that case wrote them (the fitted log only, but for
    no-current, which both logs lack)."""
    if case == "no-current":
        data["outputs"].pop("i")
        data["start"].pop("i", None)
    elif not fitted:
        return
    elif case in ("window", "window-freed"):
        data["window"] = [2.0, 10.0]
        if case == "window-freed":
            data["start"].update(dtheta0={"free": [-3.0, 3.0]}, dtheta1={"free": [-3.0, 3.0]}, i="data")
    elif case == "deg":
        data["outputs"]["theta0"]["unit"] = "deg"
    elif case == "mA":
        data["outputs"]["i"]["unit"] = "mA"


def _spec(folder: Path, fitted: Path, held: Path, starts: dict, way: str, case: str = "good") -> Path:
    import yaml

    def experiment(path: Path, name: str) -> str:
        data = yaml.safe_load(path.read_text())
        data["name"] = name
        data["data"] = str(path.parent / data["data"])
        _case(data, case, name == "fitted")
        if way != "loop":
            loop = data.pop("loop")
            if way == "shooting":  # no controller known; the delay is (the board's datasheet)
                data["segments"] = 0.2
                data["inputs"]["V"]["delay"] = loop["delay"]
        if "controller" in data.get("loop", {}):
            data["loop"]["controller"] = str(path.parent / data["loop"]["controller"])
        out = folder / f"{name}-{way}-{case}.yaml"
        out.write_text(yaml.safe_dump(data, sort_keys=False))
        return out.name

    spec = {"name": f"balancing-{way}-{case}", "plant": "qube-servo-3",
            "experiments": [experiment(fitted, "fitted")], "validation": [experiment(held, "held")],
            "free": {name: {"start": float(starts[name]), "bounds": list(BOUNDS[name])} for name in FREE}}
    path = folder / f"spec-{way}-{case}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--ways", default="loop,shooting,open")
    parser.add_argument("--laws", default="lqr,pd")
    parser.add_argument("--shooting-laws", default="lqr")
    parser.add_argument("--cases", help=f"what identify says, per case ({','.join(CASES)}): see the docstring")
    args = parser.parse_args()
    if args.cases:
        return cases(args.cases.split(","), args.seeds, args.workers)
    import numpy as np

    from furuta_cosim.identify.run import identify
    from furuta_cosim.identify.synthetic import balancing_log, truth

    true = truth()
    ways = args.ways.split(",")
    rows = {}
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        for law in args.laws.split(","):
            for seed in range(args.seeds):
                folder = root / f"{law}-{seed}"
                folder.mkdir()
                fitted = balancing_log(folder / "fitted", seed=seed, law=LAWS[law])
                held = balancing_log(folder / "held", seed=1000 + seed, law=LAWS[law], amplitude=0.2, period=3.0)
                rng = np.random.default_rng(seed)
                starts = {n: true[n] * (1 + rng.choice([-1, 1]) * rng.uniform(0.2, 0.6)) for n in FREE}
                for way in ways:
                    if way == "shooting" and law not in args.shooting_laws.split(","):
                        continue
                    spec = _spec(folder, fitted, held, starts, way)
                    clock = time.monotonic()
                    document = identify(spec, folder / f"run-{way}", workers=args.workers, profiles=False,
                                        accept=True)
                    seconds = time.monotonic() - clock
                    entry = rows.setdefault((way, law), {"inside": {n: 0 for n in FREE}, "error": {n: [] for n in FREE},
                                                         "held0": [], "held1": [], "fit0": [], "fit1": [],
                                                         "trusted": 0, "seconds": []})
                    for name in FREE:
                        p = document["parameters"][name]
                        lo, hi = p["interval"]
                        entry["inside"][name] += int(lo <= true[name] <= hi)
                        entry["error"][name].append(abs(p["value"] / true[name] - 1.0))
                    held_rms = {k: v["rms"] for k, v in next(iter(document["validation"].values())).items()}
                    fit_rms = {k: v["rms"] for k, v in next(iter(document["experiments"].values())).items()} \
                        if way != "shooting" else {}
                    entry["held0"].append(held_rms.get("theta0", math.nan) / QUANTUM)
                    entry["held1"].append(held_rms.get("theta1", math.nan) / QUANTUM)
                    entry["fit0"].append(fit_rms.get("theta0", math.nan) / QUANTUM)
                    entry["fit1"].append(fit_rms.get("theta1", math.nan) / QUANTUM)
                    entry["trusted"] += int(document["verdict"]["trusted"])
                    entry["seconds"].append(seconds)
                    print(f"{way:8s} {law:3s} seed {seed}: "
                          + ", ".join(f"{n} {document['parameters'][n]['value']:.4g}" for n in FREE)
                          + f"; held-out theta0 {entry['held0'][-1]:.2f} q, theta1 {entry['held1'][-1]:.2f} q; "
                          f"{'trusted' if document['verdict']['trusted'] else 'NOT trusted'}; {seconds:.1f} s",
                          flush=True)
    print(f"\ntruth: " + ", ".join(f"{n} {true[n]:.4g}" for n in FREE) + f"; {args.seeds} seeds, "
          f"{args.workers} workers; RMS in encoder quanta ({QUANTUM:.5f} rad)")
    print("| way | law | within 95 % interval (R_a, M_f, C0, I_a) | median error | worst error "
          "| held-out RMS theta0 / theta1 (median, worst) | trusted | time median (worst) |")
    print("|---|---|---|---|---|---|---|---|")
    for (way, law), e in rows.items():
        inside = ", ".join(str(e["inside"][n]) for n in FREE)
        median = ", ".join(f"{100 * np.median(e['error'][n]):.1f} %" for n in FREE)
        worst = ", ".join(f"{100 * max(e['error'][n]):.0f} %" for n in FREE)
        held = (f"{np.median(e['held0']):.2f} ({max(e['held0']):.2f}) / "
                f"{np.median(e['held1']):.2f} ({max(e['held1']):.2f})")
        print(f"| {way} | {law} | {inside} of {args.seeds} | {median} | {worst} | {held} | "
              f"{e['trusted']} of {args.seeds} | {np.median(e['seconds']):.1f} s ({max(e['seconds']):.1f} s) |")
    with tempfile.TemporaryDirectory() as scratch:
        clock = time.monotonic()
        document = identify("qube-servo-3", Path(scratch) / "qube", workers=args.workers, profiles=False)
        print(f"\nshipped QUBE-Servo 3 fit: {time.monotonic() - clock:.1f} s, {document['simulations']} simulations, "
              f"verdict {'trusted' if document['verdict']['trusted'] else 'NOT trusted'}; RMS "
              + "; ".join(f"{name} {o} {c['rms']:.4g}" for name, outs in document["experiments"].items()
                          for o, c in outs.items()))
    return 0


def cases(names: list[str], seeds: int, workers: int) -> int:
    """The verdicts of identify on each case (module docstring) over ``seeds`` logs."""
    import numpy as np

    from furuta_cosim.errors import ConfigError
    from furuta_cosim.identify.run import identify
    from furuta_cosim.identify.synthetic import balancing_log, truth

    unknown = sorted(set(names) - set(CASES))
    if unknown:
        raise SystemExit(f"--cases: unknown {', '.join(unknown)} (known: {', '.join(CASES)})")
    true = truth()
    rows = {name: {"refused_before": 0, "refused": 0, "trusted": 0, "held": 0, "seconds": [], "why": {}}
            for name in names}
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        for seed in range(seeds):
            folder = root / f"lqr-{seed}"
            folder.mkdir()
            fitted = balancing_log(folder / "fitted", seed=seed)
            held = balancing_log(folder / "held", seed=1000 + seed, amplitude=0.2, period=3.0)
            rng = np.random.default_rng(seed)
            starts = {n: true[n] * (1 + rng.choice([-1, 1]) * rng.uniform(0.2, 0.6)) for n in FREE}
            for name in names:
                row = rows[name]
                clock = time.monotonic()
                try:
                    spec = _spec(folder, fitted, held, starts, "loop", name)
                    document = identify(spec, folder / f"run-{name}", workers=workers, profiles=True)
                except ConfigError as error:  # refused before the fit: the line a user reads
                    seconds = time.monotonic() - clock
                    row["refused_before"] += 1
                    # the line a user reads, the scratch folder's path left out
                    why = error.problems[0].replace(str(folder) + "/", "")[:110]
                    row["why"][why] = row["why"].get(why, 0) + 1
                    row["seconds"].append(seconds)
                    print(f"{name:12s} seed {seed}: refused before the fit in {seconds:.1f} s: {why}", flush=True)
                    continue
                seconds = time.monotonic() - clock
                row["seconds"].append(seconds)
                verdict = document["verdict"]
                inside = []
                for n in FREE:
                    p = document["parameters"][n]
                    interval = p.get("interval_profile") or p["interval"]
                    lo, hi = (math.inf if v is None else v for v in interval) if interval else (math.inf, -math.inf)
                    lo = -math.inf if interval and interval[0] is None else lo
                    inside.append(lo <= true[n] <= hi)
                if verdict["trusted"]:
                    row["trusted"] += 1
                    row["held"] += int(all(inside))
                else:
                    row["refused"] += 1
                    why = verdict["reasons"][0][:90]
                    row["why"][why] = row["why"].get(why, 0) + 1
                print(f"{name:12s} seed {seed}: {'trusted' if verdict['trusted'] else 'NOT trusted'}, truth within "
                      f"the intervals of {', '.join(n for n, ok in zip(FREE, inside) if ok) or 'none'}; "
                      f"{seconds:.1f} s" + ("" if verdict["trusted"] else f": {verdict['reasons'][0][:90]}"),
                      flush=True)
    print(f"\ntruth: " + ", ".join(f"{n} {true[n]:.4g}" for n in FREE) + f"; {seeds} seeds, {workers} workers, "
          "the LQR's loop closed, profiles on")
    print("| case | refused before the fit | refused by the verdict | trusted | trusted, truth within every "
          "interval | time to verdict median (worst) |")
    print("|---|---|---|---|---|---|")
    for name, row in rows.items():
        print(f"| {name} | {row['refused_before']} | {row['refused']} | {row['trusted']} | {row['held']} of "
              f"{row['trusted']} | {np.median(row['seconds']):.1f} s ({max(row['seconds']):.1f} s) |")
    for name, row in rows.items():
        for why, count in row["why"].items():
            print(f"{name}: {count} x {why}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
