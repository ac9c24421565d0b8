"""The end of a tuning run: the best controller saved, the baselines scored alike, and the
summary in JSON and in words (summary.json, summary.md, what ``tune`` prints)."""

from __future__ import annotations

from pathlib import Path

from furuta_cosim.documents import dumps, json_safe
from furuta_cosim.files import write_text
from furuta_cosim.metrics import HEADLINE, entry, peak_metric
from furuta_cosim.report.figures import plot_convergence
from furuta_cosim.tuning.methods import front_search
from furuta_cosim.tuning.spec import TuningSpec


def _variant_spread(evaluator, document) -> dict:
    """Per controller (the tuned one, each baseline): its objective on each plant variant
    alone, the worst of them and their spread."""
    found = {}
    candidates = ([("tuned", document["best"]["metrics"])] if document["best"] else []) + [
        (name, b.get("metrics") or {}) for name, b in document["baselines"].items()]
    for name, metrics in candidates:
        scores = evaluator.by_variant(metrics)
        known = [v for v in scores if v is not None]
        found[name] = {"scores": scores,
                       "worst": max(known) if len(known) == len(scores) else None,
                       "best": min(known) if known else None}
    return found


def finish(spec, folder, evaluator, records, n_calls, method, seed, clock) -> dict:
    """The run's summary: best.yaml, the baselines scored alike, summary.json, summary.md and
    the convergence figure, written to ``folder``; returns the summary document."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.tuning.saved import save_scored

    feasible = [r for r in records if r["feasible"]]
    best = min(feasible, key=lambda r: (r["objective"], r["index"])) if feasible else None
    baselines = {}
    for name in spec.baselines:
        cfile = load_controller(name)
        outcome = evaluator.score(cfile if cfile.swingup is not None else cfile.controller)
        baselines[cfile.name] = json_safe({"objective": outcome.objective,
                                            "feasible": outcome.feasible,
                                            **({"criteria": outcome.criteria}
                                               if outcome.criteria is not None else {}),
                                            "constraints": outcome.constraints,
                                            "metrics": outcome.metrics})
    failures = sum(1 for r in records if r["error"])
    warnings = evaluator.vacuous() if spec.objective.type != "spectral" else []
    document = {"spec": spec.name, "method": method, "seed": seed, "n_calls": n_calls,
                "evaluations": len(records), "feasible": len(feasible), "failed": failures,
                "objective": spec.objective.type, "optimizer_seconds": clock["optimizer"],
                "evaluation_seconds": clock["evaluation"], "early": _early(records),
                "best": None, "baselines": baselines, "warnings": warnings}
    if method == "bo" and spec.objective.type == "tradeoff":
        document["search"] = {"ehvi": "expected hypervolume improvement",
                              "parego": "ParEGO scalarizations"}[front_search(spec)]
    if best is not None:
        prefilter = save_scored(evaluator, best, folder / "best.yaml", f"{spec.name}-best",
                                f"best of tuning {spec.name} ({method}, seed {seed})", method, seed)
        document["best"] = {"index": best["index"], "objective": best["objective"],
                            "origin": best.get("origin") or "", "parameters": best["parameters"],
                            "metrics": best["metrics"], "file": "best.yaml",
                            "prefilter": prefilter,
                            "controller": _matrices(_controller_of(load_controller(folder / "best.yaml")))}
    if best is not None:
        document["flags"] = flags(spec, evaluator, best, baselines)
    if spec.objective.type != "spectral":
        # the plant FMUs the scores came from, by content: a rebuilt FMU shows as another hash
        document["fmus"] = {prepared.fmu.name: _sha256(prepared.fmu) for _, prepared, _ in evaluator.runs()}
    if len(spec.variants) > 1 and spec.objective.type == "scenarios":
        document["variants"] = _variant_spread(evaluator, document)
    if spec.objective.type == "tradeoff":
        from furuta_cosim.tuning.front import write_front

        document["front"] = write_front(evaluator, folder, records, baselines, method, seed)
    levels = {name: b["objective"] for name, b in baselines.items() if b["feasible"]}
    plot_convergence(records, folder / "convergence", levels)
    if best is not None and spec.objective.type != "spectral":
        document["responses"] = _responses(evaluator, folder, spec.baselines)
    if best is not None:
        document["loop"] = _loop(spec, evaluator, folder)
    write_text(folder / "summary.json", dumps(document, indent=2) + "\n")
    write_text(folder / "summary.md", summary_text(spec, document))
    return document


def _responses(evaluator, folder: Path, baselines) -> dict:
    """The best controller's response beside each baseline's, one figure per scenario run
    (``responses/<run>.png`` and .svg); ``{run label: figure path relative to folder}``."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.report.figures import plot_runs

    best = load_controller(folder / "best.yaml")
    runs = {"tuned": evaluator.traces(best if best.swingup is not None else best.controller)}
    for name in baselines:
        cfile = load_controller(name)
        runs[cfile.name] = evaluator.traces(cfile if cfile.swingup is not None else cfile.controller)
    found = {}
    (folder / "responses").mkdir(exist_ok=True)
    for label in runs["tuned"]:
        traces = {who: found_runs[label] for who, found_runs in runs.items() if label in found_runs}
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
        plot_runs(traces, folder / "responses" / safe, f"{label}: tuned and baseline")
        found[label] = f"responses/{safe}.png"
    return found


def _loop(spec, evaluator, folder: Path) -> dict | None:
    """The best controller's margins on the design model, of the loop that runs (a continuous
    controller sampled at the spec's period), and its Bode, Nyquist and sensitivity plots in
    ``loop/``; None for a swing-up file or a loop without margins."""
    from furuta_cosim.controllers import load_controller
    from furuta_cosim.design.analysis import analyze

    best = load_controller(folder / "best.yaml")
    if best.swingup is not None:
        return None
    c = best.controller
    model = evaluator.model
    sampling = spec.period if not c.discrete and spec.period else None
    try:
        analysis = analyze(model, c, margins=True, sampling_period=sampling)
    except Exception as error:  # noqa: BLE001 - the figures are extra: a run's summary stands without them
        return {"problem": f"not analysed: {error}"}
    margins = analysis.running_margins
    if margins is None:
        return {"problem": "no margins: the loop is unstable on the design model, or has several inputs"}
    from furuta_cosim.report.loop import plot_loop

    plot_loop(model, c, folder / "loop", sampling_period=sampling, title=f"{spec.name} best", margins=margins)
    return {"margins": margins.as_dict(), "margins_of": analysis.margins_of, "text": margins.text(
        model.time_unit, f"Margins of the loop that runs ({analysis.margins_of})"),
        "figures": ["loop/bode.png", "loop/nyquist.png", "loop/sensitivity.png"]}


EDGE = 0.01      # a tuned parameter within this fraction of its range from a bound is at its edge
WORSE = 0.01     # a metric more than this fraction above the baseline's is worse


def flags(spec, evaluator, best: dict, baselines: dict) -> list[str]:
    """What the headline's one number does not say: a loop mode slower than the scenarios
    that score it, a parameter at its range's edge, every metric worse than the first
    baseline's (by more than WORSE)."""
    found = []
    names, bounds = evaluator.space.names, evaluator.space.bounds
    for name, (low, high) in zip(names, bounds):
        value = best["parameters"].get(name)
        if value is None or not high > low:
            continue
        side = "lower" if value - low <= EDGE * (high - low) else "upper" if high - value <= EDGE * (high - low) else None
        if side:
            found.append(f"{name} = {value:.6g} is at the {side} edge of its range [{low:g}, {high:g}]: "
                         "the best may lie beyond it")
    if spec.objective.type == "spectral":
        return found
    from furuta_cosim.design.analysis import analyze

    x = [best["parameters"][n] for n in names]
    analysis = analyze(evaluator.model, evaluator.space.controller(x, "best"))
    durations = [prepared.scenario.duration for _, prepared, _ in evaluator.runs()]
    settling = analysis.dominant.settling_time
    if durations and analysis.stable and settling > min(durations):
        found.append(f"its slowest mode ({analysis.dominant.describe()}) settles (2 %) in about "
                     f"{settling:.3g} s on the design model, longer than the shortest scenario "
                     f"({min(durations):g} s): what the scenarios score does not see it settle")
    first = next((n for n, b in baselines.items() if b.get("metrics")), None)
    if first and best.get("metrics"):
        worse = []
        for label, values in best["metrics"].items():
            theirs = baselines[first]["metrics"].get(label, {})
            for key in (*HEADLINE, *(peak_metric(n) for n, _ in spec.constraints.max_abs),
                        *(t.metric for t in spec.objective.all_terms)):
                if not getattr(entry(key), "cost", True):
                    continue  # a larger value is not worse (a step's final value, its peak time)
                ours, other = values.get(key), theirs.get(key)
                if ours is not None and other and ours > other * (1 + WORSE) and f"{label} {key}" not in worse:
                    worse.append(f"{label} {key}")
                    found.append(f"worse than {first} on {label} {key}: {ours:.4g} against {other:.4g} "
                                 f"({(ours / other - 1) * 100:+.0f} %)")
    return found


def _early(records) -> dict:
    """What early stopping spared: candidates refused by the loop's exact checks (never
    co-simulated), candidates whose runs stopped or were skipped, and the runs skipped."""
    return {"known": sum(1 for r in records if r.get("known")),
            "stopped": sum(1 for r in records if r.get("stopped")),
            "cut_short": sum(1 for r in records if r.get("stopped") or r.get("skipped")),
            "runs_skipped": sum(len(r.get("skipped") or ()) for r in records)}


def _early_line(early) -> list[str]:
    if not early or not (early["known"] or early["cut_short"]):
        return []
    return [f"- cut short: {early['cut_short']} infeasible candidates (a run stopped once broken: "
            f"{early['stopped']}; {early['runs_skipped']} runs skipped), {early['known']} refused by "
            "the loop's stability checks without a co-simulation"]


def _controller_of(cfile):
    """What the summary shows of a controller file: a swing-up file's settings, else its matrices."""
    if cfile.swingup is None:
        return cfile.controller
    from types import SimpleNamespace

    return SimpleNamespace(swingup=cfile.swingup, period=cfile.period)


def _matrices(controller) -> dict:
    if getattr(controller, "swingup", None) is not None:  # a swing-up file: its tuned settings
        return {"swingup": controller.swingup.settings(), "period": controller.period}
    return {"Ac": controller.Ac.tolist(), "Bc": controller.Bc.tolist(), "Cc": controller.Cc.tolist(),
            "Dc": controller.Dc.tolist(), "period": controller.period}


def _sha256(path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def summary_text(spec: TuningSpec, document: dict) -> str:
    """summary.md: the run's summary document in words (what ``tune`` prints)."""
    lines = [f"# Tuning {spec.name}", "", spec.description, "",
             f"- method: {document['method']}" + (f" ({document['search']})" if document.get("search") else "")
             + f", seed {document['seed']}, {document['evaluations']} "
             f"evaluations, {document['feasible']} feasible, {document['failed']} failed",
             f"- objective: {document['objective']}" + _described(spec.objective),
             f"- time: optimizer {document['optimizer_seconds']:.1f} s, waiting for evaluations "
             f"{document['evaluation_seconds']:.1f} s", *_early_line(document.get("early")), ""]
    if spec.plant is not None:
        lines += [f"On plant {spec.plant}: the controller is designed on its linearization."]
        lines += [f"- {note}." for note in spec.notes] + [""]
    lines += [f"Warning: {line}." for line in document.get("warnings") or []]
    lines += [""] if document.get("warnings") else []
    best = document["best"]
    if best:
        origin, F = best.get("origin") or "the search", best.get("prefilter") or {}
        lines.append(f"Best: objective {best['objective']:.6g} at evaluation {best['index']}, "
                     f"from {origin} (best.yaml" + (f", prefilter F = {F['F']:.6g} for {F['output']}"
                                                    if F else "") + ").")
        matrices = best.get("controller") or {}
        for key in ("Ac", "Bc", "Cc", "Dc"):
            if key in matrices:
                lines.append(f"- {key} = " + _matrix(matrices[key]))
        for key, value in (matrices.get("swingup") or {}).items():
            lines.append(f"- {key} = {value:.6g}")
        lines += [f"- note: {flag}" for flag in document.get("flags") or []]
        loop = document.get("loop") or {}
        if loop.get("text"):
            lines += ["", loop["text"] + " Bode, Nyquist and sensitivity: loop/bode.png, loop/nyquist.png, "
                      "loop/sensitivity.png.", "", "![Bode plot of the best controller's loop](loop/bode.png)"]
        elif loop.get("problem"):
            lines += ["", f"Loop figures: {loop['problem']}."]
    else:
        lines.append("No feasible controller was found.")
    for name, digest in (document.get("fmus") or {}).items():
        lines.append(f"- plant FMU {name}: sha256 {digest}")
    if document.get("variants"):
        lines.append(f"Over the {len(spec.variants)} plant variants, each scored alone (the "
                     "objective on that variant's scenarios):")
        for name, v in document["variants"].items():
            worst = "a run without a finite value" if v["worst"] is None else f"{v['worst']:.6g}"
            spread = "" if v["best"] is None else f", best {v['best']:.6g}"
            lines.append(f"- {name}: worst {worst}{spread}")
        lines.append("")
    if document.get("front") is not None:
        from furuta_cosim.tuning.front import summary_lines

        lines += summary_lines(document["front"]) + [""]
    for name, baseline in document["baselines"].items():
        lines.append(baseline_line(name, baseline, best, "scored alike"))
        if best and baseline["feasible"] and best.get("metrics") and baseline.get("metrics") \
                and spec.objective.type == "scenarios":
            lines += _run_by_run(spec, best["metrics"], baseline["metrics"], name)
    if document.get("responses"):
        lines += ["", "The tuned controller's response beside the baselines', per scenario:", ""]
        for label, path in document["responses"].items():
            lines += [f"![{label}: tuned and baseline]({path})", ""]
    if best and best.get("metrics"):
        lines += ["", "Metric by metric, on every scenario and plant variant:", ""]
        keys = list(dict.fromkeys([t.metric for t in spec.objective.all_terms]
                                  + [m for m, _ in spec.constraints.no_worse_than]
                                  + list(HEADLINE)
                                  + [peak_metric(name) for name, _ in spec.constraints.max_abs]))
        names = [n for n, b in document["baselines"].items() if b.get("metrics")]
        lines.append("| run | metric | tuned | " + " | ".join(names) + " | tuned / " +
                     (names[0] if names else "-") + " |")
        lines.append("| --- " * (4 + len(names)) + "|")
        same = []
        for label, values in best["metrics"].items():
            for key in keys:
                value = values.get(key)
                others = [document["baselines"][n]["metrics"].get(label, {}).get(key) for n in names]
                if others and all(other == value for other in others):
                    same.append(f"{label} {key}")  # equal everywhere: no information in a row
                    continue
                ratio = (f"{value / others[0]:.3f}" if names and value is not None and others[0]
                         else "")
                shown = [_cell(v) for v in [value] + others]
                lines.append(f"| {label} | {key} | " + " | ".join(shown) + f" | {ratio} |")
        if same:
            lines += ["", "The same for the tuned controller and every baseline (left out of the "
                          "table): " + ", ".join(same) + "."]
    return "\n".join(lines) + "\n"


def baseline_line(name: str, baseline: dict, best: dict | None, how: str) -> str:
    """A baseline's score (``how`` it was scored) and whether the tuned controller beats it."""
    verdict = f"{baseline['objective']:.6g}" if baseline["feasible"] else \
        f"infeasible (score {baseline['objective']:.6g})"
    better = ""
    if best and baseline["feasible"]:
        better = (" - the tuned controller scores better" if best["objective"] < baseline["objective"]
                  else f" - the tuned controller does NOT beat it (worse by "
                       f"{(best['objective'] / baseline['objective'] - 1) * 100:.1f} %)")
    return f"- {name}, {how}: {verdict}{better}"


def _described(objective) -> str:
    """The objective in words, after its type."""
    if objective.type == "spectral":
        return (" (the paper's max |Re eig(Abar)| as stated: it measures the fastest mode, not the "
                "slowest, so it rewards poles near the imaginary axis; docs/pages/paper-readings.md §3)")

    def terms(criterion) -> str:
        return " + ".join(f"{t.weight:g} {t.metric}" + (f" / {Path(t.relative_to).stem}'s"
                                                        if t.relative_to else "")
                          for t in criterion.terms) + f", {criterion.aggregate} over scenarios and plant variants"

    if objective.type == "scenarios":
        return " = " + terms(objective.criteria[0])
    return (" of " + "; ".join(f"{c.name} = {terms(c)}" for c in objective.criteria)
            + " (each minimized; best.yaml is the point of the lowest mean of the criteria)")


def _run_by_run(spec: TuningSpec, tuned: dict, baseline: dict, name: str) -> list[str]:
    """Where the tuned controller is lower and where higher than a baseline, run by run, in the
    objective's own metrics: a lower mean can hide runs on which it is worse."""
    lower, higher = [], []
    for label, values in tuned.items():
        changes = []
        for term in spec.objective.terms:
            ours, theirs = values.get(term.metric), baseline.get(label, {}).get(term.metric)
            if ours is not None and theirs:
                changes.append((term.metric, (ours / theirs - 1) * 100))
        if changes:
            text = f"{label} (" + ", ".join(f"{metric} {change:+.1f} %" for metric, change in changes) + ")"
            (lower if all(change < 0 for _, change in changes) else higher).append(text)
    return [f"  - lower than {name} in every objective metric on: " + ("; ".join(lower) or "no run"),
            "  - not lower on: " + ("; ".join(higher) or "no run")]


def _cell(value) -> str:
    return "never" if value is None else format(value, ".4g")


def _matrix(rows) -> str:
    return "[" + "; ".join(" ".join(f"{v:.6g}" for v in row) for row in rows) + "]"
