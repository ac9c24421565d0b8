"""Pareto fronts of a multi-objective tuning: which points are non-dominated, how much of the
objective space a front covers (hypervolume), its knee, and the scalarizations the optimizer
searches with.

The search is ParEGO (Knowles, "ParEGO: a hybrid algorithm with on-line landscape approximation
for expensive multiobjective optimization problems", IEEE Trans. Evol. Comput. 10(1), 2006):
each batch draws a weight vector on the simplex and minimizes the augmented Chebyshev
scalarization of the criteria, each normalized to [0, 1] over the points seen so far, with the
constrained single-objective BO of tuning/bayesopt.py. Every weight vector is a function of
the seed and the batch number, so a history still depends only on the spec, the seed and the
batch size.
"""

from __future__ import annotations

import math

import numpy as np

# the augmented Chebyshev scalarization's linear part (ParEGO's rho)
RHO = 0.05


def nondominated(points) -> list[int]:
    """Indices of the points no other point dominates (<= in every criterion, < in one);
    of equal points, the first."""
    P = np.asarray(points, dtype=float).reshape(len(points), -1)
    keep = []
    for i, p in enumerate(P):
        dominated = np.any(np.all(P <= p, axis=1) & np.any(P < p, axis=1))
        duplicate = bool(keep) and bool(np.any(np.all(P[keep] == p, axis=1)))
        if not dominated and not duplicate:
            keep.append(i)
    return keep


def hypervolume(points, reference) -> float:
    """The volume dominated by ``points`` and bounded by ``reference`` (minimization): exact,
    by slicing along the first criterion (fine for the fronts of a few hundred points)."""
    r = np.asarray(reference, dtype=float)
    P = np.asarray([p for p in np.asarray(points, dtype=float).reshape(-1, len(r))
                    if np.all(p < r)])
    if len(P) == 0:
        return 0.0
    P = P[nondominated(P)]
    if len(r) == 1:
        return float(r[0] - P[:, 0].min())
    P = P[np.argsort(P[:, 0], kind="stable")]
    volume = 0.0
    for k in range(len(P)):
        width = (P[k + 1, 0] if k + 1 < len(P) else r[0]) - P[k, 0]
        if width > 0:
            volume += width * hypervolume(P[:k + 1, 1:], r[1:])
    return float(volume)


def weights(seed: int, number: int, m: int) -> np.ndarray:
    """The weight vector of batch ``number``: uniform on the simplex of ``m`` criteria."""
    rng = np.random.default_rng([seed, 3, number])
    w = rng.exponential(size=m)
    return w / w.sum()


def scalarize(values, weight, low, high) -> np.ndarray:
    """ParEGO's augmented Chebyshev scalarization of criteria ``values`` (rows), each
    normalized by ``low``..``high``."""
    span = np.where(np.asarray(high) > np.asarray(low), np.asarray(high) - np.asarray(low), 1.0)
    f = (np.asarray(values, dtype=float) - low) / span
    weighted = f * weight
    return weighted.max(axis=1) + RHO * weighted.sum(axis=1)


def knee(points) -> int:
    """The front point farthest from the line through its two extremes, in criteria
    normalized to the front's own ranges (for two criteria; for more, the point closest to the
    ideal point). Index into ``points``."""
    P = np.asarray(points, dtype=float)
    if len(P) <= 2:
        return 0
    low, high = P.min(axis=0), P.max(axis=0)
    span = np.where(high > low, high - low, 1.0)
    N = (P - low) / span
    if P.shape[1] == 2:
        a, b = N[np.argmin(N[:, 0])], N[np.argmin(N[:, 1])]
        direction = (b - a) / (np.linalg.norm(b - a) or 1.0)
        offset = N - a
        # signed distance from the line, positive on the side of the ideal point
        return int(np.argmax(offset[:, 0] * direction[1] - offset[:, 1] * direction[0]))
    return int(np.argmin(np.linalg.norm(N, axis=1)))


def criteria_of(record, names) -> list[float] | None:
    """A history record's criteria in ``names``' order, or None when one is not a finite number."""
    found = record.get("criteria") if isinstance(record, dict) else None
    if not isinstance(found, dict):
        return None
    row = [found.get(name) for name in names]
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in row)
    return [float(v) for v in row] if ok else None


def front_of(records, names) -> list[int]:
    """Positions in ``records`` of the feasible points on the Pareto front, ordered along the
    first criterion."""
    rows = [(k, criteria_of(r, names)) for k, r in enumerate(records) if r.get("feasible")]
    rows = [(k, row) for k, row in rows if row is not None]
    if not rows:
        return []
    keep = [rows[i][0] for i in nondominated([row for _, row in rows])]
    return sorted(keep, key=lambda k: (criteria_of(records[k], names), k))


def scalarized(records, names, seed: int, number: int) -> list[dict]:
    """Copies of ``records`` whose ``value`` (and, when feasible, ``objective``) is batch
    ``number``'s scalarization: what the single-objective BO then minimizes."""
    rows = [criteria_of(r, names) for r in records]
    known = [k for k, row in enumerate(rows) if row is not None]
    basis = [k for k in known if records[k].get("feasible")] or known
    if not basis:
        return [{**r, "value": None} for r in records]
    V = np.array([rows[k] for k in basis])
    low, high = V.min(axis=0), V.max(axis=0)
    weight = weights(seed, number, len(names))
    out = []
    for r, row in zip(records, rows):
        copy = {**r, "value": None}
        if row is not None:
            copy["value"] = float(scalarize([row], weight, low, high)[0])
            if r.get("feasible"):
                copy["objective"] = copy["value"]
        out.append(copy)
    return out


def improvement_2d(front, reference, points) -> np.ndarray:
    """How much each of ``points`` (rows of two criteria) would add to the hypervolume of
    ``front`` against ``reference``: the area of the box between the point and the reference
    that the front's staircase does not already cover. Exact and vectorized over the points
    (the expected improvement averages it over posterior samples)."""
    return staircase(front, reference)(points)


def staircase(front, reference):
    """``improvement_2d`` against one front, as a function of the points (the front's
    staircase is built once for many calls; each point then costs three binary searches: the
    step it reaches and the two ends of the interval it covers)."""
    r = np.asarray(reference, dtype=float)
    F = np.asarray(front, dtype=float).reshape(-1, 2)
    F = F[np.all(F < r, axis=1)]
    if len(F):
        F = F[nondominated(F)]
        F = F[np.argsort(F[:, 0], kind="stable")]  # the second criterion falls along it
    # the covered height h(t) along the first criterion is a falling staircase: r[1] before
    # the first front point, then each point's second criterion up to the next one
    a = np.concatenate([F[:, 0], [r[0]]])             # where each step starts; r[0] ends it
    h = np.concatenate([[r[1]], F[:, 1]])             # the height before a[0], then on each step
    area = np.concatenate([[0.0], np.cumsum(h[1:] * np.diff(a))])  # integral of h from a[0]

    def integral(t):  # of h from a[0] to t (negative before a[0], where h = r[1])
        return np.where(t < a[0], (t - a[0]) * r[1], np.interp(t, a, area))

    def gained(points) -> np.ndarray:
        P = np.asarray(points, dtype=float).reshape(-1, 2)
        x, y = np.minimum(P[:, 0], r[0]), P[:, 1]
        # h > y up to the first step whose height is at most y (or the reference)
        steps = np.searchsorted(-h, -y, side="left")  # how many heights exceed y
        end = np.where(steps == 0, -np.inf, a[np.maximum(steps - 1, 0)])  # where that step ends
        inside = end > x
        x, end = np.where(inside, x, 0.0), np.where(inside, end, 0.0)
        return np.where(inside, integral(end) - integral(x) - y * (end - x), 0.0)
    return gained
