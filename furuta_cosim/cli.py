"""The ``furuta-cosim`` command: parses, dispatches, and turns errors into one clear line.

Heavy modules are imported inside the handlers so that ``--help`` stays instant. Exit codes,
the same for every command: 0 success; 1 a check failed (a requirement, a regression, a run
that stopped early, an FMU that fails validation); 2 bad input (one line per problem naming
the file and key, or the flag; a path naming a FIFO, a device or a folder where a file is
expected is refused before it is opened); 130, 143 and 129 interrupted by Ctrl-C, SIGTERM or SIGHUP
(nothing half-written; a second signal waits until the files are written);
141 the reader of the output went away; 75 a run stopped that ``--resume`` continues. A
warning (``WARN``: a run that never settles) is printed and does not change the code. ``rig
run`` and ``rig home``: 0 the run went to its end (homing: came to rest), 1 the supervisor
stopped it (a limit, a stall, a late sample) or homing timed out; the rig is left at 0 V with
the amplifier off in every case, and the last line says why it stopped.
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
import textwrap
import threading

from furuta_cosim.documents import dumps
from furuta_cosim.errors import ConfigError, Signalled

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a command whose reader closed
EXIT_STOPPED = 75  # EX_TEMPFAIL: the run stopped before its end and --resume continues it


def cmd_build_fmu(args) -> int:
    from pathlib import Path

    from furuta_cosim.files import output_file, output_folder
    from furuta_cosim.fmu.exporter import build_fmu

    if args.output:
        wanted = Path(args.output)
        (output_file if wanted.suffix == ".fmu" else output_folder)(wanted)

    path = build_fmu(args.model, output=args.output, log=lambda line: print(line, file=sys.stderr),
                     fmi_version=args.fmi_version)
    print(path)
    return 0


def cmd_new_plant(args) -> int:
    from furuta_cosim.fmu.newplant import new_plant

    folder = new_plant(args.name)
    print(f"wrote {folder}/: model.py (the declaration), model.c (the equations), plant.yaml "
          "(a parameter set), step.yaml (a scenario)\nnext:\n"
          f"  furuta-cosim build-fmu {folder}\n"
          f"  furuta-cosim linearize --plant {folder}/plant.yaml\n"
          f"  furuta-cosim design lqr --plant {folder}/plant.yaml --continuous -o {folder}/lqr.yaml\n"
          f"  furuta-cosim simulate {folder}/step.yaml")
    return 0


def cmd_linearize(args) -> int:
    from pathlib import Path

    from furuta_cosim.models import from_fmu, linearize_plant

    if args.fmu:
        if args.inputs:
            raise ConfigError(["--inputs: with --fmu the input is the mapping's control_input"])
        result = from_fmu(args.fmu, args.mapping)
        title = f"linearization of {Path(args.fmu).name} at its start state" + (
            f", named by {args.mapping}" if args.mapping else "")
    else:
        if args.mapping:
            raise ConfigError(["--mapping: maps a plant FMU given with --fmu"])
        plant, fmu, result, note = linearize_plant(args.params, args.inputs)
        title = f"linearization of {fmu.name} with {plant.name}"
        if note:
            print(f"note: {note}", file=sys.stderr)
    if args.json:
        data = result.as_dict() if hasattr(result, "as_dict") else {
            "A": result.A.tolist(), "B": result.B.tolist(), "C": result.C.tolist(), "D": result.D.tolist(),
            "states": list(result.states), "inputs": list(result.inputs), "outputs": list(result.outputs),
            "period": result.period}
        print(dumps(data))
        return 0
    import numpy as np

    with np.printoptions(precision=5, suppress=True, linewidth=120):
        print(title + (f" (discrete, period {result.period})" if result.period else ""))
        print(f"states:  {result.states}\ninputs:  {result.inputs}\noutputs: {result.outputs}")
        for name in "ABCD":
            print(f"{name} =\n{getattr(result, name)}")
    return 0


def cmd_validate_fmu(args) -> int:
    from pathlib import Path

    from furuta_cosim.fmu.check import validate
    from furuta_cosim.inputs import regular

    if Path(args.path).exists() or Path(args.path).is_symlink():
        regular(args.path)   # a FIFO or a device is refused before validation opens it
    findings = validate(args.path)
    width = max(len(f.check) for f in findings)
    for finding in findings:
        status = {True: "ok  ", False: "FAIL", None: "skip"}[finding.ok]
        print(f"{status}  {finding.check:{width}s}  {finding.detail}")
    failed = [f for f in findings if f.ok is False]
    skipped = [f for f in findings if f.ok is None]
    print(f"{args.path}: " + ("problems found" if failed else
                              f"valid as far as checked ({len(skipped)} check(s) not run)" if skipped else "valid"))
    return EXIT_FAILED if failed else 0


def cmd_design_lqr(args) -> int:
    import numpy as np

    from furuta_cosim.design.linear import time_text
    from furuta_cosim.lqr_file import design_lqr_file

    design = design_lqr_file(_model_with_mapping(_design_model(args), args.mapping), Q=args.Q, R=args.R, period=args.period,
                             continuous=args.continuous, name=args.name, track=args.track,
                             description=args.description, output=args.output)
    if design.path:
        print(f"wrote {design.path}", file=sys.stderr)
    if design.model.provenance.get("note"):
        print(f"note: {design.model.provenance['note']}", file=sys.stderr)
    cfile, model, analysis = design.cfile, design.model, design.analysis
    controller, K, result = cfile.controller, cfile.controller.K, design.as_dict()
    if args.json:
        print(dumps(result))
    else:
        print(f"{result['method']} on {model.name}"
              + (f" at period {time_text(controller.period, model.time_unit, 'g')}" if controller.discrete else ""))
        print("K = [" + " ".join(f"{k:.6g}" for k in np.ravel(K)) + "]")
        print("closed-loop eigenvalues: " + ", ".join(_complex(z) for z in analysis.eigenvalues))
        print(f"prefilter for {cfile.tracked_output}: F = {cfile.F:.6g}")
    return 0


def _design_model(args, default: str | None = "paper-printed") -> str | None:
    """--model, or the linearization of --plant (derived:PLANT), or ``default``."""
    if args.plant and args.model:
        raise ConfigError(["--plant: designs on the linearization of that plant; give it or "
                           "--model, not both"])
    if args.plant:
        return f"derived:{args.plant}"
    return args.model or default


def _complex(z) -> str:
    return f"{z.real:.5g}{z.imag:+.5g}j" if z.imag else f"{z.real:.5g}"


def _model_with_mapping(model: str, mapping: str | None) -> str:
    """``--model PLANT.fmu --mapping FILE`` as one model name (``PLANT.fmu#FILE``)."""
    if not mapping:
        return model
    if not str(model).endswith(".fmu"):
        raise ConfigError([f"--mapping: maps a plant FMU (--model PLANT.fmu), not {model}"])
    return f"{model}#{mapping}"


def cmd_analyze(args) -> int:
    from furuta_cosim.design.linear import time_text
    from furuta_cosim.lqr_file import analyze_file

    if args.mapping and not args.model:
        raise ConfigError(["--mapping: maps a plant FMU given with --model PLANT.fmu"])
    model = _design_model(args, None)
    if args.plot:
        from furuta_cosim.files import output_folder

        output_folder(args.plot, "--plot")
    if (args.rate_filter is not None or args.board_delay is not None) and not args.rig:
        raise ConfigError(["--rate-filter and --board-delay describe the rig's loop: give --rig"])
    found = analyze_file(args.controller, _model_with_mapping(model, args.mapping) if model else None)
    cfile, model, analysis, c = found.cfile, found.model, found.analysis, found.cfile.controller
    if model.provenance.get("note"):
        print(f"note: {model.provenance['note']}", file=sys.stderr)
    rig = None
    if args.rig:
        from furuta_cosim.design.rigloop import rig_analysis
        from furuta_cosim.measurement import RATE_FILTER
        from furuta_cosim.rig.virtual import DELAY

        rig = rig_analysis(model, c, period=None if c.discrete else cfile.period,
                           delay=DELAY if args.board_delay is None else args.board_delay,
                           rate_filter=RATE_FILTER if args.rate_filter is None else args.rate_filter)
    if args.json:
        document = analysis.as_dict()
        if rig is not None:
            document["rig"] = {**rig, "margins": rig["margins"].as_dict() if rig["margins"] is not None else None}
        print(dumps(document))
    else:
        print(f"{cfile.name} on {model.name} ({'discrete, ' + time_text(c.period, model.time_unit, 'g') if c.discrete else 'continuous'})")
        print("eigenvalues of Abar: " + ", ".join(_complex(z) for z in analysis.eigenvalues))
        if c.discrete:
            print(f"spectral radius: {analysis.spectral_radius:.6g}")
        else:
            print(f"spectral abscissa: {analysis.spectral_abscissa:.6g}")
        for line in analysis.verdict():
            print(line)
        if rig is not None:
            from furuta_cosim.design.rigloop import rig_text

            for line in rig_text(rig):
                print(line)
    if args.plot:
        if analysis.running_margins is None:
            running = analysis.sampled if analysis.sampled is not None else analysis
            why = ("the loop is unstable" if not analysis.stable else
                   f"the loop that runs (sampled at {analysis.sampled.period:g}) is unstable" if not running.stable else
                   "the loop has more than one input" if c.Dc.shape[0] != 1 or model.B.shape[1] != 1 else
                   "its margins could not be computed")
            print(f"no plots: {why}; margins and sensitivities are of a stable single-input loop", file=sys.stderr)
        else:
            from furuta_cosim.report.loop import plot_loop

            written = plot_loop(model, c, args.plot, sampling_period=analysis.sampled.period
                                if analysis.sampled is not None else None, margins=analysis.running_margins)
            print("wrote " + ", ".join(str(w) for w in written if w.suffix == ".png"), file=sys.stderr)
    # the exit code follows every verdict printed: the sampled loop of a continuous design too
    sampled_ok = analysis.sampled is None or analysis.sampled.stable
    rig_ok = rig is None or rig["stable"]
    return 0 if analysis.stable and sampled_ok and rig_ok else EXIT_FAILED


def cmd_simulate(args) -> int:
    import time
    from pathlib import Path

    from furuta_cosim.progress import Progress
    from furuta_cosim.scenario import load_scenario
    from furuta_cosim.simulation import simulate_scenario

    from furuta_cosim.ssp import is_ssp, on_ssp

    controllers = args.controller
    if is_ssp(args.scenario):  # an SSP runs as its system says
        if args.plant or args.fmu or controllers:
            raise ConfigError([f"{args.scenario}: an SSP runs its own system: no --plant, --fmu or --controller "
                               "with it"])
        return _simulate_system(args)
    scenario = load_scenario(args.scenario)
    if args.plant:
        if args.fmu:
            raise ConfigError(["--plant: give a plant file or an FMU (--fmu), not both"])
        if is_ssp(args.plant):
            scenario, plant = on_ssp(scenario, args.plant)
            print(f"{args.plant}: plant {plant.component} with parameter set {plant.set_name or '(none)'}",
                  file=sys.stderr)
            for warning in plant.warnings:
                print(f"warning: {warning}", file=sys.stderr)
        else:
            from furuta_cosim.cosim.master import on_plant

            scenario = on_plant(scenario, args.plant)
    out = Path(args.output or Path("out") / scenario.name)
    started = time.perf_counter()
    progress = Progress()
    try:
        document, results = simulate_scenario(
            scenario, out, controllers=controllers, fmu=args.fmu, every=args.every,
            traces=not args.no_trace, progress=progress,
            log=lambda line: (progress.close(), print(line, file=sys.stderr)))
    finally:
        progress.close()
    elapsed = time.perf_counter() - started
    if args.json:
        print(dumps(document))
    else:
        _print_table(scenario, results, document)
        print(f"{len(results)} run(s) of {document['steps']} steps in {elapsed:.2f} s; "
              f"{', '.join(document['files'])} in {out}")
    return 0 if document["passed"] else EXIT_FAILED


def _simulate_system(args) -> int:
    """``simulate LOOP.ssp[:SET]``: the archive's system checked, run by the Jacobi master,
    its values written and summed up (furuta_cosim/ssp/system.py)."""
    import time
    from pathlib import Path

    from furuta_cosim.files import output_folder
    from furuta_cosim.progress import Progress
    from furuta_cosim.ssp import split_ssp
    from furuta_cosim.ssp.system import SystemFailed, load_system, run_system, save_run
    import numpy as np

    path, name = split_ssp(args.scenario)
    system = load_system(path, name)
    out = output_folder(Path(args.output or Path("out") / Path(path).stem))
    print(system.describe(), file=sys.stderr)
    for warning in system.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if not system.validated:
        print("note: not validated against the SSP 1.0 schemas (install the ssp extra to check)", file=sys.stderr)
    started = time.perf_counter()
    progress = Progress()
    try:
        run = run_system(system, progress=lambda k, n: progress("the system", k, n))
    except SystemFailed as error:
        progress.close()
        print(f"FAIL  {path}: {error}")
        return EXIT_FAILED
    finally:
        progress.close()
    elapsed = time.perf_counter() - started
    written = save_run(system, run, out)
    outputs = [n for n in run.values if system.parts[n.split(".", 1)[0]].kinds.get(n.split(".", 1)[1]) == "output"]
    if args.json:
        print(dumps({"archive": str(path), "order": run.order, "steps": system.steps, "step": system.step,
                     "sets": {p.name: p.set_name for p in system.parts.values()},
                     "warnings": system.warnings, "validated": system.validated,
                     "outputs": {n: {"final": float(run[n][-1]), "max_abs": float(np.max(np.abs(run[n])))}
                                 for n in outputs},
                     "files": [w.name for w in written]}))
        return 0
    width = max(len(n) for n in outputs) if outputs else 10
    print(f"{'output':{width}s}  {'final':>12s}  {'max |value|':>12s}")
    for n in outputs:
        print(f"{n:{width}s}  {run[n][-1]:12.6g}  {np.max(np.abs(run[n])):12.6g}")
    print(f"{system.steps} steps ({run.order}) in {elapsed:.2f} s; {', '.join(w.name for w in written)} in {out}")
    return 0


def _cell(metrics: dict, key: str) -> str:
    """A table cell: blank when the metric does not apply, 'never' when it is not finite."""
    if key not in metrics:
        return ""
    return "never" if metrics[key] is None else format(metrics[key], ".4g")


def _print_table(scenario, results, document) -> None:
    from furuta_cosim.metrics import table_keys

    first = next(iter(results.values())).trace
    entries = document["controllers"]
    recorded = {key for entry in entries.values() for key in entry["metrics"]}
    steps = sum(1 for k in range(1, 100) if f"{first.tracked}.step{k}.RiseTime" in recorded)
    keys = table_keys(first.tracked, first.watched(), steps) + [r.metric for r in scenario.requirements]
    names = list(entries)
    rows = [k for k in dict.fromkeys(keys) if any(k in entries[n]["metrics"] for n in names)]
    width = max(len(k) for k in rows) if rows else 10
    print(f"{'metric':{width}s}  " + "  ".join(f"{n:>16s}" for n in names))
    for key in rows:
        cells = [_cell(entries[name]["metrics"], key) for name in names]
        print(f"{key:{width}s}  " + "  ".join(f"{c:>16s}" for c in cells))
    for name in names:
        if entries[name]["failure"]:
            print(f"FAIL  {name}: the run {entries[name]['failure']}")
        if entries[name].get("diverged"):
            print(f"FAIL  {name}: diverged: {entries[name]['diverged']}")
        for warning in entries[name].get("warnings", []):
            print(f"WARN  {name}: {warning}")
        for text, verdict in entries[name]["requirements"].items():
            value = verdict["value"]
            shown = "no finite value" if value is None else format(value, ".6g")
            print(f"{'PASS' if verdict['pass'] else 'FAIL'}  {name}: {text} (got {shown})")
    for note in document["unchecked"]:
        print(f"SKIP  {note}")


def _workers(args) -> int:
    """--workers as given (checked), or one per core."""
    from furuta_cosim.cosim.worker import check_workers, default_workers

    return check_workers(default_workers() if args.workers is None else args.workers)


def cmd_tune(args) -> int:
    _check_seed(args.seed)
    import time
    from pathlib import Path

    from furuta_cosim.progress import Progress
    from furuta_cosim.tuning.run import summary_text, tune
    from furuta_cosim.tuning.spec import load_spec

    if (args.samples is not None or args.variants_seed is not None) and not args.from_fit:
        raise ConfigError(["--samples and --variants-seed draw variants from a fit: give --from-fit FIT"])
    spec = load_spec(args.spec, plant=args.plant, from_fit=(
        args.from_fit, 8 if args.samples is None else args.samples,
        0 if args.variants_seed is None else args.variants_seed) if args.from_fit else None)
    out = Path(args.output or Path("runs") / spec.name)
    started = time.monotonic()
    bar = Progress(delay=0.0, unit="evaluation")

    def progress(done, total, best, feasible):
        rate = done / max(time.monotonic() - started, 1e-9)
        shown = "none yet" if best is None else format(best, ".6g")
        bar("tuning", done, total, f"best {shown}, feasible {feasible / done:.0%}, {rate:.1f}/s")

    if args.board or args.evaluator:
        return _tune_on_rig(args, spec, out, started)
    for flag, value in (("--n-trials", args.n_trials), ("--rig", args.rig), ("--wait", args.wait)):
        if value is not None:
            raise ConfigError([f"{flag}: tunes with a rig in the loop: give --board or --evaluator external DIR"])
    workers = _workers(args)
    # every option that shapes the run, so that the printed line continues this run exactly
    args.resume_from = Path(out) / "history.jsonl"
    args.resume_with = " ".join(["furuta-cosim tune", str(args.spec), "-o", str(out)]
                                + (["--plant", args.plant] if args.plant else [])
                                + (["--from-fit", args.from_fit, "--samples", str(args.samples or 8),
                                    "--variants-seed", str(args.variants_seed or 0)] if args.from_fit else [])
                                + (["--optimizer", args.optimizer] if args.optimizer else [])
                                + (["--n-calls", str(args.n_calls)] if args.n_calls is not None else [])
                                + (["--seed", str(args.seed)] if args.seed is not None else [])
                                + ["--resume"])
    try:
        document = tune(spec, out, method=args.optimizer, n_calls=args.n_calls, seed=args.seed,
                        workers=workers, dask=args.dask, resume=args.resume, progress=progress,
                        log=lambda line: print(line, file=sys.stderr))
    finally:
        bar.close()
    return _tuned(args, document, summary_text(spec, document), out)


def _tuned(args, document: dict, text: str, out) -> int:
    """A tuning's end: its summary (JSON with --json), the run directory; exit 1 without a
    feasible controller."""
    if args.json:
        print(dumps(document))
    else:
        print(text, end="")
        print(f"run directory: {out}")
    return 0 if document["best"] else EXIT_FAILED


def _tune_on_rig(args, spec, out, started) -> int:
    """``tune --board`` / ``--evaluator external DIR``: each evaluation a rig trial."""
    import time
    from pathlib import Path

    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.progress import Progress
    from furuta_cosim.tuning.rig import rig_summary_text, tune_on_rig
    from furuta_cosim.tuning.trials import WAIT, BoardTrials, ExternalTrials

    if args.board and args.evaluator:
        raise ConfigError(["--board: a tuning runs its trials on a board or on an external rig "
                           "(--evaluator external DIR), not both"])
    for flag, value in (("--n-calls", args.n_calls), ("--workers", args.workers), ("--dask", args.dask)):
        if value is not None:
            raise ConfigError([f"{flag}: a tuning on the rig runs one trial at a time, counted by "
                               "--n-trials" if flag == "--n-calls" else
                               f"{flag}: a tuning on the rig runs one trial at a time"])
    if args.evaluator:
        kind, folder = args.evaluator
        if kind != "external":
            raise ConfigError([f"--evaluator: expected external DIR, got {kind!r}"])
        if args.rig is not None:
            raise ConfigError(["--rig: an external rig is its own: its limits are its own code's"])
        from furuta_cosim.metrics import peak_metric

        metrics = sorted({t.metric for t in spec.objective.all_terms}
                         | {m for m, _ in spec.constraints.no_worse_than}
                         | {peak_metric(n) for n, _ in spec.constraints.max_abs})
        trials = ExternalTrials(folder, WAIT if args.wait is None else args.wait, metrics)
    else:
        if args.wait is not None:
            raise ConfigError(["--wait: how long to wait for an external rig's result (--evaluator external DIR)"])
        rig = args.rig or spec.plant
        if rig is None:
            raise ConfigError(["--rig: the spec names no plant: give the rig's plant file (its limits and "
                               "sensors; the virtual board runs it)"])
        plant = load_plant(rig)
        if spec.rig.reset is None:
            raise ConfigError([f"{spec.source}: rig.reset: missing: a rig trial resets the rig with a "
                               "swing-up-and-balance file (e.g. reset: swingup-qube)"])
        trials = BoardTrials(args.board, plant, spec.rig.reset, spec.rig.fall,
                             spec.optimizer.seed if args.seed is None else args.seed)
    bar = Progress(delay=0.0, unit="trial")

    def progress(done, total, best, feasible):
        rate = done / max(time.monotonic() - started, 1e-9)
        shown = "none yet" if best is None else format(best, ".6g")
        on_rig = total == (args.n_trials or spec.rig.n_trials)
        bar("rig" if on_rig else "simulated prior", done, total,
            f"best {shown}, feasible {feasible / done:.0%}, {rate:.2f}/s", "trial" if on_rig else "evaluation")

    where = (["--board", args.board] if args.board else ["--evaluator", "external", args.evaluator[1]])
    args.resume_from = Path(out) / "run.json"
    args.resume_with = " ".join(["furuta-cosim tune", str(args.spec), "-o", str(out), *where]
                                + (["--rig", args.rig] if args.rig else [])
                                + (["--optimizer", args.optimizer] if args.optimizer else [])
                                + (["--n-trials", str(args.n_trials)] if args.n_trials is not None else [])
                                + (["--seed", str(args.seed)] if args.seed is not None else [])
                                + ["--resume"])
    try:
        document = tune_on_rig(spec, out, trials, method=args.optimizer, n_trials=args.n_trials, seed=args.seed,
                               resume=args.resume, progress=progress,
                               log=lambda line: (bar.close(), print(line, file=sys.stderr)))
    finally:
        bar.close()
    return _tuned(args, document, rig_summary_text(spec, document), out)


def _overrides(items) -> dict:
    """``--params``: a plant file's parameters, or NAME=VALUE items."""
    from furuta_cosim.errors import ConfigError

    found = {}
    for item in items or []:
        if "=" in item:
            name, _, text = item.partition("=")
            try:
                value = float(text)
            except ValueError:
                raise ConfigError([f"--params {item}: expected NAME=NUMBER"]) from None
            if not name or value != value or value in (float("inf"), float("-inf")):
                raise ConfigError([f"--params {item}: expected NAME=NUMBER with a finite number"])
            found[name] = value
        else:
            from furuta_cosim.fmu.plants import load_plant

            plant = load_plant(item)
            if plant.linear is not None:
                raise ConfigError([f"--params {item}: a linear plant has no parameter set to apply"])
            found.update(plant.parameters)
    return found


def cmd_regress(args) -> int:
    from furuta_cosim.progress import Progress
    from furuta_cosim.regression import regress

    workers = _workers(args)
    bar = Progress(delay=0.0, unit="run")
    try:
        report = regress(args.paths, update=args.update, fmu=args.fmu, mapping=args.mapping,
                         overrides=_overrides(args.params), plant=args.plant, workers=workers,
                         baselines=args.baselines, junit=args.junit, output=args.output,
                         progress=lambda done, total: bar("regress", done, total, ""))
    finally:
        bar.close()
    if args.json:
        print(dumps(report.to_dict()))
        return EXIT_FAILED if report.failed else 0
    width = max([len(c.scenario) for c in report.cases] + [8])
    cwidth = max([len(c.controller) for c in report.cases] + [10])
    print(f"{'scenario':{width}s}  {'controller':{cwidth}s}  {'checked':>7s}  status")
    for case in report.cases:
        moved = f" ({len(case.differences)} moved)" if case.differences else ""
        print(f"{case.scenario:{width}s}  {case.controller:{cwidth}s}  {case.checked:7d}  {case.status}{moved}")
    for case in report.cases:
        if case.failed:
            for line in case.lines():
                print(f"{'UNFIT     ' if case.status == 'unfit' else 'REGRESSION'} {as_flags(line)}")
        elif report.update and case.differences:
            for line in case.lines():
                print(f"changed    {as_flags(line)}")
        if case.status == "n/a":
            for line in case.lines():
                print(f"n/a        {as_flags(line)}")
            continue
        for note in case.notes if case.status != "unfit" else ():
            print(f"note       {case.scenario} / {case.controller}: {as_flags(note)}")
    counts = {}
    for case in report.cases:
        counts[case.status] = counts.get(case.status, 0) + 1
    print(f"{len(report.cases)} run(s) in {report.wall_time:.1f} s: "
          + ", ".join(f"{n} {status}" for status, n in counts.items())
          + (f"; JUnit XML in {args.junit}" if args.junit else ""))
    return EXIT_FAILED if report.failed else 0


def cmd_export_controller(args) -> int:
    from pathlib import Path

    from furuta_cosim.export import export_controller
    from furuta_cosim.files import output_file, output_folder

    if args.output:
        wanted = Path(args.output)
        (output_file if wanted.suffix == ".fmu" else output_folder)(wanted)
    path = export_controller(args.controller, output=args.output, period=args.period,
                             model=args.model, delay=args.delay, fmi_version=args.fmi_version,
                             log=lambda line: print(line, file=sys.stderr))
    print(path)
    return 0


def cmd_export_ssp(args) -> int:
    from furuta_cosim.files import output_file
    from furuta_cosim.ssp import export_ssp

    output_file(args.output, "-o")
    found = export_ssp(args.scenario, args.controller, args.output, plants=args.plant or (),
                       fmi_version=args.fmi_version, log=lambda line: print(line, file=sys.stderr))
    if args.json:
        print(dumps(found))
        return 0
    print(f"parameter sets: {', '.join(found['sets'])} (default {found['sets'][0]})")
    print(f"connections: {'; '.join(found['connections'])}")
    print(f"experiment: 0 to {found['stop']:g} s in steps of {found['step']:g} s (FMI {found['fmi_version']})")
    print(f"note: {found['note']}")
    for warning in found["warnings"]:
        print(f"WARNING {warning}")
    if found["fmi_version"] != "2.0":
        print("note: libcosim's Python package (libcosimpy 0.0.6) runs FMI 2.0 archives only; Ecos and "
              "simulate LOOP.ssp run this one (export with --fmi-version 2.0 for libcosim)")
    print("schemas: " + ("valid against the SSP 1.0 schemas" if found["validated"] else
                         "not validated (install pyssp-standard to check against the SSP 1.0 schemas)"))
    print(found["path"])
    return 0


def cmd_fronts(args) -> int:
    from pathlib import Path

    from furuta_cosim.tuning.front import compare

    out = Path(args.output or Path("runs") / "fronts")
    compare(args.runs, out)
    print((out / "fronts.md").read_text(), end="")
    print(f"figure: {out / 'fronts.png'} (and .svg)")
    return 0


def cmd_report(args) -> int:
    from furuta_cosim.report.pages import write_report

    print(write_report(args.folder, args.output))
    return 0


def cmd_reproduce(args) -> int:
    from pathlib import Path

    from furuta_cosim.reproduce import reproduce

    out = Path(args.output or Path("runs") / "reproduction")
    document = reproduce(out, budget=args.budget, workers=_workers(args),
                         log=lambda line: print(line, file=sys.stderr))
    counts = document["counts"]
    print(", ".join(f"{n} {verdict}" for verdict, n in counts.items())
          + f"; {out / 'reproduction.html'} and reproduction.md")
    return 0


def cmd_replay(args) -> int:
    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.identify.run import replay

    plant, line = args.plant, ""
    if plant is None and not args.fmu:
        from furuta_cosim.identify.replay import recorded_plant

        plant, line = recorded_plant(args.experiments)
    target = target_for(plant=None if args.fmu else (plant or "furuta"), fmu=args.fmu, mapping=args.mapping)
    document = replay(args.experiments, target, output=args.output, tolerance=args.tolerance)
    if line:   # said once the logs are read: a bad log is one line, its own
        print(f"note: {line}", file=sys.stderr)
    for note in document.get("notes", []):
        print(f"note: {note}", file=sys.stderr)
    code = 0 if document["reproduced"] else EXIT_FAILED
    if args.json:
        print(dumps(document))
        return code
    print(f"replay on {document['plant']} (RMS of simulated - measured; angles also in degrees)")
    for name, entry in document["experiments"].items():
        if "failure" in entry:
            print(f"FAIL  {name}: {entry['failure']}")
            continue
        for output, c in entry["outputs"].items():
            degrees = f" ({c['rms'] * 57.29577951308232:.4g} deg)" if output.startswith("theta") else ""
            period = c.get("period")
            shown = (f", period {period['measured']:.5g} s measured, "
                     + ("none simulated" if period["simulated"] is None else
                        f"{period['simulated']:.5g} s simulated ({100 * period['error']:+.3f} %)")
                     if period else "")
            floors = "" if c.get("floors") is None else f" = {c['floors']:.3g} noise floors"
            if c.get("chatter"):
                floors += f" (the floor with the loop's chatter, {c['chatter']:.3g} RMS)"
            print(f"  {name:14s} {output:8s} RMS {c['rms']:.4g}{degrees}{floors}{shown}"
                  + ("  (its loop closed)" if entry.get("loop") == "closed" else ""))
        mode = entry.get("mode")
        if mode is not None:
            said = "; ".join(f"{'caught' if m == 1.0 else 'fell'} at {t:.3f} s" for t, m in mode["logged"]) or "no switch"
            again = "; ".join(f"{'caught' if m == 1.0 else 'fell'} at {t:.3f} s" for t, m in mode["replayed"]) or "no switch"
            whose = "the replay (in the logged mode), its own rule" if mode.get("followed") else "the replay"
            print(f"  {name:14s} mode     the log: {said}; {whose}: "
                  + ("the same" if mode["agree"] else f"{again} (apart from {mode['first_apart']:.3f} s)"))
    if args.output:
        print(f"figures and replay.json in {args.output}")
    if document["far"]:
        print(f"not reproduced: {', '.join(document['far'])} replay beyond {document['tolerance']:g} noise "
              "floors RMS (the floor: the encoder's quantum, or the stated or estimated noise); check "
              "the plant, each column's unit and offset, and for a log recorded under a controller the "
              "experiment's `loop` key (its controller, delay and voltage limit)")
    return code


def cmd_identify(args) -> int:
    import time
    from pathlib import Path

    from furuta_cosim.identify.run import identify
    from furuta_cosim.progress import Progress

    from furuta_cosim.identify.spec import load_identify_spec

    budget = load_identify_spec(args.spec).max_simulations  # the bar's end: the fit's budget
    out = Path(args.output or Path("runs") / "identify" / Path(args.spec).stem)
    bar = Progress(delay=0.0, unit="simulation")
    started = time.monotonic()

    def progress(stage, n, cost):
        bar(stage, n, budget, f"cost {cost:.6g}, {n / max(time.monotonic() - started, 1e-9):.0f}/s")

    from furuta_cosim.identify.rundir import CHECKPOINT

    args.resume_from = Path(out) / CHECKPOINT
    args.resume_with = " ".join([f"furuta-cosim identify {args.spec} -o {out}"]
                                + ([f"--starts {args.starts}"] if args.starts != 1 else [])
                                + (["--no-profiles"] if args.no_profiles else [])
                                + ([f"--bootstrap {args.bootstrap}"] if args.bootstrap else [])
                                + ([f"--seed {args.seed}"] if args.seed else [])
                                + ([f"--holdout {args.holdout:g}"] if args.holdout is not None else [])
                                + [f"--validate {v}" for v in args.validate or ()]
                                + (["--accept"] if args.accept else []) + (["--force"] if args.force else [])
                                + ["--resume"])
    try:
        document = identify(args.spec, out, workers=_workers(args), dask=args.dask, resume=args.resume,
                            starts=args.starts, profiles=not args.no_profiles, bootstrap=args.bootstrap,
                            seed=args.seed, holdout=args.holdout, validation=args.validate or (),
                            accept=args.accept, force=args.force, progress=progress,
                            log=lambda line: (bar.close(), print(line, file=sys.stderr)))
    finally:
        bar.close()
    code = 0 if document["verdict"]["trusted"] or args.accept else EXIT_FAILED
    if args.json:
        print(dumps(document))
        return code
    from furuta_cosim.identify.written import summary_text

    print(summary_text(document, out), end="")
    return code


def cmd_design_experiment(args) -> int:
    from pathlib import Path

    from furuta_cosim.files import output_folder
    from furuta_cosim.identify.next_experiment import design, design_text, write_design

    out = output_folder(Path(args.output or Path("runs") / "design" / Path(args.spec).stem))
    focus = [name.strip() for name in args.focus.split(",") if name.strip()] if args.focus else None
    found = design(args.spec, args.fit, duration=args.duration, seed=args.seed, voltage=args.voltage,
                   arm=args.arm, focus=focus, log=lambda line: print(line, file=sys.stderr))
    written = write_design(found, args.spec, out)
    if args.json:
        print(dumps(written))
        return 0
    print(design_text(found), end="")
    release = found["candidates"][0]["release"]
    print(f"written: {out / 'input.csv'}, {out / 'next.yaml'}, design.md and design.json in {out}\n"
          "next: record it, then fit with it:\n"
          f"  furuta-cosim rig run --input {out / 'input.csv'} --board BOARD -o {out / 'rig'}"
          + (f" --keep-zero  (lift the pendulum {release:g} rad and let go as it starts)" if release else "")
          + f"\n  furuta-cosim identify {out / 'next.yaml'}")
    return 0


def cmd_rig_run(args) -> int:
    _check_seed(args.seed)
    from pathlib import Path

    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.files import output_folder
    from furuta_cosim.progress import Progress
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.runner import run_rig

    controller = args.controller
    if args.input is not None:
        from furuta_cosim.rig.playback import Playback, load_input

        if controller is not None or args.scenario is not None:
            raise ConfigError(["--input: plays its table open loop: give no controller and no --scenario"])
        period, volts = load_input(args.input)
        controller = Playback(volts, period, name=Path(args.input).stem)
        if args.duration is None:
            args.duration = controller.duration
    elif controller is None:
        raise ConfigError(["controller: give a controller file, or --input FILE to play a voltage table"])
    if (args.duration is None) == (args.scenario is None):
        raise ConfigError(["--duration: give --duration SECONDS or --scenario SCENARIO, one of them"])
    plant = load_plant(args.plant)
    name = Path(args.input).stem if args.input is not None else Path(str(controller)).stem
    out = output_folder(Path(args.output or Path("runs") / "rig" / name))
    board = board_for(args.board, plant, log=out / "board.csv", seed=args.seed)
    bar = Progress(delay=0.0, unit="s")
    try:
        summary = run_rig(controller, board, plant, out, duration=args.duration, scenario=args.scenario,
                          watchdog=args.watchdog, rate_filter=args.rate_filter, zero=not args.keep_zero,
                          catch=args.catch,
                          log=lambda line: (bar.close(), print(line, file=sys.stderr)),
                          progress=lambda t, total: bar("rig", int(t), int(round(total)), ""))
    finally:
        bar.close()
    if args.json:
        print(dumps(summary))
    else:
        from furuta_cosim.rig.runner import summary_text

        print(summary_text(summary), end="")
        print(f"run folder: {out}")
    return summary["code"]


def cmd_rig_home(args) -> int:
    _check_seed(args.seed)
    from pathlib import Path

    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.files import output_folder
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.runner import home, summary_text

    plant = load_plant(args.plant)
    out = output_folder(Path(args.output or Path("runs") / "rig" / "home"))
    board = board_for(args.board, plant, log=out / "board.csv", seed=args.seed)
    summary = home(board, plant, out, timeout=args.timeout, log=lambda line: print(line, file=sys.stderr))
    print(summary_text(summary), end="")
    print(f"run folder: {out}")
    return summary["code"]


def cmd_rig_check_signs(args) -> int:
    from furuta_cosim.fmu.plants import load_plant
    from furuta_cosim.progress import Progress
    from furuta_cosim.rig.board import board_for
    from furuta_cosim.rig.checks import check_signs

    plant = load_plant(args.plant)
    if args.rig and not args.board.startswith("virtual"):
        raise ConfigError(["--rig: the plant a virtual board runs; a real board is its own rig"])
    board = board_for(args.board, load_plant(args.rig) if args.rig else plant)
    print(f"checking {plant.name}'s sensors on the {args.board} board with the amplifier off for "
          f"{args.seconds:g} s: turn the arm by hand a quarter of a turn the way a positive voltage turns it "
          "and back, then lift the pendulum a little and let it swing", file=sys.stderr)
    bar = Progress(delay=0.0, unit="s")
    try:
        found = check_signs(board, plant, seconds=args.seconds, zero=not args.keep_zero,
                            progress=lambda t, total: bar("reading", int(t), int(round(total)), ""))
    finally:
        bar.close()
    if args.json:
        print(dumps(found))
    else:
        for name, check in found["checks"].items():
            print(f"{check['verdict'].upper():7s} {name}: {check['says']}")
        for line in found["left"]:
            print(f"WARNING the board was not left safe: {line}")
    verdicts = [c["verdict"] for c in found["checks"].values()]
    return EXIT_FAILED if "wrong" in verdicts or found["left"] else 0 if "unsure" not in verdicts else EXIT_FAILED


def cmd_list(args) -> int:
    from furuta_cosim.shipped import listing

    found = listing()
    if args.json:
        print(dumps(found))
        return 0
    for kind, entries in found.items():
        print(f"{kind}:")
        width = max(map(len, entries), default=10)
        for name, text in entries.items():
            print(f"  {name:{width}s}  {text}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="furuta-cosim",
        description="Co-simulation toolchain for the Furuta pendulum and other underactuated plants.",
        epilog=textwrap.fill("exit codes: " + " ".join(__doc__.split("the same for every command: ", 1)[1]
                                                       .replace("``", "").split()), 88),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    from furuta_cosim import __version__

    parser.add_argument("--version", action="version", version=f"furuta-cosim {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    _add_plants_commands(commands)
    _add_design_commands(commands)
    _add_runs_commands(commands)
    _add_exchange_commands(commands)
    _add_identify_commands(commands)
    _add_rig_commands(commands)
    return parser


def _add_plants_commands(commands) -> None:
    """The commands of the plant: its FMU, its linearization, another tool's FMU checked."""
    from furuta_cosim.fmu.versions import VERSIONS

    p = commands.add_parser("list", help="the shipped plants, models, controllers and scenarios")
    p.add_argument("--json", action="store_true", help="print JSON: {kind: {name: description}}")
    p.set_defaults(handler=cmd_list)

    p = commands.add_parser("build-fmu", help="build a plant FMU (cached) and print its path")
    p.add_argument("model", nargs="?", default="furuta",
                   help="model or plant file: furuta (default), table-literal, toy, a .yaml path, "
                        "or a plant folder (model.py and model.c)")
    p.add_argument("-o", "--output", help="also copy the FMU to this file or folder")
    p.add_argument("--fmi-version", choices=tuple(VERSIONS), default="2.0",
                   help="FMI 2.0 (default) or 3.0; both with co-simulation, and model exchange "
                        "when the model is continuous")
    p.set_defaults(handler=cmd_build_fmu)

    p = commands.add_parser("new-plant", help="write a plant folder to start from: a declaration "
                                              "(model.py), its equations (model.c), a plant file")
    p.add_argument("name", help="the new folder (its name names the FMU)")
    p.set_defaults(handler=cmd_new_plant)

    p = commands.add_parser("linearize", help="linearize a plant FMU at its start point")
    p.add_argument("--plant", "--params", dest="params", default="paper-calibrated",
                   help="plant file or name (default: paper-calibrated)")
    p.add_argument("--inputs", nargs="+", help="inputs that make B's columns (default: all)")
    p.add_argument("--fmu", help="any plant FMU with model exchange instead of this project's plant")
    p.add_argument("--mapping", metavar="FILE", help="for --fmu: names its states and control input")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=cmd_linearize)

    p = commands.add_parser("validate-fmu", help="validate an FMU: fmpy, smoke runs, Ecos")
    p.add_argument("path", help="the .fmu file")
    p.set_defaults(handler=cmd_validate_fmu)


def _add_design_commands(commands) -> None:
    """The commands of control design: a controller designed and analyzed."""
    from furuta_cosim.defaults import PAPER_PERIOD

    p = commands.add_parser("design", help="design a controller")
    designs = p.add_subparsers(dest="design", required=True, metavar="METHOD")
    q = designs.add_parser("lqr", help="linear-quadratic regulator (discrete at 2 ms by default)")
    q.add_argument("--model",
                   help="paper-printed (default), derived[:SET], toy, a linear plant file, or a "
                        "plant FMU with model exchange (PLANT.fmu)")
    q.add_argument("--plant", metavar="PLANT",
                   help="design on this plant file's linearization (the same as --model derived:PLANT)")
    q.add_argument("--mapping", metavar="FILE",
                   help="for a plant FMU: names its states and control input (as regress --mapping)")
    timing = q.add_mutually_exclusive_group()
    timing.add_argument("--period", type=float, default=PAPER_PERIOD,
                        help="dlqr on the zero-order-hold model at this period (default 0.002 s)")
    timing.add_argument("--continuous", action="store_true", help="continuous ARE instead")
    q.add_argument("--Q", type=float, nargs="+", help="state weight: 1 value (times I), n diagonal values or n*n entries")
    q.add_argument("--R", type=float, nargs="+", help="input weight, like --Q (default 10 for the pendulum)")
    q.add_argument("--track", help="output the prefilter makes track (default theta0 / first output)")
    q.add_argument("--name", help="the controller's name in the file (default: the -o file's "
                                  "name, else lqr)")
    q.add_argument("--description", default="", help="a line saying what it is for")
    q.add_argument("-o", "--output", help="write the controller file")
    q.add_argument("--json", action="store_true", help="print JSON")
    q.set_defaults(handler=cmd_design_lqr)

    p = commands.add_parser("analyze", help="stability, margins, dominant mode and prefilter of a controller")
    p.add_argument("controller", help="controller file or name in scenarios/controllers")
    p.add_argument("--model", help="model (default: the one the file names)")
    p.add_argument("--plant", metavar="PLANT", help="analyze on this plant file's linearization "
                                                   "(the same as --model derived:PLANT)")
    p.add_argument("--mapping", metavar="FILE", help="for a plant FMU given with --model: its mapping")
    p.add_argument("--plot", metavar="DIR", help="write the loop's Bode and Nyquist plots and its sensitivities "
                                                 "|S|, |T| (PNG and SVG) into DIR")
    p.add_argument("--rig", action="store_true", help="also the loop that runs on a rig: the rates by the "
                                                      "rate filter of the counted angles, the board's delay")
    p.add_argument("--rate-filter", type=float, default=None, metavar="HZ",
                   help="with --rig: the rates' filter (default 40, as rig run)")
    p.add_argument("--board-delay", type=float, default=None, metavar="SECONDS",
                   help="with --rig: the command's delay to the motor (default 0.001, the virtual board's)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=cmd_analyze)


def _add_runs_commands(commands) -> None:
    """The commands of runs: a scenario simulated, tuned, compared, checked against baselines, reported."""
    from furuta_cosim.tuning.methods import METHODS

    p = commands.add_parser("simulate", help="run a scenario: traces, metrics, figures")
    p.add_argument("scenario", help="scenario file or name in scenarios/ (paper-step, toy-step, ...); or an "
                                    "SSP archive (LOOP.ssp[:SET]): the system it describes, checked, "
                                    "run by a Jacobi master (system.csv, system.png)")
    p.add_argument("--controller", action="append",
                   help="run this controller file instead of the scenario's (repeatable)")
    p.add_argument("--fmu", help="run on this plant FMU instead of the scenario's plant "
                                 "(mapped by the scenario's plant.mapping)")
    p.add_argument("--plant", metavar="PLANT", help="run on this plant file or name (of the "
                                                   "scenario's model) instead of the scenario's; or "
                                                   "on the plant of an SSP, LOOP.ssp[:SET], with its "
                                                   "parameter set SET (default its first)")
    p.add_argument("-o", "--output", help="folder for traces, metrics and figures (default out/<scenario>)")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="write every N-th sample to the CSV traces (metrics use all)")
    p.add_argument("--no-trace", action="store_true", help="write no CSV traces")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(handler=cmd_simulate)

    p = commands.add_parser("tune", help="tune a controller by Bayesian optimization over a spec")
    p.add_argument("spec", help="tuning spec file or name in scenarios/tuning (paper-spectral, ...)")
    p.add_argument("-o", "--output", help="run directory (default runs/<spec>); must not hold a run")
    p.add_argument("--optimizer", choices=tuple(METHODS),
                   help="; ".join(f"{name}: {m.description}" for name, m in METHODS.items()) + "; default: the spec's")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; "
                                               "1 evaluates in this process)")
    p.add_argument("--dask", metavar="ADDRESS", help="evaluate on a Dask scheduler, or 'local' for a LocalCluster")
    p.add_argument("--plant", metavar="PLANT",
                   help="tune for this plant file or name: its scenarios run on it, the controller "
                        "and the spec's LQRs are designed on its linearization")
    p.add_argument("--from-fit", metavar="FIT", help="robust to a fit: plant variants drawn from "
                                                    "this identify run's fit.json, on its plant.yaml")
    p.add_argument("--samples", type=int, help="with --from-fit: variants besides the point estimate (default 8)")
    p.add_argument("--variants-seed", type=int, help="with --from-fit: the seed of the variants' design (default 0)")
    p.add_argument("--resume", action="store_true", help="continue the run in -o after a crash")
    p.add_argument("--n-calls", type=int, help="evaluations (default: the spec's)")
    p.add_argument("--seed", type=int, help="default: the spec's")
    p.add_argument("--board", metavar="NAME[:OPTIONS]",
                   help="tune with the rig in the loop: each evaluation a trial on this board (virtual, "
                        "virtual:fast, quanser, ...; as for rig run); the method defaults to safe")
    p.add_argument("--evaluator", nargs=2, metavar=("external", "DIR"),
                   help="tune with a rig your own code runs: each candidate written to DIR, its trial's "
                        "result read back (docs: Tuning on the rig)")
    p.add_argument("--rig", metavar="PLANT", help="with --board: the rig's plant file (limits, sensors; "
                                                  "the virtual board runs it); default the spec's plant")
    p.add_argument("--n-trials", type=int, help="with --board or --evaluator: rig trials in all, the "
                                                "baseline's included (default the spec's rig.n_trials)")
    p.add_argument("--wait", type=float, metavar="SECONDS",
                   help="with --evaluator external: wait this long for a trial's result (default 3600)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=cmd_tune)

    p = commands.add_parser("fronts", help="the Pareto fronts of tradeoff tunings on one figure, compared")
    p.add_argument("runs", nargs="+", help="run directories of tradeoff tunings (the first is compared with the others)")
    p.add_argument("-o", "--output", help="folder (default: runs/fronts)")
    p.set_defaults(handler=cmd_fronts)

    p = commands.add_parser("regress", help="run scenarios and compare with their baselines")
    p.add_argument("paths", nargs="*", help="scenario files, names or folders (default: every shipped scenario)")
    p.add_argument("--update", action="store_true", help="write the baselines and say what changed")
    p.add_argument("--junit", metavar="FILE", help="also write the results as JUnit XML")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--fmu", help="run on this plant FMU instead of the scenarios' plants")
    p.add_argument("--mapping", metavar="FILE",
                   help="plant mapping for --fmu (control_input, states, disturbances, initial)")
    p.add_argument("--plant", metavar="PLANT",
                   help="run every scenario of the same model on this plant file or name; the "
                        "others are listed as not applicable")
    p.add_argument("--params", action="append", metavar="SET",
                   help="plant parameters on top of the scenarios': a plant file, or NAME=VALUE "
                        "(repeatable); a scenario whose plant lacks one is not applicable")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="also write regress.json and regress.xml there (furuta-cosim report DIR)")
    p.add_argument("--baselines", metavar="DIR",
                   help="baseline folder (default: baselines/ beside each scenario file)")
    p.set_defaults(handler=cmd_regress)

    p = commands.add_parser("report", help="one self-contained HTML page for a run directory")
    p.add_argument("folder", help="a run directory of simulate, tune, regress -o or reproduce")
    p.add_argument("-o", "--output", help="the HTML file (default: DIR/report.html)")
    p.set_defaults(handler=cmd_report)

    p = commands.add_parser("reproduce", help="the paper, claim by claim: our value and a verdict")
    p.add_argument("-o", "--output", help="folder (default: runs/reproduction)")
    p.add_argument("--budget", choices=("quick", "full"), default="quick",
                   help="tuning calls: quick 30, full 150 (the paper's)")
    p.add_argument("--workers", type=int, help="worker processes for the tunings (default: one per core)")
    p.set_defaults(handler=cmd_reproduce)


def _add_exchange_commands(commands) -> None:
    """The commands of exchange: a controller and the closed loop for other tools."""
    from furuta_cosim.fmu.versions import VERSIONS

    p = commands.add_parser("export-controller",
                            help="build a controller as an FMI 2.0 or 3.0 FMU and print its path")
    p.add_argument("controller", help="controller file or name in scenarios/controllers")
    p.add_argument("-o", "--output", help="also copy the FMU to this file or folder")
    p.add_argument("--fmi-version", choices=tuple(VERSIONS), default="2.0",
                   help="FMI 2.0 (default) or 3.0; both with co-simulation, and model exchange "
                        "when the model is continuous")
    p.add_argument("--delay", type=int, choices=(0, 1), default=0,
                   help="1: apply each command one sample late, with no direct feedthrough "
                        "(the same loop in any master; timing.delay: 1 in a scenario)")
    p.add_argument("--period", type=float, help="sample a continuous controller at this period "
                                                "(default: the file's)")
    p.add_argument("--model", help="model whose states name the inputs (default: the file's)")
    p.set_defaults(handler=cmd_export_controller)

    p = commands.add_parser("export-ssp", help="the closed loop (plant, controller, wiring, parameter sets) "
                                               "as an SSP archive for Ecos, libcosim, OMSimulator, ...")
    p.add_argument("scenario", help="scenario file or name: its plant, start, reference, period, duration")
    p.add_argument("--controller", help="controller file or name (default: the scenario's first)")
    p.add_argument("--plant", action="append", metavar="PLANT",
                   help="a parameter set from this plant file or name (repeatable; the first is the "
                        "default; default: the scenario's plant)")
    p.add_argument("--fmi-version", choices=tuple(VERSIONS), default="2.0",
                   help="FMI version of both FMUs (2.0, the default, or 3.0)")
    p.add_argument("-o", "--output", required=True, help="the .ssp file to write")
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    p.set_defaults(handler=cmd_export_ssp)


def _add_identify_commands(commands) -> None:
    """The commands of identification: logs replayed, plants fitted, the next experiment designed."""
    p = commands.add_parser("replay", help="run a log's inputs (and its loop, if it names one) on a plant and compare")
    p.add_argument("experiments", nargs="+", help="experiment files (YAML naming a CSV log)")
    p.add_argument("--plant", help="plant file or name (default: the plant a rig run's log was recorded on, "
                                   "else furuta)")
    p.add_argument("--fmu", help="a plant FMU from another tool instead of --plant")
    p.add_argument("--mapping", metavar="FILE", help="for --fmu: its names and units (as regress --mapping)")
    p.add_argument("-o", "--output", metavar="DIR", help="write overlay and residual figures and replay.json there")
    p.add_argument("--tolerance", type=float, default=None, metavar="FLOORS",
                   help="exit 1 when an output replays beyond FLOORS noise floors RMS (default 20)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=cmd_replay)

    p = commands.add_parser("identify", help="fit plant parameters to measured logs (an identify spec)")
    p.add_argument("spec", help="identify spec file or name in scenarios/identify (qube-servo-3)")
    p.add_argument("-o", "--output", metavar="DIR", help="run directory (default runs/identify/<spec>)")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; 1: this process)")
    p.add_argument("--dask", metavar="ADDRESS", help="simulate on a Dask scheduler, or 'local'")
    p.add_argument("--resume", action="store_true",
                   help="go on with the stopped run in -o from its last finished stage")
    p.add_argument("--starts", type=int, default=1,
                   help="fit from this many starts (the spec's, then a Latin hypercube around it) and keep "
                        "the lowest cost (default 1)")
    p.add_argument("--no-profiles", action="store_true",
                   help="skip the profile likelihoods (their intervals and verdicts): the fit alone")
    p.add_argument("--bootstrap", type=int, default=0, metavar="N",
                   help="N replicates of a block bootstrap of the residuals: a third interval (default 0)")
    p.add_argument("--seed", type=int, default=0, help="the multi-start's design and the bootstrap's draws")
    p.add_argument("--holdout", type=float, metavar="FRACTION",
                   help="hold out the last FRACTION of each log and validate on it (default: the spec's "
                        "holdout, else 0)")
    p.add_argument("--validate", action="append", metavar="EXPERIMENT",
                   help="an experiment file to validate on, never fitted (repeat for more)")
    p.add_argument("--accept", action="store_true",
                   help="write plant.yaml even when the verdict does not trust the fit (exit 0)")
    p.add_argument("--force", action="store_true",
                   help="fit even when the experiments cannot separate some free parameters (by the "
                        "sensitivities at the start values, checked first)")
    p.add_argument("--json", action="store_true", help="print fit.json")
    p.set_defaults(handler=cmd_identify)

    p = commands.add_parser("design-experiment",
                            help="rank excitations by what they would add to a fit; write the best to play on the rig")
    p.add_argument("spec", help="the identify spec of the fit")
    p.add_argument("--fit", required=True, metavar="DIR", help="the fit's run directory (identify -o DIR)")
    p.add_argument("-o", "--output", metavar="DIR", help="where to write (default runs/design/<spec>)")
    p.add_argument("--duration", type=float, default=10.0, help="seconds of the experiment (default 10)")
    p.add_argument("--focus", metavar="NAMES",
                   help="comma-separated free parameters to rank for (default: every free parameter)")
    p.add_argument("--voltage", type=float, help="the largest voltage (default: the plant's limits.voltage)")
    p.add_argument("--arm", type=float, help="the arm's limit in rad (default: the plant's limits.theta0); "
                                             "candidates keep within 60 %% of it in simulation")
    p.add_argument("--seed", type=int, default=0, help="the PRBS candidates' draws")
    p.add_argument("--json", action="store_true", help="print design.json")
    p.set_defaults(handler=cmd_design_experiment)


def _add_rig_commands(commands) -> None:
    """The commands of the rig: runs on a board, homing, the encoders' signs."""
    p = commands.add_parser("rig", help="run controllers on a rig: a board in real time")
    rigs = p.add_subparsers(dest="rig", required=True, metavar="ACTION")
    q = rigs.add_parser("run", help="run a controller on a board, log every sample, leave the rig at 0 V")
    q.add_argument("controller", nargs="?",
                   help="controller file or name (a swing-up-and-balance file too); none with --input")
    q.add_argument("--input", metavar="CSV",
                   help="play this voltage table (t,V; design-experiment writes one) open loop instead")
    q.add_argument("--keep-zero", action="store_true",
                   help="keep the board's counts from before instead of zeroing them (a free swing "
                        "released by hand: zero hanging, lift, start, let go)")
    q.add_argument("--catch", type=float, default=0.3, metavar="RAD",
                   help="a balance controller without a swing-up starts only with the pendulum within "
                        "RAD of upright (default 0.3); else the run is refused before anything moves")
    from furuta_cosim.rig.board import BOARDS
    from furuta_cosim.rig import quanser, virtual  # noqa: F401 - their boards, for the help
    q.add_argument("--board", default="virtual", metavar="NAME[:OPTIONS]",
                   help="; ".join(f"{name}: {b.description}" for name, b in BOARDS.items()) + " (default virtual)")
    q.add_argument("--plant", default="qube-servo-3",
                   help="the rig's plant file: its limits and sensors, and the virtual board's plant "
                        "(default qube-servo-3)")
    length = q.add_mutually_exclusive_group()
    length.add_argument("--duration", type=float, metavar="SECONDS", help="run this long, regulating at 0")
    length.add_argument("--scenario", help="run on this scenario's reference, for its duration")
    q.add_argument("--watchdog", type=float, default=0.1, help="the board's watchdog timeout in s (default 0.1)")
    q.add_argument("--rate-filter", type=float, default=40.0, metavar="HZ",
                   help="cutoff of the rates' filtered difference (default 40 Hz)")
    q.add_argument("--seed", type=int, default=0, help="the virtual board's sensor noise (default 0)")
    q.add_argument("-o", "--output", metavar="DIR", help="run folder (default runs/rig/<controller>)")
    q.add_argument("--json", action="store_true", help="print summary.json")
    q.set_defaults(handler=cmd_rig_run)
    q = rigs.add_parser("home", help="bring the rig to rest: the pendulum hanging still, the arm home")
    q.add_argument("--board", default="virtual", metavar="NAME[:OPTIONS]", help="as for rig run (default virtual)")
    q.add_argument("--plant", default="qube-servo-3", help="the rig's plant file (default qube-servo-3)")
    q.add_argument("--timeout", type=float, default=20.0, help="give up after this many seconds (default 20)")
    q.add_argument("--seed", type=int, default=0, help="the virtual board's sensor noise (default 0)")
    q.add_argument("-o", "--output", metavar="DIR", help="run folder (default runs/rig/home)")
    q.set_defaults(handler=cmd_rig_home)
    q = rigs.add_parser("check-signs", help="read the encoders and the current with the amplifier off and "
                                            "say which sign of the plant file is wrong")
    q.add_argument("--board", default="virtual", metavar="NAME[:OPTIONS]", help="as for rig run (default virtual)")
    q.add_argument("--plant", default="qube-servo-3", help="the rig's plant file whose sensors are checked "
                                                          "(default qube-servo-3)")
    q.add_argument("--rig", metavar="PLANT", help="the virtual board only: the plant it runs, when not --plant "
                                                  "(a rig whose sensors differ from the file checked)")
    q.add_argument("--seconds", type=float, default=10.0, help="how long to read (default 10)")
    q.add_argument("--keep-zero", action="store_true", help="keep the board's counts from before instead of "
                                                            "zeroing them with the rig at rest")
    q.add_argument("--json", action="store_true", help="print the verdicts as JSON")
    q.set_defaults(handler=cmd_rig_check_signs)


def _check_seed(seed) -> None:
    """``--seed`` checked before anything starts (a board's noise took -1 as a traceback)."""
    if seed is not None and not 0 <= seed <= 2**32 - 1:
        raise ConfigError([f"--seed: expected a whole number from 0 to 2^32 - 1, got {seed}"])


class _FirstSignalStops:
    """Ctrl-C, SIGTERM and SIGHUP: the first one stops the command (an exception, so that the
    way out writes its files and leaves the rig safe); every later one is held off until the
    process ends with the first one's code. A second Ctrl-C used to land in that way out and
    kill it half done: a rig run's log, a tuning's last trial. A signal the launching shell set
    to be ignored (nohup, a background job) stays ignored."""

    def __init__(self):
        self.first = self.hook = None

    def __call__(self, number, _frame):
        if self.first is not None:
            return
        self.first = number
        if number == signal.SIGINT:
            raise KeyboardInterrupt()
        raise Signalled(signal.Signals(number).name, 128 + number)

    def install(self) -> dict:
        """The handlers replaced, to put back (none outside the main thread: an embedding
        program keeps its own)."""
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous = {}
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            number = getattr(signal, name, None)
            if number is not None and signal.getsignal(number) is not signal.SIG_IGN:
                previous[number] = signal.signal(number, self)
        self.hook, sys.unraisablehook = sys.unraisablehook, self._lost
        return previous

    def _lost(self, unraisable) -> None:
        """A stop raised where Python cannot raise (a weakref callback, a ``__del__``) is only
        printed and dropped, and the later signals it made us ignore would leave the command
        running on: send it again, to land in the command (from a thread a moment later: sent
        from here, its handler runs at once, inside this hook)."""
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and self.first is not None:
            number, self.first = self.first, None
            # to the main thread: one that waits in a system call wakes to it
            threading.Timer(0.01, signal.pthread_kill, (threading.main_thread().ident, number)).start()
            return
        self.hook(unraisable)

    def uninstall(self, previous: dict) -> None:
        """The handlers and hook as they were; after a signal, the rest of a burst ignored:
        the process is ending, and Python puts the default handlers back as it exits (a late
        Ctrl-C then killed it, -2, after it said that it wrote its files)."""
        for number, handler in previous.items():
            signal.signal(number, handler if self.first is None else signal.SIG_IGN)
        if self.hook is not None:
            sys.unraisablehook, self.hook = self.hook, None


def _say(line: str) -> None:
    """The last line on stderr; a terminal that closed (SIGHUP) cannot take it, and that is no
    reason to fail the way out."""
    try:
        print(line, file=sys.stderr)
    except OSError:
        pass


def _say_pools() -> None:
    """What the command did with its worker processes on the way out (each ended in bounded
    time). Nothing is imported here: a stop that came during an import (numpy's, cffi's
    parser) leaves that module half made, and importing again on the way out raised in it."""
    worker = sys.modules.get("furuta_cosim.cosim.worker")   # no pool was ever started without it
    if worker is None:
        return
    try:
        lines = worker.stopped_pools()
    except Exception:  # noqa: BLE001 (the way out says what it can, and goes on)
        return
    for line in lines:
        _say(line)


def _resume_hint(args) -> str:
    """For an interrupted command that can go on: how. Where the file a resume reads (its
    ``resume_from``) was not written yet, nothing is there to resume: the same command without
    --resume starts it again (--resume would be refused)."""
    from pathlib import Path

    command = getattr(args, "resume_with", None)
    if not command:
        return ""
    marker = getattr(args, "resume_from", None)
    if marker is not None and not Path(marker).is_file():
        return f"; nothing was recorded yet: '{command.removesuffix(' --resume')}' starts it again"
    return f"; '{command}' continues it"


# The library's errors name its functions' parameters (``n_calls: expected ...``, and
# ```resume``` inside a sentence); the command line says its flags instead.
FLAGS = {"n_calls": "--n-calls", "seed": "--seed", "resume": "--resume", "method": "--optimizer",
         "plant": "--plant", "fmu": "--fmu", "mapping": "--mapping", "every": "--every",
         "period": "--period", "track": "--track", "Q": "--Q", "R": "--R", "workers": "--workers",
         "dask": "--dask", "delay": "--delay", "fmi_version": "--fmi-version", "junit": "--junit",
         "baselines": "--baselines", "update": "--update", "budget": "--budget",
         "overrides": "--params", "run_dir": "-o", "output": "-o", "controllers": "--controller",
         "from_fit: samples": "--samples", "from_fit: seed": "--variants-seed", "from_fit": "--from-fit",
         "model": "--model", "duration": "--duration", "scenario": "--scenario",
         "watchdog": "--watchdog", "rate_filter": "--rate-filter", "board": "--board",
         "timeout": "--timeout", "n_trials": "--n-trials", "wait": "--wait", "starts": "--starts",
         "bootstrap": "--bootstrap", "holdout": "--holdout", "validation": "--validate", "tolerance": "--tolerance",
         "evaluator": "--evaluator external", "plants": "--plant", "zero=False": "--keep-zero",
         "catch": "--catch", "force=True": "--force", "accept=True": "--accept",
         "controller=NAME": "--controller NAME"}
_LEADING = re.compile("^(" + "|".join(sorted(map(re.escape, FLAGS), key=len, reverse=True)) + ")(?=[: ])")
_QUOTED = re.compile("`(" + "|".join(map(re.escape, FLAGS)) + ")`")


def as_flags(line: str) -> str:
    """A library error line as the command line's: parameter names become flags."""
    line = _LEADING.sub(lambda m: FLAGS[m.group(1)], line)
    return _QUOTED.sub(lambda m: FLAGS[m.group(1)], line)


def main(argv: list[str] | None = None) -> int:
    from furuta_cosim.errors import DesignError, FmuError, RunStopped

    args = build_parser().parse_args(argv)
    stops = _FirstSignalStops()
    previous = stops.install()
    try:
        try:
            code = args.handler(args)
        except RuntimeError as error:
            # a signal's stop raised inside a class being made (a dataclass's field, during an
            # import) comes out wrapped by Python: "Error calling __set_name__ ...": it is the stop
            if isinstance(error.__cause__, KeyboardInterrupt):
                raise error.__cause__ from None
            raise
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except BrokenPipeError:
        # the reader went away (| head): end quietly, as a shell's commands do on SIGPIPE
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_PIPE
    except (ConfigError, DesignError) as error:
        for line in str(error).splitlines():
            print(f"error: {as_flags(line)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FmuError as error:
        print(f"error: {as_flags(str(error))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RunStopped as error:
        _say_pools()
        print(f"stopped: {as_flags(str(error))}" + _resume_hint(args), file=sys.stderr)
        return EXIT_STOPPED
    except OSError as error:
        # a full disk, a folder that went away: one line; the atomic writers left nothing
        where = f"{error.filename}: " if error.filename else ""
        print(f"error: {where}{error.strerror or error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Signalled as stop:
        said = "terminated" if stop.name == "SIGTERM" else f"stopped by {stop.name}"
        _say_pools()
        _say(f"{said}: no file was left half-written" + _resume_hint(args))
        return stop.code
    except KeyboardInterrupt:
        _say_pools()
        _say("interrupted: no file was left half-written" + _resume_hint(args))
        return 130
    finally:
        stops.uninstall(previous)
        _forget_interrupted_exec()


def _forget_interrupted_exec() -> None:
    """Let the exit code main returns stand after a Ctrl-C that stopped a string ``exec``.

    CPython (3.11, 3.12) marks the interpreter "interrupted" when a KeyboardInterrupt ends code
    run by ``exec`` of a string (dataclasses and namedtuple build their methods so: a Ctrl-C
    during an import lands there), and under ``python -m`` it then dies of SIGINT at exit (-2)
    even though main caught the interrupt and returned 130. The mark is cleared at the start of
    every string ``exec``; an empty one clears it.
    """
    exec("", {})


if __name__ == "__main__":
    sys.exit(main())
