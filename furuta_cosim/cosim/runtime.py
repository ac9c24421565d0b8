"""Controllers and estimators in a form fit for the hot loop.

numpy on 5-element vectors costs more than the plant's whole step, so each discrete
controller (and Kalman estimator) is turned into a small Python function over plain floats,
generated from its matrices: zero coefficients vanish, the rest are float literals.
"""

from __future__ import annotations

import numpy as np

from furuta_cosim.cosim.generated import compile_source
from furuta_cosim.design.controller import GeneralizedController


def _dot(row, names) -> str:
    terms = [f"{float(a)!r}*{n}" for a, n in zip(row, names) if a != 0.0]
    return " + ".join(terms) if terms else "0.0"


def _compile(source: str, kind: str):
    return compile_source(source, kind, "make")()


class RuntimeController:
    """u[k] = F rbar[k] - (Cc xc[k] + Dc x[k]);  xc[k+1] = Ac xc[k] + Bc x[k] (single input).

    With ``delay=1`` the command computed at sample k is returned at sample k+1 (a computation
    delay of one control sample; 0 at the first sample). ``__call__(x, rbar)`` returns u and
    advances the controller state; ``reset()`` zeroes it. It pickles as its matrices and is
    compiled again where it is unpickled.
    """

    def __init__(self, controller: GeneralizedController, F: float = 1.0, delay: int = 0):
        self._made_from = (controller, F, delay)
        self.controller, self.F, self.delay = controller, float(F), delay  # for the loop in C
        if not controller.discrete:
            raise ValueError("the runtime needs a discrete controller: discretize it first")
        if controller.Dc.shape[0] != 1:
            raise ValueError("the runtime supports single-input plants")
        n, m = controller.Dc.shape[1], controller.n_xc
        xs = [f"x{j}" for j in range(n)]
        cs = [f"c{j}" for j in range(m)]
        feedback = _dot(np.concatenate([controller.Cc[0], controller.Dc[0]]), cs + xs)
        if delay not in (0, 1):
            raise ValueError(f"delay must be 0 or 1 control samples, got {delay}")
        held = ["held"] if delay else []
        lines = ["def make():"]
        lines += [f"    {c} = 0.0" for c in cs + held]
        lines.append("    def control(x, rbar):")
        if cs + held:
            lines.append(f"        nonlocal {', '.join(cs + held)}")
        lines.append(f"        {', '.join(xs)}, = x")
        lines.append(f"        u = {float(F)!r}*rbar - ({feedback})")
        if delay:
            lines.append("        u, held = held, u")
        if cs:
            updates = [_dot(np.concatenate([controller.Ac[i], controller.Bc[i]]), cs + xs)
                       for i in range(m)]
            lines.append(f"        {', '.join(cs)}, = {', '.join(updates)},")
        lines.append("        return u")
        lines.append("    def reset():")
        if cs + held:
            lines.append(f"        nonlocal {', '.join(cs + held)}")
            lines += [f"        {c} = 0.0" for c in cs + held]
        else:
            lines.append("        pass")
        lines.append(f"    def state():\n        return [{', '.join(cs)}]")
        lines.append("    return control, reset, state")
        self.source = "\n".join(lines) + "\n"
        self.control, self.reset, self.state = _compile(self.source, "controller")
        self.n_xc = m

    def __reduce__(self):
        return (RuntimeController, self._made_from)

    def __call__(self, x, rbar: float) -> float:
        return self.control(x, rbar)


class RuntimeEstimator:
    """Steady-state Kalman filter in predictor-corrector form, over plain floats.

    ``correct(y)`` returns xhat[k|k] = xpred + M (y - C xpred); ``predict(u)`` sets
    xpred = Ad xhat + Bd u for the next sample. The prediction starts at zero.
    """

    def __init__(self, Ad, Bd, C, M):
        self._made_from = (Ad, Bd, C, M)
        n, p = Ad.shape[0], C.shape[0]
        ps = [f"p{j}" for j in range(n)]
        hs = [f"h{j}" for j in range(n)]
        ys = [f"y{j}" for j in range(p)]
        innovations = [f"e{i}" for i in range(p)]
        lines = ["def make():"]
        lines += [f"    {v} = 0.0" for v in ps + hs]
        lines.append("    def correct(y):")
        lines.append(f"        nonlocal {', '.join(hs)}")
        lines.append(f"        {', '.join(ys)}, = y")
        for i in range(p):
            lines.append(f"        {innovations[i]} = {ys[i]} - ({_dot(C[i], ps)})")
        for j in range(n):
            lines.append(f"        {hs[j]} = {ps[j]} + {_dot(M[j], innovations)}")
        lines.append(f"        return [{', '.join(hs)}]")
        lines.append("    def predict(u):")
        lines.append(f"        nonlocal {', '.join(ps)}")
        updates = [f"{_dot(Ad[j], hs)} + {float(Bd[j, 0])!r}*u" for j in range(n)]
        lines.append(f"        {', '.join(ps)}, = {', '.join(updates)},")
        lines.append("    def reset():")
        lines.append(f"        nonlocal {', '.join(ps + hs)}")
        lines += [f"        {v} = 0.0" for v in ps + hs]
        lines.append("    return correct, predict, reset")
        self.source = "\n".join(lines) + "\n"
        self.correct, self.predict, self.reset = _compile(self.source, "kalman")

    def __reduce__(self):
        return (RuntimeEstimator, self._made_from)


def runtime_for(cfile, period: float, where: str = "the rig"):
    """(the controller file checked for a 5-state plant at ``period``, its runtime): the
    controller discretized at ``period`` and compiled, inside its swing-up when the file has
    one. A rig runs it so (rig/runner.py), and a replay that closes the loop of a rig's log
    (identify/replay.py)."""
    from furuta_cosim.controllers import fit
    from furuta_cosim.design.controller import discretize_controller
    from furuta_cosim.swingup import SwingUpRuntime

    cfile = fit(cfile, plant=where, states=5, period=period if cfile.controller.discrete else None)
    runtime = RuntimeController(discretize_controller(cfile.controller, period),
                                cfile.F if cfile.F is not None else 1.0)
    if cfile.swingup is not None:
        runtime = SwingUpRuntime(runtime, cfile.swingup)
    return cfile, runtime
