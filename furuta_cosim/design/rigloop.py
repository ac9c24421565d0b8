"""The loop that runs on a rig, as a linear loop whose margins can be read.

``analyze`` reads a controller's margins on the full-state loop it was designed for: every
state measured, the command at the plant at once. On a rig (rig/runner.py, the virtual
board) the loop is another one:

- the controller sees the angles as the encoders count them, and their rates as the filtered
  differences of those angles (measurement.RateFilter: a first-order filter at ``rate_filter``
  Hz on the difference, by the bilinear transform), never the true rates;
- its command reaches the motor ``delay`` seconds after the sample (the board's transport and
  amplifier: 1 ms on the virtual board), held over each sample: over a sample the motor gets
  the command of ``m`` samples before for the delay's fraction of a sample and that of
  ``m - 1`` before for the rest;
- it runs at the sample period, the plant in between continuous.

:func:`rig_loop` writes that loop as a discrete plant (its state with the commands still on
their way) and a discrete controller on that plant's state (the rate filter's states, then the
controller's own), so that the margins of design/margins.py read it broken at the plant
input as they read the full-state one. The encoders' rounding is left out (it is not linear):
its chatter is a limit cycle inside these margins.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from furuta_cosim.design.controller import GeneralizedController, discretize_controller
from furuta_cosim.design.linear import LinearModel
from furuta_cosim.errors import DesignError

ANGLES = ("theta0", "theta1")
RATES = {"theta0": "dtheta0", "theta1": "dtheta1"}
MAX_DELAY_SAMPLES = 10


def _held(A: np.ndarray, B: np.ndarray, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, the integral of e^{A s} B over [0, t]) for a held input, by one matrix exponential."""
    n, m = A.shape[0], B.shape[1]
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = A * seconds, B * seconds
    M = expm(block)
    return M[:n, :n], M[:n, n:]


def delayed_plant(model: LinearModel, period: float, delay: float) -> LinearModel:
    """The continuous ``model`` sampled at ``period`` with its input ``delay`` seconds late and
    held: the state is the model's followed by the commands still on their way (the newest
    first); the input is the command computed at the sample."""
    if model.discrete:
        raise DesignError("the rig's loop starts from the continuous plant model")
    if not 0.0 <= delay <= MAX_DELAY_SAMPLES * period:
        raise DesignError(f"the board's delay must be 0 to {MAX_DELAY_SAMPLES} samples ({MAX_DELAY_SAMPLES * period:g} s), "
                          f"got {delay:g} s")
    A, B = np.asarray(model.A, dtype=float), np.asarray(model.B, dtype=float)
    n, m = A.shape[0], B.shape[1]
    whole = int(math.floor(delay / period + 1e-9))
    part = delay - whole * period
    if part < 1e-12 * period:
        part = 0.0
    # over a sample: the command of ``whole + 1`` samples before for ``part``, then that of
    # ``whole`` before for the rest
    rest, g_rest = _held(A, B, period - part)
    first, g_first = _held(A, B, part) if part else (np.eye(n), np.zeros((n, m)))
    Ad = rest @ first
    B_older, B_newer = rest @ g_first, g_rest
    lags = whole + (1 if part else 0)         # the commands the state must keep
    size = n + lags * m
    F = np.zeros((size, size))
    G = np.zeros((size, m))
    F[:n, :n] = Ad

    def feed(age: int, matrix: np.ndarray) -> None:
        """The command ``age`` samples before drives the plant through ``matrix``."""
        nonlocal F, G
        if age == 0:
            G[:n] += matrix
        else:
            F[:n, n + (age - 1) * m:n + age * m] += matrix

    feed(whole, B_newer)
    if part:
        feed(whole + 1, B_older)
    if lags:
        G[n:n + m] = np.eye(m)                     # the newest command kept
        for j in range(1, lags):                   # and each one a sample older
            F[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
    states = tuple(model.states) + tuple(f"u[k-{j + 1}]" for j in range(lags))
    C = np.hstack([np.asarray(model.C, dtype=float), np.zeros((model.C.shape[0], lags * m))])
    return LinearModel(f"{model.name} (sampled at {period:g} s, its input {delay * 1000:g} ms late)", F, G, C,
                       np.asarray(model.D, dtype=float), states, tuple(model.inputs), tuple(model.outputs), period,
                       {**model.provenance, "rig_delay": delay})


def seen_through_filter(controller: GeneralizedController, plant: LinearModel, states: tuple[str, ...],
                        rate_filter: float) -> GeneralizedController:
    """``controller`` (discrete) as it runs on a rig: on ``plant``'s state (``states`` the
    model's own, first), seeing the angles and the other measured states as they are and the
    rates as the filtered differences of the angles at ``rate_filter`` Hz. Its state: the two
    filtered rates and the two angles of the sample before, then the controller's own."""
    T = controller.period
    w = 2.0 * math.pi * rate_filter
    a, b = (2.0 - w * T) / (2.0 + w * T), 2.0 * w / (2.0 + w * T)
    size = plant.A.shape[0]
    n = len(states)
    missing = [s for s in (*ANGLES, *RATES.values()) if s not in states]
    if missing:
        raise DesignError(f"the rig's loop needs the states {', '.join(missing)} in the model")
    angle = np.zeros((2, size))
    for j, name in enumerate(ANGLES):
        angle[j, states.index(name)] = 1.0
    # what the controller sees, x_seen = P x + Q r_new, r_new = a r_prev + b (angle x - prev)
    P = np.zeros((n, size))
    Q = np.zeros((n, 2))
    for k, name in enumerate(states):
        if name in RATES.values():
            Q[k, list(RATES.values()).index(name)] = 1.0
        else:
            P[k, k] = 1.0
    Ac, Bc, Cc, Dc = (np.asarray(getattr(controller, k), dtype=float) for k in ("Ac", "Bc", "Cc", "Dc"))
    n_c = Ac.shape[0]
    # the state z = [r_prev (2), prev (2), xc]; r_new = a r_prev - b prev + b angle x
    R_z = np.hstack([a * np.eye(2), -b * np.eye(2), np.zeros((2, n_c))])
    R_x = b * angle
    seen_z = Q @ R_z                                # x_seen's part from z
    seen_x = P + Q @ R_x                            # and from the plant's state
    A_new = np.vstack([R_z,
                       np.hstack([np.zeros((2, 4)), np.zeros((2, n_c))]),
                       np.hstack([Bc @ seen_z[:, :4], Ac])])
    B_new = np.vstack([R_x, angle, Bc @ seen_x])
    C_new = np.hstack([Dc @ seen_z[:, :4], Cc])
    D_new = Dc @ seen_x
    return GeneralizedController(A_new, B_new, C_new, D_new, T, f"{controller.name} on the rig",
                                 {**controller.provenance, "rig_rate_filter_hz": rate_filter})


def rig_loop(model: LinearModel, controller: GeneralizedController, *, period: float | None = None,
             delay: float = 0.001, rate_filter: float = 40.0) -> tuple[LinearModel, GeneralizedController]:
    """(the plant, the controller) of the loop that runs on a rig (module docstring): the
    continuous ``model`` sampled at ``period`` (the controller's, for a discrete one) with its
    input ``delay`` s late, and ``controller`` (discretized at the period if continuous) seeing
    the rates through the ``rate_filter`` Hz filter of the angles."""
    T = controller.period if controller.discrete else period
    if T is None or not T > 0:
        raise DesignError("a continuous controller runs on a rig at a period: give it")
    if period is not None and controller.discrete and abs(period - controller.period) > 1e-12:
        raise DesignError(f"the controller is discrete at {controller.period:g} s, not {period:g} s")
    law = discretize_controller(controller, T)
    plant = delayed_plant(model, T, delay)
    return plant, seen_through_filter(law, plant, tuple(model.states), rate_filter)


def rig_analysis(model: LinearModel, controller: GeneralizedController, *, period: float | None = None,
                 delay: float = 0.001, rate_filter: float = 40.0) -> dict:
    """The loop that runs on a rig (:func:`rig_loop`), read as ``analyze`` reads a loop: its
    closed-loop spectral radius and verdict, and where it is stable its margins at the plant
    input (design/margins.py: gain, phase, disk, Ms, Mt)."""
    from furuta_cosim.design.margins import loop_margins

    plant, law = rig_loop(model, controller, period=period, delay=delay, rate_filter=rate_filter)
    top = np.hstack([plant.A - plant.B @ law.Dc, -plant.B @ law.Cc])
    bottom = np.hstack([law.Bc, law.Ac])
    radius = float(np.max(np.abs(np.linalg.eigvals(np.vstack([top, bottom])))))
    stable = radius < 1.0
    margins = loop_margins(plant, law) if stable and plant.B.shape[1] == 1 else None
    return {"period": law.period, "delay": delay, "rate_filter": rate_filter, "spectral_radius": radius,
            "stable": stable, "margins": margins}


def rig_text(found: dict) -> list[str]:
    """The lines ``analyze --rig`` prints for :func:`rig_analysis`'s result."""
    what = (f"the loop on a rig: rates by the {found['rate_filter']:g} Hz filter of the angles, the command "
            f"{found['delay'] * 1000:g} ms late, {found['period'] * 1000:g} ms samples")
    lines = [f"On a rig ({what[len('the loop on a rig: '):]}) the loop is "
             f"{'stable' if found['stable'] else 'UNSTABLE'} (spectral radius {found['spectral_radius']:.6f})."]
    if found["margins"] is not None:
        lines.append(found["margins"].text("s", f"Margins of {what}"))
    return lines
