"""Figures of co-simulation runs, controllers overlaid, as PNG and SVG.

The layout follows the paper's figures: the tracked output with its reference, the other
signals of interest (the pendulum angle), and the input.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import numpy as np  # noqa: E402

from furuta_cosim.cosim.trace import Trace  # noqa: E402

LABELS = {"theta0": "arm angle θ0 [rad]", "theta1": "pendulum angle θ1 [rad]",
          "dtheta0": "arm velocity [rad/s]", "dtheta1": "pendulum velocity [rad/s]",
          "i": "current i [A]", "y": "output y", "V": "voltage V [V]"}


def default_signals(trace: Trace) -> list[str]:
    """The tracked output, the pendulum angle when there is one, and the input."""
    signals = [trace.tracked]
    if "theta1" in trace.signals and trace.tracked != "theta1":
        signals.append("theta1")
    return signals + ["u"]


# points per line at most: a 600 s run at 2 ms has 300,000 samples, more than any screen shows
MAX_POINTS = 20_000


def plot_runs(traces: Mapping[str, Trace], path: str | Path, title: str = "",
              signals: Sequence[str] | None = None, time_unit: str = "s") -> list[Path]:
    """One figure, a row per signal, every controller overlaid; returns the PNG and SVG paths.

    Axes are scaled to the runs that stayed bounded (those without a failure); a run that
    left that range is drawn until it does and marked where it left, so a diverging
    controller does not flatten the others into a line.
    """
    first = next(iter(traces.values()))
    signals = list(signals) if signals else default_signals(first)
    if "u" not in signals:
        signals.append("u")
    figure, axes = plt.subplots(len(signals), 1, sharex=True, figsize=(8, 2.3 * len(signals) + 0.6),
                                squeeze=False)
    bounded = [trace for trace in traces.values() if not trace.failure]
    for axis, name in zip(axes[:, 0], signals):
        for label, trace in traces.items():
            t, y = _thin(trace.t, trace[name])
            if name == "u":
                axis.step(t, y, where="post", label=label, linewidth=1.2)
            else:
                axis.plot(t, y, label=label, linewidth=1.2)
        if name == first.tracked:
            t, r = _thin(first.t, first.r)
            axis.plot(t, r, "k--", linewidth=1.0, label="reference")
        if bounded and len(bounded) < len(traces):
            _scale_to(axis, name, bounded, [tr for tr in traces.values() if tr.failure])
        label = first.input_name if name == "u" else name
        axis.set_ylabel(LABELS.get(label, label))
        axis.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel(f"time [{time_unit}]")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    written = []
    try:
        for suffix in (".png", ".svg"):
            target = path.with_suffix(suffix)
            partial = target.with_name(f".{target.name}.partial")
            try:
                figure.savefig(partial, dpi=120, format=suffix[1:])
                partial.replace(target)
            finally:
                partial.unlink(missing_ok=True)
            written.append(target)
    finally:
        plt.close(figure)
    return written


def _thin(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At most about MAX_POINTS points, keeping each stretch's extremes so peaks still show."""
    n = len(t)
    if n <= MAX_POINTS:
        return t, y
    width = int(np.ceil(n / (MAX_POINTS // 2)))
    usable = n - n % width
    blocks = y[:usable].reshape(-1, width)
    low, high = blocks.argmin(axis=1), blocks.argmax(axis=1)
    offsets = np.arange(0, usable, width)
    index = np.sort(np.concatenate([offsets + np.minimum(low, high), offsets + np.maximum(low, high),
                                    np.arange(usable, n)]))
    return t[index], y[index]


def _scale_to(axis, name: str, bounded: list[Trace], escaped: list[Trace]) -> None:
    values = np.concatenate([np.asarray(tr[name], dtype=float) for tr in bounded] +
                            ([bounded[0].r] if name == bounded[0].tracked else []))
    values = values[np.isfinite(values)]
    if not len(values):
        return
    low, high = float(values.min()), float(values.max())
    margin = 0.1 * (high - low) or 0.1 * max(abs(high), 1e-9)
    low, high = low - margin, high + margin
    axis.set_ylim(low, high)
    for trace in escaped:
        y = np.asarray(trace[name], dtype=float)
        outside = np.nonzero(~((y >= low) & (y <= high)))[0]
        if len(outside):
            k = outside[0]
            edge = high if not y[k] < low else low
            axis.plot([trace.t[k]], [edge], marker="^" if edge == high else "v", color="red",
                      markersize=8, clip_on=False, zorder=5)
            axis.annotate(f"{trace.controller} leaves the plot at {trace.t[k]:.3g}",
                          (trace.t[k], edge), textcoords="offset points",
                          xytext=(6, -12 if edge == high else 4), fontsize="x-small", color="red")
