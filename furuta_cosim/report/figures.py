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


def plot_runs(traces: Mapping[str, Trace], path: str | Path, title: str = "",
              signals: Sequence[str] | None = None, time_unit: str = "s") -> list[Path]:
    """One figure, a row per signal, every controller overlaid; returns the PNG and SVG paths."""
    first = next(iter(traces.values()))
    signals = list(signals) if signals else default_signals(first)
    if "u" not in signals:
        signals.append("u")
    figure, axes = plt.subplots(len(signals), 1, sharex=True, figsize=(8, 2.3 * len(signals) + 0.6),
                                squeeze=False)
    for axis, name in zip(axes[:, 0], signals):
        for label, trace in traces.items():
            if name == "u":
                axis.step(trace.t, trace.u, where="post", label=label, linewidth=1.2)
            else:
                axis.plot(trace.t, trace[name], label=label, linewidth=1.2)
        if name == first.tracked:
            axis.plot(first.t, first.r, "k--", linewidth=1.0, label="reference")
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
    for suffix in (".png", ".svg"):
        target = path.with_suffix(suffix)
        figure.savefig(target, dpi=120)
        written.append(target)
    plt.close(figure)
    return written
