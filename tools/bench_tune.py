"""Tuning measured as the docs report it (Tuning and Performance pages): each optimizer over 10 seeds at the same budget,
beside the LQR scored alike and the best value known, in one run.

    python tools/bench_tune.py [--specs effort robust-effort] [--seeds 10] [--first-seed 0] [--calls 150]
                               [--workers 2] [--methods ours,global,before,random,de,skopt]
                               [--best-known 3000] [--kernel NAME] [--plant PLANT] [-o FOLDER]
    python tools/bench_tune.py --against REV [--specs ...] [--seeds 10] [--best-known 0] [--plant PLANT]

``--against REV`` times the main job as a user runs it, ``furuta-cosim tune SPEC --seed S``
(one process from start to exit: imports, the baselines, the search, summary and figures),
for this checkout and for revision REV of its git history (unpacked into the output folder),
seed by seed in turn, and prints each one's wall time and best with the ratios this / REV.

Rows, per spec (every run ``tune`` of the spec with ``--seed S --n-calls CALLS``):

- ``ours``: ``bo`` as shipped (constrained BO, ``optimizer.region: trust``);
- ``global``: the same with ``region: global``, the alternative the trust region is measured
  against;
- ``before``: the search this project shipped before constrained BO, its optimizer modules
  read from revision 8804270 in this checkout's git history and run as they were
  (scikit-optimize's GP and EI with the spec's ``xi``, ``n_initial_points`` and ``gp_restarts``,
  hyperparameters refitted every fifth tell, batches of the spec's ``optimizer.batch`` by the
  constant liar) on today's objective, told the penalized objective; that revision's own run
  loop cannot read today's specs (relative terms, baselines), and took ``max(batch, workers)``
  points at a time, the same as here with its default two workers;
- ``random``, ``de``: random search and scipy's differential evolution, same budget;
- ``skopt``: scikit-optimize's ``gp_minimize`` defaults (GP, gp_hedge, 10 random initial
  points), told the penalized objective (``penalty + violation`` when infeasible), one point
  at a time;
- ``restart``, ``wide``, ``elsewhere``, ``design30``: variants of ``ours`` tried for the basin
  that one seed found (:class:`Variant`), patched in for the run only;
- the spec's first baseline (the LQR) scored alike, and the best known: differential evolution
  with ``--best-known`` evaluations (seed 0), or any run's best if lower.

For each row: the best per seed, median, worst, and on how many seeds it is at least as good as
the LQR; for ``ours``, the optimizer's seconds per iteration (median over every point of every
seed: fitting the surrogates shared by the points of a batch, plus the point's acquisition).
``--kernel NAME`` runs the rows a GP drives (``ours``, its variants) again under
OPENBLAS_CORETYPE=NAME (a child process) and prints the spread of each seed's best between the
two BLAS kernels and the range across them (what the docs state). Every run's folder
stays under ``-o`` (default: a new temporary folder) with bench.json, the table as data.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from blas import check_kernel  # tools/blas.py: run as a script, tools/ is on the path
from furuta_cosim.errors import ConfigError
from furuta_cosim.tuning import bayesopt
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec

ROOT = Path(__file__).resolve().parent.parent
METHODS = ("ours", "global", "before", "random", "de", "skopt", "optuna", "restart", "wide", "elsewhere",
           "design30", "space", "baseline")
# variants of ours tried for the basin one seed found (docs: Performance), each a patch of the
# shipped optimizer made here, for the run only; ``space`` and ``baseline`` are ours with
# optimizer.start set (the Tuning page's two columns: ours takes one of them by its budget)
VARIANTS = ("restart", "wide", "elsewhere", "design30", "space", "baseline")
# the rows whose path follows the BLAS kernel's rounding (a GP in the loop): --kernel runs these again
KERNEL_BOUND = ("ours", "global", *VARIANTS)


class Timer:
    """Optimizer seconds per proposed point: ConstrainedBO's fits and acquisitions, timed."""

    def __init__(self):
        self.points: list[float] = []
        self._propose = bayesopt.ConstrainedBO.propose

    def __enter__(self):
        timer, propose = self, self._propose

        def timed(bo, *args, **kwargs):
            started = time.perf_counter()
            proposal = propose(bo, *args, **kwargs)
            fitting, first = time.perf_counter() - started, [True]
            inner = proposal._next

            def next_point():
                began = time.perf_counter()
                point = inner()
                timer.points.append(time.perf_counter() - began + (fitting if first[0] else 0.0))
                first[0] = False
                return point

            proposal._next = next_point
            return proposal

        bayesopt.ConstrainedBO.propose = timed
        return self

    def __exit__(self, *exc):
        bayesopt.ConstrainedBO.propose = self._propose


def ours(spec, folder: Path, seed: int, calls: int, workers: int, region: str, timer=None) -> dict:
    from dataclasses import replace

    spec = replace(spec, optimizer=replace(spec.optimizer, region=region))
    return tune(spec, folder, method="bo", n_calls=calls, seed=seed, workers=workers)


class Variant:
    """One of VARIANTS, patched into the optimizer for the run (``with Variant(name):``):

    - ``restart``: the trust region starts again (at its first size, around the incumbent)
      once it is below 0.5^4 of the cube instead of 0.5^7, so that a run restarts within its
      budget;
    - ``wide``: every second point of a batch is proposed in a region of at least the first
      size (0.8) around the incumbent: one local point, one wide one;
    - ``elsewhere``: every second point of a batch comes from a second region of the same
      size around the best feasible point outside the incumbent's region (another basin; the
      wide region when there is none);
    - ``design30``: an initial design of 30 points instead of 15 (a change of the spec);
    - ``space``, ``baseline``: the spec's ``optimizer.start`` set so (no patch: a change of the spec).
    """

    def __init__(self, name: str):
        self.name, self._saved = name, {}

    def __enter__(self):
        bo = bayesopt.ConstrainedBO
        if self.name == "restart":
            self._saved["REGION_MIN"] = bayesopt.REGION_MIN
            bayesopt.REGION_MIN = 0.5 ** 4
        elif self.name in ("wide", "elsewhere"):
            self._saved["propose"], self._saved["_maximize"] = bo.propose, bo._maximize
            propose, maximize, name = bo.propose, bo._maximize, self.name

            def patched_propose(optimizer, records, *args, **kwargs):
                optimizer._seen, optimizer._calls = records, 0
                return propose(optimizer, records, *args, **kwargs)

            def patched_maximize(optimizer, objective, feasibility, best, center, length, rng, *rest):
                optimizer._calls += 1
                if optimizer._calls % 2 == 0 and best is not None:
                    center, length = _second_region(optimizer, name, center, length, objective or feasibility)
                return maximize(optimizer, objective, feasibility, best, center, length, rng, *rest)

            bo.propose, bo._maximize = patched_propose, patched_maximize
        return self

    def __exit__(self, *exc):
        bo = bayesopt.ConstrainedBO
        if "REGION_MIN" in self._saved:
            bayesopt.REGION_MIN = self._saved["REGION_MIN"]
        if "propose" in self._saved:
            bo.propose, bo._maximize = self._saved["propose"], self._saved["_maximize"]


def _second_region(optimizer, name, center, length, surrogate):
    import numpy as np

    wide = (center, max(length, bayesopt.REGION_START))
    if name == "wide":
        return wide
    records = optimizer._seen
    X = np.array([optimizer._unit(r["x"]) for r in records])
    half = 0.5 * length * bayesopt._weights(surrogate.length_scales())
    outside = [k for k, r in enumerate(records) if r["feasible"] and np.any(np.abs(X[k] - center) > half)]
    if not outside:
        return wide
    k = min(outside, key=lambda k: (records[k]["objective"], records[k]["index"]))
    return X[k], length


def variant(spec, folder: Path, seed: int, calls: int, workers: int, name: str) -> dict:
    from dataclasses import replace

    if name == "design30":
        spec = replace(spec, optimizer=replace(spec.optimizer, n_initial_points=30))
    elif name in ("space", "baseline"):
        spec = replace(spec, optimizer=replace(spec.optimizer, start=name))
    with Variant(name):
        return tune(spec, folder, method="bo", n_calls=calls, seed=seed, workers=workers)


def plain(spec, folder: Path, seed: int, calls: int, workers: int, method: str) -> dict:
    return tune(spec, folder, method=method, n_calls=calls, seed=seed, workers=workers)


def skopt(spec, folder: Path, seed: int, calls: int, workers: int) -> dict:
    """scikit-optimize's ``gp_minimize`` defaults on the spec's space, one point at a time."""
    from skopt import Optimizer

    from furuta_cosim.tuning.objective import Evaluator

    dimensions = Evaluator(spec).space.dimensions()
    optimizer = Optimizer(dimensions, base_estimator="GP", acq_func="gp_hedge", acq_optimizer="lbfgs",
                          n_initial_points=10, initial_point_generator="random", random_state=seed)
    return _ask_tell(spec, folder, calls, workers, 1, lambda count: [optimizer.ask()], optimizer.tell)


def optuna_tpe(spec, folder: Path, seed: int, calls: int, workers: int) -> dict:
    """Optuna's TPE, multivariate and told the constraint (each evaluation's margin, <= 0 when
    feasible), one point at a time, on the spec's space; Optuna is not a dependency of the
    project (``python3 -m pip install optuna`` to run this method)."""
    try:
        import optuna
    except ImportError:
        raise SystemExit("--methods optuna needs Optuna: python3 -m pip install optuna") from None
    from furuta_cosim.tuning.objective import Evaluator

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    dimensions = Evaluator(spec).space.dimensions()
    names = [f"x{k}" for k in range(len(dimensions))]
    distributions = {name: optuna.distributions.FloatDistribution(float(d.low), float(d.high),
                                                                  log=d.prior == "log-uniform")
                     for name, d in zip(names, dimensions)}
    told = hasattr(optuna.trial.Trial, "set_constraint")  # Optuna 5; before: constraints_func
    sampler = (optuna.samplers.TPESampler(seed=seed, multivariate=True) if told else
               optuna.samplers.TPESampler(seed=seed, multivariate=True,
                                          constraints_func=lambda trial: trial.user_attrs["constraint"]))
    study = optuna.create_study(sampler=sampler)
    asked = {}

    def ask(count):
        trials = [study.ask(distributions) for _ in range(count)]
        xs = [[t.params[name] for name in names] for t in trials]
        for t, x in zip(trials, xs):
            asked[tuple(x)] = t
        return xs

    def tell(xs, ys, outcomes):
        for x, y, outcome in zip(xs, ys, outcomes):
            trial = asked.pop(tuple(x))
            margin = outcome.margin if outcome.margin is not None and math.isfinite(outcome.margin) else 1.0
            if told:
                trial.set_constraint("margin", float(margin))
            else:
                trial.set_user_attr("constraint", [float(margin)])
            study.tell(trial, float(y) if math.isfinite(y) else 1e6)
    return _ask_tell(spec, folder, calls, workers, 1, ask, tell, outcomes_told=True)


# the last revision before constrained BO; its optimizer modules are read from git history
BEFORE = "8804270"


def before(spec, folder: Path, seed: int, calls: int, workers: int) -> dict:
    """The optimizer of revision BEFORE as it was (module doc), on today's objective."""
    from threadpoolctl import threadpool_limits

    from furuta_cosim.tuning.objective import Evaluator

    settings, make = spec.optimizer, _before_make()
    dimensions = Evaluator(spec).space.dimensions()
    # that revision's loop: one BLAS thread for the optimizer, batches by the constant liar
    with threadpool_limits(1):
        optimizer = make(dimensions, "bo", seed, xi=settings.xi, n_initial_points=settings.n_initial_points,
                         gp_restarts=settings.gp_restarts)
        return _ask_tell(spec, folder, calls, workers, settings.batch,
                         lambda count: list(optimizer.batch(count)), optimizer.tell)


def _before_make():
    """``make`` of revision BEFORE's tuning/optimizers.py (bayesopt.py since) (with its tuning/gp.py), loaded from
    this checkout's git history as modules of their own."""
    import types

    sources = {}
    for name in ("gp", "optimizers"):
        shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{BEFORE}:furuta_cosim/tuning/{name}.py"],
                               capture_output=True, text=True)
        if shown.returncode:
            raise SystemExit(f"--methods before reads revision {BEFORE} from the git history of "
                             f"{ROOT}: {shown.stderr.strip() or 'git failed'}")
        sources[name] = shown.stdout
    importing = "from furuta_cosim.tuning.gp import"
    if importing not in sources["optimizers"]:
        raise SystemExit(f"revision {BEFORE}'s optimizers.py does not import its gp module as expected")
    sources["optimizers"] = sources["optimizers"].replace(importing, "from bench_before_gp import")
    modules = {}
    for name in ("gp", "optimizers"):
        module = types.ModuleType(f"bench_before_{name}")
        sys.modules[module.__name__] = module
        exec(compile(sources[name], f"{BEFORE}:furuta_cosim/tuning/{name}.py", "exec"), module.__dict__)
        modules[name] = module
    return modules["optimizers"].make


def _ask_tell(spec, folder: Path, calls: int, workers: int, batch: int, ask, tell,
              outcomes_told: bool = False) -> dict:
    """Batches of ``ask(count)`` points evaluated and told (``tell(xs, ys)``) with the penalized
    objective (``penalty + violation`` when infeasible), with ``outcomes_told`` also each
    outcome (``tell(xs, ys, outcomes)``: its constraint margin); the best feasible in
    summary.json."""
    import warnings

    from furuta_cosim.tuning.executors import Processes, Serial
    from furuta_cosim.tuning.objective import Evaluator

    evaluator = Evaluator(spec)
    executor = Processes(spec, workers) if workers > 1 else Serial(spec, evaluator)
    best, done = None, 0
    try:
        while done < calls:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                xs = ask(min(batch, calls - done))
                outcomes = executor.gather([executor.submit(x) for x in xs])
                ys = [outcome.objective for outcome in outcomes]
                tell(xs, ys, outcomes) if outcomes_told else tell(xs, ys)
            done += len(xs)
            for outcome in outcomes:
                if outcome.feasible and (best is None or outcome.objective < best):
                    best = outcome.objective
    finally:
        executor.close()
    folder.mkdir(parents=True, exist_ok=True)
    document = {"best": {"objective": best} if best is not None else None}
    (folder / "summary.json").write_text(json.dumps(document) + "\n")
    return document


def unpack(revision: str, folder: Path) -> Path:
    """Revision ``revision`` of this checkout's history as files under ``folder``."""
    target = folder / f"revision-{revision}"
    if not (target / "furuta_cosim").is_dir():
        target.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision], capture_output=True)
        if archive.returncode:
            raise SystemExit(f"--against {revision}: git archive failed: "
                             f"{archive.stderr.decode(errors='replace').strip()}")
        subprocess.run(["tar", "-x", "-C", str(target)], input=archive.stdout, check=True)
    return target


def _this() -> str:
    """This checkout's revision, with ``+`` when it has uncommitted changes."""
    def git(*words):
        return subprocess.run(["git", "-C", str(ROOT), *words], capture_output=True, text=True).stdout.strip()

    return (git("rev-parse", "--short", "HEAD") or "this checkout") + ("+" if git("status", "--porcelain", "--untracked-files=no") else "")


def main_job(root: Path, spec: str, seed: int, args, folder: Path) -> tuple[float, dict]:
    """``furuta-cosim tune SPEC --seed SEED`` of the code under ``root``: wall seconds and the
    summary it printed."""
    command = [sys.executable, "-m", "furuta_cosim", "tune", spec, "--seed", str(seed),
               "--n-calls", str(args.calls), "--workers", str(args.workers), "-o", str(folder), "--json",
               *(["--plant", args.plant] if args.plant else [])]
    started = time.perf_counter()
    done = subprocess.run(command, env={**os.environ, "PYTHONPATH": str(root)}, cwd=root,
                          capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(command)} (under {root}) exited {done.returncode}:\n{done.stderr[-2000:]}")
    return wall, json.loads(done.stdout)


def against(args, work: Path) -> dict:
    """The main job of this checkout and of revision ``args.against``, seed by seed in turn."""
    roots = {_this(): ROOT, args.against: unpack(args.against, work)}
    results = {}
    for name in args.specs:
        rows = {label: {"wall": [], "best": []} for label in roots}
        lqr = None
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for label, root in (roots.items() if seed % 2 == 0 else reversed(roots.items())):
                wall, document = main_job(root, name, seed, args, work / Path(name).stem / label / f"seed-{seed}")
                rows[label]["wall"].append(wall)
                rows[label]["best"].append(best_of(document))
                for baseline in (document.get("baselines") or {}).values():
                    if lqr is None and baseline.get("feasible"):
                        lqr = baseline["objective"]
                print(f"  {name} {label} seed {seed}: best {rows[label]['best'][-1]}, {wall:.1f} s",
                      file=sys.stderr, flush=True)
        known = _known(args, work, name, [v for row in rows.values() for v in row["best"]])
        results[name] = {"rows": rows, "lqr": lqr, "best_known": known}
    return results


def _known(args, work: Path, name: str, bests) -> float | None:
    """The best known: the lowest of ``bests`` (every run's best), or differential
    evolution's with --best-known evaluations when lower."""
    found = [v for v in bests if v is not None]
    known = None
    if args.best_known:
        from dataclasses import replace

        spec = load_spec(name, plant=args.plant)
        started = time.perf_counter()
        # the spec's budget sets differential evolution's population (at most 15 per
        # parameter): the long run gets the population of a long run
        long = replace(spec, optimizer=replace(spec.optimizer, n_calls=args.best_known))
        known = best_of(plain(long, work / Path(name).stem / "best-known", 0, args.best_known,
                              args.workers, "de"))
        print(f"  {name} de {args.best_known}: best {known}, {time.perf_counter() - started:.1f} s",
              file=sys.stderr, flush=True)
    if found and (known is None or min(found) < known):
        known = min(found)
    return known


def against_table(results: dict, args) -> list[str]:
    lines = []
    for name, data in results.items():
        rows, lqr, known = data["rows"], data["lqr"], data["best_known"]
        labels = list(rows)
        lines += ["", f"{name}: the main job (`furuta-cosim tune {name} --seed S`, {args.calls} calls, "
                      f"{args.workers} workers, seeds {args.first_seed}-{args.first_seed + args.seeds - 1}); "
                      f"LQR {_f(lqr)}; best known {_f(known)}",
                  "", "| code | wall median (s) | wall per seed | best median | worst | median vs best known "
                      "| seeds <= LQR | best per seed |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for label in labels:
            wall, best = rows[label]["wall"], rows[label]["best"]
            found = [v for v in best if v is not None]
            median = statistics.median(found) if found else None
            worst = max(found) if found and len(found) == len(best) else None
            versus = f"{(median / known - 1) * 100:+.2f} %" if median and known else "-"
            beat = f"{sum(1 for v in best if v is not None and lqr is not None and v <= lqr)}/{len(best)}"
            lines.append(f"| {label} | {statistics.median(wall):.1f} | {' '.join(f'{w:.1f}' for w in wall)} | "
                         f"{_f(median)} | {_f(worst)} | {versus} | {beat} | {' '.join(_f(v) for v in best)} |")
        this, other = rows[labels[0]], rows[labels[1]]
        ratios = [a / b for a, b in zip(this["wall"], other["wall"])]
        mine = statistics.median([v for v in this["best"] if v is not None] or [math.nan])
        theirs = statistics.median([v for v in other["best"] if v is not None] or [math.nan])
        lines += ["", f"{labels[0]} / {labels[1]}: wall time, ratio of medians "
                      f"{statistics.median(this['wall']) / statistics.median(other['wall']):.3f}, "
                      f"median of the seeds' ratios {statistics.median(ratios):.3f}; best, ratio of "
                      f"medians {mine / theirs:.4f}"]
    return lines


def best_of(document: dict) -> float | None:
    return document["best"]["objective"] if document.get("best") else None


def measure(args, work: Path) -> dict:
    results: dict = {}
    timer = Timer()
    for name in args.specs:
        spec = load_spec(name, plant=args.plant)
        rows, lqr = {}, None
        for method in args.methods:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                folder = work / Path(name).stem / method / f"seed-{seed}"
                started = time.perf_counter()
                if method in ("ours", "global"):
                    region = "trust" if method == "ours" else "global"
                    with timer if method == "ours" else _nothing():
                        document = ours(spec, folder, seed, args.calls, args.workers, region)
                elif method in VARIANTS:
                    document = variant(spec, folder, seed, args.calls, args.workers, method)
                elif method == "skopt":
                    document = skopt(spec, folder, seed, args.calls, args.workers)
                elif method == "optuna":
                    document = optuna_tpe(spec, folder, seed, args.calls, args.workers)
                elif method == "before":
                    document = before(spec, folder, seed, args.calls, args.workers)
                else:
                    document = plain(spec, folder, seed, args.calls, args.workers, method)
                rows.setdefault(method, []).append(best_of(document))
                for baseline in (document.get("baselines") or {}).values():
                    if lqr is None and baseline.get("feasible"):
                        lqr = baseline["objective"]
                print(f"  {name} {method} seed {seed}: best {rows[method][-1]}, "
                      f"{time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
        known = _known(args, work, name, [v for values in rows.values() for v in values])
        results[name] = {"rows": rows, "lqr": lqr, "best_known": known,
                         "best_known_evaluations": args.best_known}
    results["optimizer_seconds_per_iteration"] = timer.points
    return results


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def table(results: dict, args) -> list[str]:
    lines = []
    for name, data in results.items():
        if not isinstance(data, dict) or "rows" not in data:
            continue
        lqr, known = data["lqr"], data["best_known"]
        seeds = f"{args.first_seed}-{args.first_seed + args.seeds - 1}"
        lines += ["", f"{name}: best objective over seeds {seeds}, {args.calls} calls "
                      f"(lower is better); LQR scored alike {_f(lqr)}; best known {_f(known)} "
                      f"(de with {data['best_known_evaluations']} evaluations, or any run's best)",
                  "", "| method | median | worst | median vs best known | seeds <= LQR | per seed |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for method, values in data["rows"].items():
            found = [v for v in values if v is not None]
            median = statistics.median(found) if found else None
            worst = max(found) if len(found) == len(values) and found else None
            versus = f"{(median / known - 1) * 100:+.2f} %" if median and known else "-"
            # the LQR is scored by the rows that run tune (skopt and before alone do not score it)
            beat = (f"{sum(1 for v in values if v is not None and v <= lqr)}/{len(values)}"
                    if lqr is not None else "- (LQR not scored)")
            lines.append(f"| {method} | {_f(median)} | {_f(worst) if worst else 'none found on some seed'} | "
                         f"{versus} | {beat} | {' '.join(_f(v) for v in values)} |")
    per = results.get("optimizer_seconds_per_iteration") or []
    if per:
        lines += ["", f"ours: optimizer seconds per iteration, median {statistics.median(per):.3f}, "
                      f"mean {statistics.mean(per):.3f}, max {max(per):.3f} ({len(per)} points)"]
    return lines


def _f(value) -> str:
    return "none" if value is None else f"{value:.4f}"


def kernel_lines(results: dict, other: dict, methods, args, kernel: str) -> list[str]:
    """Each kernel-bound row under the default kernel and under ``args.kernel``: how many seeds
    agree, and the range across the two a user of either can expect (what the docs state)."""
    lines = [f"\nunder OPENBLAS_CORETYPE={args.kernel} ({kernel}) against the default kernel:"]
    for name in args.specs:
        lqr = results[name]["lqr"]
        for method in methods:
            mine, theirs = results[name]["rows"].get(method, []), other[name]["rows"][method]
            same = sum(1 for a, b in zip(mine, theirs) if a == b)
            spread = [abs(a - b) / a for a, b in zip(mine, theirs) if a and b]
            flips = sum(1 for a, b in zip(mine, theirs)
                        if a is not None and b is not None and lqr is not None and (a <= lqr) != (b <= lqr))
            lines.append(f"  {name} {method}: {same}/{len(mine)} seeds identical; largest relative difference "
                         f"of a seed's best {max(spread, default=0):.2e}; verdicts against the LQR flipped: {flips}")
            if None in mine + theirs or not mine:
                continue
            ranged = lambda a, b: f"{min(a, b):.4f}-{max(a, b):.4f}"  # noqa: E731
            below = sorted({sum(v <= lqr for v in mine), sum(v <= lqr for v in theirs)}) if lqr is not None else []
            lines.append(f"  {name} {method}: across the two kernels: median "
                         f"{ranged(statistics.median(mine), statistics.median(theirs))}, worst "
                         f"{ranged(max(mine), max(theirs))}, every seed's best within "
                         f"{min(mine + theirs):.4f}-{max(mine + theirs):.4f}, seeds <= LQR "
                         f"{'-'.join(map(str, below))}/{len(mine)}; seed {args.first_seed}: {mine[0]:.4f} "
                         f"(default kernel), {theirs[0]:.4f} ({args.kernel})")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--specs", nargs="+", default=["effort", "robust-effort"])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0,
                        help="seeds FIRST .. FIRST + SEEDS - 1 (to extend an earlier run)")
    parser.add_argument("--calls", type=int, default=150)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", default=",".join(m for m in METHODS if m not in VARIANTS),
                        type=lambda text: [m for m in text.split(",") if m])
    parser.add_argument("--best-known", type=int, default=3000, help="evaluations of the de run (0: none)")
    parser.add_argument("--kernel", help="rerun the GP-driven rows under OPENBLAS_CORETYPE=KERNEL and compare")
    parser.add_argument("--plant", help="tune for this plant file or name (tune --plant): the LQR "
                                        "row is the spec's LQR designed again for it")
    parser.add_argument("-o", "--output", help="folder of the runs (default: a new temporary one)")
    parser.add_argument("--against", metavar="REV",
                        help="time the main job against revision REV of this checkout's history")
    parser.add_argument("--json", help=argparse.SUPPRESS)  # a child's results (--kernel)
    args = parser.parse_args()
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        parser.error(f"--methods: unknown {', '.join(unknown)} (expected: {', '.join(METHODS)})")
    if args.kernel and not any(m in KERNEL_BOUND for m in args.methods):
        parser.error(f"--kernel compares the rows a GP drives: --methods must include one of {', '.join(KERNEL_BOUND)}")
    kernel = check_kernel(args.kernel) if args.kernel else None  # before any long work
    work = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="bench-tune-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"runs in {work}; OPENBLAS_CORETYPE={os.environ.get('OPENBLAS_CORETYPE', '(default)')}",
          file=sys.stderr)
    try:
        results = against(args, work) if args.against else measure(args, work)
    except ConfigError as error:
        print("\n".join(error.problems), file=sys.stderr)
        return 2
    (work / "bench.json").write_text(json.dumps(results, indent=1) + "\n")
    if args.against:
        print("\n".join(against_table(results, args)))
        return 0
    if args.json:
        Path(args.json).write_text(json.dumps(results) + "\n")
        return 0
    print("\n".join(table(results, args)))
    if args.kernel:
        again = [m for m in args.methods if m in KERNEL_BOUND]
        child = work / f"kernel-{args.kernel}"
        command = [sys.executable, __file__, "--specs", *args.specs, "--seeds", str(args.seeds),
                   "--first-seed", str(args.first_seed),
                   *(["--plant", args.plant] if args.plant else []),
                   "--calls", str(args.calls), "--workers", str(args.workers), "--methods", ",".join(again),
                   "--best-known", "0", "-o", str(child), "--json", str(child / "results.json")]
        subprocess.run(command, env={**os.environ, "OPENBLAS_CORETYPE": args.kernel}, check=True)
        other = json.loads((child / "results.json").read_text())
        print("\n".join(kernel_lines(results, other, again, args, kernel)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
