"""The Pareto front of a ``tradeoff`` tuning, as the run directory holds it:

    front.csv, front.json   the non-dominated feasible points along the first criterion: their
                            evaluation, criteria, origin and controller file; the knee; the
                            baselines' criteria and what the front reaches at each baseline
    front/NN.yaml           the controller of each front point (a file simulate accepts)
    tradeoff.png, .svg      every feasible point, the front, its knee and the baselines

and each history line gets ``front: true`` or ``false`` (the history is rewritten atomically
at the end of the run; a resumed run marks its front again).
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from furuta_cosim.config import excerpt, plain_name
from furuta_cosim.documents import dumps
from furuta_cosim.files import folder as make_folder, write_text
from furuta_cosim.tuning import pareto
from furuta_cosim.tuning.saved import save_scored


def write_front(evaluator, folder: Path, records: list[dict], baselines: dict, method: str,
                seed: int) -> dict:
    """Every front file of the run; the front's part of the summary document."""
    from furuta_cosim.report.figures import plot_tradeoff

    spec = evaluator.spec
    names = [criterion.name for criterion in spec.objective.criteria]
    on_front = pareto.front_of(records, names)
    points = []
    files = make_folder(folder / "front")
    for rank, k in enumerate(on_front):
        record = records[k]
        file = f"front/{rank:02d}.yaml"
        prefilter = save_scored(evaluator, record, folder / file, f"{spec.name}-front-{rank:02d}",
                                f"point {rank} of the front of tuning {spec.name} ({method}, seed {seed})",
                                method, seed)
        points.append({"index": record["index"], "criteria": record["criteria"],
                       "origin": record.get("origin") or "", "file": file, "prefilter": prefilter,
                       "parameters": record["parameters"]})
    kept = {Path(p["file"]).name for p in points}
    for stale in files.glob("*.yaml"):  # a resumed run's earlier front
        if stale.name not in kept:
            stale.unlink()
    knee = pareto.knee([pareto.criteria_of(records[k], names) for k in on_front]) if on_front else None
    reached = {name: reach(points, names, b.get("criteria")) for name, b in baselines.items()}
    document = {"criteria": names, "points": points,
                "knee": points[knee]["index"] if knee is not None else None,
                "knee_file": points[knee]["file"] if knee is not None else None,
                "baselines": {name: {"criteria": b.get("criteria"), "feasible": b["feasible"]}
                              for name, b in baselines.items()},
                "at_baselines": reached}
    write_text(folder / "front.json", dumps(document, indent=2) + "\n")
    write_text(folder / "front.csv", _csv(points, names))
    feasible = [pareto.criteria_of(r, names) for r in records if r.get("feasible")]
    plot_tradeoff([row for row in feasible if row is not None],
                  [[p["criteria"][n] for n in names] for p in points], knee, names,
                  {name: b.get("criteria") for name, b in baselines.items()}, folder / "tradeoff",
                  title=f"{spec.name}: {method}, seed {seed}")
    _mark(folder / "history.jsonl", records, {records[k]["index"] for k in on_front})
    return document


def reach(points: list[dict], names: list[str], baseline: dict | None) -> dict:
    """For each criterion, the lowest value a front point reaches while no worse than the
    baseline in every other criterion (None: no such point), and that point's evaluation."""
    if not baseline or any(baseline.get(n) is None for n in names):
        return {}
    found = {}
    for name in names:
        fits = [p for p in points if all(p["criteria"][o] <= baseline[o] for o in names if o != name)]
        best = min(fits, key=lambda p: p["criteria"][name]) if fits else None
        found[name] = ({"value": best["criteria"][name], "index": best["index"], "file": best["file"],
                        "change": best["criteria"][name] / baseline[name] - 1 if baseline[name] else None}
                       if best else None)
    return found


def _csv(points: list[dict], names: list[str]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["evaluation", *names, "origin", "file"])
    for p in points:
        writer.writerow([p["index"], *(repr(p["criteria"][n]) for n in names), p["origin"], p["file"]])
    return out.getvalue()


def _mark(path: Path, records: list[dict], front: set) -> None:
    for record in records:
        record["front"] = record["index"] in front
    write_text(path, "".join(dumps(r) + "\n" for r in records))


def summary_lines(front: dict) -> list[str]:
    """The front in words, for summary.md."""
    names, points = front["criteria"], front["points"]
    lines = ["", f"Pareto front: {len(points)} non-dominated feasible points of "
                 f"{', '.join(names)} (front.csv, front.json, tradeoff.png; each point's "
                 "controller in front/)."]
    if not points:
        return lines + ["No feasible point: no front."]
    knee = next(p for p in points if p["index"] == front["knee"])
    lines.append(f"Knee: evaluation {knee['index']} ({_values(knee['criteria'], names)}), "
                 f"{knee['file']}.")
    for name, reached in front["at_baselines"].items():
        baseline = front["baselines"][name]["criteria"]
        if not reached:
            lines.append(f"- {name}: its criteria could not be computed (it diverged on a run)")
            continue
        if not front["baselines"][name]["feasible"]:
            lines.append(f"- {name} ({_values(baseline, names)}): infeasible, not compared")
            continue
        lines.append(f"- {name} ({_values(baseline, names)}):")
        for criterion, found in reached.items():
            others = " and ".join(o for o in names if o != criterion)
            if found is None:
                lines.append(f"  - no front point is as good in {others}")
            else:
                lines.append(f"  - at its {others} or better, the lowest {criterion} on the front is "
                             f"{found['value']:.4g} ({found['change'] * 100:+.1f} %, evaluation "
                             f"{found['index']}, {found['file']})")
    return lines


def _values(criteria: dict, names: list[str]) -> str:
    return ", ".join(f"{n} {criteria[n]:.4g}" for n in names)


def load_front(folder: Path) -> dict:
    """A run directory's front.json (for comparisons across runs)."""
    from furuta_cosim.errors import ConfigError

    path = Path(folder) / "front.json"
    try:
        document = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError([f"{folder}: no front.json (is it the run directory of a tradeoff "
                           "tuning that finished?)"]) from None
    except (OSError, ValueError) as error:
        raise ConfigError([f"{path}: cannot be read ({error})"]) from None
    if not isinstance(document, dict) or not isinstance(document.get("points"), list) \
            or not isinstance(document.get("criteria"), list):
        raise ConfigError([f"{path}: not a front (expected criteria and points)"])
    problems = _front_problems(document)
    if problems:
        raise ConfigError([f"{path}: {problem}" for problem in problems[:10]])
    return document


def _front_problems(document: dict) -> list[str]:
    """What a comparison would trip over: criteria that are not distinct names, a point or a
    baseline without a finite number for every criterion."""
    names = document["criteria"]
    if not names or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
        return [f"criteria: expected distinct names, got {excerpt(repr(names))}"]
    problems = []

    def numbers(values, key: str) -> None:
        if not isinstance(values, dict):
            problems.append(f"{key}: expected a mapping of {', '.join(names)}, got {type(values).__name__}")
            return
        for name in names:
            value = values.get(name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                problems.append(f"{key}.{name}: expected a finite number, got {excerpt(repr(value))}")

    for k, point in enumerate(document["points"]):
        numbers(point.get("criteria") if isinstance(point, dict) else point, f"points[{k}].criteria")
        if isinstance(point, dict):
            if isinstance(point.get("index"), bool) or not isinstance(point.get("index"), int):
                problems.append(f"points[{k}].index: expected the evaluation's number")
            if not isinstance(point.get("file"), str):
                problems.append(f"points[{k}].file: expected the point's controller file")
    baselines = document.get("baselines", {})
    if not isinstance(baselines, dict):
        return problems + [f"baselines: expected a mapping, got {type(baselines).__name__}"]
    for name, baseline in baselines.items():
        name = name if plain_name(name) else excerpt(name)
        if not isinstance(baseline, dict) or not isinstance(baseline.get("feasible"), bool):
            problems.append(f"baselines.{name}: expected feasible (true or false) and criteria")
        elif baseline.get("criteria") is not None:
            numbers(baseline["criteria"], f"baselines.{name}.criteria")
    return problems


def compare(folders, out: Path) -> dict:
    """The fronts of several tradeoff runs on one figure (``out``/fronts.png and .svg) with the
    first run's baselines, and in words (fronts.md, fronts.json): for each feasible baseline,
    the lowest value of each criterion each front reaches while no worse in the others, the
    hypervolume of each front against one reference point (the worst value of each criterion
    over every front and baseline drawn, times 1.1), and for every run after the first how it
    differs from the first."""
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.files import output_folder
    from furuta_cosim.report.figures import plot_tradeoff

    fronts, labels = [], []
    for folder in folders:
        front = load_front(folder)
        try:
            name = json.loads((Path(folder) / "summary.json").read_text()).get("spec")
        except (OSError, ValueError):
            name = None
        label = str(name or Path(folder).name)
        while label in labels:
            label += "'"
        fronts.append(front)
        labels.append(label)
    names = fronts[0]["criteria"]
    for folder, front in zip(folders, fronts):
        if front["criteria"] != names:
            raise ConfigError([f"{Path(folder) / 'front.json'}: criteria: {', '.join(front['criteria'])} "
                               f"differ from {Path(folders[0]) / 'front.json'}'s ({', '.join(names)}): "
                               "the fronts are not comparable"])
    baselines = {n: b for n, b in fronts[0]["baselines"].items() if b.get("criteria")}
    rows = {label: [[p["criteria"][n] for n in names] for p in front["points"]]
            for label, front in zip(labels, fronts)}
    drawn = [row for front in rows.values() for row in front]
    drawn += [[b["criteria"][n] for n in names] for b in baselines.values() if b["feasible"]]
    reference = (1.1 * np.max(np.array(drawn), axis=0)).tolist() if drawn else None
    document = {"criteria": names, "reference": reference, "runs": {}}
    for label, front, folder in zip(labels, fronts, folders):
        document["runs"][label] = {
            "folder": str(folder), "points": len(front["points"]),
            "hypervolume": pareto.hypervolume(rows[label], reference) if reference else None,
            "at_baselines": {n: reach(front["points"], names, b["criteria"])
                             for n, b in baselines.items() if b["feasible"]}}
    out = make_folder(output_folder(out))
    plot_tradeoff([], [], None, names, {n: b["criteria"] for n, b in baselines.items()},
                  out / "fronts", title="Pareto fronts", fronts=rows)
    write_text(out / "fronts.json", dumps(document, indent=2) + "\n")
    write_text(out / "fronts.md", "\n".join(_comparison(document, labels, baselines)) + "\n")
    return document


def _comparison(document: dict, labels: list[str], baselines: dict) -> list[str]:
    names, runs = document["criteria"], document["runs"]
    lines = ["# Pareto fronts compared", "", "| run | points | hypervolume |", "| --- | --- | --- |"]
    for label in labels:
        volume = runs[label]["hypervolume"]
        lines.append(f"| {label} | {runs[label]['points']} | "
                     + ("-" if volume is None else f"{volume:.4g}") + " |")
    if document["reference"]:
        lines += ["", "Hypervolume against the reference point ("
                  + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, document["reference"]))
                  + "): larger is better."]
    for name, baseline in baselines.items():
        if not baseline["feasible"]:
            lines += ["", f"{name}: infeasible, not compared."]
            continue
        lines += ["", f"At {name} ({_values(baseline['criteria'], names)}):"]
        for criterion in names:
            others = " and ".join(o for o in names if o != criterion)
            found = {label: runs[label]["at_baselines"][name].get(criterion) for label in labels}
            text = "; ".join(f"{label} {v['value']:.4g} ({v['change'] * 100:+.1f} %)" if v
                             else f"{label} none" for label, v in found.items())
            lines.append(f"- the lowest {criterion} at its {others} or better: {text}")
            first = found[labels[0]]
            for label in labels[1:]:
                other = found[label]
                if first and other:
                    lines.append(f"  - {labels[0]} against {label}: {criterion} "
                                 f"{(first['value'] / other['value'] - 1) * 100:+.1f} %")
    return lines
