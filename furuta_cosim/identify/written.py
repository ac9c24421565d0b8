"""What identify writes and prints: the fitted plant file, the summary, the report page and
each log's overlay and residual figures (the write stage's formatting; identify/pipeline.py).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from furuta_cosim.identify.fit import FitResult, with_values
from furuta_cosim.identify.verdict import line as verdict_line


def per_log(pairs) -> dict:
    """``{log: [(experiment, its simulations), ...]}``: a log's segments (``log@k``) together."""
    found: dict = {}
    for experiment, simulated in pairs:
        name = experiment.alias if experiment.alias and "@" in experiment.name else experiment.name
        found.setdefault(name, []).append((experiment, simulated))
    return found


def draw_figures(out: Path, name: str, members) -> list[Path]:
    """A log's overlay and residuals: ``members`` its (experiment, {label: simulated outputs})
    pairs, its segments (each from its own start) drawn one after the other on the log's time
    axis, the line broken between them."""
    from furuta_cosim.report.rig import plot_overlay, plot_residuals

    first = members[0][0]
    gap = [np.array([np.nan])] if len(members) > 1 else []

    def joined(pieces):
        parts = []
        for k, piece in enumerate(pieces):
            parts += ([] if k == 0 else gap) + [np.asarray(piece, dtype=float)]
        return np.concatenate(parts)

    t = joined([e.t for e, _ in members])
    measured = {n: joined([e.outputs[n].values for e, _ in members]) for n in first.outputs}
    labels = list(members[0][1])
    simulated = {label: {n: joined([runs[label][n] for _, runs in members]) for n in first.outputs}
                 for label in labels}
    quantum = {n: 2 * 3 ** 0.5 * m.sigma for n, m in first.outputs.items() if m.sigma_from == "quantum"}
    segments = f" ({len(members)} segments, each from its measured state)" if len(members) > 1 else ""
    written = plot_overlay(t, measured, simulated, out / f"{name}-overlay", f"{name}: measured and simulated{segments}")
    written += plot_residuals(t, measured, simulated, out / f"{name}-residuals",
                              f"{name}: simulated - measured{segments}", quantum)
    return [p for p in written if p.suffix == ".png"]


def plant_text(result: FitResult, out: Path, rejected: str | None = None, verdict: dict | None = None) -> str:
    """The fitted plant file: the spec's plant extended with the fitted values (a name stays a
    name; a file is named by its path relative to ``out``, so the folder travels). A fit the
    verdict does not trust carries ``rejected: <why>``, which load_plant refuses."""
    spec, plant = result.spec, result.target.plant
    base = spec.plant
    if "/" in base or base.endswith((".yaml", ".yml")):
        base = os.path.relpath(Path(plant.path).resolve(), out.resolve())
    document = {
        "model": plant.model,
        "extends": base,
        "description": f"{plant.name} fitted to {', '.join(e.name for e in spec.experiments)} "
                       f"(identify {spec.name})",
        "parameters": {name: float(value) for name, value in with_values(result).items()},
        "provenance": {
            "identify": spec.name,
            "data": {e.name: {"file": e.data.name, "sha256": e.sha256} for e in spec.experiments},
            "rms": {name: {o: c["rms"] for o, c in outputs.items()}
                    for name, outputs in result.experiments.items()},
            "fit": "fit.json",
        },
    }
    if verdict is not None:
        document["provenance"]["verdict"] = ("trusted" if verdict["trusted"] else
                                             "not trusted, written with --accept: " + "; ".join(verdict["reasons"]))
    if rejected is not None:
        document = {"rejected": rejected, **document}
    head = (f"# Written by furuta-cosim identify {spec.name}: the fitted parameters on top of "
            f"{base}.\n# Their intervals and correlations are in fit.json beside this file.\n")
    return head + yaml.safe_dump(document, sort_keys=False)


def _bounds_text(interval) -> str:
    """``[lo, hi]``, a side the profile never crossed said so."""
    if interval is None:
        return "none"
    lo, hi = interval
    return (f"[{'to its bound' if lo is None else format(lo, '.4g')}, "
            f"{'to its bound' if hi is None else format(hi, '.4g')}]")


def parameter_rows(document: dict) -> list[list[str]]:
    """Per unknown: name, start, fitted, each interval fit.json has, the verdict (text cells)."""
    bootstrap = any("interval_bootstrap" in p for p in document["parameters"].values())
    rows = [["parameter", "start", "fitted", "sandwich 95 %", "profile 95 %"]
            + (["bootstrap 95 %"] if bootstrap else []) + ["verdict"]]
    for name, p in document["parameters"].items():
        fitted = f"{p['value']:.5g}" + (" (at a bound)" if p.get("at_bound") else "")
        row = [name, f"{p['start']:.5g}", fitted, _bounds_text(p["interval"]),
               _bounds_text(p["interval_profile"]) if "interval_profile" in p else "not profiled"]
        if bootstrap:
            row.append(_bounds_text(p.get("interval_bootstrap")) if "interval_bootstrap" in p else "")
        rows.append(row + [p["verdict"]])
    return rows


def summary_text(document: dict, out: Path) -> str:
    """What ``identify`` prints: the values and intervals, the verdicts, the optima of a
    multi-start, the pairs not separable, the residuals."""
    rows = parameter_rows(document)
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]) - 1)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r[:-1], widths)) + "  " + r[-1] for r in rows]
    optima = (document.get("starts") or {}).get("optima") or []
    if len(optima) > 1:
        lines.append(f"{document['starts']['count']} starts, {len(optima)} distinct optima: "
                     + "; ".join(f"cost {o['cost']:.6g} ({len(o['starts'])} start(s))" for o in optima)
                     + "; the lowest is kept")
    elif document.get("starts", {}).get("count", 1) > 1:
        lines.append(f"{document['starts']['count']} starts, all at the same optimum")
    for a, b, r in document["not_separable"]:
        lines.append(f"not separable: {a} and {b} (correlation {r:+.3f})")
    for kind, name, output, start, c in _replays(document):
        period = c.get("period", {}).get("error")
        segments = c.get("segments")
        lines.append(f"{'validation ' if kind == 'validation' else ''}{name} {output}: RMS {start:.4g} -> "
                     f"{c['rms']:.4g}" + (f" ({c['rms'] * 57.29577951308232:.4g} deg)"
                                          if output.startswith("theta") else "")
                     + ("" if period is None else f", period {100 * period:+.3f} %")
                     + (f" over {segments['count']} segments (median segment {segments['median']:.4g}, worst "
                        f"{segments['worst']:.4g}: {segments['worst_of'][0]})" if segments else ""))
    lines.append(f"{document['simulations']} simulations in {document['seconds']:.1f} s; "
                 f"plant.yaml, fit.json and report.html in {out}")
    if document.get("profiles"):
        lines.append(f"profiles: {document['profiles']['simulations']} simulations in "
                     f"{document['profiles']['seconds']:.1f} s")
    if document.get("bootstrap"):
        lines.append(f"bootstrap: {document['bootstrap']['replicates']} replicates in "
                     f"{document['bootstrap']['seconds']:.1f} s")
    if document["message"].startswith("stopped"):
        lines.append(f"note: {document['message']}: the fit is the best point found within the budget")
    verdict = document.get("verdict")
    if verdict:
        lines += [f"note: {n}" for n in verdict["notes"]]
        lines.append(verdict_line(verdict) + (" (plant.yaml written all the same: --accept)"
                                              if document.get("accepted") else
                                              "" if verdict["trusted"] else " (plant.yaml is marked rejected)"))
    return "\n".join(lines) + "\n"


def _replays(document: dict) -> list[tuple]:
    """(kind, log, output, RMS at the start values, the fitted comparison) per log and output,
    the segments of a log fitted by multiple shooting as one log (identify/verdict.py by_log)."""
    from furuta_cosim.identify.verdict import by_log

    found = []
    for kind in ("experiments", "validation"):
        start = by_log({kind: {name: document["at_start"][name] for name in document[kind]},
                        "data": document.get("data", {})}, kind)
        for (name, output), c in by_log(document, kind).items():
            found.append((kind, name, output, start[(name, output)]["rms"], c))
    return found


def report_page(document: dict, out: Path) -> str:
    from furuta_cosim.report.html import figure, markdown_to_html, page

    table = parameter_rows(document)
    rows = ["| " + " | ".join(table[0]) + " |", "|" + "---|" * len(table[0])]
    rows += ["| " + " | ".join(r) + " |" for r in table[1:]]
    fits = ["| experiment | output | RMS at start | RMS fitted | period error fitted |", "|---|---|---|---|---|"]
    for kind, name, output, start, c in _replays(document):
        period = c.get("period", {}).get("error")
        segments = c.get("segments")
        shown = name + (f" ({segments['count']} segments, the worst {', '.join(segments['worst_of'])})"
                        if segments else "")
        fits.append(f"| {shown}{' (validation)' if kind == 'validation' else ''} | {output} | "
                    f"{start:.4g} | {c['rms']:.4g} | {'' if period is None else f'{100 * period:+.3f} %'} |")
    pairs = "".join(f"- {a} and {b}: correlation {r:+.3f}, not separable on these data\n"
                    for a, b, r in document["not_separable"]) or "- none above 0.95\n"
    methods = f"Intervals: sandwich, {document['interval_method']}."
    if document.get("interval_profile_method"):
        methods += f" Profile, {document['interval_profile_method']}."
    if document.get("bootstrap"):
        methods += f" Bootstrap, {document['bootstrap']['method']} ({document['bootstrap']['replicates']} replicates)."
    optima = (document.get("starts") or {}).get("optima") or []
    starts = ""
    if document.get("starts", {}).get("count", 1) > 1:
        starts = (f"\n## Starts\n\n{document['starts']['count']} starts reached {len(optima)} distinct "
                  "optima (the lowest kept):\n\n" + "".join(
                      f"- cost {o['cost']:.6g} from {len(o['starts'])} start(s)\n" for o in optima))
    text = (f"# identify {document['name']}\n\n"
            f"Plant {document['plant']}; {document['simulations']} simulations in "
            f"{document['seconds']:.1f} s; {document['message']}\n\n" + "\n".join(rows) + "\n\n"
            + methods + " The textbook s^2 (J^T J)^-1, which assumes independent residuals, is in "
            "fit.json (stderr_plain).\n" + starts + "\n## Correlated pairs\n\n" + pairs
            + "\n## Residuals (SI units: rad, A)\n\n" + "\n".join(fits) + "\n")
    data = ["| experiment | file | samples | window [s] | sha256 |", "|---|---|---|---|---|"]
    data += [f"| {name} | {d['file']} | {d['samples']} | {d['window'][0]:g} to {d['window'][1]:g} | {d['sha256'][:16]} |"
             for name, d in document["data"].items()]
    text += "\n## Data\n\n" + "\n".join(data) + f"\n\nPlant FMU sha256 {document['fmu_sha256'][:16]}.\n"
    body = markdown_to_html(text) + "".join(
        figure(out / Path(name).with_suffix(".svg"), Path(name).stem) for name in document["figures"])
    return page(f"identify {document['name']}", body)
