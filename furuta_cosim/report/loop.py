"""Figures of a loop broken at the plant input: Bode, Nyquist, and the sensitivities |S|, |T|.

The loop drawn is the one that runs: a continuous controller run at a period is drawn
sampled (the controller discretized, the plant through a zero-order hold), its continuous
design dashed beside it. The margins marked are the running loop's (design/margins.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import numpy as np  # noqa: E402

from furuta_cosim.report.figures import _save  # noqa: E402

NAMES = ("bode", "nyquist", "sensitivity")
# every THIN-th point of the margins' grid is drawn (800 of 4000, log-spaced: smooth at any
# zoom a page shows); the margins and peaks marked are the full grid's
THIN = 5


def plot_loop(model, controller, folder: str | Path, *, sampling_period: float | None = None,
              title: str = "", margins=None) -> list[Path]:
    """``bode``, ``nyquist`` and ``sensitivity`` (.png and .svg) of the loop of ``model`` and
    ``controller`` written into ``folder``; returns the paths written. The loop must be stable
    and single-input (as :func:`furuta_cosim.design.margins.loop_margins` needs); ``margins``:
    the running loop's, when the caller has them (else computed here)."""
    from furuta_cosim.design.controller import discretize_controller
    from furuta_cosim.design.margins import loop_margins, loop_response

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    running = controller
    if sampling_period and not controller.discrete and not model.discrete:
        running = discretize_controller(controller, sampling_period)
    margins = margins if margins is not None else loop_margins(model, running)
    _, omega, L = loop_response(model, running)
    omega, L = omega[::THIN], L[::THIN]
    design = None
    if running is not controller:
        _, w_c, L_c = loop_response(model, controller)
        design = (w_c[::THIN], L_c[::THIN])
    unit = f"rad/{model.time_unit}"
    label = (f"sampled at {running.period * 1e3:g} ms (runs)" if design is not None and model.time_unit == "s"
             else "sampled (runs)" if design is not None else "loop")
    heading = title or f"{controller.name} on {model.name}"
    written = []
    written += _save(_bode(omega, L, design, margins, unit, label, heading), folder / "bode", dpi=110)
    written += _save(_nyquist(L, design, margins, label, heading), folder / "nyquist", dpi=110)
    written += _save(_sensitivity(omega, L, design, margins, unit, label, heading), folder / "sensitivity",
                     dpi=110)
    return written


def _bode(omega, L, design, margins, unit, label, heading):
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    phase = np.degrees(np.unwrap(np.angle(L)))
    top.semilogx(omega, 20 * np.log10(np.abs(L)), label=label)
    bottom.semilogx(omega, phase, label=label)
    if design is not None:
        w, Lc = design
        top.semilogx(w, 20 * np.log10(np.abs(Lc)), "--", color="grey", label="continuous design")
        bottom.semilogx(w, np.degrees(np.unwrap(np.angle(Lc))), "--", color="grey", label="continuous design")
    top.axhline(0.0, color="black", linewidth=0.6)
    if margins.crossover is not None:
        top.axvline(margins.crossover, color="tab:red", linewidth=0.8)
        bottom.axvline(margins.crossover, color="tab:red", linewidth=0.8)
        k = int(np.argmin(np.abs(omega - margins.crossover)))
        bottom.annotate(f"phase margin {margins.phase:.1f} deg", (margins.crossover, phase[k]),
                        textcoords="offset points", xytext=(8, 8), color="tab:red", fontsize=8)
    for level in range(-1080, 1081, 360):  # the -180 deg lines the phase may cross
        if phase.min() - 30 < level - 180 < phase.max() + 30:
            bottom.axhline(level - 180, color="black", linewidth=0.6)
    low, high = margins.gain
    top.set_title(f"{heading}: loop L at the plant input\nstable for input gains {low:.3g} to "
                  + ("any" if not math.isfinite(high) else f"{high:.3g}"), fontsize=10)
    top.set_ylabel("|L| (dB)")
    bottom.set_ylabel("arg L (deg)")
    bottom.set_xlabel(f"frequency ({unit})")
    top.legend(fontsize=8)
    for axis in (top, bottom):
        axis.grid(True, which="major", alpha=0.3)
    figure.tight_layout()
    return figure


def _nyquist(L, design, margins, label, heading):
    figure, axis = plt.subplots(figsize=(6.5, 6.0))
    axis.plot(L.real, L.imag, label=f"{label}, w > 0")
    axis.plot(L.real, -L.imag, ":", color="tab:blue", linewidth=0.8, label="w < 0")
    if design is not None:
        axis.plot(design[1].real, design[1].imag, "--", color="grey", label="continuous design")
    axis.plot([-1.0], [0.0], "r+", markersize=12, label="-1")
    if math.isfinite(margins.ms) and margins.ms > 0:
        r = 1.0 / margins.ms
        a = np.linspace(0, 2 * math.pi, 200)
        axis.plot(-1 + r * np.cos(a), r * np.sin(a), color="tab:red", linewidth=0.8,
                  label=f"1/Ms = {r:.3g} around -1")
    # the plot of an open-loop unstable plant's loop reaches far; show the part near -1 that decides
    span = max(3.0, min(20.0, 2.0 * margins.ms if math.isfinite(margins.ms) else 3.0))
    axis.set_xlim(-span, span)
    axis.set_ylim(-span, span)
    axis.set_aspect("equal")
    axis.axhline(0, color="black", linewidth=0.5)
    axis.axvline(0, color="black", linewidth=0.5)
    axis.set_xlabel("Re L")
    axis.set_ylabel("Im L")
    axis.set_title(f"{heading}: Nyquist plot of L", fontsize=10)
    axis.legend(fontsize=8, loc="lower right")
    axis.grid(True, alpha=0.3)
    figure.tight_layout()
    return figure


def _sensitivity(omega, L, design, margins, unit, label, heading):
    figure, axis = plt.subplots(figsize=(7.5, 4.5))
    with np.errstate(divide="ignore", invalid="ignore"):
        S, T = 1.0 / (1.0 + L), L / (1.0 + L)
    axis.semilogx(omega, 20 * np.log10(np.abs(S)), label=f"|S|, Ms = {margins.ms:.3g}")
    axis.semilogx(omega, 20 * np.log10(np.abs(T)), label=f"|T|, Mt = {margins.mt:.3g}")
    if design is not None:
        w, Lc = design
        with np.errstate(divide="ignore", invalid="ignore"):
            axis.semilogx(w, 20 * np.log10(np.abs(1.0 / (1.0 + Lc))), "--", color="grey", linewidth=0.8,
                          label="continuous design")
            axis.semilogx(w, 20 * np.log10(np.abs(Lc / (1.0 + Lc))), "--", color="grey", linewidth=0.8)
    axis.plot([margins.ms_at], [20 * math.log10(margins.ms)], "o", color="tab:blue")
    axis.plot([margins.mt_at], [20 * math.log10(margins.mt)], "o", color="tab:orange")
    axis.axhline(0.0, color="black", linewidth=0.6)
    axis.set_xlabel(f"frequency ({unit})")
    axis.set_ylabel("dB")
    axis.set_title(f"{heading}: sensitivity at the plant input ({label})", fontsize=10)
    axis.legend(fontsize=8)
    axis.grid(True, which="major", alpha=0.3)
    figure.tight_layout()
    return figure
