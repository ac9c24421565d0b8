"""What the experiments can tell, asked before the fit spends its budget.

At the start values a forward-difference Jacobian of the weighted residuals (one simulation
per experiment and unknown, all at once on the workers: a few seconds) says how far each
unknown, and each combination of them, moves the replayed outputs. Two readings of it:

- **Separability.** With the columns in relative units (a change of 100 % of each start), the
  Jacobian's singular value decomposition gives the combinations the outputs barely see: a
  right singular vector whose singular value is ``s`` can move by ``1 / s`` (relative; an
  initial state or a sensor bias, whose start may be 0, by its bounds' width) before
  the outputs move by one noise standard deviation in all, *even if the noise were white*.
  The residuals of a real fit are not white (identify/fit.py's sandwich covariance is wider,
  often ten times), so a combination whose white-noise deviation is already above
  :data:`SEPARABLE` (5 %) would carry a real interval of tens of percent at best: the fit
  wanders along it, its profiles run flat. Such combinations are named (the unknowns in them
  and how they move together) and the fit stops there, in seconds, unless ``--force``.
  Measured at the start values of tools/bench_balancing.py's ten seeds: with the current
  logged every deviation is at most 0.6 %; without it the motor's combination is 5.9 % to
  76 %; on the shipped QUBE spec the largest is 1.6 % (C0).
  A log without the current, for one: the angles see the motor only through ``M_f / R_a`` and
  ``M_f^2 / R_a + C0``, so R_a, M_f and C0 move together unseen.
- **Where it starts.** An output whose replay at the start values is hundreds of noise floors
  off (:data:`FAR`) before anything is fitted may be a column read wrongly: its unit, sign or
  zero. Each other reading of it (another unit of its kind, the sign flipped, a half or whole
  turn away) is tried against the same simulation; one that replays :data:`HINT` times better
  is named (:func:`unit_hint`), and a fit that is not trusted then says it first. A log with
  its loop is checked without the plant too: the command the loop computes from the logged
  angles and current is the logged command to rounding; where it is not, the reading of a
  column that makes it so is named (:func:`loop_hint`): a column in the wrong unit corrupts
  the closed-loop replay itself, so only this check sees it.

An unknown the outputs do not depend on at all (a zero column: an end stop the arm never
reaches) is left to the fit, which keeps it at its start and reports it as not identifiable.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

SEPARABLE = 0.05    # relative white-noise deviation above which a combination is not separable
FAR = 100.0         # noise floors of RMS at the start values that point at a column read wrongly
SHOWN = 0.15        # an unknown takes part in a combination when it moves this share of the largest


def natural(J: np.ndarray, items) -> tuple[np.ndarray, list[float | None]]:
    """``J`` (by the fit's scaled units, identify/fit.py Unknown) in natural units: a plant
    parameter by a change of 100 % of its start, an initial state or a sensor bias (whose start
    may be 0) by the width of its bounds. Returns (J, per unknown None for relative or the width)."""
    widths = [None if "." not in u.name and u.start != 0 else float(u.bounds[1] - u.bounds[0]) for u in items]
    factors = np.array([abs(u.start) / u.scale if w is None else w / u.scale for u, w in zip(items, widths)])
    return J * factors, widths


def separability(J: np.ndarray, names: Sequence[str], samples: int,
                 widths: Sequence[float | None] | None = None) -> dict:
    """The readings of ``J`` (weighted residuals by relative change of each unknown).

    Returns ``{"deviation": {name: the white-noise relative standard deviation, others free
    (None: unbounded)},
    "groups": [{"names", "change": {name: relative change}, "floors": RMS in noise floors
    that change makes}], "threshold": SEPARABLE}``; ``groups`` empty when every combination
    is separable. Columns that are zero (the outputs do not depend on the unknown) are left out.
    ``widths`` (from :func:`natural`): an unknown measured by its bounds' width, whose change is
    then given in its own unit; None (the default): every column relative."""
    names = list(names)
    widths = list(widths) if widths is not None else [None] * len(names)
    norms = np.linalg.norm(J, axis=0)
    largest = float(np.max(norms)) if norms.size else 0.0
    seen = [k for k, n in enumerate(norms) if n > 1e-9 * largest]
    deviation = {names[k]: math.inf for k in range(len(names)) if k not in seen}
    groups: list[dict] = []
    if seen:
        Js = J[:, seen]
        _, s, vt = np.linalg.svd(Js, full_matrices=False)
        inverse = 1.0 / np.maximum(s, 1e-300)
        for j, k in enumerate(seen):
            deviation[names[k]] = float(math.sqrt(np.sum((vt[:, j] * inverse) ** 2)))
        for i in range(len(s)):
            if inverse[i] <= SEPARABLE:
                continue
            v = vt[i]
            v = v / v[int(np.argmax(np.abs(v)))]           # the largest share +1
            part = [j for j in range(len(seen)) if abs(v[j]) >= SHOWN]
            if len(part) < 2:                               # one unknown alone: its own deviation says it
                part = [int(np.argmax(np.abs(v)))]
            # the largest moved by a tenth (of its start, or of its bounds' width)
            change = {names[seen[j]]: 0.1 * float(v[j]) * (1.0 if widths[seen[j]] is None else widths[seen[j]])
                      for j in part}
            relative = {names[seen[j]]: widths[seen[j]] is None for j in part}
            floors = float(np.linalg.norm(Js @ (0.1 * v))) / math.sqrt(max(samples, 1))
            groups.append({"names": [names[seen[j]] for j in part], "change": change, "relative": relative,
                           "floors": floors})
    deviation = {k: (v if math.isfinite(v) and v < 1e12 else None) for k, v in deviation.items()}
    return {"deviation": deviation, "groups": groups, "threshold": SEPARABLE}


def describe(group: dict) -> str:
    """One group as a line: which unknowns, how they move together, what the outputs see."""
    names = group["names"]
    together = ", ".join(f"{n} {100 * c:+.3g} %" if group["relative"][n] else f"{n} {c:+.3g}"
                         for n, c in group["change"].items())
    if len(names) == 1:
        return (f"{names[0]}: the experiments barely see it ({together} moves the outputs by "
                f"{group['floors']:.2g} noise floors RMS)")
    return (f"{', '.join(names[:-1])} and {names[-1]} cannot be told apart: together {together} move "
            f"the outputs by {group['floors']:.2g} noise floors RMS")


def next_step(groups: list[dict], outputs: set[str], plant_has_current: bool) -> str:
    """What to do about groups that are not separable."""
    held = groups[0]["names"][0]
    steps = [f"hold {held} at a known value (take it out of free:)"]
    if plant_has_current and "i" not in outputs and any(
            {"R_a", "M_f"} & set(g["names"]) for g in groups):
        steps.append("log the motor current (an output i) to separate the motor's parameters")
    steps.append("or add a log that excites them (design-experiment); `force=True` fits anyway")
    return "; ".join(steps)


def unit_hint(measured: np.ndarray, simulated: np.ndarray, unit: str | None, floor: float) -> tuple[str, float] | None:
    """What a column read wrongly would look like: the measured values in another unit of the
    same kind, with the sign flipped, or moved by a half or whole turn, each tried against the
    simulation at the start values. Returns (what, the RMS in noise floors it then replays
    at) for the best reading that replays at least HINT times better, else None."""
    rms = float(np.sqrt(np.mean((simulated - measured) ** 2)))
    best = None
    for what, values in _readings(measured, unit):
        found = float(np.sqrt(np.mean((simulated - values) ** 2)))
        if found * HINT <= rms and (best is None or found < best[1]):
            best = (what, found)
    return None if best is None or floor <= 0 else (best[0], best[1] / floor)


HINT = 5.0   # a reading of a column that replays this many times better is named


def _readings(measured: np.ndarray, unit: str | None) -> list[tuple[str, np.ndarray]]:
    """Other readings of a column: another unit of its kind, the sign flipped, a turn away."""
    from furuta_cosim.identify.columns import UNITS

    kinds = (("rad", "deg", "rev"), ("rad/s", "deg/s", "rpm"), ("A", "mA"), ("V",))
    same = next((k for k in kinds if unit in k), ())
    found = [(f"in {other} (not {unit})", measured * UNITS[other] / UNITS[unit]) for other in same if other != unit]
    found.append(("with its sign flipped", -measured))
    if unit in ("rad", "deg", "rev"):
        for turns in (0.5, -0.5, 1.0, -1.0):
            shift = turns * 2 * math.pi
            found.append((f"moved by {turns:+g} turn ({shift:+.4g} rad: where is its zero?)", measured + shift))
    return found


def loop_hint(experiment) -> dict | None:
    """For a log with a loop: how far its logged command is from the one the loop computes from
    the logged data (identify/replay.py rebuilt_command), and, when they differ, the other
    reading of one output column that rebuilds it :data:`HINT` times better. None without a
    loop or a logged voltage; ``hint`` None when nothing reads better."""
    from furuta_cosim.identify.replay import rebuilt_command

    rebuilt = rebuilt_command(experiment)
    if rebuilt is None:
        return None
    logged = experiment.input_at("V")
    scale = max(float(np.sqrt(np.mean(logged ** 2))), 1e-9)
    rms = float(np.sqrt(np.mean((rebuilt - logged) ** 2)))
    found = {"experiment": experiment.name, "file": str(experiment.path), "rms": rms, "command_rms": scale,
             "hint": None}
    if rms <= 1e-6 * scale:
        return found
    best = None
    for name, m in experiment.outputs.items():
        for what, values in _readings(m.values, experiment.units.get(name)):
            other = rebuilt_command(experiment, {name: values})
            error = float(np.sqrt(np.mean((other - logged) ** 2)))
            if error * HINT <= rms and (best is None or error < best["rms"]):
                best = {"output": name, "column": m.column, "reading": what, "rms": error}
    found["hint"] = best
    return found


def loop_line(entry: dict) -> str:
    """A loop whose command does not rebuild, as a line naming the column to check."""
    line = (f"{entry['experiment']}: the loop's command rebuilt from the logged data is {entry['rms']:.3g} V RMS "
            f"from the logged one ({entry['command_rms']:.3g} V RMS)")
    hint = entry["hint"]
    if hint:
        what = "" if hint["column"] == hint["output"] else f" (the output {hint['output']})"
        line += (f"; with its column {hint['column']!r}{what} read {hint['reading']} it is "
                 f"{hint['rms']:.3g} V: check the unit, offset and sign of that column")
    return line


def far_outputs(before: dict, floors_of) -> list[tuple[str, str, float]]:
    """(experiment, output, floors) of each output whose start replay is beyond FAR floors;
    ``before``: experiment -> output -> comparison; ``floors_of(c)``: (floor, what)."""
    found = []
    for name, outputs in before.items():
        for output, c in outputs.items():
            floor, _ = floors_of(c)
            ratio = c["rms"] / floor if floor > 0 else math.inf
            if ratio > FAR:
                found.append((name, output, ratio))
    return found


def wrong_loop(experiment) -> str | None:
    """One line when a log's stated loop does not rebuild its logged command (beyond
    :data:`~furuta_cosim.identify.mismatch.MISMATCH` of its RMS), else None (no loop, or no logged command): the loop named, the
    first sample where they part, and the cause measured: a column read another way that
    rebuilds it (:func:`loop_hint`), else a factor, the sign or a shift
    (identify/mismatch.py :func:`cause`), else another loop than the one stated."""
    from furuta_cosim.identify.mismatch import MAX_SHIFT, MISMATCH, apart, cause, first_apart, rms
    from furuta_cosim.identify.replay import rebuilt_command

    rebuilt = rebuilt_command(experiment)
    if rebuilt is None:
        return None
    logged = np.asarray(experiment.input_at("V"), dtype=float)
    off = apart(rebuilt, logged)
    if off <= MISMATCH:
        return None
    k = first_apart(rebuilt, logged)
    line = (f"{experiment.path}: loop: the command {experiment.loop.describe()} computes from the logged data is "
            f"{rms(rebuilt - logged):.3g} V RMS from the logged one ({rms(logged):.3g} V RMS: {off:.0%} of it, at "
            f"most {MISMATCH:.0%}), from t = {experiment.t[k]:g} s (logged {logged[k]:.4g} V, rebuilt "
            f"{rebuilt[k]:.4g} V)")
    hint = loop_hint(experiment)
    hint = hint["hint"] if hint else None
    if hint is not None and hint["rms"] <= MISMATCH * rms(logged):
        what = "" if hint["column"] == hint["output"] else f" (the output {hint['output']})"
        return (line + f": its column {hint['column']!r}{what} read {hint['reading']} rebuilds it to "
                f"{hint['rms']:.3g} V: check the unit, offset and sign of that column")
    words = cause(rebuilt, logged, experiment.period)
    if words:
        return line + ": " + words
    return (line + ": not a factor, the sign or a shift of up to "
            f"{MAX_SHIFT} samples: another loop than the one that ran (its controller or law, its gains, "
            "the reference it followed, its rate filter)")
