"""Tuning with the rig in the loop, measured on a rig that is not the model.

The rig is the virtual board running ``--rig`` (default ``qube-servo-3-worn``: more friction, a
softer cable) with a ``--delay`` transport delay (default 3 ms; the model's board: 1 ms); every
controller is designed and simulated on ``qube-servo-3``. ``--rig qube-servo-3-offset --delay
0.002`` is a rig whose encoder cable pulls the arm 3 degrees off home (the reset holds the arm
home with an integral). For each seed of ``--seeds``, on the spec ``effort-qube``:

- (a) transferred: the spec tuned in simulation alone (``bo``, the spec's budget), its best
  controller run on the rig;
- (b) safe: ``tune --board`` with the safe method, at most ``--trials`` rig trials, the same
  simulation as its prior; its best controller;
- (c) the LQR (lqr-qube), the baseline;
- (d) random: ``tune --board --optimizer random``, the same number of trials, nothing but the
  supervisor between a candidate and the rig (what the safe method spares it).

(a), (b), (c) and (d) are then each run again in ``--validations`` validation trials (3; in each
round the same noise for all, new to every tuning), each scored against the LQR's trial of its
round: the rig objective of the table is the mean, and a controller counts as feasible when it
was in every round. Differential evolution is not a row: its first generation (5 x 11
candidates) is already beyond 30 trials. Each row also says the trials each tuning broke a
constraint in or had stopped by the supervisor, and the wall time; the safe tuning's own trials
say how many it took to beat the LQR's trial (the first feasible trial scoring below it) and
its best feasible trial after 15 and after 30 trials (one trial's score each, not validated); ``--paced N`` runs the first
N seeds' safe tuning again on the board paced in real time (its wall time beside the unpaced
one's).

    python tools/bench_rig_tune.py --seeds 10 --out bench-rig-tune
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import time
from pathlib import Path

from furuta_cosim.controllers import load_controller
from furuta_cosim.errors import RunStopped
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.tuning.rig import Fidelity, RigEvaluator, tune_on_rig
from furuta_cosim.tuning.spec import load_spec
from furuta_cosim.tuning.trials import BoardTrials

RIG, DELAY = "qube-servo-3-worn", 0.003
BOARD = {"delay": DELAY}  # the virtual board's options (--delay)


def trials_on(board: str, plant, spec, seed: int) -> BoardTrials:
    return BoardTrials(board, plant, spec.rig.reset, spec.rig.fall, seed, dict(BOARD))


def progress(folder: Path) -> dict:
    """From a rig tuning's history: the trials it took to beat the LQR's trial (the safe seed,
    trial 1; None if none did) and its best feasible trial after 15 and after 30 trials."""
    records = [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines() if line.strip()]
    lqr = records[0]["objective"]
    beat = next((k + 1 for k, r in enumerate(records) if r.get("feasible") and r["objective"] < lqr), None)

    def best(n):
        values = [r["objective"] for r in records[:n] if r.get("feasible")]
        return min(values) if values else None
    return {"beat_lqr_at": beat, "best_15": best(15), "best_30": best(30), "lqr_trial": lqr}


def tuned(spec, plant, folder: Path, seed: int, n_trials: int, method: str, board: str) -> tuple[dict, float]:
    if folder.exists():
        shutil.rmtree(folder)
    trials = trials_on(board, plant, spec, seed)
    started = time.perf_counter()
    document = tune_on_rig(spec, folder, trials, method=method, n_trials=n_trials, seed=seed)
    return document, time.perf_counter() - started


def validated(spec, plant, folder: Path, seed: int, files: dict, count: int) -> dict:
    """Each controller file of ``files`` (and the LQR) in ``count`` validation trials on the rig,
    each round against the LQR's trial of that round, the noise new to every tuning: name ->
    (the mean of its values, the rounds it was feasible in)."""
    rounds = []
    for v in range(count):
        where = folder / f"round-{v}"
        if where.exists():
            shutil.rmtree(where)
        trials = trials_on("virtual:fast", plant, spec, seed + 1000 * (v + 1))
        evaluator = RigEvaluator(spec, trials, where, Fidelity(spec, []))
        evaluator.check_references()
        found = {}
        for k, (name, path) in enumerate(files.items()):
            evaluator.index = k
            outcome = evaluator.score(load_controller(path))
            found[name] = (outcome.value, outcome.feasible)
        lqr = evaluator.baseline_outcome(spec.baselines[0])
        found["lqr"] = (lqr.value, lqr.feasible)
        rounds.append(found)
    result = {}
    for name in rounds[0]:
        values = [r[name][0] for r in rounds]
        mean = None if any(v is None for v in values) else statistics.fmean(values)
        result[name] = (mean, sum(1 for r in rounds if r[name][1]))
    return result


def shown(value, feasible, count) -> str:
    if value is None:
        return "failed"
    return f"{value:.3f}" + ("" if feasible == count else f" (feasible in {feasible} of {count})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--paced", type=int, default=0, help="seeds whose safe tuning also runs paced")
    parser.add_argument("--validations", type=int, default=3, help="validation trials per controller")
    parser.add_argument("--out", default="bench-rig-tune")
    parser.add_argument("--rig", default=RIG, help=f"the virtual board's plant (default {RIG})")
    parser.add_argument("--delay", type=float, default=DELAY, help=f"its transport delay in s (default {DELAY})")
    args = parser.parse_args()
    BOARD["delay"] = args.delay
    spec = load_spec("effort-qube")
    plant = load_plant(args.rig)
    out = Path(args.out)
    rows = []
    for seed in range(args.seeds):
        safe, safe_wall = tuned(spec, plant, out / f"seed-{seed}" / "safe", seed, args.trials, "safe", "virtual:fast")
        rand, rand_wall = tuned(spec, plant, out / f"seed-{seed}" / "random", seed, args.trials, "random",
                                "virtual:fast")
        folder = out / f"seed-{seed}" / "safe"
        files = {"transferred": folder / "simulation" / "best.yaml", "safe": folder / "best.yaml"}
        if (out / f"seed-{seed}" / "random" / "best.yaml").is_file():
            files["random"] = out / f"seed-{seed}" / "random" / "best.yaml"
        scores = validated(spec, plant, out / f"seed-{seed}" / "validation", seed, files, args.validations)
        row = {"seed": seed, "scores": scores, "safe": {k: safe[k] for k in ("trials", "violations", "trips")},
               "random": {k: rand[k] for k in ("trials", "violations", "trips")},
               "safe_best_in_run": safe["best"]["objective"] if safe["best"] else None,
               "progress": progress(out / f"seed-{seed}" / "safe"),
               "wall": {"safe": safe_wall, "random": rand_wall}}
        rows.append(row)
        print(f"seed {seed}: " + ", ".join(f"{k} {shown(*v, args.validations)}" for k, v in scores.items())
              + f"; safe: {safe['violations']} broke a constraint, {safe['trips']} tripped, "
                f"{safe['trials']} trials, {safe_wall:.0f} s; random: {rand['violations']} broke a "
                f"constraint, {rand['trips']} tripped", flush=True)
    # the paced runs last: in real time a loaded machine's late samples change what the rig does
    stopped = []
    for row in rows[:args.paced]:
        seed = row["seed"]
        try:
            _, row["wall"]["safe_paced"] = tuned(spec, plant, out / f"seed-{seed}" / "safe-paced", seed,
                                                 args.trials, "safe", "virtual")
        except RunStopped as error:
            stopped.append(f"seed {seed}: {error}")
    (out / "results.json").write_text(json.dumps(rows, indent=2) + "\n")
    print()
    print(f"rig objective: the mean of {args.validations} validation trials; infeasible unless feasible in every one")
    print("| | rig objective, median | worst | seeds where (b) is lower | trials that broke a constraint "
          "(seeds with none) | supervisor trips |")
    print("|---|---|---|---|---|---|")
    for name, label in (("transferred", "(a) tuned in simulation, transferred"),
                        ("safe", "(b) safe, on the rig"), ("lqr", "(c) LQR"), ("random", "(d) random, on the rig")):
        values = [r["scores"][name] for r in rows if name in r["scores"]]
        if not values:
            continue
        objective = [v if (v is not None and ok == args.validations) else float("inf") for v, ok in values]
        lower = sum(1 for r in rows if name in r["scores"]
                    and _beats(r["scores"]["safe"], r["scores"][name], args.validations))
        counts = {"safe": "safe", "random": "random"}.get(name)
        broke = trips = "-"
        if counts:
            broke = (f"{sum(r[counts]['violations'] for r in rows)} "
                     f"({sum(1 for r in rows if r[counts]['violations'] == 0)} of {len(rows)})")
            trips = str(sum(r[counts]["trips"] for r in rows))
        infeasible = sum(1 for v, ok in values if ok < args.validations)
        print(f"| {label} | {_fmt(statistics.median(objective))} | {_fmt(max(objective))}"
              + (f" ({infeasible} infeasible)" if infeasible else "")
              + f" | {'-' if name == 'safe' else f'{lower} of {len(values)}'} | {broke} | {trips} |")
    known = [v for r in rows for v, ok in r["scores"].values() if v is not None and ok == args.validations]
    print(f"\nthe lowest known: {min(known):.3f} (any controller here, feasible in every validation round)")
    beats = [r["progress"]["beat_lqr_at"] for r in rows]
    found = sorted(b for b in beats if b is not None)
    print(f"\nthe safe tuning's own trials (one trial's score each): beat the LQR's trial at trial "
          + (f"{statistics.median(found):g} (median), {max(found)} (worst)" if found else "-")
          + f", in {len(found)} of {len(rows)} seeds")
    for n in (15, 30):
        bests = [r["progress"][f"best_{n}"] for r in rows if r["progress"][f"best_{n}"] is not None]
        if bests and n <= args.trials:
            print(f"best feasible trial after {n} trials: median {statistics.median(bests):.3f}, "
                  f"worst {max(bests):.3f} (the LQR's trial {rows[0]['progress']['lqr_trial']:.3f})")
    walls = [r["wall"]["safe"] for r in rows]
    print(f"wall time of a safe tuning (simulation prior included), unpaced: median {statistics.median(walls):.0f} s")
    paced = [r["wall"]["safe_paced"] for r in rows if "safe_paced" in r["wall"]]
    if paced:
        print(f"paced in real time: {', '.join(f'{w:.0f} s' for w in paced)} "
              f"({paced[0] / walls[0]:.0f} times the unpaced run of the same seed)")
    for line in stopped:
        print(f"paced in real time, stopped: {line}")


def _beats(ours, theirs, count: int) -> bool:
    """(b) is lower: feasible in every validation round, and the other is not or scores more."""
    value, ok = ours
    other, other_ok = theirs
    return ok == count and value is not None and (other_ok < count or other is None or value < other)


def _fmt(value: float) -> str:
    return "infeasible" if value == float("inf") else f"{value:.3f}"


if __name__ == "__main__":
    main()
