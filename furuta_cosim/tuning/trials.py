"""Where a rig trial runs: on a board through ``rig run`` (:class:`BoardTrials`), or on any rig a
lab drives itself, through request and result files (:class:`ExternalTrials`).

Both take one trial at a time: the candidate for each of the spec's scenarios (its controller
file, and its runtime controller for a board) and the folder of the trial in the run directory
(``trials/NNNN``), and give back a :class:`TrialResult`: the trace of each scenario (or its
metrics, where an external rig sends only those), the trial's status and what failed. A trial
the supervisor stops is a result too, with the data it collected.

The external protocol (docs: Tuning on the rig) in one paragraph: for trial ``NNNN`` the tuning
writes ``DIR/NNNN/`` with ``candidate.yaml`` (the controller file), ``candidate.fmu`` (the same
controller as an FMI 2.0 FMU), ``reference-<scenario>.csv`` (``t,r``: the reference at each
control sample) and, last, ``request.json`` (what to run and what to send back); the rig side
writes ``DIR/NNNN/result.json`` (atomically: a temporary name, then renamed) with a status and,
per scenario, an experiment file (the log from the moment the candidate took over) or the
metrics. Every file the rig side writes is read as hostile: paths stay inside ``DIR/NNNN``,
sizes are bounded, every number must be finite.
"""

from __future__ import annotations

import json
import os
import math
import shutil
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.errors import ConfigError, RunStopped
from furuta_cosim.files import folder as make_folder, write_text

PROTOCOL = 1
MAX_RESULT_BYTES = 1_000_000      # result.json
WAIT = 3600.0                     # s an external trial may take by default (--wait)
STATUSES = ("finished", "tripped", "failed")


@dataclass(frozen=True)
class TrialScenario:
    """One scenario of a trial: its label, the prepared scenario (reference, period), the
    candidate's controller file for it and its runtime controller."""

    label: str
    prepared: object
    cfile: object
    runtime: object


@dataclass
class TrialResult:
    """What a trial gave: ``status`` (finished, tripped, failed), ``reason``, ``failures``
    (scenario label, or ``reset``, -> why), the traces or metrics of the scenarios that ran,
    seconds of rig time, whether the rig was left at rest, and the arm reference the reset held
    the arm home with when it handed over to the first scenario (``hold_offset``, rad; None
    where the reset did not finish or the trial does not say)."""

    status: str
    reason: str
    failures: dict = field(default_factory=dict)
    traces: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    seconds: float = 0.0
    at_rest: bool = True
    hold_offset: float | None = None


def trial_seed(seed: int, name: str) -> int:
    """The virtual board's noise seed for trial ``name`` of a run of ``seed``: a resumed run's
    trial sees the noise the uninterrupted run's did."""
    return int(np.random.default_rng([seed, 7, zlib.crc32(name.encode())]).integers(2**31 - 1))


class BoardTrials:
    """Trials on a board (``--board``): each trial one ``rig run`` of the trial runtime
    (rig/trial.py) into ``trials/NNNN/run``; before it, when the rig was not left at rest
    (a session's first trial, a trial the supervisor stopped), ``rig home`` into
    ``trials/NNNN/home``.

    Parameters
    ----------
    board : str
        As ``--board`` names it (``virtual:fast``, ``quanser``).
    plant : PlantSet
        The rig's plant file (limits, sensors, the pendulum of the damp-down; the virtual board
        runs it).
    reset : str
        The swing-up-and-balance file that resets the rig (``rig.reset``).
    fall : float
        rad from upright where a candidate's scenario counts as failed.
    seed : int
        The run's seed (the virtual board's noise per trial).
    options : dict
        More of the board's options (``board_for``), e.g. the virtual board's ``delay``.
    """

    kind = "board"

    def __init__(self, board: str, plant, reset: str, fall: float, seed: int, options: dict | None = None):
        from furuta_cosim.rig.board import board_for

        self.board, self.plant, self.reset, self.fall, self.seed = board, plant, reset, fall, seed
        self.options = dict(options or {})
        self.at_rest = False  # nothing is known of the rig before this session's first homing
        self._check(board_for(board, plant, **self._options(None, "check")))
        self.where = f"on the {board} board"

    def _check(self, board) -> None:
        """Before the run (its folder, its simulated prior): the reset file is a swing-up, the
        board opens (its SDK, its channels) and reads finite counts and current with the
        amplifier off; one ConfigError otherwise. Nothing is driven."""
        import math

        from furuta_cosim.controllers import load_controller

        reset = load_controller(self.reset)
        if reset.swingup is None:
            raise ConfigError([f"rig.reset: {self.reset}: not a swing-up-and-balance file: a trial resets the "
                               "rig by swinging the pendulum up (e.g. reset: swingup-qube)"])
        board.open()
        try:
            reading = board.read()
        finally:
            board.close()
        values = (reading.arm, reading.pendulum) + ((reading.current,) if reading.current is not None else ())
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ConfigError([f"board {self.board}: the board reads {values} with the amplifier off: "
                               "not finite counts and current; check its channels"])

    def _options(self, folder: Path | None, name: str) -> dict:
        options = dict(self.options)
        if self.board.partition(":")[0] == "virtual":
            options.setdefault("seed", trial_seed(self.seed, name))
            if folder is not None:
                options["log"] = folder / "board.csv"
        return options

    def run(self, folder: Path, name: str, scenarios: list[TrialScenario],
            log: Callable[[str], None] = lambda line: None) -> TrialResult:
        """Run trial ``name`` on the board.

        Parameters
        ----------
        folder : path
            The trial's folder in the run directory (``trials/NAME``): its rig run goes to
            ``run/``, a homing before it to ``home/``.
        name : str
            ``NNNN`` (the history's index) or ``baseline-NAME``; it seeds the virtual board's
            noise.
        scenarios : list of TrialScenario
            The candidate for each of the spec's scenarios.
        log : callable
            Takes the lines the runs say.

        Returns
        -------
        TrialResult
            Each scenario's trace from the log, the status, what failed.

        Raises
        ------
        RunStopped
            When the rig does not come to rest before the trial.
        """
        from furuta_cosim.rig.board import board_for
        from furuta_cosim.rig.runner import home
        from furuta_cosim.rig.trial import Segment, run_trial, segment_traces

        if not self.at_rest:
            homed = home(board_for(self.board, self.plant, **self._options(folder / "home", name + "/home")),
                         self.plant, folder / "home", log=log)
            if homed["status"] != "finished":
                raise RunStopped(f"the rig did not come to rest before trial {name} ({homed['reason']}; "
                                 f"{folder / 'home'}): check it, then resume the tuning")
            self.at_rest = True
        segments = [Segment(s.label, s.runtime, np.asarray(s.prepared.rbar, dtype=float)) for s in scenarios]
        period = scenarios[0].prepared.control_period
        board = board_for(self.board, self.plant, **self._options(folder / "run", name))
        summary = run_trial(segments, board, self.plant, folder / "run", reset=self.reset, period=period,
                            zero=True, fall=self.fall, log=log)
        self.at_rest = bool(summary["at_rest"])
        traces = segment_traces(folder / "run", segments)
        status = "tripped" if summary["tripped"] else ("finished" if summary["code"] == 0 else "failed")
        return TrialResult(status, summary["reason"], dict(summary["failures"]), traces, {},
                           float(summary["seconds"]), self.at_rest, summary["hold_offset"])


class ExternalTrials:
    """Trials on a rig driven by someone else's code, through files in ``folder`` (module
    docstring).

    Parameters
    ----------
    folder : path
        The exchange folder (``--evaluator external DIR``).
    wait : float
        Seconds to wait for a trial's result before the tuning stops (resumable: a resume waits
        for the same request again).
    metrics : list of str
        The metrics the spec needs of each scenario (a rig that sends metrics must send these).
    poll : float
        Seconds between looks for the result.
    """

    kind = "external"

    def __init__(self, folder: str | Path, wait: float = WAIT, metrics=(), poll: float = 0.2):
        if not (isinstance(wait, (int, float)) and math.isfinite(wait) and 0 < wait <= 7 * 86400):
            raise ConfigError([f"wait: expected seconds in (0, 604800], got {wait}"])
        if Path(folder).exists() and not Path(folder).is_dir():
            raise ConfigError([f"evaluator: {folder}: expected the folder the trials are exchanged "
                               "through (made if missing), got a file"])
        self.folder = make_folder(Path(folder))
        self.wait, self.metrics, self.poll = float(wait), sorted(set(metrics)), poll
        self.where = f"on an external rig through {self.folder}"

    def run(self, folder: Path, name: str, scenarios: list[TrialScenario],
            log: Callable[[str], None] = lambda line: None) -> TrialResult:
        """Write trial ``name``'s request and wait for the rig's result.

        Parameters
        ----------
        folder : path
            The trial's folder in the run directory: what the rig sent back is copied to
            ``external/`` there.
        name : str
            ``NNNN`` or ``baseline-NAME``: the request is ``DIR/NAME``.
        scenarios : list of TrialScenario
            The candidate for each of the spec's scenarios.
        log : callable
            Takes a line when the request is written.

        Returns
        -------
        TrialResult
            Each scenario's trace (from an experiment file) or metrics, the status, what failed.

        Raises
        ------
        RunStopped
            When no result comes within ``wait`` seconds (a resume waits for it again).
        ConfigError
            When the result cannot be read (module docstring).
        """
        if (self.folder / name).is_symlink():  # written through, it overwrote a user's files
            raise ConfigError([f"{self.folder / name}: a symbolic link, not a request folder of this tuning: "
                               "remove it"])
        request = make_folder(self.folder / name)
        result = request / "result.json"
        if not (request / "request.json").is_file():
            if os.path.lexists(result):  # there before its request: not this trial's result
                raise ConfigError([f"{result}: there before its request was written: remove it (a result "
                                   "is read only after its request)"])
            self._write_request(request, name, scenarios)
            log(f"trial {name}: request written to {request}; waiting for {result.name}")
        else:
            log(f"trial {name}: waiting for {result} (the request was written before)")
        waited = 0.0
        while not result.is_file():
            if os.path.lexists(result):   # a folder, a FIFO, a dangling link: it never will be a result
                raise ConfigError([f"{result}: not a plain file (a {_kind(result)}): the rig's result "
                                   "must be one; remove it"])
            if waited >= self.wait:
                raise RunStopped(f"no result for trial {name} in {self.wait:g} s ({result}); resume "
                                 "the tuning to wait for it again")
            time.sleep(self.poll)
            waited += self.poll
        found = read_result(request, scenarios, self.metrics)
        # the run directory keeps the trial's data: the request, the result and its files
        make_folder(folder)
        for name in sorted({"request.json", "result.json", "candidate.yaml", *found.pop("files")}):
            source = request / name
            target = folder / "external" / name
            make_folder(target.parent)
            shutil.copyfile(source, target)
        return TrialResult(found["status"], found["reason"], found["failures"], found["traces"],
                           found["metrics"], found["seconds"], True)

    def _write_request(self, request: Path, name: str, scenarios: list[TrialScenario]) -> None:
        from furuta_cosim.controllers import save_controller
        from furuta_cosim.export import export_controller

        first = scenarios[0].cfile
        save_controller(first, request / "candidate.yaml")
        export_controller(request / "candidate.yaml", request / "candidate.fmu")
        entries = []
        for s in scenarios:
            prepared = s.prepared
            lines = ["t,r"] + [f"{t!r},{r!r}" for t, r in zip(map(float, prepared.t), map(float, prepared.rbar))]
            write_text(request / f"reference-{s.label}.csv", "\n".join(lines) + "\n")
            entries.append({"name": s.label, "reference": f"reference-{s.label}.csv",
                            "tracked": prepared.tracked, "period": prepared.control_period,
                            "samples": len(prepared.t), "prefilter": s.cfile.F})
        document = {"protocol": PROTOCOL, "trial": name, "controller": "candidate.yaml",
                    "fmu": "candidate.fmu", "scenarios": entries, "metrics": self.metrics,
                    "result": "result.json", "statuses": list(STATUSES)}
        write_text(request / "request.json", json.dumps(document, indent=2) + "\n")


def _kind(path: Path) -> str:
    """What a path that is not a plain file is, in a word."""
    import stat

    mode = os.lstat(path).st_mode
    return ("symbolic link" if stat.S_ISLNK(mode) else "folder" if stat.S_ISDIR(mode)
            else "FIFO" if stat.S_ISFIFO(mode) else "socket" if stat.S_ISSOCK(mode) else "device")


def read_result(request: Path, scenarios: list[TrialScenario], metrics) -> dict:
    """An external rig's ``result.json`` for the trial in ``request``, checked: its status,
    and per scenario a trace (from an experiment file) or the metrics ``metrics`` names.
    Raises ConfigError naming the file and key of the first problem: a result that cannot be
    read is the rig side's fault, not a failed candidate."""
    path = request / "result.json"
    where = f"{path}"
    if path.is_symlink() or not path.is_file():
        raise ConfigError([f"{where}: not a plain file"])
    if path.stat().st_size > MAX_RESULT_BYTES:
        raise ConfigError([f"{where}: larger than {MAX_RESULT_BYTES} bytes"])
    request_file = request / "request.json"
    if request_file.is_file() and path.stat().st_mtime < request_file.stat().st_mtime - 1.0:
        raise ConfigError([f"{where}: older than its request ({request_file.name}): not this trial's result"])
    from furuta_cosim.inputs import read_input

    try:
        text = read_input(path, MAX_RESULT_BYTES).decode("utf-8", errors="strict")
    except UnicodeDecodeError as error:
        raise ConfigError([f"{where}: not UTF-8 text (byte {error.start}): the rig side wrote it so"]) from None
    from furuta_cosim.identify.variants import _depth   # the one count of nesting (fit.json's too)

    if _depth(text.encode("utf-8")) > MAX_NESTING:
        raise ConfigError([f"{where}: nested deeper than {MAX_NESTING} levels"])
    try:
        document = json.loads(text, parse_constant=_no_constant, object_pairs_hook=_no_duplicates)
    except (ValueError, UnicodeDecodeError, RecursionError) as error:
        raise ConfigError([f"{where}: not JSON ({error})"]) from None
    if not isinstance(document, dict):
        raise ConfigError([f"{where}: expected an object"])
    unknown = sorted(set(document) - {"status", "reason", "seconds", "scenarios", "failures"})
    if unknown:
        raise ConfigError([f"{where}: unknown key(s) {', '.join(map(repr, unknown))}"])
    status = document.get("status")
    if status not in STATUSES:
        raise ConfigError([f"{where}: status: expected one of {', '.join(STATUSES)}, got {status!r}"])
    reason = document.get("reason", status)
    if not isinstance(reason, str) or len(reason) > 2000:
        raise ConfigError([f"{where}: reason: expected text of at most 2000 characters"])
    seconds = document.get("seconds", 0.0)
    if not _finite(seconds) or seconds < 0:
        raise ConfigError([f"{where}: seconds: expected a finite number >= 0, got {seconds!r}"])
    given = document.get("scenarios", {})
    if not isinstance(given, dict):
        raise ConfigError([f"{where}: scenarios: expected an object of scenario name -> result"])
    labels = {s.label: s for s in scenarios}
    extra = sorted(set(given) - set(labels))
    if extra:
        raise ConfigError([f"{where}: scenarios: {', '.join(map(repr, extra))} not in the request "
                           f"({', '.join(labels)})"])
    failures = document.get("failures", {})
    if not isinstance(failures, dict) or not all(isinstance(k, str) and isinstance(v, str) and len(v) <= 2000
                                                 for k, v in failures.items()):
        raise ConfigError([f"{where}: failures: expected an object of scenario name -> why it failed"])
    traces, found, files = {}, {}, []
    for label, entry in given.items():
        key = f"{where}: scenarios.{label}"
        if not isinstance(entry, dict) or len(entry) != 1 or next(iter(entry)) not in ("experiment", "metrics"):
            raise ConfigError([f"{key}: expected {{\"experiment\": FILE}} or {{\"metrics\": {{...}}}}"])
        if "metrics" in entry:
            values = entry["metrics"]
            if not isinstance(values, dict):
                raise ConfigError([f"{key}.metrics: expected an object of metric -> number"])
            missing = [m for m in metrics if m not in values]
            if missing:
                raise ConfigError([f"{key}.metrics: missing {', '.join(missing)} (request.json names "
                                   "the metrics to send)"])
            from furuta_cosim.metrics import lower_bound

            for metric, value in values.items():
                if not _finite(value):
                    raise ConfigError([f"{key}.metrics.{metric}: expected a finite number, got {value!r}"])
                least = lower_bound(str(metric))
                if least is not None and value < least:
                    raise ConfigError([f"{key}.metrics.{metric}: {value!r} is below {least:g}, the least "
                                       f"{str(metric).rsplit('.', 1)[-1]} can be: not a measurement"])
            found[label] = {m: float(v) for m, v in values.items()}
            continue
        experiment, data = _inside(request, entry["experiment"], f"{key}.experiment")
        traces[label] = trace_of(experiment, labels[label].prepared, f"{key}.experiment")
        files += [experiment.relative_to(request).as_posix(), data.relative_to(request).as_posix()]
    reason = _printable(reason)
    failures = {_printable(k): _printable(v) for k, v in failures.items()}
    return {"status": status, "reason": reason, "failures": dict(failures), "traces": traces,
            "metrics": found, "seconds": float(seconds), "files": files}


def _inside(request: Path, name, key: str) -> tuple[Path, Path]:
    """An experiment file the rig side names, and its CSV: both plain files inside ``request``."""
    from furuta_cosim.identify.experiment import load_experiment

    if not isinstance(name, str) or not name or len(name) > 255:
        raise ConfigError([f"{key}: expected a file name inside {request}"])
    root = request.resolve()
    path = (request / name)
    if Path(name).is_absolute() or path.is_symlink() or root not in path.resolve().parents:
        raise ConfigError([f"{key}: {name!r} is not a file inside {request}"])
    if not path.is_file():
        raise ConfigError([f"{key}: {path}: no such file"])
    try:
        experiment = load_experiment(path)
    except ConfigError as error:
        raise error.within(key) from None
    data = Path(experiment.data)
    if data.is_symlink() or root not in data.resolve().parents:
        raise ConfigError([f"{key}: its data {data} is not a file inside {request}"])
    controller = experiment.loop.controller if experiment.loop is not None else None
    if controller is not None and (controller.is_symlink() or root not in controller.resolve().parents):
        raise ConfigError([f"{key}: its loop.controller {controller} is not a file inside {request}"])
    return path, data


def trace_of(path: Path, prepared, key: str):
    """A scenario's trace from an experiment file of the rig: the candidate's samples from the
    file's first, as many as the scenario has (fewer: the candidate was stopped), the
    reference the scenario's, the pendulum's angle wrapped to (-pi, pi], the voltage the input."""
    from furuta_cosim.cosim.trace import Trace
    from furuta_cosim.identify.experiment import load_experiment
    from furuta_cosim.swingup import wrap

    experiment = load_experiment(path)
    period = prepared.control_period
    if abs(experiment.period - period) > 1e-6 * period:
        raise ConfigError([f"{key}: its samples are {experiment.period:g} s apart; the scenario "
                           f"runs at {period:g} s"])
    if "V" not in experiment.inputs:
        raise ConfigError([f"{key}: inputs: needs V (the voltage applied)"])
    missing = [name for name in ("theta0", "theta1") if name not in experiment.outputs]
    if missing:
        raise ConfigError([f"{key}: outputs: needs {', '.join(missing)}"])
    n = min(experiment.samples, len(prepared.t))
    t = np.asarray(experiment.t[:n], dtype=float) - float(experiment.t[0])
    signals = {"theta0": np.asarray(experiment.outputs["theta0"].values[:n], dtype=float),
               "theta1": np.array([wrap(v) for v in experiment.outputs["theta1"].values[:n]])}
    units = {"theta0": "rad", "theta1": "rad", "V": "V"}
    for name in ("dtheta0", "dtheta1", "i"):
        if name in experiment.outputs:
            signals[name] = np.asarray(experiment.outputs[name].values[:n], dtype=float)
            units[name] = {"i": "A"}.get(name, "rad/s")
    failure = None if n == len(prepared.t) else f"the rig ran {n} of the scenario's {len(prepared.t)} samples"
    return Trace(prepared.scenario.name, t, np.asarray(prepared.rbar[:n], dtype=float),
                 np.asarray(experiment.input_at("V")[:n], dtype=float), signals, prepared.tracked,
                 "V", failure, units)


def _finite(value) -> bool:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:   # an integer of hundreds of digits: no measurement
        return False


def _printable(text: str) -> str:
    """Text from the rig side with its control characters (a terminal's escape codes: they
    clear a screen or retitle a window) shown as escapes, never sent to the terminal."""
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in text)


MAX_NESTING = 32   # levels of brackets a result.json may nest


def _no_duplicates(pairs):
    """A JSON object whose keys are each given once (of two ``status`` keys the last won)."""
    found = {}
    for key, value in pairs:
        if key in found:
            raise ValueError(f"the key {key!r} is given twice")
        found[key] = value
    return found


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")
