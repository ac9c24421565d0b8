"""Stability margins of a loop broken at the plant input.

The loop gain is L = K G: the plant from its input u to its state (zero-order hold at the
controller's period for a discrete controller) and the controller from the state back to u
(``u = F r - K(x)``, negative feedback). Three margins, each what a control engineer reads:

- **gain**: the factors k on the plant input for which the loop stays stable, from the closed
  loop's eigenvalues with the feedback scaled by k (exact, also for a plant that is unstable
  open loop, where a gain too low fails as well as one too high: the pendulum);
- **phase**: at each crossover |L| = 1, 180 deg minus |arg L|; the least of them;
- **disk**: the balanced disk margin (python-control's ``disk_margins``, skew 0): the gain
  and phase the input may change by at once and the loop stay stable;
- **Ms, Mt**: the peaks of the sensitivity |S| = |1/(1 + L)| and the complementary
  sensitivity |T| = |L/(1 + L)| over the grid, the robustness figures an engineer compares
  (1/Ms is the least distance from L to -1 on the Nyquist plot).

A continuous controller runs sampled: analysis.py asks for the margins of the sampled loop
(the controller discretized at its period, the plant held by a zero-order hold), the loop that
runs, beside those of the continuous loop.

Classical margins read off crossings (python-control's ``stability_margins``) were wrong on
the open-loop unstable QUBE loop (a 17.5 deg phase margin where the only crossover has 72 deg),
so gain and phase are computed here from the eigenvalues and a dense frequency grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_cosim.design.controller import GeneralizedController, discretize
from furuta_cosim.design.linear import LinearModel

GRID = 4000           # frequencies of the grid, log-spaced (phase interpolated between them)
LOWEST = 1e-3         # rad per time unit: the grid's lowest frequency
HIGHEST = 1e4         # rad per time unit: a continuous loop's highest (a discrete one: Nyquist)


@dataclass(frozen=True)
class Margins:
    gain: tuple[float, float]        # factors on the plant input: stable strictly between
    phase: float | None              # degrees; None: |L| never crosses 1
    crossover: float | None          # rad per time unit, where the phase margin is
    disk: float                      # the balanced disk margin alpha
    disk_gain: float                 # dB: the input's gain may change by +- this ...
    disk_phase: float                # deg: ... and its phase by +- this, at once
    ms: float = math.nan             # peak |S| and where (rad per time unit)
    ms_at: float = math.nan
    mt: float = math.nan             # peak |T| and where
    mt_at: float = math.nan

    def as_dict(self) -> dict:
        def finite(v):
            return None if v is None or not math.isfinite(v) else float(v)

        return {"gain": [finite(self.gain[0]), finite(self.gain[1])],
                "gain_db": [finite(20 * math.log10(self.gain[0])) if self.gain[0] > 0 else None,
                            finite(20 * math.log10(self.gain[1])) if math.isfinite(self.gain[1]) else None],
                "phase_deg": finite(self.phase), "crossover": finite(self.crossover),
                "disk": finite(self.disk), "disk_gain_db": finite(self.disk_gain),
                "disk_phase_deg": finite(self.disk_phase), "ms": finite(self.ms),
                "ms_frequency": finite(self.ms_at), "mt": finite(self.mt), "mt_frequency": finite(self.mt_at)}

    def text(self, unit: str = "s", label: str = "Margins at the plant input") -> str:
        low, high = self.gain
        gain = (f"gain {low:.3g} to {'any' if not math.isfinite(high) else format(high, '.3g')}"
                + (f" ({20 * math.log10(low):+.1f} dB" if low > 0 else " (")
                + (f", {20 * math.log10(high):+.1f} dB)" if math.isfinite(high) else ", no upper limit)"))
        phase = ("phase: |L| never crosses 1" if self.phase is None else
                 f"phase {self.phase:.1f} deg at {self.crossover:.3g} rad/{unit}")
        peaks = (f"; Ms {self.ms:.3g} at {self.ms_at:.3g} rad/{unit}, Mt {self.mt:.3g} at {self.mt_at:.3g} rad/{unit}"
                 if math.isfinite(self.ms) else "")
        return (f"{label}: {gain}, {phase}, disk {self.disk:.3g} "
                f"(+-{self.disk_gain:.1f} dB and +-{self.disk_phase:.1f} deg at once){peaks}.")


def loop_margins(model: LinearModel, controller: GeneralizedController) -> Margins:
    """The margins of the loop of ``model`` and ``controller`` at the plant input (module
    docstring); the loop must be stable."""
    import control

    loop, omega, L = loop_response(model, controller)
    phase, crossover = _phase(omega, L)
    disk, disk_gain, disk_phase = control.disk_margins(loop, omega, skew=0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        S, T = np.abs(1.0 / (1.0 + L)), np.abs(L / (1.0 + L))
    s, t = int(np.nanargmax(S)), int(np.nanargmax(T))
    if controller.discrete and not model.discrete:
        model = discretize(model, controller.period)
    return Margins(_gain_range(model, controller), phase, crossover, float(disk), float(disk_gain),
                   float(disk_phase), float(S[s]), float(omega[s]), float(T[t]), float(omega[t]))


def loop_response(model: LinearModel, controller: GeneralizedController):
    """(L as a python-control system, the grid of frequencies, L on the grid): the loop broken
    at the plant input, in the controller's time (a discrete controller's grid ends just below
    its Nyquist frequency)."""
    import control

    discrete = controller.discrete
    if discrete and not model.discrete:
        model = discretize(model, controller.period)
    A, B = model.A, model.B
    n = A.shape[0]
    dt = controller.period if discrete else 0
    plant = control.ss(A, B, np.eye(n), np.zeros((n, B.shape[1])), dt)
    law = (control.ss(controller.Ac, controller.Bc, controller.Cc, controller.Dc, dt) if controller.n_xc
           else control.ss([], [], [], controller.Dc, dt))
    loop = law * plant
    top = math.pi / controller.period * (1 - 1e-9) if discrete else HIGHEST
    omega = np.logspace(math.log10(LOWEST), math.log10(top), GRID)
    response = loop.frequency_response(omega)
    return loop, omega, np.asarray(response.complex).reshape(-1)


def _phase(omega: np.ndarray, L: np.ndarray) -> tuple[float | None, float | None]:
    magnitude = np.abs(L)
    found = None
    for k in np.nonzero(np.diff(np.sign(magnitude - 1.0)))[0]:
        # interpolate in log |L| between the two grid points
        a, b = math.log(magnitude[k]), math.log(magnitude[k + 1])
        t = -a / (b - a) if b != a else 0.0
        w = omega[k] * (omega[k + 1] / omega[k]) ** t
        angle = math.degrees(abs(np.angle(L[k] + t * (L[k + 1] - L[k]))))
        margin = 180.0 - angle
        if found is None or margin < found[0]:
            found = (margin, float(w))
    return (None, None) if found is None else found


def _stable(model, controller, k: float) -> bool:
    A, B = model.A, model.B
    top = np.hstack([A - k * B @ controller.Dc, -k * B @ controller.Cc])
    bottom = np.hstack([controller.Bc, controller.Ac])
    eigenvalues = np.linalg.eigvals(np.vstack([top, bottom]))
    if controller.discrete:
        return bool(np.max(np.abs(eigenvalues)) < 1.0)
    return bool(np.max(eigenvalues.real) < 0.0)


def _gain_range(model, controller) -> tuple[float, float]:
    """The factors k around 1 with a stable loop: scanned on a log grid, edges bisected."""
    grid = np.logspace(-3, 3, 241)
    stable = [_stable(model, controller, k) for k in grid]

    def edge(inside: float, outside: float) -> float:
        for _ in range(40):
            middle = math.sqrt(inside * outside)
            if _stable(model, controller, middle):
                inside = middle
            else:
                outside = middle
        return inside

    one = int(np.searchsorted(grid, 1.0))
    low = 0.0
    for j in range(one - 1, -1, -1):
        if not stable[j]:
            low = edge(float(grid[j + 1]) if j + 1 < one else 1.0, float(grid[j]))
            break
    high = math.inf
    for j in range(one, len(grid)):
        if not stable[j]:
            high = edge(float(grid[j - 1]) if j > one else 1.0, float(grid[j]))
            break
    return low, high
