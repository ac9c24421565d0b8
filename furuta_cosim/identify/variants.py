"""Plant variants drawn from what a fit left uncertain (a tuning spec's
``variants: {from_fit: FILE, samples: N, seed: S}``).

The fitted plant parameters are taken as Gaussian with the fit's covariance (``fit.json``:
standard errors and correlations, the Newey-West ones), so correlated pairs move together.
``samples`` draws are a Latin hypercube in probability, mapped through the normal quantile
and the covariance's square root: a space-filling design over the fit's uncertainty rather
than a handful of random draws. Each draw is clipped to the parameter's bounds of the fit.
Variant 0 is the point estimate itself (the fitted plant as it is).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from furuta_cosim.errors import ConfigError

MAX_SAMPLES = 64


def read_fit(path: str | Path) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """(names, values, covariance, bounds) of the plant parameters of a fit.json; every problem
    of the file is one ConfigError naming it and the key."""
    path = Path(path)
    try:
        raw = path.read_bytes()
        if len(raw) > 10_000_000:
            raise ConfigError([f"{path}: larger than 10 MB: not a fit.json of identify"])
        document = json.loads(raw.decode("utf-8"))
    except OSError as error:
        raise ConfigError([f"{path}: cannot be read ({error.__class__.__name__})"]) from None
    except (UnicodeDecodeError, ValueError):
        raise ConfigError([f"{path}: not JSON: not a fit.json of identify"]) from None
    problems = []
    parameters = document.get("parameters") if isinstance(document, dict) else None
    correlation = document.get("correlation") if isinstance(document, dict) else None
    if not isinstance(parameters, dict) or not parameters:
        raise ConfigError([f"{path}: parameters: expected the fitted parameters (a fit.json of identify)"])
    if not isinstance(correlation, dict) or not isinstance(correlation.get("names"), list) \
            or not isinstance(correlation.get("matrix"), list):
        raise ConfigError([f"{path}: correlation: expected names and matrix"])
    every = correlation["names"]
    names = [n for n in every if isinstance(n, str) and "." not in n]  # states and biases are not the plant's
    values, errors, bounds = [], [], []
    for name in names:
        entry = parameters.get(name)
        numbers = [entry.get(k) for k in ("value", "stderr")] if isinstance(entry, dict) else []
        pair = entry.get("bounds") if isinstance(entry, dict) else None
        good = (len(numbers) == 2 and all(_finite(v) for v in numbers) and numbers[1] >= 0
                and isinstance(pair, list) and len(pair) == 2 and all(_finite(v) for v in pair)
                and pair[0] <= numbers[0] <= pair[1])
        if not good:
            problems.append(f"{path}: parameters.{name}: expected value, stderr >= 0 and bounds "
                            "[lo, hi] around the value")
            continue
        values.append(float(numbers[0]))
        errors.append(float(numbers[1]))
        bounds.append((float(pair[0]), float(pair[1])))
    matrix = correlation["matrix"]
    n = len(every)
    if len(matrix) != n or not all(isinstance(row, list) and len(row) == n and all(_finite(v) for v in row)
                                   for row in matrix):
        problems.append(f"{path}: correlation.matrix: expected {n}x{n} finite numbers")
    if problems:
        raise ConfigError(problems)
    index = [every.index(name) for name in names]
    corr = np.array(matrix, dtype=float)[np.ix_(index, index)]
    if not np.allclose(corr, corr.T, atol=1e-9) or np.any(np.abs(corr) > 1 + 1e-9):
        raise ConfigError([f"{path}: correlation.matrix: not a correlation matrix (symmetric, "
                           "entries within [-1, 1])"])
    sd = np.array(errors)
    return names, np.array(values), corr * np.outer(sd, sd), np.array(bounds)


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def variants_from_fit(path: str | Path, samples: int, seed: int) -> list[dict[str, float]]:
    """``[{}] + samples`` parameter overrides (see the module docstring)."""
    from scipy.stats import norm, qmc

    names, mean, covariance, bounds = read_fit(path)
    # the covariance's square root through its eigenvectors: a correlation of exactly 1 (a
    # pair the data cannot separate) is a valid, singular covariance
    w, v = np.linalg.eigh(covariance)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    u = qmc.LatinHypercube(d=len(names), seed=seed).random(samples)
    draws = mean + norm.ppf(u) @ root.T
    draws = np.clip(draws, bounds[:, 0], bounds[:, 1])
    return [{}] + [{name: float(x) for name, x in zip(names, row)} for row in draws]
