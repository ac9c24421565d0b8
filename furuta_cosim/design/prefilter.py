"""Prefilters: r = F rbar, so that the chosen output tracks rbar with unit DC gain.

With the augmented loop (Abar, Bbar) and the tracked output's row Cbar = [c, 0], the DC gain
from r to y is  G = -Cbar Abar^-1 Bbar  (continuous)  or  Cbar (I - Abar)^-1 Bbar  (discrete),
and F = G^-1. For static feedback this is the classical F; for the generalized controller it
is the paper's generalized F (the paper's (A - I) form is the discrete-time formula).
"""

from __future__ import annotations

import numpy as np

from furuta_cosim.design.controller import GeneralizedController, augmented
from furuta_cosim.design.linear import LinearModel
from furuta_cosim.errors import DesignError


def dc_gain(model: LinearModel, controller: GeneralizedController, output: str) -> float:
    """Steady-state gain from r to ``output`` of the closed loop."""
    Abar, Bbar = augmented(model, controller)
    c = np.concatenate([model.output_vector(output), np.zeros(controller.n_xc)])
    system = np.eye(len(Abar)) - Abar if controller.discrete else -Abar
    try:
        solution = np.linalg.solve(system, Bbar)
    except np.linalg.LinAlgError:
        raise DesignError(f"prefilter: the closed loop has a pole at "
                          f"{'z = 1' if controller.discrete else 's = 0'}, so it has no DC gain") from None
    gain = c @ solution
    return float(gain[0]) if gain.size == 1 else gain


def prefilter(model: LinearModel, controller: GeneralizedController, output: str) -> float:
    """The static prefilter F that gives unit steady-state gain from rbar to ``output``.

    Parameters
    ----------
    model : LinearModel
        A single-input plant.
    controller : GeneralizedController
        The feedback the loop is closed with.
    output : str
        The tracked output (a state name of ``model``).

    Returns
    -------
    float

    Raises
    ------
    DesignError
        When the loop's DC gain to ``output`` is zero or not finite.
    """
    if model.B.shape[1] != 1:
        raise DesignError("prefilter: only single-input plants are supported")
    gain = dc_gain(model, controller, output)
    if not np.isfinite(gain) or abs(gain) < 1e-12:
        raise DesignError(f"prefilter: the DC gain from r to {output} is {gain:.3g}, so no "
                          "prefilter can make it track (the loop blocks that output at steady state)")
    return 1.0 / gain


def tracking_bandwidth(model: LinearModel, controller: GeneralizedController, output: str,
                       F: float) -> float:
    """The -3 dB bandwidth (rad per time unit) of rbar -> ``output`` with prefilter F: the
    lowest frequency where the gain falls to 1/sqrt(2) of its DC value, so the fastest sine
    the loop follows with at least 71 % of its amplitude (infinite when it never falls that
    far below the Nyquist frequency of a discrete loop, or 1e6 rad per time unit)."""
    from scipy.optimize import brentq

    Abar, Bbar = augmented(model, controller)
    c = np.concatenate([model.output_vector(output), np.zeros(controller.n_xc)])
    identity = np.eye(len(Abar))

    def gain(w: float) -> float:
        point = np.exp(1j * w * controller.period) if controller.discrete else 1j * w
        return float(abs(c @ np.linalg.solve(point * identity - Abar, Bbar[:, 0] * F)))

    level = abs(dc_gain(model, controller, output) * F) / np.sqrt(2.0)
    top = np.pi / controller.period if controller.discrete else 1e6
    grid = np.logspace(-6, np.log10(top), 2000)
    below = [w for w in grid if gain(w) < level]
    if not below:
        return float("inf")
    k = int(np.searchsorted(grid, below[0]))
    if k == 0:
        return float(grid[0])
    return float(brentq(lambda w: gain(w) - level, grid[k - 1], grid[k], xtol=1e-12, rtol=1e-10))
