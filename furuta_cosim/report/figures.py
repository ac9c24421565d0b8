"""Figures of co-simulation runs, controllers overlaid, as PNG and SVG.

The layout follows the paper's figures: the tracked output with its reference, the other
outputs in the tracked output's unit (the pendulum angle), and the input.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import numpy as np  # noqa: E402

from furuta_cosim.cosim.trace import Trace  # noqa: E402
from furuta_cosim.files import atomic  # noqa: E402

def default_signals(trace: Trace) -> list[str]:
    """The tracked output, the outputs measured in its unit (the pendulum's angle beside the
    arm's), and the input."""
    return [trace.tracked, *trace.watched(), "u"]


# points per line at most: a 600 s run at 2 ms has 300,000 samples, more than any screen shows
MAX_POINTS = 20_000


def plot_runs(traces: Mapping[str, Trace], path: str | Path, title: str = "",
              signals: Sequence[str] | None = None, time_unit: str = "s") -> list[Path]:
    """:func:`figure_of_runs` written as PNG and SVG (atomically); returns their paths."""
    with np.errstate(all="ignore"):  # a run that blew up is drawn until it left the axes
        return _plot_runs(traces, path, title, signals, time_unit)


def _plot_runs(traces, path, title, signals, time_unit) -> list[Path]:
    return _save(figure_of_runs(traces, title, signals, time_unit), path, dpi=120)


def _save(figure, path: str | Path, dpi: int) -> list[Path]:
    """The figure as ``path``.png and .svg (atomically), closed afterwards."""
    path = Path(path)
    written = []
    try:
        for suffix in (".png", ".svg"):
            target = path.with_suffix(suffix)
            with atomic(target) as partial:
                figure.savefig(partial, dpi=dpi, format=suffix[1:])
            written.append(target)
    finally:
        plt.close(figure)
    return written


def plot_convergence(records: Sequence[Mapping], path: str | Path,
                     levels: Mapping[str, float] | None = None) -> list[Path]:
    """A tuning's convergence as ``path``.png and .svg: above, each feasible evaluation's
    objective, the best so far and the baselines' scores (``levels``, a dashed line each),
    on an axis scaled to where the gain is (from the best to the worst baseline, with room),
    points beyond it drawn on its edge; below, each infeasible evaluation by its constraint
    margin (how far it broke its worst constraint, normalized), so that neither hides the
    other. ``records`` are the history lines."""
    index = np.array([r["index"] for r in records])
    feasible = np.array([bool(r["feasible"]) for r in records], dtype=bool)
    values = np.array([float(r["objective"]) if r["feasible"] else np.nan for r in records])
    running = np.fmin.accumulate(np.where(np.isnan(values), np.inf, values))
    infeasible = ~feasible
    rows = 2 if infeasible.any() else 1
    figure, axes = plt.subplots(rows, 1, sharex=True, figsize=(7, 3.2 + 1.6 * (rows - 1)), squeeze=False,
                                gridspec_kw={"height_ratios": [2, 1][:rows]})
    axis = axes[0, 0]
    low, high = convergence_range(values, levels)
    shown = np.clip(values, low, high)
    outside = np.isfinite(values) & (values > high)
    axis.plot(index[~outside], shown[~outside], "o", markersize=3, alpha=0.5, label="feasible evaluation")
    if outside.any():
        axis.plot(index[outside], shown[outside], "^", markersize=4, alpha=0.5, color="C0",
                  label=f"feasible, above {high:.4g}")
    axis.step(index, np.where(np.isfinite(running), running, np.nan), where="post", color="C3",
              linewidth=1.6, label="best so far")
    for k, (name, level) in enumerate((levels or {}).items()):
        axis.axhline(level, linestyle="--", linewidth=1.0, color=f"C{(k + 4) % 10}",
                     label=f"{name} (scored alike)")
    axis.set_ylim(low, high)
    axis.set_ylabel("objective")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize="small")
    if rows == 2:
        margins = np.array([float(r.get("margin") or 0.0) for r in records])
        below = axes[1, 0]
        below.plot(index[infeasible], margins[infeasible], "x", color="grey", markersize=4,
                   label="infeasible evaluation")
        below.axhline(0.0, color="black", linewidth=0.8)
        below.set_ylabel("constraint margin\n(> 0: broken)", fontsize="small")
        below.grid(True, alpha=0.3)
        below.legend(fontsize="small")
    axes[-1, 0].set_xlabel("evaluation")
    figure.tight_layout()
    return _save(figure, path, dpi=110)


def convergence_range(values: np.ndarray, levels: Mapping[str, float] | None = None) -> tuple[float, float]:
    """The objective axis of a convergence figure: from the best feasible value to the worst
    baseline (or the median feasible value, when higher), widened by a tenth on each side."""
    finite = values[np.isfinite(values)]
    marks = [float(v) for v in (levels or {}).values() if np.isfinite(v)]
    if not len(finite) and not marks:
        return 0.0, 1.0
    best = [float(finite.min()), float(np.median(finite))] if len(finite) else []
    low, top = min(best[:1] + marks), max(best[1:] + marks)
    span = max(top - low, 1e-9 * max(abs(top), 1.0))
    return low - 0.1 * span, top + 0.1 * span


def figure_of_runs(traces: Mapping[str, Trace], title: str = "",
                   signals: Sequence[str] | None = None, time_unit: str = "s"):
    """One figure, a row per signal, every controller overlaid.

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
    scale = bool(bounded) and len(bounded) < len(traces)
    for axis, name in zip(axes[:, 0], signals):
        limits = _limits(name, bounded) if scale else None
        for label, trace in traces.items():
            t, y = trace.t, np.asarray(trace[name], dtype=float)
            exit = _exit(y, limits) if limits and trace.failure else None
            if exit is not None:
                # drawn until it leaves the bounded runs' range, then marked there
                t, y = t[:exit + 1], y[:exit + 1]
            when, value = (t[-1], y[-1]) if exit is not None else (None, None)
            t, y = _thin(t, y)
            if name == "u":
                lines = axis.step(t, y, where="post", label=label, linewidth=1.2)
            else:
                lines = axis.plot(t, y, label=label, linewidth=1.2)
            if exit is not None:
                _mark_exit(axis, trace, when, value, limits, lines[0].get_color())
        if name == first.tracked:
            t, r = _thin(first.t, first.r)
            axis.plot(t, r, "k--", linewidth=1.0, label="reference")
        if limits:
            axis.set_ylim(*limits)
        axis.set_ylabel(first.label(name))
        axis.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel(f"time [{time_unit}]")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return figure


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


def _limits(name: str, bounded: list[Trace]) -> tuple[float, float] | None:
    """The range of the bounded runs (and the reference) with a margin."""
    values = np.concatenate([np.asarray(tr[name], dtype=float) for tr in bounded] +
                            ([bounded[0].r] if name == bounded[0].tracked else []))
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    low, high = float(values.min()), float(values.max())
    margin = 0.1 * (high - low) or 0.1 * max(abs(high), 1e-9)
    return low - margin, high + margin


def _exit(y: np.ndarray, limits: tuple[float, float]) -> int | None:
    outside = np.nonzero(~((y >= limits[0]) & (y <= limits[1])))[0]
    return int(outside[0]) if len(outside) else None


def _mark_exit(axis, trace: Trace, when: float, value: float, limits: tuple[float, float],
               color) -> None:
    edge = limits[0] if value < limits[0] else limits[1]
    axis.plot([when], [edge], marker="v" if edge == limits[0] else "^", color=color,
              markersize=9, clip_on=False, zorder=5)
    axis.annotate(f"{trace.controller} leaves the plot at {when:.3g} (its run stopped at "
                  f"{trace.t[-1]:.3g})", (when, edge),
                  textcoords="offset points", xytext=(8, 6 if edge == limits[0] else -12),
                  fontsize="small", color=color)


def plot_tradeoff(feasible: Sequence[Sequence[float]], front: Sequence[Sequence[float]],
                  knee: int | None, names: Sequence[str],
                  baselines: Mapping[str, Mapping | None], path: str | Path, title: str = "",
                  fronts: Mapping[str, Sequence[Sequence[float]]] | None = None) -> list[Path]:
    """A trade-off between the first two criteria as ``path``.png and .svg: every feasible
    evaluation, the Pareto front (a step line), its knee, each baseline's point. ``fronts``
    draws further labelled fronts on the same axes (families compared)."""
    figure, axis = plt.subplots(figsize=(6.4, 4.6))
    if len(feasible):
        F = np.asarray(feasible, dtype=float)
        axis.plot(F[:, 0], F[:, 1], "o", markersize=3, alpha=0.35, color="grey",
                  label="feasible evaluation")
    for k, (label, points) in enumerate(({"front": front} if fronts is None else fronts).items()):
        if len(points):
            P = np.asarray(points, dtype=float)
            axis.step(P[:, 0], P[:, 1], where="post", color=f"C{k}", linewidth=1.4)
            axis.plot(P[:, 0], P[:, 1], "o", color=f"C{k}", markersize=4, label=f"{label} ({len(P)})")
    if knee is not None and len(front) and fronts is None:
        axis.plot(front[knee][0], front[knee][1], "*", markersize=14, color="C3", label="knee")
    # the axes span the evaluations (a baseline far outside them is named, not drawn: one
    # diverging controller must not squash the front into a corner)
    # rows hold every criterion; the figure shows the first two
    shown = [np.asarray(p, dtype=float)[:, :2] for p in
             [feasible, front, *((fronts or {}).values())] if len(p)]
    box = np.vstack(shown) if shown else np.ones((1, 2))
    low, high = box.min(axis=0), box.max(axis=0)
    for k, (name, criteria) in enumerate(baselines.items()):
        if not criteria or any(criteria.get(n) is None for n in names[:2]):
            continue
        point = np.array([criteria[names[0]], criteria[names[1]]], dtype=float)
        inside = np.all(point <= high + 0.5 * (high - low) + 1e-12)
        if inside:
            low, high = np.minimum(low, point), np.maximum(high, point)
        axis.plot(*(point if inside else [np.nan, np.nan]), "D", markersize=7,
                  color=f"C{(k + 4) % 10}",
                  label=name if inside else f"{name} (off the axes: {point[0]:.4g}, {point[1]:.4g})")
    pad = 0.05 * np.where(high > low, high - low, np.abs(high) + 1.0)
    axis.set_xlim(low[0] - pad[0], high[0] + pad[0])
    axis.set_ylim(low[1] - pad[1], high[1] + pad[1])
    axis.set_xlabel(names[0])
    axis.set_ylabel(names[1])
    if title:
        axis.set_title(title + (f" (first two of {len(names)} criteria)" if len(names) > 2 else ""),
                       fontsize="medium")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize="small")
    figure.tight_layout()
    return _save(figure, path, dpi=110)


def plot_system(t: np.ndarray, values: Mapping[str, np.ndarray], path: str | Path, title: str = "") -> list[Path]:
    """An SSP's run (furuta_cosim/ssp/system.py) as ``path``.png and .svg: one panel per
    component output, grouped by component, at most 8 panels (the first by name)."""
    names = list(values)[:8]
    figure, axes = plt.subplots(len(names), 1, sharex=True, figsize=(8, 1.6 + 1.5 * len(names)), squeeze=False)
    for axis, name in zip(axes[:, 0], names):
        x, y = _thin(np.asarray(t), np.asarray(values[name]))
        axis.plot(x, y, lw=1.0)
        axis.set_ylabel(name, fontsize=8)
        axis.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    with np.errstate(all="ignore"):
        return _save(figure, path, dpi=110)
