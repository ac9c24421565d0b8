"""Whether a fit can be trusted, judged before its plant file is written.

A fit is trusted when it reproduces its data and says something physical:

- every output of every fitted and held-out log replays within ``tolerance`` noise floors
  RMS (the floor: the encoder's quantum for an angle that states one, else the stated or
  estimated noise's standard deviation);
- the fit ran to its end (not stopped by its spec's ``max_simulations``);
- no 95 % interval of a plant parameter reaches across a strict physical bound (a
  resistance or an inertia at or below 0): the data do not tell that parameter.

``identify`` prints the verdict's one line last, exits non-zero when the fit is not trusted
and then writes its plant file with a ``rejected`` key that every ``--plant`` refuses;
``identify --accept`` writes it as a plant all the same, the verdict in its provenance.
"""

from __future__ import annotations

import math

TOLERANCE = 20.0   # noise floors (quanta, or noise standard deviations) of replay RMS, at most

_UNITS = {"theta0": "rad", "theta1": "rad", "i": "A", "dtheta0": "rad/s", "dtheta1": "rad/s"}


def floor_of(comparison: dict) -> tuple[float, str]:
    """(the noise floor, what it is) of one output's comparison (identify/replay.py compare)."""
    if comparison.get("quantum"):
        return float(comparison["quantum"]), "the encoder's quantum"
    where = comparison.get("sigma_from", "")
    return float(comparison["sigma"]), ("the noise estimated from the data" if where == "estimated"
                                        else "the stated noise")


def judge(document: dict, ranges: dict, tolerance: float = TOLERANCE) -> dict:
    """The verdict on a fit.json ``document``: ``trusted``, the ``reasons`` it is not (each
    with its next step), per output the RMS in noise floors, and ``notes`` that do not count
    against it. ``ranges``: each parameter's physical range (identify/fit.py physical_ranges)."""
    reasons, notes, outputs = [], [], {}
    for kind in ("experiments", "validation"):
        for name, found in document[kind].items():
            for output, c in found.items():
                floor, what = floor_of(c)
                ratio = c["rms"] / floor if floor > 0 else math.inf
                outputs.setdefault(name, {})[output] = {"rms": c["rms"], "floor": floor, "floors": ratio}
                if not ratio <= tolerance:
                    held = " (held out)" if kind == "validation" else ""
                    unit = _UNITS.get(output, "")
                    reasons.append(
                        f"{name}{held} {output}: replay RMS {c['rms']:.4g} {unit} is {ratio:.3g} times its "
                        f"noise floor ({floor:.3g} {unit}, {what}); at most {tolerance:g} is accepted".replace("  ", " "))
    message = document.get("message", "")
    if message.startswith("stopped"):
        reasons.append(f"the fit {message}: it had not converged (raise max_simulations in the spec, "
                       "or start nearer)")
    for name, p in document["parameters"].items():
        if "." in name or not p.get("identifiable", True) or p.get("interval") is None:
            continue
        low, _, strict = ranges.get(name, (None, None, False))
        lo, hi = p["interval"]
        if low is None or lo is None:
            continue
        if strict and lo <= low:
            reasons.append(f"{name}: its 95 % interval [{lo:.4g}, {hi:.4g}] reaches {low:g} and below, "
                           f"where no {name} is: these data do not tell it")
        elif not strict and lo < low:
            notes.append(f"{name}: its 95 % interval [{lo:.4g}, {hi:.4g}] reaches below {low:g}: the data "
                         f"are consistent with no {name} at all")
    step = _next_step(reasons, document)
    return {"trusted": not reasons, "tolerance": tolerance, "reasons": reasons, "notes": notes,
            "outputs": outputs, "next": step}


def _next_step(reasons: list[str], document: dict) -> str:
    if not reasons:
        return ""
    if any("replay RMS" in r for r in reasons):
        closed = document.get("loops", {})
        if any(v == "open" for v in closed.values()) or not closed:
            return ("check each column's unit and offset; a log recorded under a controller needs "
                    "that controller in its experiment's loop: (or segments:) to be replayed")
        return "check each column's unit and offset, the loop's delay and limit, and which parameters are free"
    if any("interval" in r for r in reasons):
        return "hold that parameter at a known value, or add a log that excites it (design-experiment)"
    return "raise max_simulations, or resume with a larger budget"


def line(verdict: dict) -> str:
    """The verdict as the last line identify prints."""
    if verdict["trusted"]:
        worst = max((o["floors"] for found in verdict["outputs"].values() for o in found.values()), default=0.0)
        return (f"verdict: trusted: every output replays within {worst:.3g} noise floors RMS "
                f"(at most {verdict['tolerance']:g})")
    return (f"verdict: NOT trusted: {verdict['reasons'][0]}"
            + (f" (and {len(verdict['reasons']) - 1} more reason(s), in fit.json)" if len(verdict["reasons"]) > 1 else "")
            + f"; next: {verdict['next']}")
