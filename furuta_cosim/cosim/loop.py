"""The sample loop, generated once per configuration.

Which signals are picked and noisy, whether an estimator, an actuator limit, disturbances,
several communication steps per sample or a controller state are present: all decided
here, once, instead of at each of the thousands of samples. Every configuration is tested
against a plain loop written by hand (tests/test_loop.py).
"""

from __future__ import annotations

from functools import lru_cache

from furuta_cosim.cosim.generated import compile_source

# the loop's arguments, in order
ARGUMENTS = ("step", "control", "state", "correct", "predict", "rbar", "measurement",
             "disturbance", "h", "first", "last", "values", "limit", "rows", "inputs",
             "commands", "states", "estimates")


def loop_source(n_sources: int, pick: tuple | None, noisy: tuple, estimator: bool,
                record_state: bool, limited: bool, n_disturbances: int, substeps: int) -> str:
    """The loop over samples ``first..last-1`` as Python source; it returns the last outputs
    read, from which the next chunk goes on.

    ``pick``: the positions of the fed-back signals among the outputs read (None: all, in
    order); ``noisy``: the positions among those that get measurement noise.
    """
    signal = [f"values[{i}]" for i in (pick if pick is not None else range(n_sources))]
    for position, j in enumerate(noisy):
        signal[j] += f" + m[{position}]"
    body = []
    if noisy:
        body.append("m = measurement[k]")
    body.append(f"s = [{', '.join(signal)}]" if pick is not None or noisy else "s = values")
    if estimator:
        body += ["s = correct(s)", "estimates(s)"]
    if record_state:
        body.append("states(state())")
    body.append("c = control(s, rbar[k])")
    if limited:
        body += ["u = c if -limit <= c <= limit else (limit if c > 0 else -limit)", "commands(c)"]
    else:
        body.append("u = c")
    if estimator:
        body.append("predict(u)")
    body += ["rows(values)", "inputs(u)"]
    if n_disturbances:
        body.append("d = disturbance[k]")
    applied = "[u" + "".join(f", d[{j}]" for j in range(n_disturbances)) + "]"
    if substeps == 1:
        body.append(f"values = step({applied}, h)")
    else:
        body += [f"applied = {applied}", f"for _ in range({substeps}):", "    values = step(applied, h)"]
    lines = [f"def loop({', '.join(ARGUMENTS)}):", "    for k in range(first, last):"]
    lines += [f"        {line}" for line in body]
    lines.append("    return values")
    return "\n".join(lines) + "\n"


@lru_cache(maxsize=None)
def loop_for(*configuration):
    """The compiled loop of one configuration (the arguments of :func:`loop_source`)."""
    return compile_source(loop_source(*configuration), "loop", "loop")
