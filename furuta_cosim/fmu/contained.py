"""Engines we did not write, run in a child process: a crash there (SIGSEGV, SIGABRT), a hang or
a stray temporary folder cannot take the caller with it.

``contained(function, *args, engine=..., timeout=...)`` runs ``function(*args)`` in a new
interpreter (``python -m furuta_cosim.fmu.contained``) whose temporary directory is a folder of
its own, removed afterwards whatever happened; it returns the function's value or raises
:class:`EngineFailed` with the engine's verdict in one line: "Ecos crashed on this FMU:
SIGSEGV", "fmpy did not finish in 60 s (stopped)", or what the engine raised. What the engine
prints goes to stderr; the caller's stdout stays its own.
"""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from furuta_cosim.errors import FmuError


class EngineFailed(FmuError):
    """The contained engine crashed, hung or raised; the message is its verdict."""


def contained(function, *args, engine: str, timeout: float = 120.0):
    """``function(*args)`` in a child process.

    Parameters
    ----------
    function : callable
        A module-level function (pickled by reference); its value must pickle.
    *args
        Its arguments; they must pickle.
    engine : str
        The engine's name, for the verdict (``"Ecos"``, ``"fmpy"``).
    timeout : float, optional
        Seconds before the child is killed.

    Raises
    ------
    EngineFailed
        When the child crashed, did not finish in time, or raised.
    """
    scratch = Path(tempfile.mkdtemp(prefix="furuta-cosim-engine-"))
    try:
        job, answer = scratch / "job.pickle", scratch / "answer.pickle"
        # the caller's import path first, so that the child can unpickle the function
        job.write_bytes(pickle.dumps((list(sys.path), pickle.dumps((function, args)), str(answer))))
        environment = {**os.environ, "TMPDIR": str(scratch / "tmp"), "TMP": str(scratch / "tmp"),
                       "TEMP": str(scratch / "tmp")}
        (scratch / "tmp").mkdir()
        try:
            done = subprocess.run([sys.executable, "-m", "furuta_cosim.fmu.contained", str(job)],
                                  stdin=subprocess.DEVNULL, stdout=sys.stderr.fileno()
                                  if _has_fileno(sys.stderr) else subprocess.DEVNULL,
                                  env=environment, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise EngineFailed(f"{engine} did not finish in {timeout:g} s (stopped)") from None
        if not answer.is_file():
            raise EngineFailed(f"{engine} crashed on this FMU: {_how(done.returncode)}")
        status, payload = pickle.loads(answer.read_bytes())  # written by our own child
        if status == "raised":
            raise EngineFailed(f"{engine}: {payload}")
        return payload
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _has_fileno(stream) -> bool:
    try:
        stream.fileno()
        return True
    except (AttributeError, OSError, ValueError):
        return False


def _how(code: int) -> str:
    if code < 0:
        try:
            return signal.Signals(-code).name
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


def _child(job: str) -> None:
    path, inner, answer = pickle.loads(Path(job).read_bytes())
    sys.path[:] = path + [p for p in sys.path if p not in path]
    try:
        function, args = pickle.loads(inner)
        reply = ("ok", function(*args))
    except BaseException as error:  # the engine is foreign: whatever it raised is its verdict
        message = " ".join(str(error).split()) or type(error).__name__
        reply = ("raised", message[:2000])
    partial = answer + ".partial"
    Path(partial).write_bytes(pickle.dumps(reply))
    os.replace(partial, answer)


if __name__ == "__main__":
    _child(sys.argv[1])
