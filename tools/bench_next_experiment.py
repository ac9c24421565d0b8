"""Does a designed experiment tell the fit what another free swing cannot? Measured on the
virtual board, whose plant (the worn QUBE) is not the model the fit starts from.

    python tools/bench_next_experiment.py [--duration 10] [--truth qube-servo-3-worn] [--out DIR] [--json]

1. Two logs recorded on the virtual board: a free swing (the pendulum let go 1 rad from
   hanging, 0 V) and a weak motor run (a 1 Hz square wave of 0.5 V): the kind of data a first
   afternoon gives. identify fits the seven parameters of the shipped QUBE spec to them,
   starting from the nominal QUBE.
2. design-experiment ranks the candidate excitations for that fit (focus M_f, C0, I_a) and
   writes the best; the virtual board plays it; identify fits the three logs.
3. Against it: another free swing of the same length (let go from the other side), fitted with
   the two first logs.

Printed: for each fit, the largest correlation among M_f, C0 and I_a and the widest relative
95 % interval (half-width over value) among them and among all seven, and the fitted values
against the truth. The claim checked: the designed experiment brings the largest correlation
below 0.9 and at least halves the widest relative interval, against the second free swing.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

FOCUS = ["M_f", "C0", "I_a"]


def record(board_text: str, plant, volts: np.ndarray, period: float, out: Path, keep: bool, seed: int) -> Path:
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.playback import Playback
    from furuta_cosim.rig.runner import run_rig

    board = board_for(board_text, plant, log=out / "board.csv", seed=seed)
    summary = run_rig(Playback(volts, period), board, plant, out, duration=len(volts) * period, zero=not keep)
    if summary["code"] != 0:
        raise SystemExit(f"{out}: the rig run stopped: {summary['reason']}")
    return out / "experiment.yaml"


def measures(document: dict) -> dict:
    names = document["correlation"]["names"]
    matrix = np.array(document["correlation"]["matrix"])
    index = [names.index(n) for n in FOCUS]
    sub = np.abs(matrix[np.ix_(index, index)])
    np.fill_diagonal(sub, 0.0)
    i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)

    def widest(which):
        halves = {}
        for n in which:
            p = document["parameters"][n]
            halves[n] = (np.inf if not p["interval"] else (p["interval"][1] - p["interval"][0]) / 2 / abs(p["value"]))
        name = max(halves, key=halves.get)
        return {"name": name, "half_width": float(halves[name])}

    plant_names = [n for n in document["parameters"] if "." not in n]
    return {"largest_correlation": float(sub[i, j]), "pair": [FOCUS[i], FOCUS[j]],
            "widest_focus": widest(FOCUS), "widest_all": widest(plant_names),
            "values": {n: document["parameters"][n]["value"] for n in plant_names}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--truth", default="qube-servo-3-worn", help="the virtual board's plant")
    parser.add_argument("--out", default="runs/bench-design")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    import shutil

    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.identify.next_experiment import PERIOD, design, design_text, write_design
    from furuta_cosim.identify.run import identify

    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    truth = load_plant(args.truth)
    n = int(round(args.duration / PERIOD)) + 1
    t = np.arange(n) * PERIOD
    started = time.monotonic()
    swing = record("virtual:fast,pendulum=1.0", truth, np.zeros(n), PERIOD, out / "swing", True, 1)
    weak = record("virtual:fast", truth, np.where(np.sin(2 * np.pi * t) >= 0, 0.5, -0.5), PERIOD,
                  out / "motor", False, 2)
    shipped = yaml.safe_load((ROOT / "scenarios" / "identify" / "qube-servo-3.yaml").read_text())
    base = {"name": "afternoon", "plant": "qube-servo-3", "free": shipped["free"],
            "experiments": ["swing/experiment.yaml", "motor/experiment.yaml"]}
    (out / "afternoon.yaml").write_text(yaml.safe_dump(base))
    fits = {"first two logs": identify(out / "afternoon.yaml", out / "fit", profiles=False)}
    found = design(out / "afternoon.yaml", out / "fit", duration=args.duration, focus=FOCUS)
    write_design(found, out / "afternoon.yaml", out / "design")
    print(design_text(found))
    best = found["candidates"][0]
    record("virtual:fast" + (f",pendulum={best['release']:g}" if best["release"] else ""), truth, best["volts"],
           PERIOD, out / "design" / "rig", bool(best["release"]), 3)
    fits[f"+ designed ({best['name']})"] = identify(out / "design" / "next.yaml", out / "fit-designed",
                                                     profiles=False)
    record("virtual:fast,pendulum=-1.0", truth, np.zeros(n), PERIOD, out / "swing2", True, 4)
    again = dict(base, name="afternoon-swing", experiments=base["experiments"] + ["swing2/experiment.yaml"])
    (out / "again.yaml").write_text(yaml.safe_dump(again))
    fits["+ another free swing"] = identify(out / "again.yaml", out / "fit-swing", profiles=False)
    results = {name: measures(document) for name, document in fits.items()}
    results["seconds"] = time.monotonic() - started
    results["truth"] = {k: truth.parameters[k] for k in results["first two logs"]["values"]}
    if args.json:
        print(json.dumps(results))
        return 0
    print(f"virtual board: {args.truth}; experiments of {args.duration:g} s; {results['seconds']:.0f} s in all")
    print(f"{'fit':34s} {'largest corr (M_f, C0, I_a)':>30s} {'widest of M_f, C0, I_a':>24s} {'widest of all 7':>20s}")
    for name, r in results.items():
        if not isinstance(r, dict) or "pair" not in r:
            continue
        print(f"{name:34s} {r['largest_correlation']:>10.3f} ({' and '.join(r['pair'])}){'':8s}"
              f"{r['widest_focus']['name']:>8s} +-{100 * r['widest_focus']['half_width']:.3g} %"
              f"{r['widest_all']['name']:>9s} +-{100 * r['widest_all']['half_width']:.3g} %")
    print("\nfitted values against the truth (relative error):")
    for name, true in results["truth"].items():
        print(f"  {name:4s} {true:.4g}: " + ", ".join(
            f"{100 * (r['values'][name] / true - 1):+.2f} %" for r in results.values()
            if isinstance(r, dict) and "values" in r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
