"""Whether a fit can be trusted, judged before its plant file is written.

A fit is trusted when it reproduces its data, is better than where it started and says
something physical:

- every output of every fitted and held-out log replays within ``tolerance`` noise floors
  RMS (the floor: the encoder's quantum for an angle that states one, else the stated or
  estimated noise's standard deviation);
- no output of a fitted or held-out log replays worse than at the start values (by more than
  :data:`WORSE`, 5 %, and more than :data:`WORSE_FLOORS`, half its noise floor): a
  fit that trades one output for another, or follows a wrong start state away from the
  plant, is not a better plant whatever the tolerance (a fit that replays at 19.7 floors
  where the start values replayed at 7 passes the tolerance alone); an output already at its
  noise may move within it;
- no start rate a balancing log states (a number, or the slope of its first counts) is more
  than :data:`STATED_START` standard deviations from what the log's smoother (identify/
  estimate.py), at the fitted values, puts it at: a window cut mid-run that keeps the run's
  start rates of 0 was trusted on one of ten synthetic logs with its values out of their
  intervals, its stated rates 31.8 standard deviations off; whole synthetic logs stated at
  rest read 2.7 to 5.6 (their pendulum has fallen for 4 ms at the first row, and the smoother
  is biased by up to 2); windows cut mid-run 9 to 35. At start values 20 to 60 % off the
  smoother can be tens away, so this is judged after the fit, not before;
- the fit ran to its end (not stopped by its spec's ``max_simulations``);
- no 95 % interval of a plant parameter reaches across a strict physical bound (a
  resistance or an inertia at or below 0): the data do not tell that parameter; nor, for a
  parameter that may be 0 (a friction), reaches both below 0 and above :data:`FAR_ABOVE` times
  its start (a Tc0 3760 times the thesis value with [-200, 200] was trusted by a note).

A reason is first what points at its cause: in a fit that is not trusted, an output whose
replay at the start values was already hundreds of noise floors off (identify/precheck.py FAR)
and whose column, read in another unit, with its sign flipped or a turn away, would replay far
better, is that column to check before anything about the fit; one far off without such a
reading comes last (a fit that starts that far and ends within the tolerance is fine: a start
30 % off moves an arm by radians over seconds).

Each parameter's own verdict says what it rests on (``rests_on``): its profile (identify/
profile.py), or, not profiled, its sandwich interval, which calls it identifiable only when
the interval stays inside the fit's bounds and its physical range and, for a plant parameter,
does not reach 0.

``identify`` prints the verdict's one line last, exits non-zero when the fit is not trusted
and then writes its plant file with a ``rejected`` key that every ``--plant`` refuses;
``identify --accept`` writes it as a plant all the same, the verdict in its provenance.
"""

from __future__ import annotations

import math

TOLERANCE = 20.0   # noise floors (quanta, or noise standard deviations) of replay RMS, at most
WORSE = 0.05       # an output replaying this fraction worse than at the start values is not a better fit
FAR_ABOVE = 10.0     # a friction's interval below 0 and this many times its start above: not told
WORSE_FLOORS = 0.5   # ... and by this many noise floors (within the encoder's resolution, outputs trade freely)
STATED_START = 10.0  # standard deviations a stated start rate may be from the smoother's (whole logs: up to 5.6)

_UNITS = {"theta0": "rad", "theta1": "rad", "i": "A", "dtheta0": "rad/s", "dtheta1": "rad/s"}


def floor_of(comparison: dict) -> tuple[float, str]:
    """(the noise floor, what it is) of one output's comparison (identify/replay.py compare)."""
    if comparison.get("quantum"):
        return float(comparison["quantum"]), "the encoder's quantum"
    if comparison.get("chatter"):   # identify/replay.py chatter: a loop closed on counts
        return (math.hypot(float(comparison["sigma"]), float(comparison["chatter"])),
                f"the stated noise and the command's chatter that the encoders' rounding drives "
                f"({comparison['chatter']:.3g} RMS between two replays half a count apart)")
    where = comparison.get("sigma_from", "")
    return float(comparison["sigma"]), ("the noise estimated from the data" if where == "estimated"
                                        else "the stated noise")


def judge(document: dict, ranges: dict, tolerance: float = TOLERANCE) -> dict:
    """The verdict on a fit.json ``document``: ``trusted``, the ``reasons`` it is not (each
    with its next step), per output the RMS in noise floors, and ``notes`` that do not count
    against it. The default ``judge`` of identify's pipeline (identify/pipeline.py).

    Parameters
    ----------
    document : dict
        A fit.json document (its replays, held-out scores, parameters and intervals).
    ranges : dict
        Each parameter's physical range (identify/fit.py physical_ranges).
    tolerance : float
        The largest replay RMS that is trusted, in noise floors (the spec's ``tolerance``).
    """
    reasons, notes, outputs = [], [], {}
    for kind in ("experiments", "validation"):
        for (name, output), c in by_log(document, kind).items():
            floor, what = floor_of(c)
            ratio = c["rms"] / floor if floor > 0 else math.inf
            entry = outputs.setdefault(name, {})[output] = {"rms": c["rms"], "floor": floor, "floors": ratio}
            segments = c.get("segments")
            if segments:
                entry["segments"] = dict(segments, median_floors=segments["median"] / floor,
                                         worst_floors=segments["worst"] / floor)
            held = " (held out)" if kind == "validation" else ""
            unit = _UNITS.get(output, "")
            if not ratio <= tolerance:
                over = (f" over its {segments['count']} segments (the median segment "
                        f"{segments['median'] / floor:.3g} floors, the worst {segments['worst'] / floor:.3g}: "
                        f"{', '.join(segments['worst_of'])})" if segments else "")
                reasons.append(
                    f"{name}{held} {output}: replay RMS {c['rms']:.4g} {unit}{over} is {ratio:.3g} times its "
                    f"noise floor ({floor:.3g} {unit}, {what}); at most {tolerance:g} is accepted".replace("  ", " "))
    for name, found in (document.get("whole") or {}).items():
        # a log fitted in segments, run through as `replay` runs it
        if "failure" in found:
            reasons.append(f"{name}: replayed whole as `replay` runs it, its simulation fails "
                           f"({found['failure']}): its segments fit, the log does not")
            continue
        for output, c in found.items():
            floor, what = floor_of(c)
            ratio = c["rms"] / floor if floor > 0 else math.inf
            outputs.setdefault(f"{name} (whole)", {})[output] = {"rms": c["rms"], "floor": floor, "floors": ratio}
            if not ratio <= tolerance:
                unit = _UNITS.get(output, "")
                reasons.append(f"{name} {output}: replayed whole as `replay` runs it, RMS {c['rms']:.4g} {unit} is "
                               f"{ratio:.3g} times its noise floor ({floor:.3g} {unit}, {what}); its segments fit, "
                               "the log does not (a log the plant cannot run through open loop, a balancing one, is replayed "
                               "through its loop: give the experiment its `loop` key)".replace("  ", " "))
    reasons += _worse(document)
    for name, rates in (document.get("stated_starts") or {}).items():
        for rate, c in rates.items():
            off = abs(c["stated"] - c["estimate"]) / c["sigma"] if c["sigma"] > 0 else math.inf
            if off > STATED_START:
                reasons.append(
                    f"{name}: its stated start {rate} = {c['stated']:.4g} rad/s is {off:.3g} standard deviations "
                    f"from what its log shows at t = {c['at']:g} s ({c['estimate']:.4g} +- {c['sigma']:.2g} rad/s, "
                    f"its smoother at the fitted values): the fit followed a start the rig was not in; free it "
                    f"(start: {{{rate}: {{free: [lo, hi]}}}})")
    if reasons:  # a column that reads far better another way is the first thing to check
        from furuta_cosim.identify.precheck import loop_line

        far = (document.get("precheck") or {}).get("far") or []
        reasons[:0] = [loop_line(e) for e in far if e.get("loop")] + [
            far_line(e) for e in far if e.get("hint") and not e.get("loop")]
        reasons += [far_line(e) + ": check the unit, offset and sign of its column, and whether it "
                    "replays as the rig ran (its loop)" for e in far if not e.get("hint")]
    message = document.get("message", "")
    if message.startswith("stopped"):
        reasons.append(f"the fit {message}: it had not converged (raise max_simulations in the spec, "
                       "or start nearer)")
    for name, p in document["parameters"].items():
        if "." in name or p.get("interval") is None:
            continue
        if str(p.get("rests_on", "")).startswith("its profile") and not p.get("identifiable"):
            continue   # the profile's verdict says it; tune --from-fit holds it
        low, _, strict = ranges.get(name, (None, None, False))
        lo, hi = p["interval"]
        if low is None or lo is None:
            continue
        if strict and lo <= low:
            reasons.append(f"{name}: its 95 % interval [{lo:.4g}, {hi:.4g}] reaches {low:g} and below, "
                           f"where no {name} is: these data do not tell it")
        elif not strict and lo < low and p.get("start") and hi > FAR_ABOVE * abs(p["start"]):
            # below 0 and ten times its start's scale above: not a value the data tell
            reasons.append(f"{name}: its 95 % interval [{lo:.4g}, {hi:.4g}] reaches below {low:g} and above "
                           f"{FAR_ABOVE:g} times its start ({p['start']:.4g}): these data do not tell it")
        elif not strict and lo < low:
            notes.append(f"{name}: its 95 % interval [{lo:.4g}, {hi:.4g}] reaches below {low:g}: the data "
                         f"are consistent with no {name} at all")
    step = _next_step(reasons, document)
    return {"trusted": not reasons, "tolerance": tolerance, "reasons": reasons, "notes": notes,
            "outputs": outputs, "next": step}


def by_log(document: dict, kind: str) -> dict:
    """``{(log, output): comparison}`` of a fit.json section (``experiments`` or
    ``validation``), the segments of a log fitted by multiple shooting (``log@k``) as one log:
    the RMS over all their samples, and ``segments`` (their count, median and worst RMS, the
    three worst by name)."""
    samples = {name: d.get("samples", 1) for name, d in document.get("data", {}).items()}
    groups: dict = {}
    for name, found in document[kind].items():
        log = name.split("@")[0] if "@" in name else name
        for output, c in found.items():
            groups.setdefault((log, output), []).append((name, c))
    found = {}
    for (log, output), members in groups.items():
        if len(members) == 1 and "@" not in members[0][0]:
            found[(log, output)] = members[0][1]
            continue
        weights = [samples.get(name, 1) for name, _ in members]
        pooled = math.sqrt(sum(w * c["rms"] ** 2 for w, (_, c) in zip(weights, members)) / sum(weights))
        ordered = sorted(members, key=lambda m: m[1]["rms"])
        rms = [c["rms"] for _, c in ordered]
        middle = len(rms) // 2
        median = rms[middle] if len(rms) % 2 else 0.5 * (rms[middle - 1] + rms[middle])
        kept = {k: members[0][1][k] for k in ("sigma", "sigma_from", "quantum", "chatter") if k in members[0][1]}
        found[(log, output)] = dict(kept, rms=pooled, segments={
            "count": len(members), "median": median, "worst": rms[-1],
            "worst_of": [name for name, _ in reversed(ordered[-3:])]})
    return found


def _worse(document: dict) -> list[str]:
    """A reason per output of a log that replays worse than at the start values (module
    docstring); the segments of a log fitted by multiple shooting (``log@k``) as one log: each
    segment trades with the others, the log as a whole must not be worse."""
    whole: dict = {}
    samples = {name: d.get("samples", 1) for name, d in document.get("data", {}).items()}
    for kind in ("experiments", "validation"):
        for name, found in document[kind].items():
            log = name.split("@")[0] if "@" in name else name
            for output, c in found.items():
                start = document.get("at_start", {}).get(name, {}).get(output, {}).get("rms")
                if start is None:
                    continue
                n = samples.get(name, 1)
                entry = whole.setdefault((log, kind, output), {"n": 0, "fit": 0.0, "start": 0.0, "c": c})
                entry["n"] += n
                entry["fit"] += n * c["rms"] ** 2
                entry["start"] += n * start ** 2
    reasons = []
    for (log, kind, output), e in whole.items():
        fit, start = math.sqrt(e["fit"] / e["n"]), math.sqrt(e["start"] / e["n"])
        floor, _ = floor_of(e["c"])
        if not fit <= max((1.0 + WORSE) * start, start + WORSE_FLOORS * floor):
            held = " (held out)" if kind == "validation" else ""
            unit = _UNITS.get(output, "")
            reasons.append(f"{log}{held} {output}: replays worse than at the start values (RMS {start:.4g} -> "
                           f"{fit:.4g} {unit}, {100 * (fit / start - 1):+.0f} %, {(fit - start) / floor:+.2g} noise "
                           "floors): the fit is not a better plant".replace("  ", " ").replace(" ,", ","))
    return reasons


def read_intervals(document: dict, ranges: dict, why: str = "not profiled") -> None:
    """The verdict of each parameter fit.json holds no profile for, from its sandwich interval
    (in place): ``identifiable`` only when the interval stays inside the fit's bounds and the
    physical range and, for a plant parameter, does not reach 0; ``why`` says why it rests on
    the sandwich (not profiled, the fit did not converge)."""
    for name, p in document["parameters"].items():
        if str(p.get("rests_on", "")).startswith("its profile") or p.get("interval") is None:
            continue
        lo, hi = p["interval"]
        bound_lo, bound_hi = p["bounds"]
        # an initial state, a sensor's bias or an input's delay is never profiled
        reason = why if "." not in name else "only plant parameters are profiled"
        low, high, strict = ranges.get(name, (None, None, False)) if "." not in name else (None, None, False)
        wrong = []
        if "." not in name and lo <= 0.0 <= hi:
            wrong.append("reaches 0")
        elif low is not None and (lo <= low if strict else lo < low):
            wrong.append(f"reaches {low:g}, where no {name} is")
        if lo <= bound_lo or hi >= bound_hi:
            wrong.append(f"reaches the fit's bound{'s' if lo <= bound_lo and hi >= bound_hi else ''} "
                         f"({bound_lo:g}, {bound_hi:g})")
        if high is not None and hi > high:
            wrong.append(f"reaches above {high:g}")
        p["identifiable"] = not wrong
        p["rests_on"] = f"its sandwich interval ({reason})" + (
            ", widened by its reach" if p.get("reach") else "")
        p["verdict"] = (f"identifiable by its sandwich interval ({reason})" if not wrong else
                        f"practically not identifiable: its sandwich interval [{lo:.4g}, {hi:.4g}] "
                        f"{' and '.join(wrong)} ({reason})")


def _next_step(reasons: list[str], document: dict) -> str:
    if not reasons:
        return ""
    if any("check the unit, offset and sign of that column" in r for r in reasons):
        return ("read that column as named (its unit:, the sign, or its offset:) and fit again; the plant's "
                "own units are rad, rad/s, A and V, the pendulum 0 upright")
    if any("stated start" in r for r in reasons):
        return ("free that log's start rates (start: {dtheta0: {free: [lo, hi]}, dtheta1: ...}); its intervals are "
                "then widened by what its smoother knows of them")
    if any("worse than at the start" in r for r in reasons) and not any("replay RMS" in r for r in reasons):
        return ("check each log's start state (a window cut mid-motion needs its rates and current: "
                "start: data) and the loop; or hold the parameters the data cannot tell")
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


def far_line(entry: dict) -> str:
    """One far column as a line: where it starts, and the reading that would fit it if any."""
    line = (f"{entry['experiment']} {entry['output']}: at the start values it replays {entry['floors']:.3g} "
            f"noise floors off before anything is fitted")
    if entry["hint"]:
        line += (f"; its column {entry['column']!r} read {entry['hint']['reading']} would replay at "
                 f"{entry['hint']['floors']:.3g}: check the unit, offset and sign of that column")
    return line
