"""The rig's side of ``tune --evaluator external DIR``, played on the virtual board.

A lab that runs its rig from Simulink/QUARC, LabVIEW or its own code writes a loop like this
one: watch DIR for a request (``DIR/NNNN/request.json``), run the candidate on the rig (here:
reset by the shipped swing-up, each scenario's reference from its ``reference-<name>.csv``,
damp down), and answer with ``DIR/NNNN/result.json``, written under another name first and then
renamed, so the tuning never reads half a file. Per scenario the answer is an experiment file
of the log from the moment the candidate took over (``--send experiments``, the default) or the
metrics the request names (``--send metrics``).

    python tools/external_rig.py DIR --rig qube-servo-3 --trials 30

It is also the test's external rig (tests/test_rig_tuning.py).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from pathlib import Path

import numpy as np
import yaml


def answer(request: Path, plant, board_text: str, send: str, seed: int) -> None:
    """Run the request in ``request`` and write its result.json."""
    from furuta_cosim.metrics import compute
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.runner import COLUMNS, controller_for
    from furuta_cosim.rig.trial import Segment, run_trial, segment_traces

    asked = json.loads((request / "request.json").read_text())
    segments = []
    for entry in asked["scenarios"]:
        with (request / entry["reference"]).open() as handle:
            r = np.array([float(row["r"]) for row in csv.DictReader(handle)])
        _, runtime, _, _, _ = controller_for(request / asked["controller"], period=entry["period"])
        segments.append(Segment(entry["name"], runtime, r))
    run = request / "rig-run"
    board = board_for(board_text, plant, seed=seed, log=run / "board.csv")
    summary = run_trial(segments, board, plant, run, reset="swingup-qube", period=asked["scenarios"][0]["period"])
    traces = segment_traces(run, segments)
    log = np.loadtxt(run / "log.csv", delimiter=",", skiprows=1, ndmin=2)
    column = {name: k for k, name in enumerate(COLUMNS)}
    scenarios = {}
    for k, segment in enumerate(segments):
        rows = log[log[:, column["phase"]] == k]
        if not len(rows):
            continue
        if send == "metrics":
            values = compute(traces[segment.name])
            scenarios[segment.name] = {"metrics": {m: values[m] for m in asked["metrics"]}}
            continue
        name = f"scenario-{segment.name}"
        lines = ["t,V,theta0,theta1,i"] + [
            ",".join(repr(float(v)) for v in (row[column["t"]] - rows[0, column["t"]], row[column["V"]],
                                                row[column["theta0"]], row[column["theta1"]], row[column["i"]]))
            for row in rows]
        (request / f"{name}.csv").write_text("\n".join(lines) + "\n")
        experiment = {"name": name, "data": f"{name}.csv", "columns": ["t", "V", "theta0", "theta1", "i"],
                      "time": "t", "inputs": {"V": {"column": "V", "unit": "V"}},
                      "outputs": {"theta0": {"column": "theta0", "unit": "rad"},
                                  "theta1": {"column": "theta1", "unit": "rad"},
                                  "i": {"column": "i", "unit": "A"}}}
        (request / f"{name}.yaml").write_text(yaml.safe_dump(experiment, sort_keys=False))
        scenarios[segment.name] = {"experiment": f"{name}.yaml"}
    status = "tripped" if summary["tripped"] else ("finished" if summary["code"] == 0 else "failed")
    result = {"status": status, "reason": summary["reason"], "seconds": summary["seconds"],
              "scenarios": scenarios, "failures": summary["failures"]}
    partial = request / ".result.json.partial"
    partial.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(partial, request / "result.json")


def main() -> None:
    from furuta_cosim.fmu.plants import load_plant

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="the exchange folder (tune --evaluator external DIR)")
    parser.add_argument("--rig", default="qube-servo-3", help="the virtual board's plant file")
    parser.add_argument("--board", default="virtual:fast", help="the board (default virtual:fast)")
    parser.add_argument("--send", choices=("experiments", "metrics"), default="experiments")
    parser.add_argument("--trials", type=int, default=1000, help="stop after answering this many")
    parser.add_argument("--timeout", type=float, default=600.0, help="stop after this long without a request")
    args = parser.parse_args()
    folder, plant = Path(args.folder), load_plant(args.rig)
    answered, idle = 0, 0.0
    while answered < args.trials and idle < args.timeout:
        pending = sorted(p.parent for p in folder.glob("*/request.json") if not (p.parent / "result.json").exists())
        if not pending:
            time.sleep(0.1)
            idle += 0.1
            continue
        idle = 0.0
        request = pending[0]
        answer(request, plant, args.board, args.send, seed=answered)
        answered += 1
        print(f"answered {request.name}", flush=True)


if __name__ == "__main__":
    main()
