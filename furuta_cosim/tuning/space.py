"""The search space of a tuning: how a vector of numbers becomes a generalized controller.

Each of Ac, Bc, Cc, Dc is made by one block:

- ``fixed``: the matrix as given;
- ``box: [low, high]``: each free entry uniform in [low, high];
- ``log: [low, high]`` with ``sign``: each free entry sign * 10^e, e uniform in [low, high];
- ``lqr: [low, high]`` (Dc only): Dc = lqr(model, Q = diag(10^q), R), one q per state in
  [low, high]: a gain that stabilizes the design model by construction, which raw boxes on
  this plant almost never do.

``entries: [[i, j], ...]`` restricts ``box`` and ``log`` to some entries; the others take
``fixed`` (default zeros).
"""

from __future__ import annotations

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
            matrix[i, j] = self.sign * 10.0 ** value if self.kind == "log" else value
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
        return [(block.low, block.high) for block in self.blocks for _ in block.free]

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
