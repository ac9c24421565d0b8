"""The sample loop in C, for a linear controller on the plant's outputs.

The generated Python loop (:mod:`furuta_cosim.cosim.loop`) costs about 2 us a sample around
a plant step of about 1 us. For the common configuration (no estimator, no unit
conversion: any noise, disturbances, actuator limit, delay, controller states and substeps)
``_c/loop.c`` runs the same events with the same arithmetic in C, stepping the session
through its own step_io, and writes the records into arrays. Its results equal the Python
loop's bit for bit (tests/test_native.py); where it does not apply, or no C compiler is
there, the Python loop runs.

    native = NativeLoop.on(prepared, session, runtime)
    failed = native.run(0, prepared.steps)  # 0, or the code of the step that failed
"""

from __future__ import annotations

import os
from pathlib import Path

import cffi
import numpy as np

from furuta_cosim.fmu.compiler import load_helper

_FFI = cffi.FFI()
_FFI.cdef("""
typedef struct {
    void *step; void *call; double *in; const double *out;
    double start, h; long long k; int substeps; int n_out;
    int n_s; const int *pick; int n_noisy; const int *noisy; const double *noise;
    int n_d; const double *disturbance; const double *rbar;
    int n_xc; double *xc; const double *feedback; const double *update;
    double F; int delay; double held; int limited; double limit;
    double *values; double *rows; double *us; double *commands; double *xcs;
    long long failed_at;
} Loop;
int run_loop(Loop *, long long, long long);
""")
MAX_SIGNALS = 64  # the C loop's own buffers
OFF = "FURUTA_COSIM_PYTHON_LOOP"  # set to 1: always the Python loop (for comparisons)


def _library():
    return load_helper(_FFI, Path(__file__).parent / "_c" / "loop.c")


def _doubles(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64)


def _fits(prepared, session) -> bool:
    """Whether every array the C loop indexes has the rows and columns it reads (it checks
    no bounds itself); where not, the Python loop runs and raises what it raises."""
    steps, n_d = prepared.steps, len(prepared.disturbances)
    return (len(prepared.rbar) >= steps
            and len(session.inputs) == 1 + n_d and len(session.outputs) == len(prepared.outputs)
            and (not prepared.noisy or prepared.measurement_noise.shape[:2] == (steps, len(prepared.noisy)))
            and (not n_d or prepared.disturbance.shape[:2] == (steps, n_d)))


class NativeLoop:
    """One run's loop in C and its records: ``rows`` (samples x outputs), ``us``,
    ``commands`` (with an actuator limit) and ``xcs`` (samples x controller states)."""

    def __init__(self, prepared, session, runtime, native: dict, pick: list[int], noisy: list[int]):
        controller = runtime.controller
        n_s, m = len(pick), runtime.n_xc
        steps, n_out = prepared.steps, len(prepared.outputs)
        self.session = session
        self.rows = np.zeros((steps, n_out))
        self.us = np.zeros(steps)
        self.commands = np.zeros(steps)
        self.xcs = np.zeros((steps, m))
        self._keep = keep = {
            "pick": np.asarray(pick, dtype=np.intc), "noisy": np.asarray(noisy or [0], dtype=np.intc),
            "noise": _doubles(prepared.measurement_noise if noisy else [0.0]),
            "disturbance": _doubles(prepared.disturbance if prepared.disturbances else [0.0]),
            "rbar": _doubles(prepared.rbar), "xc": np.zeros(max(m, 1)),
            "feedback": _doubles(np.concatenate([controller.Cc[0], controller.Dc[0]])),
            "update": _doubles(np.hstack([controller.Ac, controller.Bc]) if m else [0.0]),
            "values": np.zeros(n_out)}
        loop = self._loop = _FFI.new("Loop *")
        loop.step = _FFI.cast("void *", native["step"])
        loop.call = _FFI.cast("void *", native["call"])
        loop.out = _FFI.cast("double *", native["out"])
        loop.start, loop.h, loop.k = native["start"], prepared.communication_step, native["k"]
        loop.substeps, loop.n_out, loop.n_s = prepared.substeps, n_out, n_s
        loop.n_noisy, loop.n_d, loop.n_xc = len(noisy), len(prepared.disturbances), m
        loop.F, loop.delay, loop.held = runtime.F, runtime.delay, 0.0
        limit = prepared.limit
        loop.limited, loop.limit = bool(limit), float(limit or 0.0)
        for name, array in keep.items():
            setattr(loop, name, _FFI.cast("int *" if array.dtype == np.intc else "double *",
                                          _FFI.from_buffer(array)))
        for name in ("rows", "us", "commands", "xcs"):
            setattr(loop, name, _FFI.cast("double *", _FFI.from_buffer(getattr(self, name))))
        setattr(loop, "in", _FFI.cast("double *", native["in"]))  # "in" is a Python keyword

    @classmethod
    def on(cls, prepared, session, runtime, pick: list[int], noisy: list[int],
           values) -> "NativeLoop | None":
        """The loop in C for this run, starting from the outputs ``values``: ``pick`` the
        fed-back outputs' positions, ``noisy`` the positions among those that get noise. None
        where it does not apply (an estimator, unit conversions, no step helper)."""
        if os.environ.get(OFF) == "1" or prepared.estimator() is not None or prepared.conversions \
                or not getattr(runtime, "native", True):  # a swing-up switches: Python's loop
            return None
        if len(pick) > MAX_SIGNALS or runtime.n_xc > MAX_SIGNALS or not _fits(prepared, session):
            return None
        if _library() is None:
            return None
        native = session.native(prepared.communication_step)
        if native is None:
            return None
        loop = cls(prepared, session, runtime, native, list(pick), list(noisy))
        loop._keep["values"][:] = values
        return loop

    def run(self, first: int, last: int) -> int:
        """Samples ``first..last-1``: 0, or what step_io returned for the step that failed
        (raise it with :meth:`raise_failure`)."""
        failed = _library().run_loop(self._loop, first, last)
        self.session.advanced(self._loop.k)
        if failed < 0:
            raise RuntimeError("the C loop was set up beyond its buffers")
        return failed

    @property
    def failed_at(self) -> int:
        return int(self._loop.failed_at)

    def raise_failure(self, failed: int, disturbance) -> None:
        """The session's error for a failed step (an FmuError)."""
        k = self.failed_at
        applied = [float(self.us[k])] + ([float(d) for d in disturbance[k]] if self._loop.n_d else [])
        self.session.step_failed(failed, applied)
