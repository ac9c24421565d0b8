"""A tuning run: scikit-optimize's ask/tell loop over a spec, written to a run directory.

    run-dir/
      spec.yaml        a copy of the spec
      history.jsonl    one line per evaluation, appended and flushed to disk (fsync) at once
      best.yaml        the best feasible controller, a controller file simulate/analyze accept
      convergence.png  (and .svg) best objective against evaluations
      summary.json     best, baselines scored alike, counts; summary.md the same in words

This first version evaluates in the calling process, one candidate at a time (``bo``: GP +
Expected Improvement; ``random``: the same space drawn at random, with the same history).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.errors import ConfigError
from furuta_cosim.files import atomic, output_folder, write_text
from furuta_cosim.tuning.objective import Evaluator, Outcome
from furuta_cosim.tuning.spec import TuningSpec


def _optimizer(spec: TuningSpec, evaluator: Evaluator, method: str, seed: int):
    from skopt import Optimizer

    settings = spec.optimizer
    if method == "random":
        return _Random(evaluator.space.dimensions(), seed)
    return Optimizer(evaluator.space.dimensions(), base_estimator="GP", acq_func="EI",
                     acq_func_kwargs={"xi": settings.xi}, n_initial_points=settings.n_initial_points,
                     random_state=seed)


class _Random:
    """Uniform draws from the same space, with the optimizer's ask/tell (skopt's own "dummy"
    estimator does not run with current scikit-learn)."""

    def __init__(self, dimensions, seed: int):
        from skopt.space import Space

        self._space, self._rng = Space(dimensions), np.random.RandomState(seed)

    def ask(self):
        return self._space.rvs(1, random_state=self._rng)[0]

    def tell(self, x, y) -> None:
        pass


def _json_safe(value):
    """Non-finite numbers become null (JSON has none); numpy scalars plain numbers."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _record(index: int, x, names, outcome: Outcome) -> dict:
    return _json_safe({"index": index, "x": [float(v) for v in x],
                       "parameters": dict(zip(names, map(float, x))),
                       "objective": outcome.objective, "feasible": outcome.feasible,
                       "constraints": outcome.constraints, "metrics": outcome.metrics,
                       "wall_time": outcome.wall_time, "worker": os.getpid(), "error": outcome.error})


def _append(handle, record: dict) -> None:
    handle.write(json.dumps(record, allow_nan=False) + "\n")
    handle.flush()
    os.fsync(handle.fileno())


def tune(spec: TuningSpec, run_dir: str | Path, *, method: str | None = None,
         n_calls: int | None = None, seed: int | None = None,
         progress: Callable[[int, int, float | None, int], None] | None = None) -> dict:
    """Run the spec's optimization into ``run_dir`` and return the summary document.

    ``progress(done, total, best, feasible)`` is called after every evaluation."""
    method = method or spec.optimizer.method
    n_calls = n_calls or spec.optimizer.n_calls
    seed = spec.optimizer.seed if seed is None else seed
    if method not in ("bo", "random"):
        raise ConfigError([f"--optimizer: expected bo or random, got {method!r}"])
    if n_calls < 1:
        raise ConfigError([f"--n-calls: must be >= 1, got {n_calls}"])
    folder = output_folder(run_dir)
    if (folder / "history.jsonl").exists():
        raise ConfigError([f"-o {folder}: holds a tuning run already; choose another folder"])
    evaluator = Evaluator(spec)
    if spec.objective.type == "scenarios":
        evaluator.runs()  # every scenario and variant prepared (and checked) before any file
    folder.mkdir(parents=True, exist_ok=True)
    if spec.path:
        write_text(folder / "spec.yaml", Path(spec.path).read_text())
    optimizer = _optimizer(spec, evaluator, method, seed)
    names = evaluator.space.names
    best: tuple[float, int, list] | None = None
    feasible = 0
    optimizer_time = evaluation_time = 0.0
    with (folder / "history.jsonl").open("a") as history:
        for index in range(n_calls):
            started = time.perf_counter()
            x = optimizer.ask()
            asked = time.perf_counter()
            outcome = evaluator(x)
            evaluated = time.perf_counter()
            optimizer.tell(x, outcome.objective)
            optimizer_time += (asked - started) + (time.perf_counter() - evaluated)
            evaluation_time += evaluated - asked
            _append(history, _record(index, x, names, outcome))
            if outcome.feasible:
                feasible += 1
                if best is None or outcome.objective < best[0]:
                    best = (outcome.objective, index, list(x))
            if progress:
                progress(index + 1, n_calls, best[0] if best else None, feasible)
    return _finish(spec, folder, evaluator, best, n_calls, feasible, method, seed,
                   optimizer_time, evaluation_time)


def _finish(spec, folder, evaluator, best, n_calls, feasible, method, seed, optimizer_time,
            evaluation_time) -> dict:
    from furuta_cosim.controllers import ControllerFile, load_controller, save_controller

    baselines = {}
    for name in spec.baselines:
        cfile = load_controller(name)
        outcome = evaluator.score(cfile.controller)
        baselines[cfile.name] = _json_safe({"objective": outcome.objective,
                                            "feasible": outcome.feasible,
                                            "constraints": outcome.constraints})
    document = {"spec": spec.name, "method": method, "seed": seed, "n_calls": n_calls,
                "feasible": feasible, "objective": spec.objective.type,
                "optimizer_seconds": optimizer_time, "evaluation_seconds": evaluation_time,
                "best": None, "baselines": baselines}
    if best is not None:
        objective, index, x = best
        controller = evaluator.space.controller(x, name=f"{spec.name}-best")
        provenance = {"method": f"furuta-cosim tune ({method})", "spec": spec.name, "seed": seed,
                      "evaluation": index, "objective": objective}
        save_controller(ControllerFile(controller, spec.period, spec.model, None, None,
                                       f"best of tuning {spec.name} ({method}, seed {seed})",
                                       provenance=provenance), folder / "best.yaml")
        document["best"] = {"index": index, "objective": objective,
                            "parameters": dict(zip(evaluator.space.names, x)), "file": "best.yaml"}
    _convergence(folder, folder / "history.jsonl")
    write_text(folder / "summary.json", json.dumps(_json_safe(document), indent=2, allow_nan=False) + "\n")
    write_text(folder / "summary.md", _markdown(spec, document))
    return document


def _convergence(folder: Path, history: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = [json.loads(line) for line in history.read_text().splitlines() if line.strip()]
    index = [r["index"] for r in records]
    values = np.array([r["objective"] if r["feasible"] else math.nan for r in records])
    running = np.fmin.accumulate(np.where(np.isnan(values), np.inf, values))
    figure, axis = plt.subplots(figsize=(7, 3.6))
    axis.plot(index, values, "o", markersize=3, alpha=0.5, label="feasible evaluation")
    infeasible = [r["index"] for r in records if not r["feasible"]]
    if infeasible:
        axis.plot(infeasible, [np.nanmax(values) if np.isfinite(np.nanmax(values)) else 1.0] * len(infeasible)
                  if np.any(np.isfinite(values)) else [1.0] * len(infeasible),
                  "x", color="grey", markersize=3, label="infeasible")
    axis.step(index, np.where(np.isfinite(running), running, np.nan), where="post", color="C3",
              label="best so far")
    axis.set_xlabel("evaluation")
    axis.set_ylabel("objective")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize="small")
    figure.tight_layout()
    for suffix in ("png", "svg"):
        with atomic(folder / f"convergence.{suffix}") as partial:
            figure.savefig(partial, dpi=110, format=suffix)
    plt.close(figure)


def _markdown(spec: TuningSpec, document: dict) -> str:
    lines = [f"# Tuning {spec.name}", "", spec.description, "",
             f"- method: {document['method']}, seed {document['seed']}, {document['n_calls']} evaluations, "
             f"{document['feasible']} feasible",
             f"- objective: {document['objective']}"
             + (" (the paper's max |Re eig(Abar)| as stated: it measures the fastest mode, not the "
                "slowest, so it rewards poles near the imaginary axis; docs/paper-readings.md §3)"
                if document["objective"] == "spectral" else ""),
             f"- time: optimizer {document['optimizer_seconds']:.1f} s, evaluations "
             f"{document['evaluation_seconds']:.1f} s", ""]
    best = document["best"]
    if best:
        lines.append(f"Best: objective {best['objective']:.6g} at evaluation {best['index']} (best.yaml).")
    else:
        lines.append("No feasible controller was found.")
    for name, baseline in document["baselines"].items():
        verdict = f"{baseline['objective']:.6g}" if baseline["feasible"] else \
            f"infeasible (score {baseline['objective']:.6g})"
        lines.append(f"- {name}, scored alike: {verdict}")
    return "\n".join(lines) + "\n"
