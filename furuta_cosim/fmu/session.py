"""A fast plant session: one FMI 2.0 instance driven through raw fmi2 calls (cffi).

fmpy reads the model description and extracts the FMU once; the fmi2 functions are then
called directly with buffers and value references prepared once, because the convenience
wrappers cost several times the model's own step (see ``tools/bench_fmu.py``).

    with PlantSession.open(build_fmu(plant_file)) as plant:
        plant.reset(parameters={"x_start": 0.1})        # a state's start parameter
        plant.set_io(inputs=["u"], outputs=["x", "v"])   # the declaration's names
        for k in range(1000):
            y = plant.step([0.0], 1e-3)
"""

from __future__ import annotations

import functools
import math
import shutil
import weakref
import zipfile
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import cffi
import fmpy
from fmpy.model_description import ModelDescription

from furuta_cosim.errors import FmuError
from furuta_cosim.files import temporary_folder
from furuta_cosim.fmu.archive import check_archive
from furuta_cosim.fmu.compiler import load_helper
from furuta_cosim.fmu.variables import settable_start
from furuta_cosim.signals import start_parameter

_FFI = cffi.FFI()
_FFI.cdef("""
typedef void* fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef struct {
    void (*logger)(void*, const char*, int, const char*, const char*);
    void* (*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void*);
    void* stepFinished;
    void* componentEnvironment;
} fmi2CallbackFunctions;
typedef struct {
    int newDiscreteStatesNeeded; int terminateSimulation;
    int nominalsOfContinuousStatesChanged; int valuesOfContinuousStatesChanged;
    int nextEventTimeDefined; double nextEventTime;
} fmi2EventInfo;
fmi2Component fmi2Instantiate(const char*, int, const char*, const char*,
                              const fmi2CallbackFunctions*, int, int);
void fmi2FreeInstance(fmi2Component);
int fmi2SetupExperiment(fmi2Component, int, double, double, int, double);
int fmi2EnterInitializationMode(fmi2Component);
int fmi2ExitInitializationMode(fmi2Component);
int fmi2Terminate(fmi2Component);
int fmi2Reset(fmi2Component);
int fmi2GetReal(fmi2Component, const fmi2ValueReference*, size_t, double*);
int fmi2SetReal(fmi2Component, const fmi2ValueReference*, size_t, const double*);
int fmi2GetInteger(fmi2Component, const fmi2ValueReference*, size_t, int*);
int fmi2SetInteger(fmi2Component, const fmi2ValueReference*, size_t, const int*);
int fmi2DoStep(fmi2Component, double, double, int);
int fmi2GetFMUstate(fmi2Component, void**);
int fmi2SetFMUstate(fmi2Component, void*);
int fmi2FreeFMUstate(fmi2Component, void**);
int fmi2EnterContinuousTimeMode(fmi2Component);
int fmi2NewDiscreteStates(fmi2Component, fmi2EventInfo*);
int fmi2SetContinuousStates(fmi2Component, const double*, size_t);
int fmi2GetContinuousStates(fmi2Component, double*, size_t);
int fmi2GetDerivatives(fmi2Component, double*, size_t);
typedef struct {
    void* set_real; void* do_step; void* get_real; void* component;
    const unsigned int* in_vr; size_t n_in; const double* in_;
    const unsigned int* out_vr; size_t n_out; double* out;
    bool flags[3]; double last;
} StepCall;
int step_io(const StepCall*, double, double);
int step_io3(StepCall*, double, double);
typedef void* fmi3Instance;
typedef void (*fmi3LogMessageCallback)(void*, int, const char*, const char*);
fmi3Instance fmi3InstantiateCoSimulation(const char*, const char*, const char*, bool, bool, bool,
    bool, const unsigned int*, size_t, void*, fmi3LogMessageCallback, void*);
fmi3Instance fmi3InstantiateModelExchange(const char*, const char*, const char*, bool, bool, void*,
    fmi3LogMessageCallback);
void fmi3FreeInstance(fmi3Instance);
int fmi3EnterInitializationMode(fmi3Instance, bool, double, double, bool, double);
int fmi3ExitInitializationMode(fmi3Instance);
int fmi3Terminate(fmi3Instance);
int fmi3Reset(fmi3Instance);
int fmi3GetFloat64(fmi3Instance, const unsigned int*, size_t, double*, size_t);
int fmi3SetFloat64(fmi3Instance, const unsigned int*, size_t, const double*, size_t);
int fmi3GetInt32(fmi3Instance, const unsigned int*, size_t, int*, size_t);
int fmi3SetInt32(fmi3Instance, const unsigned int*, size_t, const int*, size_t);
int fmi3DoStep(fmi3Instance, double, double, bool, bool*, bool*, bool*, double*);
int fmi3GetFMUState(fmi3Instance, void**);
int fmi3SetFMUState(fmi3Instance, void*);
int fmi3FreeFMUState(fmi3Instance, void**);
int fmi3UpdateDiscreteStates(fmi3Instance, bool*, bool*, bool*, bool*, bool*, double*);
int fmi3EnterContinuousTimeMode(fmi3Instance);
int fmi3SetContinuousStates(fmi3Instance, const double*, size_t);
int fmi3GetContinuousStateDerivatives(fmi3Instance, double*, size_t);
void* calloc(size_t, size_t);
void free(void*);
""")
_LIBC = _FFI.dlopen(None)


def _step_helper():
    """The compiled step_io (one foreign call per step), or None to fall back to three."""
    return load_helper(_FFI, Path(__file__).parent / "_c" / "step_io.c")


# What an instance that failed fatally may still point to, kept for the life of the process:
# its library (never unloaded), and the callbacks, logger and strings it was instantiated
# with. The FMU is never told the instance is gone (fmi2FreeInstance is itself forbidden after
# fmi2Fatal), so it may hold on to them; pythonfmu's logger keeps the callbacks' address.
_LOST: list = []
_FATAL = 4  # fmi2Fatal (and fmi2Pending, which nothing here asks for): the instance is lost;
# fmi2Error (3) and fmi2Discard (2) are errors: nothing here retries


@functools.lru_cache(maxsize=64)
def _read(path: str, _stamp: tuple) -> ModelDescription:
    # ``_stamp`` (size and mtime) only keys the cache: a changed file is read again
    check_archive(path)
    try:
        md = fmpy.read_model_description(path)
    except Exception as error:  # fmpy raises bare Exceptions for malformed FMUs
        raise FmuError(f"{path}: cannot read modelDescription.xml: {error}") from None
    for variable in md.modelVariables:
        if getattr(variable, "derivative", None) is variable:
            raise FmuError(f"{path}: modelDescription.xml: {variable.name} is declared the derivative "
                           "of itself (derivative= names its own variable)")
    return md


def model_description(fmu: str | Path) -> ModelDescription:
    """The FMU's model description, read once per file version in this process (do not modify)."""
    from furuta_cosim.inputs import regular

    status = regular(fmu).stat()
    return _read(str(fmu), (status.st_mtime_ns, status.st_size))


def refuse_clocks(fmu: str | Path, md: ModelDescription) -> None:
    """Clocked FMUs need event mode or scheduled execution, which nothing here drives."""
    clocks = [v.name for v in md.modelVariables if v.type == "Clock"]
    if clocks:
        raise FmuError(f"{fmu}: declares {len(clocks)} clock(s) ({', '.join(clocks[:3])}); "
                       "clocked FMUs (event mode, scheduled execution) are not supported")


def _extract(fmu: Path) -> Path:
    """Unzip what an importer needs (the platform binary and resources) into a new folder."""
    check_archive(fmu)
    folder = temporary_folder("fmu")
    wanted = (f"binaries/{fmpy.platform}/", f"binaries/{fmpy.platform_tuple}/", "resources/")
    try:
        with zipfile.ZipFile(fmu) as archive:
            archive.extractall(folder, [n for n in archive.namelist() if n.startswith(wanted)])
    except (zipfile.BadZipFile, OSError) as error:
        shutil.rmtree(folder, ignore_errors=True)
        raise FmuError(f"{fmu}: cannot be extracted: {error}") from None
    return folder


def state_names(model_description: ModelDescription) -> list[str]:
    """The plant's states: this project's convention (the outputs ``x`` that have a start
    parameter ``x_start``), else the continuous states the model structure declares (the
    variables its derivatives name), in the order of the FMU's state vector."""
    names = {v.name for v in model_description.modelVariables}
    marked = [v.name for v in model_description.modelVariables
              if v.causality == "output" and start_parameter(v.name) in names]
    declared = [d.variable.derivative.name for d in model_description.derivatives
                if d.variable.derivative is not None]
    if marked and (not declared or sorted(marked) == sorted(declared)):
        return declared or marked
    return declared


def _within_declared(identifier: str, variable, value: float) -> None:
    """A value below the variable's declared ``min`` or above its ``max`` is refused: FMI
    leaves the result of setting one undefined (a negative friction is a motor)."""
    for bound, outside, word in ((variable.min, lambda b: value < b, "below its minimum"),
                                 (variable.max, lambda b: value > b, "above its maximum")):
        try:
            limit = float(bound) if bound is not None else None
        except (TypeError, ValueError):
            continue  # an unreadable bound of a foreign FMU: fmpy's validation reports it
        if limit is not None and math.isfinite(limit) and outside(limit):
            raise FmuError(f"{identifier}: {variable.name} = {value:g} is {word} {limit:g} "
                           "(its range in the model description)")


class FmuBinary:
    """An extracted FMU with its shared library loaded; shared by the sessions on it."""

    lost = False  # an instance on it failed fatally: the library is never unloaded then

    def __init__(self, fmu: str | Path):
        self.path = Path(fmu)
        if not self.path.is_file():
            raise FmuError(f"{self.path}: no such FMU")
        self.model_description = md = model_description(self.path)
        if md.fmiVersion not in SESSIONS:
            raise FmuError(f"{self.path}: FMI {md.fmiVersion} is not supported "
                           f"(FMI {' and '.join(SESSIONS)} are)")
        interface = md.coSimulation or md.modelExchange or md.scheduledExecution
        if interface is None:
            raise FmuError(f"{self.path}: declares no interface (co-simulation, model exchange "
                           "or scheduled execution)")
        refuse_clocks(self.path, md)
        self.identifier = interface.modelIdentifier
        self.version = md.fmiVersion
        self.directory = _extract(self.path)
        platform = fmpy.platform if md.fmiVersion == "2.0" else fmpy.platform_tuple
        library = self.directory / "binaries" / platform / f"{self.identifier}{fmpy.sharedLibraryExtension}"
        if not library.is_file():
            shutil.rmtree(self.directory, ignore_errors=True)
            raise FmuError(f"{self.path}: no binary for {platform} "
                           f"(rebuild it from sources/ with 'fmpy compile')")
        try:
            self.lib = _FFI.dlopen(str(library))
        except OSError as error:
            shutil.rmtree(self.directory, ignore_errors=True)
            raise FmuError(f"{self.path}: its binary cannot be loaded ({error})") from None
        self.variables = {v.name: v for v in md.modelVariables}
        self.states = state_names(md)
        self._sessions: weakref.WeakSet = weakref.WeakSet()

    def lose(self) -> None:
        """An instance failed fatally: no session on this binary calls the FMU again."""
        self.lost = True
        for session in list(self._sessions):
            session._lose()

    def variable(self, name: str):
        try:
            return self.variables[name]
        except KeyError:
            known = ", ".join(self.variables)
            raise FmuError(f"{self.identifier} has no variable {name!r} (known: {known})") from None

    def close(self) -> None:
        if self.lib is not None and self.lost:
            # an instance on it failed fatally: FMI allows no further call of any instance of
            # this FMU, so the library stays loaded, unused, for the life of the process
            _LOST.append(self.lib)
            self.lib = None
            shutil.rmtree(self.directory, ignore_errors=True)
        if self.lib is not None:
            _FFI.dlclose(self.lib)
            # cffi's FFI keeps every library it opened in a list, even closed ones: about 9 KB
            # per open, which a tuning worker opening sessions for hours would feel
            opened = getattr(_FFI, "_libraries", None)
            if isinstance(opened, list) and self.lib in opened:
                opened.remove(self.lib)
            self.lib = None
            shutil.rmtree(self.directory, ignore_errors=True)

    def __enter__(self) -> "FmuBinary":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PlantSession:
    """One FMU instance: parameters, reset, inputs, steps and outputs, with few allocations.

    Parameters
    ----------
    binary : FmuBinary
        The loaded FMU; :meth:`open` creates one that the session owns.
    interface : {"CoSimulation", "ModelExchange"}
        Model exchange serves linearization (states in, derivatives out).
    name : str, optional
        The instance name passed to the FMU.
    """

    VERSION = "2.0"
    INSTANTIATE, STEP_IO = "fmi2Instantiate", "step_io"
    REAL, INTEGER = "Real", "Integer"  # the FMI types read and written as double and int
    # the calls whose signature is the same in FMI 2.0 and 3.0 but whose name is not
    GET_STATE, SET_STATE, FREE_STATE = "fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate"
    SET_X, GET_DX = "fmi2SetContinuousStates", "fmi2GetDerivatives"
    TERMINATE, FREE, DO_STEP = "fmi2Terminate", "fmi2FreeInstance", "fmi2DoStep"
    # one step in one call (the helper's step_io): the struct and the calls it makes
    SET_REALS, GET_REALS = "fmi2SetReal", "fmi2GetReal"

    def __init__(self, binary: FmuBinary, interface: str = "CoSimulation", name: str = "plant"):
        if binary.version != self.VERSION:
            raise FmuError(f"{binary.identifier}: an FMI {binary.version} FMU, not {self.VERSION}: "
                           "open it with PlantSession.for_binary")
        if binary.lost:
            raise FmuError(f"{binary.identifier}: an instance of this FMU failed fatally, so no "
                           "new one may be made from it: open the FMU again")
        self.binary = binary
        binary._sessions.add(self)
        self._owns_binary = False
        self._lib = binary.lib
        self._messages: list[str] = []
        self._interface = interface
        md = binary.model_description
        if interface == "ModelExchange" and md.modelExchange is None:
            raise FmuError(f"{binary.identifier} has no model exchange interface")
        self._name = _FFI.new("char[]", name.encode())
        self._c = self._instantiate(md, interface)
        if self._c == _FFI.NULL:
            raise FmuError(f"{binary.identifier}: {self.INSTANTIATE} failed: {self._drain()}")
        helper = self._helper = _step_helper()
        self._step_io = getattr(helper, self.STEP_IO) if helper else self._step_three_calls
        self._nx = len(binary.states)
        self._x = _FFI.new("double[]", max(self._nx, 1))
        self._dx = _FFI.new("double[]", max(self._nx, 1))
        self.set_io()
        self.time = 0.0
        self._start = 0.0
        self._k = 0
        self._h = 0.0
        self._initialized = False

    def _instantiate(self, md, interface: str):
        """The FMI 2.0 instance (``fmi2Instantiate``), its callbacks kept alive on ``self``."""
        self._logger = _FFI.callback("void(void*, const char*, int, const char*, const char*)",
                                     self._log)
        self._callbacks = _FFI.new("fmi2CallbackFunctions*")
        self._callbacks.logger = self._logger
        self._callbacks.allocateMemory = _LIBC.calloc
        self._callbacks.freeMemory = _LIBC.free
        self._guid = _FFI.new("char[]", md.guid.encode())
        self._resources = _FFI.new("char[]", (self.binary.directory / "resources").as_uri().encode())
        return self._lib.fmi2Instantiate(self._name, 0 if interface == "ModelExchange" else 1,
                                         self._guid, self._resources, self._callbacks, 0, 0)

    @staticmethod
    def for_binary(binary: FmuBinary, interface: str = "CoSimulation", name: str = "plant") -> "PlantSession":
        """A session of the class for the binary's FMI version (:data:`SESSIONS`).

        Parameters
        ----------
        binary : FmuBinary
            The loaded FMU; the caller keeps it and closes it.
        interface : {"CoSimulation", "ModelExchange"}, optional
        name : str, optional
            The instance name passed to the FMU.
        """
        return SESSIONS[binary.version](binary, interface, name)

    @classmethod
    def open(cls, fmu: str | Path, interface: str = "CoSimulation") -> "PlantSession":
        """Extract and load ``fmu`` for this session alone; :meth:`close` removes it again.

        Parameters
        ----------
        fmu : path
            An FMI 2.0 or 3.0 FMU.
        interface : {"CoSimulation", "ModelExchange"}, optional

        Returns
        -------
        PlantSession
            Of the class for the FMU's version; a context manager.
        """
        binary = FmuBinary(fmu)
        try:
            session = cls.for_binary(binary, interface)
        except Exception:
            binary.close()
            raise
        session._owns_binary = True
        return session

    # -- errors ----------------------------------------------------------------------------
    def _log(self, _env, _instance, _status, _category, message) -> None:
        self._messages.append(_FFI.string(message).decode(errors="replace"))

    def _drain(self) -> str:
        text = "; ".join(self._messages) or "no message"
        self._messages.clear()
        return text

    def _check(self, status: int, what: str) -> None:
        if status >= _FATAL:
            # FMI 2.0 and 3.0: after fmi2Fatal no function of any instance of the FMU may be
            # called, not even fmi2Terminate or fmi2FreeInstance
            self.binary.lose()
            raise FmuError(f"{self.binary.identifier}: {what} failed fatally: {self._drain()} "
                           "(the instance cannot be used again)")
        if status >= 2:
            raise FmuError(f"{self.binary.identifier}: {what} failed: {self._drain()}")

    def _lose(self) -> None:
        """Never call this instance again; keep alive what the FMU may still point to."""
        if self._c is not None:
            _LOST.append(tuple(getattr(self, name, None) for name in
                               ("_c", "_callbacks", "_logger", "_name", "_guid", "_token",
                                "_resources", "_call", "_in", "_out", "_in_vr", "_out_vr")))
        self._c = None
        self._step_io = self._gone

    def _gone(self, _call, _t: float, _h: float) -> int:
        """A step of an instance that is closed or failed fatally: an error, never a call."""
        self._usable()
        return 0

    def _usable(self) -> None:
        if self._c is None:
            raise FmuError(f"{self.binary.identifier}: the instance is gone (closed, or an "
                           "instance of this FMU failed fatally): open a new session")

    @property
    def usable(self) -> bool:
        """False once closed or after an instance of the FMU reported fmi2Fatal."""
        return self._c is not None

    # -- set-up ----------------------------------------------------------------------------
    def reset(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0) -> None:
        """Return to the FMU's start values, apply ``parameters`` and initialize at ``start_time``.

        Parameters
        ----------
        parameters : mapping of str to float, optional
            Any parameter or input, and any variable whose start value an importer may set
            (``initial`` exact or approx); ``<state>_start`` sets initial states.
        start_time : float, optional
        """
        self._usable()
        lib, c = self._lib, self._c
        if self._initialized:
            self._check(lib.fmi2Reset(c), "fmi2Reset")
        reals, integers = self._split(parameters or {}, starts=True)
        self._check(lib.fmi2SetupExperiment(c, 0, 0.0, start_time, 0, 0.0), "fmi2SetupExperiment")
        self._initialized = True
        # before initialization: where FMI 2.0 lets an importer set every start value (a
        # variable with initial="approx" may be set only here)
        self._set_starts(reals, integers)
        self._check(lib.fmi2EnterInitializationMode(c), "fmi2EnterInitializationMode")
        self._check(lib.fmi2ExitInitializationMode(c), "fmi2ExitInitializationMode")
        if self._interface == "ModelExchange":
            info = _FFI.new("fmi2EventInfo*")
            self._check(lib.fmi2NewDiscreteStates(c, info), "fmi2NewDiscreteStates")
            self._check(lib.fmi2EnterContinuousTimeMode(c), "fmi2EnterContinuousTimeMode")
        self.time = self._start = start_time
        self._k = 0

    def _set_starts(self, reals, integers) -> None:
        for pairs, integer in ((reals, False), (integers, True)):
            if pairs:
                vrs, values = zip(*pairs)
                self._check(self._set_values(integer, vrs, values), "setting start values")

    # the calls that differ in their arguments between FMI 2.0 and 3.0
    def _get_values(self, integer: bool, vrs, buffer) -> int:
        return (self._lib.fmi2GetInteger if integer else self._lib.fmi2GetReal)(self._c, vrs, len(vrs), buffer)

    def _set_values(self, integer: bool, vrs, values) -> int:
        return (self._lib.fmi2SetInteger if integer else self._lib.fmi2SetReal)(self._c, vrs, len(vrs), values)

    def _split(self, values: Mapping[str, float], starts: bool = False):
        reals, integers = [], []
        for name, value in values.items():
            variable = self.binary.variable(name)
            start = starts and settable_start(variable)
            if variable.causality not in ("parameter", "input") and not start:
                raise FmuError(f"{self.binary.identifier}: {name} is a {variable.causality}"
                               + (" without a start value an importer may set" if starts else "")
                               + ", it cannot be set")
            if variable.type == self.INTEGER:
                if not math.isfinite(value) or value != int(value) or not -2**31 <= value < 2**31:
                    raise FmuError(f"{self.binary.identifier}: {name} must be a whole number "
                                   f"(32 bits), got {value}")
                integers.append((variable.valueReference, int(value)))
            elif variable.type == self.REAL:
                if not math.isfinite(value):
                    raise FmuError(f"{self.binary.identifier}: {name} = {value} is not finite")
                _within_declared(self.binary.identifier, variable, value)
                reals.append((variable.valueReference, float(value)))
            else:
                raise FmuError(f"{self.binary.identifier}: {name} is a {variable.type}; only "
                               f"{self.REAL} and {self.INTEGER} variables can be set")
        return reals, integers

    def set_io(self, inputs: Sequence[str] = (), outputs: Sequence[str] = ()) -> None:
        """Choose the inputs :meth:`step` takes and the outputs it returns, in that order.

        Parameters
        ----------
        inputs : sequence of str
            Real input variables.
        outputs : sequence of str
            Real variables read after each step.
        """
        self._usable()
        self.inputs, self.outputs = list(inputs), list(outputs)
        self._n_in, self._n_out = len(self.inputs), len(self.outputs)
        self._in_vr = _FFI.new("unsigned int[]", [self._real_vr(n, "input") for n in inputs] or [0])
        self._out_vr = _FFI.new("unsigned int[]", [self._real_vr(n, None) for n in outputs] or [0])
        self._in = _FFI.new("double[]", max(self._n_in, 1))
        self._out = _FFI.new("double[]", max(self._n_out, 1))
        call = self._call = _FFI.new("StepCall*")
        call.set_real = _FFI.cast("void*", _FFI.addressof(self._lib, self.SET_REALS))
        call.do_step = _FFI.cast("void*", _FFI.addressof(self._lib, self.DO_STEP))
        call.get_real = _FFI.cast("void*", _FFI.addressof(self._lib, self.GET_REALS))
        call.component = self._c
        call.in_vr, call.n_in, call.in_ = self._in_vr, self._n_in, self._in
        call.out_vr, call.n_out, call.out = self._out_vr, self._n_out, self._out

    def _real_vr(self, name: str, causality: str | None) -> int:
        variable = self.binary.variable(name)
        if variable.type != self.REAL or (causality and variable.causality != causality):
            raise FmuError(f"{self.binary.identifier}: {name} is not a {self.REAL} {causality or 'variable'}")
        return variable.valueReference

    # -- the hot path ----------------------------------------------------------------------
    def step(self, inputs: Sequence[float], h: float) -> list[float]:
        """Set the chosen inputs, advance by ``h`` and return the chosen outputs.

        Time is kept as ``t0 + k*h`` while ``h`` stays the same, so it does not drift.

        Parameters
        ----------
        inputs : sequence of float
            Values of the inputs chosen with :meth:`set_io`.
        h : float
            Communication step size.

        Returns
        -------
        list of float
            The chosen outputs at the end of the step.
        """
        if self._n_in == 1:
            self._in[0] = inputs[0]
        elif self._n_in:
            self._in[0:self._n_in] = inputs
        if h != self._h:
            self._start, self._k, self._h = self.time, 0, h
        failed = self._step_io(self._call, self.time, h)
        if failed:
            self._step_failed(failed, inputs)
        self._k += 1
        self.time = self._start + self._k * h
        return _FFI.unpack(self._out, self._n_out)

    # -- a loop in C that steps the session itself (furuta_cosim/cosim/native.py) ---------
    def native(self, h: float) -> dict | None:
        """What a sample loop in C needs to step this session without Python: the addresses of
        the step function (step_io) and of its call, of the input and output buffers chosen
        with :meth:`set_io`, and the clock (``start``, ``k``: time ``start + k*h``) for steps
        of ``h``. None when the step helper could not be built. The loop hands the clock back
        with :meth:`advanced`, and a failed step's code to :meth:`step_failed`.

        Parameters
        ----------
        h : float
            The communication step size the loop will step with.
        """
        self._usable()
        if not self._helper:
            return None
        if h != self._h:
            self._start, self._k, self._h = self.time, 0, h

        def address(cdata) -> int:
            return int(_FFI.cast("uintptr_t", cdata))

        return {"step": address(_FFI.addressof(self._helper, self.STEP_IO)),
                "call": address(self._call), "in": address(self._in), "out": address(self._out),
                "start": self._start, "k": self._k}

    def advanced(self, k: int) -> None:
        """The clock after a loop in C took the session to step ``k`` (see :meth:`native`).

        Parameters
        ----------
        k : int
            Steps of ``h`` since the clock's ``start``.
        """
        self._k = k
        self.time = self._start + self._k * self._h

    def step_failed(self, failed: int, inputs: Sequence[float]) -> None:
        """Raise the error :meth:`step` raises for what step_io returned.

        Parameters
        ----------
        failed : int
            step_io's nonzero return value.
        inputs : sequence of float
            The inputs of the failed step, for the message.
        """
        self._step_failed(failed, inputs)

    def _step_failed(self, failed: int, inputs: Sequence[float]) -> None:
        which, status = divmod(failed, 8)
        what = {1: f"setting {', '.join(self.inputs)} = {list(inputs)}",
                2: f"{self.DO_STEP} at t = {self.time:.9g}", 3: "reading the outputs"}[which]
        self._check(status, what)

    def _step_three_calls(self, _call, t: float, h: float) -> int:
        lib, c = self._lib, self._c  # a closed or fatally failed instance steps through _gone
        if self._n_in and (status := lib.fmi2SetReal(c, self._in_vr, self._n_in, self._in)) >= 2:
            return 8 + status
        if (status := lib.fmi2DoStep(c, t, h, 1)) >= 2:
            return 16 + status
        if self._n_out and (status := lib.fmi2GetReal(c, self._out_vr, self._n_out, self._out)) >= 2:
            return 24 + status
        return 0

    # -- any variable, any time ------------------------------------------------------------
    def get(self, names: Iterable[str]) -> list[float]:
        """Current values of Real or Integer variables.

        Parameters
        ----------
        names : iterable of str
        """
        self._usable()
        values = []
        for name in names:
            variable = self.binary.variable(name)
            if variable.type not in (self.REAL, self.INTEGER):
                raise FmuError(f"{self.binary.identifier}: {name} is a {variable.type}; only "
                               f"{self.REAL} and {self.INTEGER} variables are read")
            integer = variable.type == self.INTEGER
            buffer = _FFI.new("int[1]" if integer else "double[1]")
            self._check(self._get_values(integer, [variable.valueReference], buffer), f"reading {name}")
            values.append(buffer[0])
        return values

    def set(self, values: Mapping[str, float]) -> None:
        """Set Real inputs between steps.

        Parameters
        ----------
        values : mapping of str to float
        """
        self._usable()
        reals, integers = self._split(values)
        if integers:
            raise FmuError(f"{self.binary.identifier}: integers are parameters, set them in reset()")
        if reals:
            vrs, numbers = zip(*reals)
            self._check(self._set_values(False, vrs, numbers), f"setting {', '.join(values)}")

    # -- model exchange --------------------------------------------------------------------
    def derivatives(self, x: Sequence[float]) -> list[float]:
        """f(x, inputs) of a model-exchange session.

        Parameters
        ----------
        x : sequence of float
            The continuous states, ordered as the FMU declares them.
        """
        self._usable()
        self._x[0:self._nx] = x
        self._check(getattr(self._lib, self.SET_X)(self._c, self._x, self._nx), self.SET_X)
        self._check(getattr(self._lib, self.GET_DX)(self._c, self._dx, self._nx), self.GET_DX)
        return _FFI.unpack(self._dx, self._nx)

    # -- FMU state -------------------------------------------------------------------------
    def save_state(self):
        """A snapshot of the instance (fmi2GetFMUstate); give it to :meth:`restore_state`."""
        self._usable()
        state = _FFI.new("void**")
        self._check(getattr(self._lib, self.GET_STATE)(self._c, state), self.GET_STATE)
        return _Snapshot(self, state, self.time)

    def _free_state(self, pointer) -> None:
        getattr(self._lib, self.FREE_STATE)(self._c, pointer)

    def restore_state(self, snapshot: "_Snapshot") -> None:
        """Return the instance to a state saved with :meth:`save_state`.

        Parameters
        ----------
        snapshot : object
            What :meth:`save_state` returned, on this session.
        """
        self._usable()
        self._check(getattr(self._lib, self.SET_STATE)(self._c, snapshot.pointer[0]), self.SET_STATE)
        self.time, self._start, self._k = snapshot.time, snapshot.time, 0

    # -- end -------------------------------------------------------------------------------
    def close(self) -> None:
        """Terminate and free the instance; remove the extracted FMU if this session owns it."""
        if self._c is not None:
            if self._initialized:
                getattr(self._lib, self.TERMINATE)(self._c)
            getattr(self._lib, self.FREE)(self._c)
            self._c = None
            self._call = None
        self._step_io = self._gone
        if self._owns_binary:
            self.binary.close()

    def __enter__(self) -> "PlantSession":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PlantSession3(PlantSession):
    """The same session on an FMI 3.0 FMU (Float64 and Int32 variables): ``PlantSession.open``
    and :meth:`PlantSession.for_binary` give one when the binary is FMI 3.0. Each step is one foreign call (step_io3 of the
    helper), or three without a compiler (set, doStep, get)."""

    VERSION = "3.0"
    INSTANTIATE, STEP_IO = "fmi3Instantiate", "step_io3"
    REAL, INTEGER = "Float64", "Int32"
    GET_STATE, SET_STATE, FREE_STATE = "fmi3GetFMUState", "fmi3SetFMUState", "fmi3FreeFMUState"
    SET_X, GET_DX = "fmi3SetContinuousStates", "fmi3GetContinuousStateDerivatives"
    TERMINATE, FREE, DO_STEP = "fmi3Terminate", "fmi3FreeInstance", "fmi3DoStep"
    SET_REALS, GET_REALS = "fmi3SetFloat64", "fmi3GetFloat64"

    def __init__(self, binary: FmuBinary, interface: str = "CoSimulation", name: str = "plant"):
        md = binary.model_description
        if interface == "CoSimulation" and md.coSimulation is None:
            raise FmuError(f"{binary.identifier} has no co-simulation interface"
                           + (" (scheduled execution, with clocks, is not supported)"
                              if md.scheduledExecution else ""))
        self._flags = _FFI.new("bool[6]")
        super().__init__(binary, interface, name)

    def _instantiate(self, md, interface: str):
        """The FMI 3.0 instance (``fmi3Instantiate<interface>``), its callback kept on ``self``."""
        self._logger = _FFI.callback("void(void*, int, const char*, const char*)", self._log3)
        self._token = _FFI.new("char[]", (md.instantiationToken or "").encode())
        # FMI 3.0 gives the resources as a native path that ends with a separator
        self._resources = _FFI.new("char[]", (str(self.binary.directory / "resources") + "/").encode())
        if interface == "ModelExchange":
            return self._lib.fmi3InstantiateModelExchange(self._name, self._token, self._resources,
                                                          False, False, _FFI.NULL, self._logger)
        return self._lib.fmi3InstantiateCoSimulation(
            self._name, self._token, self._resources, False, False, False, False, _FFI.NULL, 0,
            _FFI.NULL, self._logger, _FFI.NULL)

    def _log3(self, _env, _status, _category, message) -> None:
        self._messages.append(_FFI.string(message).decode(errors="replace"))

    def reset(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0) -> None:
        self._usable()
        lib, c = self._lib, self._c
        if self._initialized:
            self._check(lib.fmi3Reset(c), "fmi3Reset")
        reals, integers = self._split(parameters or {}, starts=True)
        self._initialized = True
        self._set_starts(reals, integers)
        self._check(lib.fmi3EnterInitializationMode(c, False, 0.0, start_time, False, 0.0),
                    "fmi3EnterInitializationMode")
        self._check(lib.fmi3ExitInitializationMode(c), "fmi3ExitInitializationMode")
        if self._interface == "ModelExchange":
            # event mode: iterate the discrete states to a fixed point, then continuous time
            flags, when = self._flags, _FFI.new("double*")
            for _ in range(100):
                self._check(lib.fmi3UpdateDiscreteStates(c, flags, flags + 1, flags + 2, flags + 3,
                                                         flags + 4, when), "fmi3UpdateDiscreteStates")
                if not flags[0]:
                    break
            self._check(lib.fmi3EnterContinuousTimeMode(c), "fmi3EnterContinuousTimeMode")
        self.time = self._start = start_time
        self._k = 0

    def _step_failed(self, failed: int, inputs: Sequence[float]) -> None:
        if failed in (32, 33):  # step_io3: the FMU asked to end, or returned early
            what = "asked to end the simulation" if failed == 32 else "returned early from the step"
            self._messages.append(f"the FMU {what} at t = {self._call.last:.9g}")
            failed = 16 + 3
        super()._step_failed(failed, inputs)

    def _step_three_calls(self, call, t: float, h: float) -> int:
        lib, c = self._lib, self._c  # a closed or fatally failed instance steps through _gone
        if self._n_in and (status := lib.fmi3SetFloat64(c, self._in_vr, self._n_in, self._in, self._n_in)) >= 2:
            return 8 + status
        flags = call.flags  # as step_io3 does: its answers go to the call, 32 and 33 as there
        if (status := lib.fmi3DoStep(c, t, h, True, flags, flags + 1, flags + 2,
                                     _FFI.addressof(call, "last"))) >= 2:
            return 16 + status
        if flags[1] or flags[2]:
            return 32 if flags[1] else 33
        if self._n_out and (status := lib.fmi3GetFloat64(c, self._out_vr, self._n_out, self._out, self._n_out)) >= 2:
            return 24 + status
        return 0

    def _get_values(self, integer: bool, vrs, buffer) -> int:
        get = self._lib.fmi3GetInt32 if integer else self._lib.fmi3GetFloat64
        return get(self._c, vrs, len(vrs), buffer, len(vrs))

    def _set_values(self, integer: bool, vrs, values) -> int:
        put = self._lib.fmi3SetInt32 if integer else self._lib.fmi3SetFloat64
        return put(self._c, vrs, len(vrs), values, len(values))


class _Snapshot:
    def __init__(self, session: PlantSession, pointer, time: float):
        self.session, self.pointer, self.time = session, pointer, time

    def __del__(self):
        if self.session._c is not None and self.pointer[0] != _FFI.NULL:
            self.session._free_state(self.pointer)


# the session class of each FMI version this project imports (fmu/versions.py lists them)
SESSIONS: dict[str, type[PlantSession]] = {cls.VERSION: cls for cls in (PlantSession, PlantSession3)}
