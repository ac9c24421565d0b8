"""A replay's closed loop in C (``_c/replay.c``): the loop of :func:`~furuta_cosim.identify.replay.closed_loop`
for the logs whose controller is linear, the common case of a fit (a balancing log under a
controller file's law or a law in the logger's own words), on the log's clock as it ran.

It applies where the loop's controller is a controller file without a swing-up (the rates by
the loop's filter, any lead-in before the window) or a law in the logger's words (its
matrices once, or per sample on a jittered clock), with any delay in the loop (whole samples
and a part of one), feedforward, voltage limit, the encoders' rounding or a balancing log's
smoother, on a uniform clock or the instants the log records (its ``late`` and ``compute``
columns, a jittered time column). A swing-up (its modes switch by a rule), where no C
compiler is there, or with ``FURUTA_COSIM_PYTHON_LOOP=1``, the Python loop runs; the Python loop is the reference the
C loop is checked against (within 1e-12: tests/test_native_replay.py) and ``tools/bench_replay.py``
times the two.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cffi
import numpy as np

from furuta_cosim.fmu.compiler import load_helper

_FFI = cffi.FFI()
_FFI.cdef("""
typedef struct {
    void *step; void *call; double *in; const double *out;
    const double *first;
    double time, start, h; long long k;
    int n_out, n_names;
    const double *scale, *offset;
    double v_scale, v_offset;
    long long n;
    double period;
    int counted; double zero, per_count;
    const double *noise0, *noise1;
    const double *feedforward;
    int limited; double limit;
    int whole; double part;
    const double *logged; long long n_logged;
    int kind;
    double F; const double *reference;
    int n_xc; double *xc; const double *feedback; const double *update;
    double ra, rb;
    long long n_lead; const double *lead_angles, *lead_current, *lead_reference;
    double first0, first1;
    int n_x, n_v; double *x; const double *A, *B, *C, *D; double law_offset, law_factor;
    int varying;
    const int *source;
    const double *c0, *c1;
    const double *columns;
    int timed;
    const double *read, *arrive;
    double *when, *value; long long capacity;
    long long n_pending; double level;
    double *raw;
    double *volts;
    long long stopped_at;
    long long failed_at;
    double failed_input;
} Replay;
int run_replay(Replay *);
""")
OFF = "FURUTA_COSIM_PYTHON_LOOP"   # 1: always the Python loop (to compare, or to debug)
MAX = 64                           # the C loop's own buffers: outputs, states, sources
_SEEN = {"theta0": 0, "theta1": 1, "i": 2}


def _library():
    return load_helper(_FFI, Path(__file__).parent / "_c" / "replay.c")


def _doubles(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64).ravel()


_VARYING: dict = {}   # the last varying law's matrices by sample: (law, n) -> arrays


def _matrices(law, n: int) -> tuple:
    """(A, B, C, D) of ``law`` flattened for the C loop: once, or, for a law whose matrices vary
    with the clock (a jittered log), one set per sample as the Python loop assembles them,
    kept for the next replay of the same law (a fit replays it hundreds of times)."""
    if law.varying is None:
        return _doubles(law.A), _doubles(law.B), _doubles(law.C[0]), _doubles(law.D[0])
    key = (id(law), n)
    if key not in _VARYING or _VARYING[key][0] is not law:
        sets = [law.matrices(float(law.dt[k])) for k in range(n)]
        _VARYING.clear()
        _VARYING[key] = (law, tuple(_doubles([m[j] if j < 2 else m[j][0] for m in sets]) for j in range(4)))
    return _VARYING[key][1]


def _command(loop, experiment, runtime_of) -> dict | None:
    """The loop's command as the C loop takes it, or None where it cannot (a swing-up, a law
    whose matrices vary with the clock, more than it has room for)."""
    if loop.linear is not None:
        law = loop.linear
        if law.A.shape[0] > MAX or len(law.sources) > MAX:
            return None
        factor, offset = law.command
        sources, c0, c1, columns = [], [], [], []
        for name, conversion in zip(law.sources, law.measured):
            if conversion is not None:
                if name not in _SEEN:
                    return None
                sources.append(_SEEN[name])
                c0.append(conversion[0])
                c1.append(conversion[1])
                columns.append(np.zeros(experiment.samples))
            else:
                sources.append(3)
                c0.append(1.0)
                c1.append(0.0)
                columns.append(np.asarray(law.columns[name], dtype=float)[:experiment.samples])
        n_x = law.A.shape[0]
        A, B, C, D = _matrices(law, experiment.samples)
        return {"kind": 2, "n_x": n_x, "n_v": len(sources), "varying": law.varying is not None,
                "x": _doubles(np.zeros(n_x) if law.x0 is None else law.x0) if n_x else np.zeros(1),
                "A": A if n_x else np.zeros(1), "B": B if n_x else np.zeros(1),
                "C": C if n_x else np.zeros(1), "D": D,
                "law_offset": float(offset), "law_factor": float(factor),
                "source": np.asarray(sources, dtype=np.intc), "c0": _doubles(c0), "c1": _doubles(c1),
                "columns": _doubles(np.concatenate(columns) if columns else [0.0])}
    runtime = runtime_of()
    if not hasattr(runtime, "controller") or runtime.delay or runtime.n_xc > MAX:
        return None   # a swing-up (it switches), or a runtime that holds its command
    controller = runtime.controller
    m = runtime.n_xc
    w = 2.0 * math.pi * loop.rate_filter
    h = experiment.period
    lead = loop.lead_in
    reference = loop.reference if loop.reference is not None else np.zeros(experiment.samples)
    logged = [experiment.outputs[n].values[0] if n in experiment.outputs else 0.0 for n in ("theta0", "theta1")]
    return {"kind": 1, "F": float(runtime.F), "reference": _doubles(reference), "n_xc": m,
            "xc": np.zeros(max(m, 1)),
            "feedback": _doubles(np.concatenate([controller.Cc[0], controller.Dc[0]])),
            "update": _doubles(np.hstack([controller.Ac, controller.Bc]) if m else [0.0]),
            "ra": (2.0 - w * h) / (2.0 + w * h), "rb": 2.0 * w / (2.0 + w * h),
            "n_lead": 0 if lead is None else len(lead.current),
            "lead_angles": _doubles(lead.angles if lead is not None and len(lead.current) else [0.0, 0.0]),
            "lead_current": _doubles(lead.current if lead is not None and len(lead.current) else [0.0]),
            "lead_reference": _doubles(lead.reference if lead is not None and len(lead.current) else [0.0]),
            "first0": float(logged[0]), "first1": float(logged[1])}


def _hand_back(session, R) -> None:
    """The session's clock where the C loop left it, kept as its own step keeps it (the start
    of the current run of equal steps, their count and size: fmu/session.py step)."""
    session._start, session._k, session._h, session.time = R.start, R.k, R.h, R.time


def replay_in_c(session, experiment, *, names, fmu_out, first, v_scale: float, v_offset: float,
                noise, phase: float, delay: float, logged, runtime_of, timed: bool = False, read=None,
                arrive=None, pending=(), level: float = 0.0) -> tuple | None:
    """(raw outputs n x len(names), volts, the sample where an output stopped being finite or
    -1) of the closed loop in C, the session already reset with its inputs and outputs chosen
    and ``first`` its outputs there; None where the C loop does not apply (the Python loop
    then runs). A ``timed`` log steps the plant to each reading (``read``) and switches its
    voltage at each command's arrival (``arrive``), ``pending`` the commands on their way as the
    window starts and ``level`` the voltage then (replay.py closed_loop).

    A step that fails raises the session's error, as the Python loop's step does."""
    loop = experiment.loop
    if os.environ.get(OFF) == "1" or loop.mode is not None or len(fmu_out) > MAX:
        return None
    if len(session.inputs) != 1 or len(session.outputs) != len(fmu_out):
        return None
    command = _command(loop, experiment, runtime_of)
    if command is None or _library() is None:
        return None
    clock = session.native(experiment.period)   # the step helper's addresses
    if clock is None:
        return None
    n, h = experiment.samples, experiment.period
    whole = int(math.floor(delay / h + 1e-9))
    part = delay - whole * h
    if part < 1e-12 * h:
        part = 0.0
    raw, volts = np.full((n, len(names)), np.nan), np.zeros(n)
    per_count = 2.0 * math.pi / loop.counts
    feedforward = loop.feedforward if loop.feedforward is not None else np.zeros(n)
    keep = {"scale": _doubles([s for _, s, _ in fmu_out]), "offset": _doubles([o for _, _, o in fmu_out]),
            "noise0": _doubles(noise[0] if noise is not None else [0.0]),
            "noise1": _doubles(noise[1] if noise is not None else [0.0]),
            "feedforward": _doubles(feedforward), "logged": _doubles(logged if len(logged) else [0.0]),
            "raw": raw, "volts": volts, "first": _doubles(first),
            "read": _doubles(read if timed else [0.0]), "arrive": _doubles(arrive if timed else [0.0]),
            "when": np.zeros(n + len(pending) + 1), "value": np.zeros(n + len(pending) + 1),
            **{k: v for k, v in command.items() if isinstance(v, np.ndarray)}}
    R = _FFI.new("Replay *")
    R.step, R.call = _FFI.cast("void *", clock["step"]), _FFI.cast("void *", clock["call"])
    setattr(R, "in", _FFI.cast("double *", clock["in"]))
    R.out = _FFI.cast("double *", clock["out"])
    R.time, R.start, R.h, R.k = session.time, session._start, session._h, session._k   # as it stands
    R.n_out, R.n_names = len(fmu_out), len(names)
    R.v_scale, R.v_offset = float(v_scale), float(v_offset)
    R.n, R.period = n, h
    R.counted = noise is None
    R.zero, R.per_count = phase * per_count, per_count
    R.limited, R.limit = loop.voltage is not None, float(loop.voltage or 0.0)
    R.whole, R.part = whole, part
    R.n_logged = len(logged)
    R.timed, R.capacity, R.n_pending, R.level = bool(timed), n + len(pending) + 1, len(pending), float(level)
    for j, (when, value) in enumerate(pending):
        keep["when"][j], keep["value"][j] = when, value
    for key, value in command.items():
        if not isinstance(value, np.ndarray):
            setattr(R, key, value)
    for key, array in keep.items():
        setattr(R, key, _FFI.cast("int *" if array.dtype == np.intc else "double *", _FFI.from_buffer(array)))
    failed = _library().run_replay(R)
    _hand_back(session, R)
    if failed < 0:
        raise RuntimeError("the C replay loop was set up beyond its buffers")
    if failed:
        session.step_failed(failed, [R.failed_input])
    return raw, volts, int(R.stopped_at)
