"""Plant variants drawn from what a fit left uncertain (a tuning spec's
``variants: {from_fit: FILE, samples: N, seed: S}``).

The fitted plant parameters are taken as Gaussian with the fit's covariance (``fit.json``:
standard errors and correlations, the Newey-West ones), so correlated pairs move together;
a parameter's standard error is widened by its ``reach`` / 1.96 (identify/reach.py), so that
the draws span its 95 % interval as fit.json states it.
``samples`` draws are a Latin hypercube in probability, mapped through the normal quantile
and the covariance's square root: a space-filling design over the fit's uncertainty rather
than a handful of random draws. Each draw is clipped to the parameter's bounds of the fit.
Variant 0 is the point estimate itself (the fitted plant as it is).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from furuta_cosim.errors import ConfigError

MAX_SAMPLES = 64
Z95 = 1.959963984540054


MAX_JSON_DEPTH = 64  # a fit.json is four levels deep


@dataclass(frozen=True)
class Fit:
    """What a tuning takes from a fit.json: the drawn plant parameters (names, values,
    covariance, the fit's bounds), those held at their value (not identifiable from the fit's
    data), and the fitted plant it belongs to."""

    path: Path
    names: list
    values: np.ndarray
    covariance: np.ndarray
    bounds: np.ndarray
    held: dict
    plant: Path
    plant_sha256: str


def _load_json(path: Path):
    from furuta_cosim.inputs import read_input

    raw = read_input(path, 10_000_000, beyond="not a fit.json of identify")
    if _depth(raw) > MAX_JSON_DEPTH:
        raise ConfigError([f"{path}: nested more than {MAX_JSON_DEPTH} levels deep: not a "
                           "fit.json of identify"])
    try:
        return json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise ConfigError([f"{path}: not JSON: not a fit.json of identify"]) from None


def _depth(raw: bytes) -> int:
    """The deepest nesting of brackets outside strings, counted without parsing."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in raw:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_JSON_DEPTH:
                return deepest
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def load_fit(path: str | Path) -> Fit:
    """A fit.json checked whole: every problem is one ConfigError naming the file and the key.
    The plant.yaml beside it must be the plant it was fitted to (its values' sha256)."""
    path = Path(path)
    document = _load_json(path)
    problems = []
    parameters = document.get("parameters") if isinstance(document, dict) else None
    correlation = document.get("correlation") if isinstance(document, dict) else None
    if not isinstance(parameters, dict) or not parameters:
        raise ConfigError([f"{path}: parameters: expected the fitted parameters (a fit.json of identify)"])
    if not isinstance(correlation, dict) or not isinstance(correlation.get("names"), list) \
            or not isinstance(correlation.get("matrix"), list):
        raise ConfigError([f"{path}: correlation: expected names and matrix"])
    fitted = document.get("fitted_plant")
    if isinstance(fitted, dict) and fitted.get("rejected"):
        raise ConfigError([f"{path}: identify judged this fit untrustworthy (its verdict in this file); "
                           "fit again, or run identify with `accept=True` to use it all the same"])
    if not isinstance(fitted, dict) or not isinstance(fitted.get("sha256"), str):
        raise ConfigError([f"{path}: fitted_plant: expected the sha256 of the plant it was fitted "
                           "to (a fit.json of identify names its plant.yaml)"])
    every = correlation["names"]
    if not all(isinstance(n, str) for n in every) or len(set(every)) != len(every):
        raise ConfigError([f"{path}: correlation.names: expected unique names"])
    names = [n for n in every if "." not in n]  # states and biases are not the plant's
    values, errors, bounds, held = [], [], [], {}
    for name in names:
        entry = parameters.get(name)
        key = f"{path}: parameters.{name}"
        if isinstance(entry, dict) and entry.get("identifiable") is False:
            if not _finite(entry.get("value")):
                problems.append(f"{key}.value: expected a finite number")
            else:
                held[name] = float(entry["value"])
            continue
        numbers = [entry.get(k) for k in ("value", "stderr")] if isinstance(entry, dict) else []
        pair = entry.get("bounds") if isinstance(entry, dict) else None
        good = (len(numbers) == 2 and all(_finite(v) for v in numbers) and numbers[1] >= 0
                and isinstance(pair, list) and len(pair) == 2 and all(_finite(v) for v in pair)
                and pair[0] <= numbers[0] <= pair[1])
        if not good:
            problems.append(f"{key}: expected value, stderr >= 0 and bounds [lo, hi] around the value")
            continue
        if numbers[1] > LARGEST_SPREAD * max(abs(pair[1] - pair[0]), abs(numbers[0]), 1e-300):
            problems.append(f"{key}.stderr: {numbers[1]:g} is beyond any spread its bounds allow")
            continue
        reach = entry.get("reach") or 0.0
        if not _finite(reach) or reach < 0:
            problems.append(f"{key}.reach: expected a finite number >= 0 or none")
            continue
        values.append(float(numbers[0]))
        # the reach (identify/reach.py) widens the spread as it widens the 95 % interval
        errors.append(float(numbers[1]) + float(reach) / Z95)
        bounds.append((float(pair[0]), float(pair[1])))
    matrix = correlation["matrix"]
    n = len(every)
    if len(matrix) != n or not all(isinstance(row, list) and len(row) == n and all(_finite(v) for v in row)
                                   for row in matrix):
        problems.append(f"{path}: correlation.matrix: expected {n}x{n} finite numbers")
    if problems:
        raise ConfigError(problems)
    full = np.array(matrix, dtype=float)
    if not np.allclose(full, full.T, atol=1e-9) or np.any(np.abs(full) > 1 + 1e-9) \
            or not np.allclose(np.diag(full), 1.0, atol=1e-9) \
            or np.min(np.linalg.eigvalsh(0.5 * (full + full.T))) < -1e-6:
        raise ConfigError([f"{path}: correlation.matrix: not a correlation matrix (symmetric, unit "
                           "diagonal, entries within [-1, 1], positive semi-definite)"])
    drawn = [name for name in names if name not in held]
    index = [every.index(name) for name in drawn]
    corr = full[np.ix_(index, index)]
    sd = np.array(errors)
    plant = path.parent / "plant.yaml"
    _belongs(path, plant, fitted["sha256"])
    return Fit(path, drawn, np.array(values), corr * np.outer(sd, sd), np.array(bounds).reshape(-1, 2),
               held, plant, fitted["sha256"])


# a standard error larger than this many times its bounds' width says nothing a draw can use
LARGEST_SPREAD = 1e6


def _belongs(path: Path, plant: Path, digest: str) -> None:
    from furuta_cosim.fmu.plants import content_sha256, load_plant

    if not plant.is_file():
        raise ConfigError([f"{path}: expected the fitted plant beside it ({plant.name}), there is none"])
    if content_sha256(load_plant(plant)) != digest:
        raise ConfigError([f"{plant}: is not the plant {path.name} was fitted to (its values "
                           "differ from fitted_plant.sha256): the fit and the plant must come from "
                           "the same identify run"])


def read_fit(path: str | Path) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """(names, values, covariance, bounds) of the plant parameters a fit.json lets vary."""
    found = load_fit(path)
    return found.names, found.values, found.covariance, found.bounds


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def variants_from_fit(path: str | Path, samples: int, seed: int) -> list[dict[str, float]]:
    """``[{}] + samples`` parameter overrides (see the module docstring); a parameter the fit
    could not identify is held at its value in every variant, and a draw outside a parameter's
    physical range is refused (ConfigError), never run."""
    return draw(load_fit(path), samples, seed)


def draw(fit: Fit, samples: int, seed: int) -> list[dict[str, float]]:
    """``[{}] + samples`` variants of ``fit``."""
    from scipy.stats import norm, qmc

    from furuta_cosim.fmu.exporter import parameter_ranges
    from furuta_cosim.fmu.plants import load_plant

    names, mean, covariance, bounds = fit.names, fit.values, fit.covariance, fit.bounds
    if names:
        # the covariance's square root through its eigenvectors: a correlation of exactly 1 (a
        # pair the data cannot separate) is a valid, singular covariance
        w, v = np.linalg.eigh(covariance)
        root = v * np.sqrt(np.clip(w, 0.0, None))
        u = qmc.LatinHypercube(d=len(names), seed=seed).random(samples)
        draws = np.clip(mean + norm.ppf(u) @ root.T, bounds[:, 0], bounds[:, 1])
    else:
        draws = np.zeros((samples, 0))
    ranges = parameter_ranges(load_plant(fit.plant))
    found = [{}]
    for k, row in enumerate(draws, start=1):
        variant = {name: float(x) for name, x in zip(names, row)}
        for name, x in variant.items():
            if name in ranges:
                low, strict = ranges[name]
                if (x <= low) if strict else (x < low):
                    raise ConfigError([f"{fit.path}: variant {k} draws {name} = {x:g}, outside its "
                                       f"physical range ({'>' if strict else '>='} {low:g}): the "
                                       f"fit's bounds {list(bounds[names.index(name)])} allow it; "
                                       "narrow them in the identify spec and fit again"])
        variant.update(fit.held)
        found.append(variant)
    return found
