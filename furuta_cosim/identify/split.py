"""Parts of a log: a held-out tail to validate on, and the short segments of multiple shooting.

Each part starts from the state measured where it begins: the angles and the current as
logged, the rates from a local quadratic through the angles around that sample (a least-
squares fit over +-RATE_WINDOW seconds), unless the log's own rates are outputs.

    fitted, held = split(experiment, 0.25)           # the last quarter held out
    parts = segments(experiment, 0.5)                # 0.5 s segments, open loop

Multiple shooting (Bock and Plitt 1984; for identification, e.g. van Domselaar and Hemker
1975) fits a plant that cannot be replayed over a whole log open loop (an unstable one under
a controller that is not known) on short segments, each restarted from the measured state.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from furuta_cosim.config import Frozen
from furuta_cosim.identify.clocks import Delayed, held_means, shifted

RATE_WINDOW = 0.025     # s on each side of a sample: the quadratic that gives a rate
_RATES = {"theta0": "dtheta0", "theta1": "dtheta1"}


def measured_state(experiment, k: int) -> dict[str, float]:
    """The state at sample ``k`` as the log measures it (module docstring)."""
    state = {}
    h = experiment.period
    reach = max(2, int(round(RATE_WINDOW / h)))
    lo, hi = max(0, k - reach), min(experiment.samples, k + reach + 1)
    for angle, rate in _RATES.items():
        if angle not in experiment.outputs:
            continue
        y = experiment.outputs[angle].values
        state[angle] = float(y[k])
        if rate in experiment.outputs:
            state[rate] = float(experiment.outputs[rate].values[k])
        elif hi - lo >= 3:
            tau = experiment.t[lo:hi] - experiment.t[k]
            c = np.polyfit(tau, y[lo:hi], 2)
            state[rate] = float(c[1])
    if "i" in experiment.outputs:
        state["i"] = float(experiment.outputs["i"].values[k])
    return state


def delayed(experiment):
    """A closed-loop log as an open-loop one: its loop dropped and its logged voltage (what
    the controller wrote) delayed by the loop's ``delay`` to what the motor got, each sample
    the average of the commands over it (0 before the log)."""
    loop = experiment.loop
    if loop is None:
        return experiment
    inputs = dict(experiment.inputs)
    timed = experiment.late is not None or loop.compute is not None or experiment.jittered
    delays = dict(experiment.delays)
    if "V" in inputs and not np.isscalar(inputs["V"]) and loop.free_delay is not None:
        # the delay is fitted: the logged command kept, delayed by the fit's value in each run
        written = np.asarray(inputs["V"], dtype=float)
        if loop.voltage is not None:
            written = np.clip(written, -loop.voltage, loop.voltage)
        inputs["V"] = written
        m = int(math.ceil(loop.free_delay.bounds[1] / experiment.period)) + 1
        logged = loop.lead_in.command if loop.lead_in is not None and loop.lead_in.command is not None else np.zeros(0)
        before = np.concatenate([np.zeros(max(m - len(logged), 0)), logged[max(len(logged) - m, 0):]])
        writes = (experiment.read_at + (loop.compute if loop.compute is not None else 0.0)) if timed else None
        delays["V"] = Delayed(loop.free_delay, before, key="loop.delay",
                              timed=None if writes is None else (writes, written, experiment.read_at, 0))
    elif "V" in inputs and (loop.delay > 0.0 or timed) and not np.isscalar(inputs["V"]):
        written = np.asarray(inputs["V"], dtype=float)
        if loop.voltage is not None:
            written = np.clip(written, -loop.voltage, loop.voltage)
        if timed:   # each command at the motor from its write plus the delay, averaged over each sample
            read = experiment.read_at
            at = read + (loop.compute if loop.compute is not None else 0.0) + loop.delay
            inputs["V"] = held_means(np.maximum.accumulate(at), written, read)
        else:
            inputs["V"] = shifted(written, loop.delay / experiment.period)
    return replace(experiment, inputs=Frozen(inputs), loop=None, delays=Frozen(delays))


def part(experiment, first: int, last: int, name: str, open_loop: bool = False):
    """Samples ``first`` to ``last`` (exclusive) of ``experiment`` as an experiment named
    ``name`` that starts from the measured state (the whole log's own start when ``first`` is
    0); its outputs' sensor biases are the whole log's (``alias``). ``open_loop``: driven by
    the logged input, its loop dropped."""
    keep = slice(first, last)
    inputs = {k: v if np.isscalar(v) else v[keep] for k, v in experiment.inputs.items()}
    # the first part keeps the sensors' free biases (the whole log's unknowns), the others share them
    outputs = {k: replace(m, values=m.values[keep], bias=m.bias if first == 0 else None)
               for k, m in experiment.outputs.items()}
    start = dict(experiment.start) if first == 0 else {**{k: v for k, v in experiment.start.items()
                                                          if k not in ("theta0", "theta1", "dtheta0", "dtheta1", "i")},
                                                       **measured_state(experiment, first)}
    loop = (experiment.loop.cut(keep, experiment.lead_in_at(first))
            if experiment.loop is not None and not open_loop else None)
    # a fitted delay brings in the samples before the part: the log's own, within the window
    delays = {k: replace(d, before=np.concatenate([d.before, experiment.inputs[k]])[first:first + len(d.before)],
                         timed=None if d.timed is None else (*d.timed[:3], d.timed[3] + first))
              for k, d in experiment.delays.items()}
    return replace(experiment, name=name, t=experiment.t[keep], inputs=Frozen(inputs), delays=Frozen(delays),
                   outputs=Frozen(outputs), start=Frozen(start), loop=loop,
                   alias=experiment.alias or experiment.name,
                   late=None if experiment.late is None else experiment.late[keep])


def split(experiment, fraction: float):
    """(the first part, the last ``fraction`` of the window held out as ``<name>-held-out``)."""
    cut = int(round(experiment.samples * (1.0 - fraction)))
    cut = min(max(cut, 2), experiment.samples - 2)
    fitted = replace(experiment, t=experiment.t[:cut],
                     inputs=Frozen({k: v if np.isscalar(v) else v[:cut] for k, v in experiment.inputs.items()}),
                     outputs=Frozen({k: replace(m, values=m.values[:cut]) for k, m in experiment.outputs.items()}),
                     loop=None if experiment.loop is None else experiment.loop.cut(slice(None, cut)),
                     late=None if experiment.late is None else experiment.late[:cut])
    return fitted, part(experiment, cut, experiment.samples, f"{experiment.name}-held-out")


def segments(experiment, seconds: float) -> list:
    """``experiment`` cut into segments of ``seconds`` (the last one longer, not shorter),
    each from its measured state and driven by the logged input: ``<name>@1``, ...."""
    length = max(3, int(round(seconds / experiment.period)))
    count = max(1, experiment.samples // length)
    bounds = [k * length for k in range(count)] + [experiment.samples]
    experiment = delayed(experiment)
    return [part(experiment, a, b, f"{experiment.name}@{j + 1}", open_loop=True)
            for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]


def parts_of(spec, fraction: float = 0.0, extra=(), segmented: bool = True):
    """``spec`` as it is fitted: the last ``fraction`` of each fitted log held out (validated,
    never fitted), the experiments ``extra`` added to its validation, and each log with
    ``segments`` cut into them (multiple shooting) unless not ``segmented``."""
    fitted, held = [], []
    for experiment in spec.experiments:
        if fraction:
            first, last = split(experiment, fraction)
            fitted.append(first)
            held.append(last)
        else:
            fitted.append(experiment)

    def cut(experiments):
        return tuple(p for e in experiments for p in (segments(e, e.segments) if e.segments and segmented else [e]))

    experiments = cut(fitted)
    # the budget counts simulations: a log cut into n segments costs n a replay
    most = max(len(experiments) // max(len(fitted), 1), 1)
    return replace(spec, experiments=experiments, validation=cut(tuple(spec.validation) + tuple(held) + tuple(extra)),
                   max_simulations=spec.max_simulations * most)
