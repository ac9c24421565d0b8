"""Figures of a plant against a measured log: overlays of measured and simulated outputs, and
their residuals, one row per output, as PNG and SVG."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from furuta_cosim.report.figures import _save, _thin, plt

# angles are drawn in degrees: what a person reads off an encoder
_DEGREES = {"theta0", "theta1", "dtheta0", "dtheta1"}


def _shown(name: str, y: np.ndarray) -> tuple[np.ndarray, str]:
    if name in _DEGREES:
        return np.degrees(y), "deg" if not name.startswith("d") else "deg/s"
    return y, {"i": "A"}.get(name, "")


def _rows(count: int, height: float):
    return plt.subplots(count, 1, figsize=(9, height * count + 0.6), sharex=True, squeeze=False)


def _finish(figure, axes, path, title: str) -> list[Path]:
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("t [s]")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return _save(figure, path, dpi=110)


def plot_overlay(t: np.ndarray, measured: Mapping[str, np.ndarray],
                 simulated: Mapping[str, Mapping[str, np.ndarray]], path: str | Path,
                 title: str = "") -> list[Path]:
    """Measured outputs (points) and each simulated set (lines, by label) over time."""
    names = list(measured)
    figure, axes = _rows(len(names), 2.6)
    for axis, name in zip(axes[:, 0], names):
        y, unit = _shown(name, measured[name])
        axis.plot(*_thin(t, y), ".", ms=1.5, color="0.35", label="measured")
        for label, outputs in simulated.items():
            axis.plot(*_thin(t, _shown(name, outputs[name])[0]), lw=1.0, label=label)
        axis.set_ylabel(f"{name} [{unit}]" if unit else name)
        axis.grid(alpha=0.3)
    return _finish(figure, axes, path, title)


def plot_residuals(t: np.ndarray, measured: Mapping[str, np.ndarray],
                   simulated: Mapping[str, Mapping[str, np.ndarray]], path: str | Path,
                   title: str = "", quantum: Mapping[str, float] | None = None) -> list[Path]:
    """Simulated minus measured per output, with the encoder's +-quantum/2 band where known."""
    names = list(measured)
    figure, axes = _rows(len(names), 2.3)
    for axis, name in zip(axes[:, 0], names):
        for label, outputs in simulated.items():
            error, unit = _shown(name, outputs[name] - measured[name])
            axis.plot(*_thin(t, error), lw=0.7, label=label)
        step = (quantum or {}).get(name)
        if step:
            half = _shown(name, np.array([step / 2]))[0][0]
            axis.axhspan(-half, half, color="0.85", zorder=0, label="+-quantum/2")
        axis.axhline(0.0, color="0.5", lw=0.6)
        axis.set_ylabel(f"{name} error [{unit}]" if unit else f"{name} error")
        axis.grid(alpha=0.3)
    return _finish(figure, axes, path, title)


def plot_profiles(parameters: Mapping[str, Mapping], path: str | Path) -> list[Path]:
    """One small panel per profiled parameter (fit.json's ``parameters``): the cost's rise over
    its minimum against the parameter's value, the threshold of the 95 % interval, the
    likelihood-ratio interval where the profile crosses it and the sandwich interval beside it,
    titled with the verdict."""
    names = [name for name, p in parameters.items() if p.get("profile")]
    if not names:
        return []
    columns = min(3, len(names))
    rows = -(-len(names) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.7 * rows), squeeze=False)
    for axis in axes.flat[len(names):]:
        axis.set_visible(False)
    for axis, name in zip(axes.flat, names):
        p = parameters[name]
        profile = p["profile"]
        values, rise = np.asarray(profile["values"]), np.asarray(profile["rise"])
        axis.plot(values, rise, "o-", ms=3, lw=1.0, label="profile")
        if profile.get("threshold"):
            axis.axhline(profile["threshold"], color="0.4", ls="--", lw=0.8, label="95 % threshold")
        if p.get("interval"):
            axis.axvspan(*p["interval"], color="C1", alpha=0.15, label="sandwich 95 %")
        for edge in p.get("interval_profile") or ():
            if edge is not None:
                axis.axvline(edge, color="C2", lw=1.0)
        axis.axvline(p["value"], color="k", lw=0.6)
        axis.set_title(f"{name}: {p['verdict'].split(':')[0]}", fontsize="small")
        axis.set_xlabel(name, fontsize="small")
        axis.set_ylabel("cost rise", fontsize="small")
        axis.tick_params(labelsize="x-small")
        axis.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="x-small")
    figure.suptitle("profile likelihoods (green: where the profile crosses the threshold)", fontsize="small")
    figure.tight_layout()
    return _save(figure, path, dpi=110)
