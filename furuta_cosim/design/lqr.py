"""Linear-quadratic regulators (python-control), continuous and discrete."""

from __future__ import annotations

import numpy as np

from furuta_cosim.design.controller import GeneralizedController
from furuta_cosim.design.linear import LinearModel, discretize, unstable_uncontrollable_modes
from furuta_cosim.errors import DesignError

# The paper's weights (Sec. V-B): the pendulum angle first, then the velocities.
PAPER_Q = (1.0, 10.0, 100.0, 10.0, 1.0)
PAPER_R = 10.0


def lqr(model: LinearModel, Q=None, R=None, period: float | None = None) -> GeneralizedController:
    """Design u = r - K x minimizing the integral (or sum) of x'Qx + u'Ru.

    Parameters
    ----------
    model : LinearModel
        Continuous or discrete plant.
    Q : array_like, optional
        State weight: a matrix or its diagonal. Default the paper's diag(1, 10, 100, 10, 1)
        for 5 states, else the identity.
    R : array_like, optional
        Input weight; default the paper's 10 for 5 states, else 1.
    period : float, optional
        Design a discrete LQR (dlqr) on the zero-order-hold discretization at this period.
        The paper's printed K is dlqr at 2 ms (docs/pages/paper-readings.md §2). Ignored for discrete models.

    Returns
    -------
    GeneralizedController
        A static controller (n_xc = 0) with Dc = K.
    """
    paper = model.n == len(PAPER_Q)
    Q = np.diag(PAPER_Q if paper else [1.0] * model.n) if Q is None else np.asarray(Q, dtype=float)
    if Q.ndim == 1:
        Q = np.diag(Q)
    m = model.B.shape[1]
    R = np.eye(m) * (PAPER_R if paper else 1.0) if R is None else np.atleast_2d(np.asarray(R, dtype=float))
    if R.shape == (1, 1) and m > 1:
        R = np.eye(m) * R[0, 0]
    if Q.shape != (model.n, model.n):
        raise DesignError(f"Q must be {model.n}x{model.n} (or {model.n} diagonal values), got {Q.shape}", "Q")
    if R.shape != (m, m):
        raise DesignError(f"R must be {m}x{m}, got {R.shape}", "R")
    for name, weight, strict in (("Q", Q, False), ("R", R, True)):
        if not np.all(np.isfinite(weight)) or not np.allclose(weight, weight.T):
            raise DesignError(f"{name} must be finite and symmetric", name)
        smallest = np.linalg.eigvalsh(weight).min()
        if smallest <= 0 if strict else smallest < -1e-12:
            raise DesignError(f"{name} must be positive {'definite' if strict else 'semi-definite'}", name)
    if period is not None and not model.discrete:
        if not period > 0:
            raise DesignError(f"the period must be > 0, got {period}", "period")
        design_model = discretize(model, period)
    else:
        design_model = model
    modes = unstable_uncontrollable_modes(design_model)
    if modes:
        listed = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" for z in modes)
        raise DesignError(f"(A, B) of {model.name} is not stabilizable: mode(s) {listed} "
                          "cannot be moved by the input", "A, B")
    import control  # here: python-control takes a second to import, and runs rarely need it

    if design_model.discrete:
        K, _, _ = control.dlqr(design_model.A, design_model.B, Q, R)
        method = "dlqr (zero-order hold)" if not model.discrete else "dlqr"
    else:
        K, _, _ = control.lqr(design_model.A, design_model.B, Q, R)
        method = "lqr (continuous ARE)"
    provenance = {"method": method, "model": model.name, "Q": Q.tolist(), "R": R.tolist()}
    if design_model.discrete:
        provenance["period"] = design_model.period
    return GeneralizedController.static(np.asarray(K), period=design_model.period,
                                        provenance=provenance)
