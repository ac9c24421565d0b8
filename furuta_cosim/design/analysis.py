"""Closed-loop analysis: eigenvalues of Abar, the dominant mode, and stability verdicts.

Verdicts: the loop (spectral abscissa < -margin, or spectral radius < 1 - margin), the
controller by itself (eig(Ac); the paper recommends a stable controller), mean-square
stability of the loop driven by white process noise (for this linear loop it holds exactly
when Abar is stable; the stationary variances are reported), and for a continuous
controller the exact sampled-data loop at a given period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from furuta_cosim.design.controller import GeneralizedController, augmented, discretize_controller
from furuta_cosim.design.linear import LinearModel, time_text
from furuta_cosim.design.prefilter import prefilter, tracking_bandwidth
from furuta_cosim.errors import DesignError

if False:  # for the annotation only
    from furuta_cosim.design.margins import Margins

MARGIN = 1e-9


@dataclass(frozen=True)
class Mode:
    """An eigenvalue and its continuous-time reading (s = ln(z)/T for discrete loops)."""

    eigenvalue: complex
    s: complex

    @property
    def damping(self) -> float:
        return -self.s.real / abs(self.s) if abs(self.s) > 0 else 1.0

    @property
    def settling_time(self) -> float:
        """2 % settling time 4/|Re s|; infinite for a mode that does not decay."""
        return 4.0 / -self.s.real if self.s.real < 0 else math.inf

    def describe(self) -> str:
        z = self.eigenvalue
        text = f"{z.real:.4g}{'+-' if abs(z.imag) > 0 else ''}{abs(z.imag):.4g}j" if z.imag else f"{z.real:.4g}"
        return text.replace("+-", " ± ")

    def as_dict(self) -> dict:
        return {"eigenvalue": [self.eigenvalue.real, self.eigenvalue.imag],
                "s": [self.s.real, self.s.imag], "damping": self.damping,
                "settling_time_2pct": None if math.isinf(self.settling_time) else self.settling_time}


@dataclass(frozen=True)
class Analysis:
    """Everything ``furuta-cosim analyze`` reports about a model and a controller."""

    model: str
    controller: str
    period: float
    eigenvalues: np.ndarray
    stable: bool
    dominant: Mode
    controller_eigenvalues: np.ndarray
    controller_stable: bool
    stationary_variance: list | None
    sampled: "Analysis | None" = None
    prefilter: float | None = None
    tracked_output: str | None = None
    prefilter_problem: str | None = None
    time_unit: str = "s"
    bandwidth: float | None = None       # -3 dB of rbar -> the tracked output (rad per time unit)
    margins: "Margins | None" = None     # at the plant input (design/margins.py); a stable loop's

    @property
    def discrete(self) -> bool:
        return self.period > 0

    @property
    def spectral_abscissa(self) -> float:
        return float(np.max(self.eigenvalues.real))

    @property
    def spectral_radius(self) -> float:
        return float(np.max(np.abs(self.eigenvalues)))

    @property
    def running_margins(self) -> "Margins | None":
        """The margins of the loop that runs: the sampled loop's for a continuous controller
        run at a period, else the loop's own."""
        return self.sampled.margins if self.sampled is not None else self.margins

    @property
    def margins_of(self) -> str:
        """Which loop :attr:`running_margins` are of, in words."""
        if self.sampled is not None:
            at = self.sampled.period
            return (f"the sampled loop: the controller at {at * 1e3:g} ms, the plant through a zero-order hold"
                    if self.time_unit == "s" else f"the sampled loop at {at:g} {self.time_unit}")
        return "the discrete loop at its period" if self.discrete else "the continuous loop"

    @property
    def mean_square_stable(self) -> bool:
        return self.stable

    def as_dict(self) -> dict:
        result = {"model": self.model, "controller": self.controller,
                  "time": "discrete" if self.discrete else "continuous",
                  "eigenvalues": [[z.real, z.imag] for z in self.eigenvalues]}
        if self.discrete:
            result["period"] = self.period
            result["spectral_radius"] = self.spectral_radius
        else:
            result["spectral_abscissa"] = self.spectral_abscissa
        result.update({"stable": self.stable, "dominant": self.dominant.as_dict(),
                       "controller_eigenvalues": [[z.real, z.imag] for z in self.controller_eigenvalues],
                       "controller_stable": self.controller_stable,
                       "mean_square_stable": self.mean_square_stable,
                       "stationary_variance": self.stationary_variance})
        if self.sampled is not None:
            result["sampled"] = {"period": self.sampled.period,
                                 "spectral_radius": self.sampled.spectral_radius,
                                 "stable": self.sampled.stable,
                                 "dominant": self.sampled.dominant.as_dict()}
        running = self.running_margins
        result["margins"] = running.as_dict() if running is not None else None
        result["margins_of"] = self.margins_of
        if self.sampled is not None:
            result["margins_continuous"] = self.margins.as_dict() if self.margins is not None else None
        result["tracking_bandwidth"] = self.bandwidth
        result["prefilter"] = ({"output": self.tracked_output, "F": self.prefilter}
                               if self.prefilter is not None else
                               {"output": self.tracked_output, "problem": self.prefilter_problem})
        result["verdict"] = self.verdict()
        return result

    def verdict(self) -> list[str]:
        """The analysis in words, in the model's time unit."""
        d = self.dominant
        unit = self.time_unit
        lines = []
        if self.stable:
            lines.append(f"The closed loop is stable: its slowest mode {d.describe()} has damping "
                         f"{d.damping:.3f} and settles (2 %) in about {time_text(d.settling_time, unit)}.")
        else:
            growth = d.s.real
            lines.append(f"The closed loop is UNSTABLE: the mode {d.describe()} grows"
                         + (f" (amplitude doubles every {time_text(math.log(2) / growth, unit)})." if growth > 0
                            else " or does not decay."))
        if self.sampled is not None and self.sampled.margins is not None:
            lines.append(self.sampled.margins.text(unit, f"Margins of the loop that runs ({self.margins_of})"))
            if self.margins is not None:
                lines.append(self.margins.text(unit, "Margins of the continuous loop as designed (not the loop "
                                                     "that runs)"))
        elif self.margins is not None:
            lines.append(self.margins.text(unit))
        if self.controller_eigenvalues.size == 0:
            lines.append("The controller is static (n_xc = 0).")
        elif self.controller_stable:
            lines.append("The controller by itself is stable.")
        else:
            lines.append("The controller by itself is UNSTABLE (eig(Ac) outside the stable region):"
                         " the paper advises against it in practice.")
        lines.append("Mean-square stable with white process noise." if self.mean_square_stable
                     else "Not mean-square stable: noise makes the state's variance grow without bound.")
        if self.sampled is not None:
            s = self.sampled
            at = f"{s.period * 1e3:g} ms" if unit == "s" else time_text(s.period, unit, "g")
            lines.append(f"Sampled at {at} with zero-order hold the loop is "
                         f"{'stable' if s.stable else 'UNSTABLE'} (spectral radius {s.spectral_radius:.6f}).")
        if self.prefilter is not None:
            lines.append(f"Prefilter for {self.tracked_output}: F = {self.prefilter:.6g}."
                         + ("" if self.stable else " (The loop is unstable, so it never settles there.)"))
            if self.bandwidth is not None and self.stable:
                unit = self.time_unit
                lines.append(f"Tracking bandwidth (-3 dB, r to {self.tracked_output}): "
                             f"{self.bandwidth:.4g} rad/{unit}: it follows a sine of period "
                             f"{time_text(2 * math.pi / self.bandwidth, unit)} or longer with at "
                             "least 71 % of its amplitude." if math.isfinite(self.bandwidth) else
                             f"Tracking bandwidth (-3 dB, r to {self.tracked_output}): not reached.")
        elif self.prefilter_problem:
            lines.append(f"No prefilter: {self.prefilter_problem}")
        return lines


def _modes(eigenvalues: np.ndarray, period: float) -> list[Mode]:
    if period > 0:
        return [Mode(complex(z), complex(np.log(complex(z)) / period)) if z != 0 else
                Mode(complex(z), complex(-math.inf)) for z in eigenvalues]
    return [Mode(complex(z), complex(z)) for z in eigenvalues]


def _sorted(eigenvalues: np.ndarray, discrete: bool) -> np.ndarray:
    key = np.abs(eigenvalues) if discrete else eigenvalues.real
    order = np.lexsort((eigenvalues.imag, -key))
    return eigenvalues[order]


def analyze(model: LinearModel, controller: GeneralizedController, *,
            sampling_period: float | None = None, tracked_output: str | None = None,
            margin: float = MARGIN, margins: bool = False) -> Analysis:
    """Analyse the loop of ``model`` and ``controller`` (see the module docstring).

    Parameters
    ----------
    model : LinearModel
        The plant's linear model.
    controller : GeneralizedController
        Static or dynamic, continuous or discrete.
    sampling_period : float, optional
        Adds the sampled-data loop of a continuous controller run at this period.
    tracked_output : str, optional
        Adds the prefilter and tracking bandwidth for this output.
    margin : float
        The stability margin: how far inside the stability region the poles must be.
    margins : bool
        Adds the gain, phase and disk margins at the plant input (design/margins.py; about a
        second), for a stable single-input loop.

    Returns
    -------
    Analysis
        Poles, stability, dominant mode and, with ``tracked_output``, the prefilter.
    """
    Abar, _ = augmented(model, controller)
    discrete = controller.discrete
    period = controller.period
    eigenvalues = _sorted(np.linalg.eigvals(Abar), discrete)
    if discrete:
        stable = bool(np.max(np.abs(eigenvalues)) < 1.0 - margin)
        dominant = max(_modes(eigenvalues, period), key=lambda m: abs(m.eigenvalue))
    else:
        stable = bool(np.max(eigenvalues.real) < -margin)
        dominant = max(_modes(eigenvalues, 0.0), key=lambda m: m.eigenvalue.real)
    ac = _sorted(np.linalg.eigvals(controller.Ac), discrete) if controller.n_xc else np.zeros(0, complex)
    controller_stable = bool(np.all(np.abs(ac) < 1.0) if discrete else np.all(ac.real < 0.0))
    variance = None
    if stable:
        noise = np.zeros_like(Abar)
        noise[:model.n, :model.n] = np.eye(model.n)
        P = (linalg.solve_discrete_lyapunov(Abar, noise) if discrete
             else linalg.solve_continuous_lyapunov(Abar, -noise))
        variance = [float(v) for v in np.diag(P)[:model.n]]
    sampled = None
    if sampling_period and not discrete and not model.discrete:
        sampled = analyze(model, discretize_controller(controller, sampling_period), margin=margin,
                          margins=margins)
    F = problem = bandwidth = None
    if tracked_output:
        try:
            F = prefilter(model, controller, tracked_output)
        except DesignError as error:
            problem = str(error)
        if F is not None and stable:
            bandwidth = tracking_bandwidth(model, controller, tracked_output, F)
    found = None
    if margins and stable and controller.Dc.shape[0] == 1 and model.B.shape[1] == 1:
        from furuta_cosim.design.margins import loop_margins

        found = loop_margins(model, controller)
    return Analysis(model.name, controller.name, period, eigenvalues, stable, dominant, ac,
                    controller_stable, variance, sampled, F, tracked_output, problem,
                    model.time_unit, bandwidth, found)
