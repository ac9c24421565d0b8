"""The search space of a tuning: how a vector of numbers becomes a generalized controller.

Each of Ac, Bc, Cc, Dc is made by one block:

- ``fixed``: the matrix as given;
- ``box: [low, high]``: each free entry uniform in [low, high] (or ``[[lows], [highs]]``, a
  range per free entry); with ``around: CONTROLLER``, an offset from that controller file's
  matrix (a box around the LQR's gains, say, wide enough to hold another design's);
- ``log: [low, high]`` with ``sign``: each free entry sign * 10^e, e uniform in [low, high];
- ``lqr: [low, high]`` (Dc only): Dc = lqr(model, Q = diag(10^q), R), one q per state in
  [low, high]: a gain that stabilizes the design model by construction, which raw boxes on
  this plant almost never do.

``entries: [[i, j], ...]`` restricts ``box`` and ``log`` to some entries; the others take
``fixed`` (default zeros).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_cosim.design.controller import GeneralizedController
from furuta_cosim.design.linear import LinearModel

KINDS = ("fixed", "box", "log", "lqr")


@dataclass(frozen=True)
class Block:
    """How one of Ac, Bc, Cc, Dc is made from its share of the search vector."""

    key: str
    kind: str
    shape: tuple[int, int]
    low: float = 0.0
    high: float = 0.0
    sign: float = 1.0
    R: float = 1.0
    entries: tuple[tuple[int, int], ...] | None = None  # None: every entry
    fixed: tuple = ()                                    # the matrix, row by row
    ranges: tuple[tuple[float, float], ...] = ()         # box: (low, high) per free entry
    around: tuple = ()                                   # box: the matrix offsets start from

    def bounds(self) -> list[tuple[float, float]]:
        """(low, high) of each free entry's search value."""
        return list(self.ranges) if self.ranges else [(self.low, self.high)] * len(self.free)

    @property
    def free(self) -> list[tuple[int, int]]:
        if self.kind == "fixed":
            return []
        if self.kind == "lqr":
            return [(0, j) for j in range(self.shape[1])]
        rows, cols = self.shape
        return list(self.entries) if self.entries is not None else [(i, j) for i in range(rows)
                                                                     for j in range(cols)]

    def names(self) -> list[str]:
        if self.kind == "lqr":
            return [f"{self.key}.q{j}" for j in range(self.shape[1])]
        prefix = "log10|" if self.kind == "log" else ""
        return [f"{prefix}{self.key}[{i}][{j}]" + ("|" if prefix else "") for i, j in self.free]

    def base(self) -> np.ndarray:
        if self.around:
            return np.array(self.around, dtype=float).reshape(self.shape)
        if self.fixed:
            return np.array(self.fixed, dtype=float).reshape(self.shape)
        return np.zeros(self.shape)

    def build(self, values, model: LinearModel, period: float) -> np.ndarray:
        if self.kind == "lqr":
            from furuta_cosim.design.lqr import lqr

            Q = np.diag(10.0 ** np.asarray(values, dtype=float))
            return lqr(model, Q, self.R, period if period > 0 else None).K
        matrix = self.base()
        for (i, j), value in zip(self.free, values):
            if self.kind == "log":
                matrix[i, j] = self.sign * 10.0 ** value
            else:
                matrix[i, j] = matrix[i, j] + value if self.around else value
        return matrix


@dataclass(frozen=True)
class Space:
    """The blocks of Ac, Bc, Cc, Dc, in that order, on a design model."""

    blocks: tuple[Block, ...]
    model: LinearModel
    period: float          # > 0: the controller is discrete at this period
    discrete: bool

    @property
    def names(self) -> list[str]:
        return [name for block in self.blocks for name in block.names()]

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [bounds for block in self.blocks for bounds in block.bounds()]

    def dimensions(self):
        """scikit-optimize's dimensions of the search."""
        from skopt.space import Real

        return [Real(low, high, name=name) for (low, high), name in zip(self.bounds, self.names)]

    def controller(self, x, name: str = "candidate") -> GeneralizedController:
        """The controller at the point ``x`` of the search (raises DesignError when the lqr
        block has no solution there)."""
        x = [float(v) for v in x]
        matrices, start = {}, 0
        for block in self.blocks:
            count = len(block.free)
            matrices[block.key] = block.build(x[start:start + count], self.model,
                                              self.period if self.discrete else 0.0)
            start += count
        return GeneralizedController(matrices["Ac"], matrices["Bc"], matrices["Cc"], matrices["Dc"],
                                     self.period if self.discrete else 0.0, name)

    def point_of(self, cfile) -> tuple[list[float] | None, str]:
        """The point of this space that makes the controller of ``cfile`` (a
        :class:`~furuta_cosim.controllers.ControllerFile`), and how closely; or None and why
        not. A static controller (no controller state) is the point with Bc = 0 (the state
        then stays 0): Ac's ``log`` entries at the smallest magnitude of their range, the
        slowest state, where the trust region then starts (why, measured: docs, Performance),
        other entries of Ac and Cc at the middle of their ranges; an ``lqr`` block takes the
        file's design weights (provenance Q diagonal, the block's R), rebuilt on this
        space's model and time domain."""
        c = cfile.controller
        n_xc = self.blocks[0].shape[0]
        if c.n_xc not in (0, n_xc):
            return None, f"it has {c.n_xc} controller state(s); the search has {n_xc}"
        x = []
        for block in self.blocks:
            given = {"Ac": c.Ac, "Bc": c.Bc, "Cc": c.Cc, "Dc": c.Dc}[block.key]
            static = c.n_xc == 0 and block.key != "Dc"
            values, why = _values_of(block, given, static, cfile)
            if values is None:
                return None, f"{block.key}: {why}"
            x += values
        built = self.controller(x, name=c.name)
        gap = float(np.linalg.norm(built.Dc - c.Dc) / max(np.linalg.norm(c.Dc), 1e-300))
        if c.n_xc and any(not np.allclose(getattr(built, k), getattr(c, k), rtol=1e-9, atol=0)
                          for k in ("Ac", "Bc", "Cc")):
            return None, "its Ac, Bc, Cc are not all inside the search's ranges"
        if gap > MAX_GAP:
            return None, (f"the nearest point's gain differs from the file's by {gap:.1%} "
                          f"(more than {MAX_GAP:.0%})")
        return x, ("exactly" if gap <= 1e-9 else
                   f"as its design (the same Q and R on {self.model.name}, "
                   f"{'discrete' if self.discrete else 'continuous'} here): gain within {gap:.2%}")


# a baseline enters a search when its point reproduces its gain this closely (relative norm)
MAX_GAP = 0.05


def _values_of(block: Block, given: np.ndarray, static: bool, cfile) -> tuple[list | None, str]:
    """The search values of one block that give the matrix ``given`` (see Space.point_of)."""
    free = block.free
    if block.kind == "fixed":
        if static and block.key != "Bc":
            return [], ""
        target = np.zeros(block.shape) if static else given
        return ([], "") if np.array_equal(block.base(), target) else \
            (None, "fixed in the search to another matrix")
    if block.kind == "lqr":
        provenance = cfile.provenance or {}
        Q, R = provenance.get("Q"), provenance.get("R")
        try:
            Q, R = np.array(Q, dtype=float), np.array(R, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return None, "the file records no LQR weights Q and R (provenance)"
        if Q.ndim != 2 or Q.shape != (block.shape[1],) * 2 or np.any(Q != np.diag(np.diag(Q))) \
                or np.any(np.diag(Q) <= 0):
            return None, "its recorded Q is not a positive diagonal of the model's size"
        if R.size != 1 or not math.isclose(float(R[0]), block.R, rel_tol=1e-12):
            return None, f"its recorded R is {R.tolist()}, the search's R is {block.R:g}"
        q = np.log10(np.diag(Q))
        if np.any(q < block.low - 1e-12) or np.any(q > block.high + 1e-12):
            return None, (f"log10 diag(Q) = {np.round(q, 3).tolist()} is outside "
                          f"[{block.low:g}, {block.high:g}]")
        return q.tolist(), ""
    values = []
    base = block.base()
    for (i, j), (low, high) in zip(free, block.bounds()):
        if static:
            if block.key == "Bc":
                zero = -base[i, j] if block.around else 0.0
                if block.kind != "box" or not low <= zero <= high:
                    return None, "a static controller needs Bc = 0, outside this block's range"
                values.append(zero)
            elif block.key == "Ac" and block.kind == "log":
                values.append(low)  # the slowest controller state of the range (Space.point_of)
            else:
                values.append(0.5 * (low + high))
            continue
        value = float(given[i, j])
        if block.kind == "log":
            if value * block.sign <= 0:
                return None, f"entry [{i}][{j}] = {value:g} has the other sign"
            value = math.log10(value * block.sign)
        elif block.around:
            value -= base[i, j]
        if not low - 1e-12 <= value <= high + 1e-12:
            what = "its offset" if block.around else "it"
            return None, f"entry [{i}][{j}]: {what} is outside [{low:g}, {high:g}]"
        values.append(min(max(value, low), high))
    if static and block.key == "Bc":
        fixed_ok = all(block.base()[i, j] == 0 for i in range(block.shape[0])
                       for j in range(block.shape[1]) if (i, j) not in free)
        if not fixed_ok:
            return None, "a static controller needs Bc = 0; its fixed entries are not"
    return values, ""


@dataclass(frozen=True)
class SwingUpSpace:
    """The search over a swing-up's settings (tuning specs with ``controller: {type: swingup}``):
    each block one setting, ``box`` as it is or ``log`` as 10^value; a point is the base file
    with those settings."""

    blocks: tuple
    base: object               # the swing-up file's ControllerFile

    @property
    def names(self) -> list[str]:
        return [f"log10|{b.key}|" if b.kind == "log" else b.key for b in self.blocks]

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [(b.low, b.high) for b in self.blocks]

    def dimensions(self):
        from skopt.space import Real

        return [Real(low, high, name=name) for (low, high), name in zip(self.bounds, self.names)]

    def settings(self, x) -> dict[str, float]:
        return {b.key: (10.0 ** float(v) if b.kind == "log" else float(v)) for b, v in zip(self.blocks, x)}

    def controller(self, x, name: str = "candidate"):
        from dataclasses import replace

        return replace(self.base, swingup=self.base.swingup.with_settings(**self.settings(x)), own_name=name)

    def point_of(self, cfile) -> tuple[list[float] | None, str]:
        """The point of a swing-up file's settings (None when outside the search's ranges)."""
        if cfile.swingup is None:
            return None, "it is not a swing-up file"
        x = []
        for block in self.blocks:
            value = getattr(cfile.swingup, block.key)
            if block.kind == "log":
                if value <= 0:
                    return None, f"{block.key} = {value:g} has no logarithm"
                value = math.log10(value)
            if not block.low - 1e-12 <= value <= block.high + 1e-12:
                return None, f"{block.key} is outside [{block.low:g}, {block.high:g}]"
            x.append(min(max(value, block.low), block.high))
        return x, "exactly"
