"""A resampling check of a fit's intervals: the moving-block bootstrap of its residual series
(Kuensch, "The jackknife and the bootstrap for general stationary observations", Annals of
Statistics 17, 1989).

Each replicate is the fitted outputs plus residuals drawn in blocks from the fit's own residual
series (each (experiment, output) series on its own), blocks as long as the series'
integrated autocorrelation time (identify/fit.py's, Sokal's window), so that a replicate keeps
the residuals' correlation over that length; the fit is run again on the replicate from the
estimate, over the whole windows. The interval of each parameter is the 2.5 and 97.5
percentiles of its replicates (the percentile interval).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable

import numpy as np

from furuta_cosim.config import Frozen
from furuta_cosim.identify.fit import autocorrelation_time
from furuta_cosim.identify.problem import Problem, Runner

REFIT = 100   # residual evaluations per replicate's fit at most


def block_resample(series: np.ndarray, block: int, rng: np.random.Generator) -> np.ndarray:
    """``series`` resampled in blocks of ``block`` consecutive values, to its own length."""
    n = len(series)
    block = max(1, min(int(block), n))
    starts = rng.integers(0, n - block + 1, size=math.ceil(n / block))
    return np.concatenate([series[s:s + block] for s in starts])[:n]


def bootstrap_all(spec, target, result, *, replicates: int = 50, seed: int = 0, workers: int = 1,
                  dask: str | None = None,
                  progress: Callable[[str, int, float], None] = lambda stage, n, cost: None,
                  log: Callable[[str], None] = lambda line: None) -> dict:
    """The block bootstrap of a fit (module docstring): per free plant parameter its percentile
    interval, and how it was drawn (``replicates``, the blocks, the seed)."""
    from scipy.optimize import least_squares

    items = result.items
    x_hat = np.array([result.values[u.name] / u.scale for u in items])
    lower = np.array([u.bounds[0] / u.scale for u in items])
    upper = np.array([u.bounds[1] / u.scale for u in items])
    fitted = {e.name: result.simulated[e.name]["fit"] for e in spec.experiments}
    series, blocks = {}, {}
    for e in spec.experiments:
        for name, measured in e.outputs.items():
            r = (fitted[e.name][name] - measured.values) / measured.sigma
            series[(e.name, name)] = r
            blocks[f"{e.name}.{name}"] = int(math.ceil(autocorrelation_time(r)[0]))
    rng = np.random.default_rng([seed, 5])
    draws = []
    runner = Runner(target, spec.experiments, workers, dask)
    try:
        for b in range(replicates):
            experiments = []
            for e in spec.experiments:
                outputs = {}
                for name, measured in e.outputs.items():
                    r = block_resample(series[(e.name, name)], blocks[f"{e.name}.{name}"], rng)
                    outputs[name] = replace(measured, values=fitted[e.name][name] - measured.sigma * r)
                experiments.append(replace(e, outputs=Frozen(outputs)))
            problem = Problem(runner, experiments, items, None, math.inf,
                              lambda n, cost, b=b: progress(f"bootstrap {b + 1}/{replicates}", n, cost))
            found = least_squares(problem.fun, x_hat, jac=problem.jac, bounds=(lower, upper), x_scale="jac",
                                  method="trf", xtol=1e-8, ftol=1e-8, gtol=1e-8, max_nfev=REFIT)
            draws.append(found.x * np.array([u.scale for u in items]))
    finally:
        runner.close()
    draws = np.array(draws)
    found = {}
    for k, u in enumerate(items):
        if "." in u.name:
            continue
        lo, hi = np.percentile(draws[:, k], [2.5, 97.5])
        found[u.name] = {"interval": [float(lo), float(hi)], "stderr": float(np.std(draws[:, k], ddof=1))}
    log(f"  bootstrap: {replicates} replicates, blocks of " + ", ".join(f"{k} {v}" for k, v in blocks.items()))
    return {"parameters": found, "replicates": replicates, "seed": seed, "blocks": blocks,
            "method": "moving-block bootstrap of the residual series (blocks as long as each series' "
                      "integrated autocorrelation time), the fit run again from the estimate; "
                      "percentile intervals"}
