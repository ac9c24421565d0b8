"""Linear plant models with named states, inputs and outputs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_cosim.errors import DesignError


@dataclass(frozen=True)
class LinearModel:
    """x' = A x + B u (or x[k+1] = ...), y = C x + D u; ``period`` 0 means continuous time.

    ``inputs`` are the control inputs only (B's columns); disturbance inputs stay in the FMU.
    """

    name: str
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    period: float = 0.0
    provenance: dict = field(default_factory=dict, compare=False)
    time_unit: str = "s"          # "samples" for a plant whose time counts samples

    def __post_init__(self):
        A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (self.A, self.B, self.C, self.D))
        n = A.shape[0]
        problems = []
        if A.shape != (n, n):
            problems.append(f"A must be square, got {A.shape[0]}x{A.shape[1]}")
        if B.shape[0] != n:
            problems.append(f"B must have {n} rows, got {B.shape[0]}")
        if C.shape[1] != n:
            problems.append(f"C must have {n} columns, got {C.shape[1]}")
        if D.shape != (C.shape[0], B.shape[1]):
            problems.append(f"D must be {C.shape[0]}x{B.shape[1]}, got {D.shape[0]}x{D.shape[1]}")
        for name, m in zip("ABCD", (A, B, C, D)):
            if not np.all(np.isfinite(m)):
                problems.append(f"{name} has non-finite entries")
        if len(self.states) != n or len(self.inputs) != B.shape[1] or len(self.outputs) != C.shape[0]:
            problems.append("the names of states, inputs and outputs do not match the matrices")
        if self.period < 0:
            problems.append(f"period must be >= 0, got {self.period}")
        if problems:
            raise DesignError(f"model {self.name}: " + "; ".join(problems))
        for name, m in zip("ABCD", (A, B, C, D)):
            m.setflags(write=False)
            object.__setattr__(self, name, m)

    @property
    def discrete(self) -> bool:
        return self.period > 0

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def output_vector(self, name: str) -> np.ndarray:
        """The row c with y = c x for an output, or for a state by its name."""
        if name in self.outputs:
            return self.C[self.outputs.index(name)]
        if name in self.states:
            return np.eye(self.n)[self.states.index(name)]
        raise DesignError(f"model {self.name} has no output or state {name!r} "
                          f"(outputs: {', '.join(self.outputs)}; states: {', '.join(self.states)})")


def time_text(value: float, unit: str = "s", spec: str = ".3g") -> str:
    """A duration in a model's unit: ``0.85 s``, ``17.9 samples``, ``1 sample``."""
    if unit == "samples" and value == 1:
        return "1 sample"
    return f"{value:{spec}} {unit}"


def discretize(model: LinearModel, period: float) -> LinearModel:
    """Zero-order-hold discretization (python-control ``c2d``)."""
    if model.discrete:
        if abs(model.period - period) > 1e-12 * period:
            raise DesignError(f"model {model.name} is discrete with period {model.period}, "
                              f"not {period}")
        return model
    if not period > 0:
        raise DesignError(f"the sampling period must be > 0, got {period}")
    import control  # here: python-control takes a second to import, and runs rarely need it

    sampled = control.c2d(control.ss(model.A, model.B, model.C, model.D), period, method="zoh")
    return LinearModel(f"{model.name}@{period:g}s", sampled.A, sampled.B, sampled.C, sampled.D,
                       model.states, model.inputs, model.outputs, period,
                       {**model.provenance, "discretized": f"zoh, {period:g} s"}, model.time_unit)


def unstable_uncontrollable_modes(model: LinearModel, tolerance: float = 1e-9) -> list[complex]:
    """Eigenvalues of A that are not stable and that B cannot move (PBH test)."""
    modes = []
    n = model.n
    for eigenvalue in np.linalg.eigvals(model.A):
        unstable = abs(eigenvalue) >= 1.0 if model.discrete else eigenvalue.real >= 0.0
        if not unstable:
            continue
        pencil = np.hstack([model.A - eigenvalue * np.eye(n), model.B])
        singular = np.linalg.svd(pencil, compute_uv=False)
        if singular[-1] <= tolerance * max(1.0, singular[0]):
            modes.append(complex(eigenvalue))
    return modes
