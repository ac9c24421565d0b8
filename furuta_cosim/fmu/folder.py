"""A user's plant folder: its declaration (``model.py``) run, checked strictly, and every
problem said in one line at the file and line that causes it.

A plant folder holds ``model.py``, whose ``declare(parameters)`` returns a
:class:`~furuta_cosim.fmu.declaration.Model` (the API the project's own plants use), and
``model.c``, the equations against ``model_api.h``. The folder's rules are stricter than the
project's own models': every state, input and parameter states its unit (``"1"`` for a pure
number), since plots, the controller's view and other tools read them.
"""

from __future__ import annotations

import hashlib
import importlib.util
import re
import sys
import traceback
from pathlib import Path

from furuta_cosim.config import key_line
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.declaration import DeclarationError, Model
from furuta_cosim.fmu.plants import PlantSet


def declare_folder(plant: PlantSet) -> Model:
    """Run the folder's ``declare()`` with the plant file's parameters and check the result."""
    model_py = plant.folder / "model.py"
    module = _module(model_py)
    declare = getattr(module, "declare", None)
    if not callable(declare):
        raise ConfigError([f"{model_py}: defines no declare(parameters) function (it returns the "
                           "plant's Model; see `furuta-cosim new-plant`)"])
    try:
        model = declare(dict(plant.parameters))
    except DeclarationError as error:
        if error.variable in plant.parameters and plant.path != model_py:
            line = key_line(plant.path, ("parameters", error.variable))
            raise ConfigError([f"{plant.path}:{line or '?'}: parameters.{error.variable}: {error.reason}"]) from None
        raise ConfigError([f"{_at(error.where, model_py)}: {error}"]) from None
    except Exception as error:   # the user's code: said at its line, not as our traceback
        raise ConfigError([f"{_frame_in(error, model_py)}: {type(error).__name__}: {error}"]) from None
    if not isinstance(model, Model):
        raise ConfigError([f"{model_py}: declare() returned {type(model).__name__}, not the "
                           "furuta_cosim.fmu.declaration.Model it builds"])
    problems = _unitless(model, model_py)
    for name in model.measured:
        if name not in {v.name for v in model.reals if v.causality == "output"}:
            problems.append(f"{model_py}: measured: {name!r} is not an output of the declaration")
    if problems:
        raise ConfigError(problems[:1] + ([f"(and {len(problems) - 1} more like it)"] if len(problems) > 1 else []))
    from furuta_cosim.fmu.exporter import checked

    checked(plant, model)
    try:
        model.check()
    except DeclarationError as error:
        raise ConfigError([f"{model_py}: {error}"]) from None
    return model


def _module(model_py: Path):
    """The folder's model.py run as a module of its own name (two folders never share one)."""
    name = "_furuta_cosim_folder_" + hashlib.sha256(str(model_py).encode()).hexdigest()[:16]
    spec = importlib.util.spec_from_file_location(name, model_py)
    module = importlib.util.module_from_spec(spec)
    writes, sys.dont_write_bytecode = sys.dont_write_bytecode, True   # no __pycache__ in the user's folder
    try:
        spec.loader.exec_module(module)
    except SyntaxError as error:
        raise ConfigError([f"{model_py}:{error.lineno or '?'}: SyntaxError: {error.msg}"]) from None
    except Exception as error:
        raise ConfigError([f"{_frame_in(error, model_py)}: {type(error).__name__}: {error}"]) from None
    finally:
        sys.dont_write_bytecode = writes
    return module


def _frame_in(error: BaseException, model_py: Path) -> str:
    """``file:line`` of the last frame of ``error``'s traceback in the user's model.py."""
    found = None
    for frame in traceback.extract_tb(error.__traceback__):
        if Path(frame.filename) == model_py:
            found = frame
    return f"{model_py}:{found.lineno}" if found is not None else str(model_py)


def _at(where, model_py: Path) -> str:
    return f"{where[0]}:{where[1]}" if where else str(model_py)


def _unitless(model: Model, model_py: Path) -> list[str]:
    states = {s.name for s in model.states}
    starts = {s.start_parameter for s in model.states}
    problems = []
    for v in model.reals:
        kind = ("state" if v.name in states else "input" if v.causality == "input" else
                "parameter" if v.causality == "parameter" and v.name not in starts else None)
        if kind and not v.unit:
            problems.append(f"{_at(model.where.get(v.name), model_py)}: {kind} {v.name!r} has no unit "
                            "(say it: unit=\"m\", \"rad\", \"V\"...; \"1\" for a pure number)")
    return problems


_GCC = re.compile(r"^(?P<file>[^:\n]+):(?P<line>\d+):(?:(?P<column>\d+):)? (?:fatal )?error: (?P<text>.*)$", re.M)


def compile_error(stderr: str, work: Path, folder: Path) -> str:
    """The compiler's first error as one line at the user's file and line (the build copies
    the folder's model.c into a work folder; the line numbers are the same)."""
    errors = list(_GCC.finditer(stderr))
    if not errors:
        last = stderr.strip().splitlines()[-1] if stderr.strip() else "no message"
        return f"{folder / 'model.c'}: does not compile: {last}"
    first = errors[0]
    name = Path(first["file"]).name
    where = folder / name if Path(first["file"]).parent == work or name == "model.c" else Path(first["file"])
    more = f" (and {len(errors) - 1} more errors)" if len(errors) > 1 else ""
    return f"{where}:{first['line']}: does not compile: {first['text'].strip()}{more}"


