"""A foreign loop in its own words: the controller another lab's logger ran, as its code wrote it.

A log recorded under someone else's controller is replayed with that controller closed
again (identify/replay.py). Their controller is rarely our state feedback: a PD on the errors
to two references, with a filtered derivative discretized by backward Euler, say. An
experiment's ``loop.law`` states it in the logger's own terms, and it is kept as what every
such law is, a discrete linear system from its inputs (the references it read from the log
and the measurements it saw) to its command:

    x[k+1] = A x[k] + B v[k],    u[k] = C x[k] + D v[k]

``v`` and ``u`` are in the log's own units, signs and offsets: a measured output as its
column holds it (before the experiment's unit, scale and offset bring it to SI), a reference
as its column holds it, the command as the column of the input ``V`` holds it. Two forms:

    law:                               # PID terms, each on the error to its reference
      terms:
        theta0: {reference: arm_ref, kp: 2.0, kd: 0.1}
        theta1: {reference: 0.0, kp: -30.0, kd: -2.5}
      error: reference - measurement   # or measurement - reference
      derivative: {on: error, cutoff: 50, method: backward}   # rad/s; backward, forward, bilinear
      output: u_pd                     # the controller's own logged output: checked at load

    law:                               # any discrete linear law, at the log's period
      A: [[...]]  B: [[...]]  C: [[...]]  D: [[...]]
      inputs: [arm_ref, theta0, theta1]   # an output's name: as measured; else a log column

The state-feedback form (``K``, ``F``) stays in experiment.py; python-control discretizes
the derivative and integral terms (``sample_system``).

A log whose clock jitters (a ROS 2 controller: 2 ms nominal, 1.5 to 4.8 ms apart) ran its
terms over the intervals that actually passed, as ros2_control hands a controller the time
since its last update: there each term is stepped over the logged interval ending at its
sample, its state kept in coordinates that mean the same at every interval (the filtered
signal and the last input: :func:`_block`), so a change of interval does not move it. On a
uniform clock that form and python-control's agree to rounding (tests/test_laws.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from furuta_cosim.config import Checker, Frozen, excerpt
from furuta_cosim.defaults import MAX_MAGNITUDE

# the discretizations a logger's code uses, by the names engineers call them
METHODS = {"backward": "backward_diff", "forward": "euler", "bilinear": "bilinear"}
ERRORS = ("reference - measurement", "measurement - reference")
MEASURED = ("theta0", "theta1", "i")      # what a law may see of the plant
AGREE = 0.01                              # of the logged output's range: a law that rebuilds it
MAX_ORDER = 50                            # a law's states at most
TERMS_KEYS = ("terms", "error", "derivative", "integral", "output")
STATE_SPACE_KEYS = ("A", "B", "C", "D", "inputs", "output")
_TERM_KEYS = ("reference", "kp", "ki", "kd")
_DERIVATIVE_KEYS = ("on", "cutoff", "method")
_INTEGRAL_KEYS = ("method",)


@dataclass(frozen=True)
class LinearLaw:
    """A discrete linear law over ``sources`` (measured outputs, or columns of the log read
    over the window into ``columns``), in the log's own units: ``measured[j]`` is the
    (factor, offset) that brings source j's column to SI (None for a column), ``command`` the
    same for the command. ``x0``: its state at the window's start."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    sources: tuple
    measured: tuple
    columns: Mapping[str, np.ndarray]
    command: tuple
    words: str
    x0: np.ndarray | None = None
    logged: np.ndarray | None = None   # the window's sources as the log holds them (rows)
    # a terms law on a clock that jitters: its blocks (source, gain, kind, method, cutoff), stepped
    # over ``dt`` (s: the interval ending at each sample of the window); None: at the period
    varying: tuple | None = None
    dt: np.ndarray | None = None

    def matrices(self, dt: float) -> tuple:
        """(A, B, C, D) of a varying law over an interval of ``dt`` s."""
        return _assembled_at(self.varying, len(self.sources), dt)

    def stepper(self):
        """A function (k, {output: SI value}) -> the command in volts, from ``x0``; one per run."""
        x = np.zeros(self.A.shape[0]) if self.x0 is None else self.x0.copy()
        factor, offset = self.command
        A, B, C, D = self.A, self.B, self.C[0], self.D[0]
        lookup = [(s, conversion) for s, conversion in zip(self.sources, self.measured)]
        dt = self.dt if self.varying is not None else None

        def step(k: int, seen: Mapping[str, float]) -> float:
            nonlocal x
            v = np.array([seen[s] / c[0] - c[1] if c is not None else self.columns[s][k]
                          for s, c in lookup])
            if dt is None:
                u = float(C @ x + D @ v)
                x = A @ x + B @ v
            else:
                a, b, c, d = self.matrices(float(dt[k]))
                u = float(c[0] @ x + d[0] @ v)
                x = a @ x + b @ v
            return (u + offset) * factor
        return step

    def cut(self, keep: slice) -> "LinearLaw":
        """The law over the samples ``keep`` of its window, its state at their first the one
        it reaches on the logged samples before them."""
        from dataclasses import replace

        first = keep.start or 0
        dt = None if self.dt is None else self.dt[:first]
        x0 = self.x0 if first == 0 or self.logged is None else self.respond(self.logged[:first], self.x0, dt)[1]
        return replace(self, columns=Frozen({k: v[keep] for k, v in self.columns.items()}), x0=x0,
                       logged=None if self.logged is None else self.logged[keep],
                       dt=None if self.dt is None else self.dt[keep])

    def respond(self, v: np.ndarray, x0: np.ndarray | None = None,
                dt: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(the command in the log's units, the final state) over rows of ``v`` (sources in
        the log's units); ``dt``: each row's interval (s), for a varying law."""
        x = np.zeros(self.A.shape[0]) if x0 is None else x0.copy()
        u = np.empty(len(v))
        A, B, C, D = self.A, self.B, self.C[0], self.D[0]
        for k, row in enumerate(v):
            if self.varying is not None and dt is not None:
                A, B, C, D = self.matrices(float(dt[k]))
                C, D = C[0], D[0]
            u[k] = C @ x + D @ row
            x = A @ x + B @ row
        return u, x


def is_linear(entry) -> bool:
    """Whether ``loop.law`` is in this module's forms (terms, or a state space)."""
    return isinstance(entry, dict) and ("terms" in entry or "A" in entry or "D" in entry)


def read_law(check: Checker, entry, period: float, table, columns, keep: slice,
             outputs: Mapping[str, tuple], command: tuple, voltage: float | None,
             feedforward: np.ndarray | None, csv_name: str, lines,
             times: np.ndarray | None = None) -> LinearLaw | None:
    """``loop.law`` in its terms or state-space form, checked, with its state at the
    window's start (run over the log's rows before the window) and, when it names
    ``output``, checked against that column over the window. ``outputs``: the experiment's
    measured outputs as (column, factor, offset), SI = (column + offset) * factor;
    ``command``: the same (factor, offset) for the command; ``times``: the log's time column
    where its clock jitters (a terms law then steps over each logged interval; the first row's
    is the nominal ``period``), else None."""
    state_space = "terms" not in entry
    keys = STATE_SPACE_KEYS if state_space else TERMS_KEYS
    entry = check.mapping(entry, "loop.law", required=("A", "B", "C", "D", "inputs") if state_space
                          else ("terms",), optional=keys)
    if entry is None or any(k not in entry for k in (("A", "B", "C", "D", "inputs") if state_space else ("terms",))):
        return None
    conversions = {name: (factor, offset) for name, (_, factor, offset) in outputs.items()}
    built = (_state_space(check, entry, conversions, columns) if state_space
             else _terms(check, entry, period, conversions, columns))
    if built is None:
        return None
    A, B, C, D, sources, constants, words, recipe = built
    dt_all = None
    if times is not None and recipe is not None:   # each row's interval, the first's the period
        dt_all = np.concatenate([[period], np.diff(np.asarray(times, dtype=float))])
        A, B, C, D = _assembled_at(recipe, len(sources), period)
    else:
        recipe = None
    if A.shape[0] > MAX_ORDER:
        check.fail("loop.law.A", f"{A.shape[0]} states: at most {MAX_ORDER}")
        return None
    if not _stable(check, A, state_space, entry, period):
        return None
    whole = {}
    for s in sources:
        if s in constants:
            whole[s] = np.full(len(table[columns[0]]), constants[s])
        elif s in conversions:
            whole[s] = table[outputs[s][0]]
        else:
            whole[s] = table[s]
    law = LinearLaw(A, B, C, D, tuple(sources), tuple(conversions.get(s) for s in sources),
                    Frozen({s: whole[s][keep].copy() for s in sources if s not in conversions}),
                    command, words, logged=np.column_stack([whole[s][keep] for s in sources]),
                    varying=recipe, dt=None if dt_all is None else dt_all[keep].copy())
    # the state the law reached on the log's rows before the window (from the last row that
    # is not a number, a header's or a gap's): its filters do not restart where the window cuts
    first = keep.start or 0
    if first > 0:
        rows = np.column_stack([whole[s][:first] for s in sources])
        finite = np.all(np.isfinite(rows), axis=1)
        begin = int(len(finite) - np.argmin(finite[::-1])) if not finite.all() else 0
        steps = None if dt_all is None else np.concatenate([[period], dt_all[begin + 1:first]])
        _, x0 = law.respond(rows[begin:], dt=steps)
        from dataclasses import replace

        law = replace(law, x0=x0)
    if "output" in entry:
        name = check.string(entry["output"], "loop.law.output")
        if name is not None and name not in columns:
            check.fail("loop.law.output", f"{excerpt(name)} is not one of columns ({', '.join(columns)})")
        elif name is not None:
            _agrees(check, law, law.logged, table[name][keep], name, voltage, feedforward, csv_name, lines[keep],
                    period)
    return law


def _stable(check: Checker, A: np.ndarray, state_space: bool, entry: dict, period: float) -> bool:
    """A law whose own dynamics grow (a filter discretized unstably, an unstable A) is refused
    naming them: replayed, its output would grow without bound and the plant's integration
    diverge, which would blame the plant's step size instead."""
    if not A.size:
        return True
    radius = float(np.max(np.abs(np.linalg.eigvals(A))))
    if radius <= 1.0 + 1e-9:
        return True
    if state_space:
        check.fail("loop.law.A", f"its largest eigenvalue's modulus is {radius:.4g}, above 1: the law's state grows "
                                 "on its own, whatever it reads (a discrete A is stable inside the unit circle)")
    else:
        derivative = entry.get("derivative") if isinstance(entry.get("derivative"), dict) else {}
        method, cutoff = derivative.get("method", "backward"), derivative.get("cutoff")
        said = (f" ({method} at cutoff {cutoff:g} rad/s and period {period:g} s: w T = {cutoff * period:.3g}"
                + ("; forward Euler is stable for w T < 2 only" if method == "forward" else "") + ")"
                if isinstance(cutoff, (int, float)) and not isinstance(cutoff, bool) else "")
        check.fail("loop.law.derivative", f"the law's filter is unstable at the log's period{said}: its state grows "
                                          f"on its own (largest eigenvalue {radius:.4g}); use method backward or "
                                          "bilinear, or the cutoff the controller ran with")
    return False


def _terms(check: Checker, entry: dict, period: float, conversions, columns):
    """The PID terms as (A, B, C, D, sources, constant references, words)."""
    import control

    terms = check.mapping(entry["terms"], "loop.law.terms", optional=MEASURED)
    if not terms:
        if terms is not None:
            check.fail("loop.law.terms", f"names no output: give the terms on {', '.join(MEASURED)}")
        return None
    error = check.string(entry.get("error", ERRORS[0]), "loop.law.error", ERRORS)
    derivative = check.mapping(entry.get("derivative", {}), "loop.law.derivative", optional=_DERIVATIVE_KEYS) or {}
    on = check.string(derivative.get("on", "error"), "loop.law.derivative.on", ("error", "measurement"))
    method = check.string(derivative.get("method", "backward"), "loop.law.derivative.method", tuple(METHODS))
    cutoff = None
    if "cutoff" in derivative:
        cutoff = check.number(derivative["cutoff"], "loop.law.derivative.cutoff", positive=True, maximum=1e6)
    integral = check.mapping(entry.get("integral", {}), "loop.law.integral", optional=_INTEGRAL_KEYS) or {}
    i_method = check.string(integral.get("method", "backward"), "loop.law.integral.method", tuple(METHODS))
    if None in (error, on, method, i_method):
        return None
    sign = 1.0 if error == ERRORS[0] else -1.0   # the measurement's sign in the error is -sign
    dz = _derivative(cutoff, method, period)
    iz = control.sample_system(control.tf([1.0], [1.0, 0.0]), period, method=METHODS[i_method])
    blocks, sources, constants, words, recipe = [], [], {}, [], []
    for name, term in terms.items():
        key = f"loop.law.terms.{name}"
        term = check.mapping(term, key, optional=_TERM_KEYS)
        if term is None:
            continue
        if name not in conversions:
            check.fail(key, f"the law acts on {name}, which is not one of outputs "
                            f"({', '.join(conversions) or 'none'}): the law sees a measured output")
            continue
        gains = {k: check.number(term.get(k, 0.0), f"{key}.{k}") for k in ("kp", "ki", "kd")}
        if any(g is None for g in gains.values()):
            continue
        if any(abs(g) > MAX_MAGNITUDE for g in gains.values()):
            check.fail(key, f"expected gains of magnitude at most {MAX_MAGNITUDE:g}")
            continue
        reference = term.get("reference", 0.0)
        if isinstance(reference, str):
            if reference not in columns:
                check.fail(f"{key}.reference", f"{excerpt(reference)} is not one of columns ({', '.join(columns)})")
                continue
            ref = reference
        else:
            value = check.number(reference, f"{key}.reference")
            if value is None:
                continue
            ref = f"{name} reference"
            constants[ref] = value
        if gains["kd"] and dz is None:
            check.fail("loop.law.derivative.cutoff", "a forward-Euler derivative needs a filter (cutoff, "
                                                     "rad/s): unfiltered it uses the next sample")
            return None
        for source in (ref, name):
            if source not in sources:
                sources.append(source)
        r, y = sources.index(ref), sources.index(name)
        # u += kp e + ki I(e) + kd D(e or the measurement's part of e), e = sign (r - y)
        for gain, system, kind, on_reference in ((gains["kp"], None, None, True), (gains["ki"], iz, "i", True),
                                                 (gains["kd"], dz, "d", on == "error")):
            if gain:
                blocks.append((y, -sign * gain, system))
                recipe.append((y, -sign * gain, kind))
                if on_reference:
                    blocks.append((r, sign * gain, system))
                    recipe.append((r, sign * gain, kind))
        words.append(f"{name}: kp {gains['kp']:g}, ki {gains['ki']:g}, kd {gains['kd']:g} on "
                     f"{reference if isinstance(reference, str) else f'{reference:g}'}")
    check.done()
    A, B, C, D = _assembled(blocks, len(sources))
    what = "derivative on the " + on + (f", filtered at {cutoff:g} rad/s" if cutoff else ", unfiltered") \
        + f", {method}"
    methods = {"d": (method, cutoff), "i": (i_method, None)}
    recipe = tuple((source, gain, kind) + (methods[kind] if kind else (None, None))
                   for source, gain, kind in recipe)
    return A, B, C, D, sources, constants, f"the PID law ({'; '.join(words)}; {what})", recipe


def _derivative(cutoff: float | None, method: str, period: float):
    """The discrete derivative: s (filtered: s cutoff / (s + cutoff)) by ``method``; None when
    it is not causal (forward Euler of an unfiltered derivative)."""
    import control

    if cutoff is None:
        if method == "forward":
            return None
        if method == "backward":   # (1 - z^-1) / T
            return control.tf([1.0, -1.0], [period, 0.0], period)
        return control.tf([2.0, -2.0], [period, period], period)   # bilinear: 2 (z - 1) / (T (z + 1))
    return control.sample_system(control.tf([cutoff, 0.0], [1.0, cutoff]), period, method=METHODS[method])


def _assembled(blocks, inputs: int):
    """One state space from blocks (source, gain, discrete tf or None for a static gain),
    their outputs summed."""
    import control

    parts = []
    D = np.zeros((1, inputs))
    for source, gain, system in blocks:
        if system is None:
            D[0, source] += gain
            continue
        ss = control.ss(system)
        parts.append((source, gain, np.atleast_2d(ss.A), np.atleast_2d(ss.B), np.atleast_2d(ss.C),
                      float(np.atleast_2d(ss.D)[0, 0])))
    n = sum(p[2].shape[0] for p in parts)
    A, B, C = np.zeros((n, n)), np.zeros((n, inputs)), np.zeros((1, n))
    row = 0
    for source, gain, a, b, c, d in parts:
        m = a.shape[0]
        A[row:row + m, row:row + m] = a
        B[row:row + m, source] = b[:, 0]
        C[0, row:row + m] = gain * c[0]
        D[0, source] += gain * d
        row += m
    return A, B, C, D


def _block(kind: str, method: str, cutoff: float | None, dt: float) -> tuple:
    """(a, b, c, d) of one derivative (``kind`` "d", filtered at ``cutoff`` rad/s or not) or
    integral ("i") discretized by ``method`` over an interval of ``dt`` s, in coordinates that
    mean the same at every interval: a filtered derivative keeps the low-passed input f (the
    derivative is cutoff (v - f)), the others the last input (and the last output where the
    method needs it), so that a law can change its interval from one sample to the next."""
    if kind == "d" and cutoff is not None:
        w = cutoff
        if method == "backward":
            g = 1.0 / (1.0 + w * dt)
            return np.array([[g]]), np.array([w * dt * g]), np.array([-w * g]), w * g
        if method == "forward":   # state (f, v) of the sample before
            return (np.array([[1.0 - w * dt, w * dt], [0.0, 0.0]]), np.array([0.0, 1.0]),
                    np.array([-w * (1.0 - w * dt), -w * w * dt]), w)
        c = 0.5 * w * dt          # bilinear
        return (np.array([[(1.0 - c) / (1.0 + c), c / (1.0 + c)], [0.0, 0.0]]), np.array([c / (1.0 + c), 1.0]),
                np.array([-w * (1.0 - c) / (1.0 + c), -w * c / (1.0 + c)]), w / (1.0 + c))
    if kind == "d":
        if method == "backward":  # (v - v_before) / dt
            return np.array([[0.0]]), np.array([1.0]), np.array([-1.0 / dt]), 1.0 / dt
        # bilinear: d = -d_before + 2 (v - v_before) / dt, state (d, v) of the sample before
        return (np.array([[-1.0, -2.0 / dt], [0.0, 0.0]]), np.array([2.0 / dt, 1.0]),
                np.array([-1.0, -2.0 / dt]), 2.0 / dt)
    if method == "backward":      # I += dt v
        return np.array([[1.0]]), np.array([dt]), np.array([1.0]), dt
    if method == "forward":       # I += dt v_before, state (I, v) of the sample before
        return np.array([[1.0, dt], [0.0, 0.0]]), np.array([0.0, 1.0]), np.array([1.0, dt]), 0.0
    return (np.array([[1.0, 0.5 * dt], [0.0, 0.0]]), np.array([0.5 * dt, 1.0]),   # bilinear
            np.array([1.0, 0.5 * dt]), 0.5 * dt)


_AT: dict = {}   # (recipe, inputs, dt) -> matrices: a jittered log's intervals repeat


def _assembled_at(recipe: tuple, inputs: int, dt: float) -> tuple:
    """(A, B, C, D) of a terms law's blocks (source, gain, kind, method, cutoff) over ``dt``."""
    key = (recipe, inputs, dt)
    if key in _AT:
        return _AT[key]
    parts = [(source, gain, *_block(kind, method, cutoff, dt)) for source, gain, kind, method, cutoff in recipe
             if kind is not None]
    n = sum(len(p[3]) for p in parts)
    A, B, C, D = np.zeros((n, n)), np.zeros((n, inputs)), np.zeros((1, n)), np.zeros((1, inputs))
    for source, gain, kind, _, _ in recipe:
        if kind is None:
            D[0, source] += gain
    row = 0
    for source, gain, a, b, c, d in parts:
        m = len(b)
        A[row:row + m, row:row + m] = a
        B[row:row + m, source] = b
        C[0, row:row + m] = gain * c
        D[0, source] += gain * d
        row += m
    if len(_AT) > 10000:
        _AT.clear()
    _AT[key] = (A, B, C, D)
    return _AT[key]


def _state_space(check: Checker, entry: dict, conversions, columns):
    """The general form: (A, B, C, D, sources, {}, words)."""
    sources = check.names(entry["inputs"], "loop.law.inputs")
    if sources is None:
        return None
    for s in sources:
        if s not in conversions and s not in columns:
            check.fail("loop.law.inputs", f"{excerpt(s)} is neither one of outputs ({', '.join(conversions) or 'none'}) "
                                          f"nor one of columns ({', '.join(columns)})")
    m = len(sources)
    D = check.matrix(entry["D"], "loop.law.D", rows=1, cols=m)
    A = check.matrix(entry["A"], "loop.law.A") if entry["A"] != [] else []
    n = len(A) if A else 0
    if A and len(A[0]) != n:
        check.fail("loop.law.A", f"expected a square matrix, got {n} rows of {len(A[0])}")
        return None
    B = check.matrix(entry["B"], "loop.law.B", rows=n, cols=m) if n else []
    C = check.matrix(entry["C"], "loop.law.C", rows=1, cols=n) if n else []
    check.done()
    A = np.array(A, dtype=float).reshape(n, n)
    B = np.array(B, dtype=float).reshape(n, m)
    C = np.array(C, dtype=float).reshape(1, n)
    return (A, B, C, np.array(D, dtype=float), list(sources), {}, f"the law of {n} states on {', '.join(sources)}",
            None)


def _agrees(check: Checker, law: LinearLaw, rows: np.ndarray, output: np.ndarray, name: str,
            voltage, feedforward, csv_name: str, lines, period: float) -> None:
    """The law, run on what the log recorded over the window (``rows``: its sources as
    logged), against the controller's own logged ``output``: the law's own output (before any
    feedforward and the voltage limit), or, where the logger's output column holds them too,
    the law plus the feedforward, clipped. Beyond AGREE of the column's range in both, one line
    naming the first sample that disagrees and the cause the difference shows (a factor, the
    sign, a shift: identify/mismatch.py). A cell of the column that is not a number inside
    the window is named: the law cannot be checked there."""
    from furuta_cosim.identify.mismatch import cause

    factor, offset = law.command
    bad = np.nonzero(~np.isfinite(output))[0]
    if len(bad):
        check.fail("loop.law.output", f"{csv_name}: line {int(lines[bad[0]])}: {name} holds "
                                      f"{excerpt(str(output[bad[0]]))} inside the window: the law's output "
                                      "must be a number at every sample it is checked against")
        return
    u, _ = law.respond(rows, law.x0, law.dt)
    own = (u + offset) * factor
    logged = (output + offset) * factor
    span = float(np.max(logged) - np.min(logged)) or max(float(np.max(np.abs(logged))), 1e-12)
    if not np.all(np.isfinite(own)):
        k = int(np.argmax(~np.isfinite(own)))
        check.fail("loop.law", f"{csv_name}: line {int(lines[k])}: the law's output is not a number there: "
                               "a reference or measurement it reads is not one")
        return
    if np.max(np.abs(own - logged)) <= AGREE * span:
        return
    found = own + (0.0 if feedforward is None else feedforward)
    clipped = logged
    if voltage is not None:
        found, clipped = np.clip(found, -voltage, voltage), np.clip(logged, -voltage, voltage)
    if (feedforward is not None or voltage is not None) and np.max(np.abs(found - clipped)) <= AGREE * span:
        return
    apart = np.abs(own - logged)
    k = int(np.argmax(apart > AGREE * span))
    why = cause(own, logged, period, AGREE * span / max(
        float(np.sqrt(np.mean(logged ** 2))), 1e-12))
    if law.varying is not None and not why:
        # the clock: the law at the typical step gives the logged output, so the controller ran
        # on a uniform clock and the logged times are not when it ran (a logger's own stamps)
        u, _ = law.respond(rows, law.x0)   # its matrices at the period (read_law)
        if np.max(np.abs((u + offset) * factor - logged)) <= AGREE * span:
            why = (f"the clock: stepped at the log's typical step ({period:g} s) the law gives the logged output, "
                   "so it ran on a uniform clock and the log's times are not when it ran (a logger that "
                   "stamps each row when it writes it); give the times the loop ran at")
    check.fail("loop.law", f"{csv_name}: line {int(lines[k])}: the law gives {own[k]:.6g} where "
                           f"the controller logged {logged[k]:.6g} in {name} ({apart[k] / span:.1%} of its "
                           f"range, at most {AGREE:.0%}; largest {np.max(apart) / span:.1%}): the law as "
                           "stated is not the one that ran: "
                           + (why or "not a factor, the sign or a shift of up to 10 samples: its gains, the "
                                     "error's sense, the derivative's filter or discretization"))