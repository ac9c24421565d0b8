"""Scenario-driven regression: every controller of every scenario against its baseline.

A baseline is one small YAML file per scenario and controller,
``<scenario folder>/baselines/<scenario>/<controller>.yaml``: the metrics of the run, its trace
downsampled to about ``regression.points`` rows (one row per line, so a change shows as a
diff), and the versions it was made from (a hash of the scenario file and of the controller
file, the plant FMU's model identifier and parameters). A baseline made from another version
of its scenario file is refused: the comparison would not mean anything. A baseline is
compared on what it holds, and ``--update`` rewrites only what moved.

Metrics are compared within the scenario's ``regression`` tolerances; traces within a band
around the baseline's, with fmpy's ``validate_signal`` (the band of the Modelica CSV-compare
tool). The command-line interface only formats what :func:`regress` returns.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from furuta_cosim import __version__, paths
from furuta_cosim.config import MAX_BYTES, Checker, excerpt, load_yaml
from furuta_cosim.cosim.evaluation import Compiled, runs, scenario_controllers
from furuta_cosim.cosim.master import Prepared, lacks, on_plant, prepare
from furuta_cosim.cosim.result import RunResult
from furuta_cosim.documents import dumps, json_safe
from furuta_cosim.errors import ConfigError, NotApplicable, PlantUnfit
from furuta_cosim.fmu.plants import load_plant
from furuta_cosim.files import output_file, output_folder, write_text
from furuta_cosim.scenario import Scenario, load_mapping, load_scenario

FORMAT = 1
_PLAIN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")


def file_hash(path: Path | None) -> str | None:
    """The first 16 hex digits of the file's SHA-256 (None without a file)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16] if path else None


def baseline_path(scenario: Scenario, controller: str, folder: Path | None = None) -> Path:
    """Where the baseline of ``controller`` on ``scenario`` lives (``folder``: another root)."""
    for name in (scenario.name, controller):
        if not _PLAIN.fullmatch(name):
            raise ConfigError([f"{scenario.source}: {name!r} cannot name a baseline file "
                               "(letters, digits, '.', '_', '-')"])
    root = folder if folder is not None else (
        scenario.path.parent if scenario.path else paths.scenarios()) / "baselines"
    return Path(root) / scenario.name / f"{controller}.yaml"


@dataclass
class Difference:
    """One thing that moved: a metric, a trace signal, or whether the run finished."""

    kind: str          # "metric", "trace", "run"
    name: str
    expected: object
    got: object
    detail: str = ""

    def describe(self) -> str:
        return f"{self.name}: expected {_show(self.expected)}, got {_show(self.got)}" + (
            f" ({self.detail})" if self.detail else "")


@dataclass
class Case:
    """One scenario and controller: its status and what moved."""

    scenario: str
    controller: str
    baseline: Path
    status: str                    # pass, fail, missing, new, updated, unchanged, unfit, n/a
    differences: list[Difference] = field(default_factory=list)
    checked: int = 0               # metrics and signals compared
    wall_time: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        return self.status in ("fail", "missing", "unfit")

    def lines(self) -> list[str]:
        if self.status == "unfit":
            return [f"{self.scenario} / {self.controller}: cannot run on this FMU: {note}" for note in self.notes]
        if self.status == "n/a":
            return [f"{self.scenario} / {self.controller}: not applicable: {note}" for note in self.notes]
        if self.status == "missing":
            return [f"{self.scenario} / {self.controller}: no baseline at {self.baseline} "
                    "(regress with `update` makes it)"]
        return [f"{self.scenario} / {self.controller}: {d.describe()}" for d in self.differences]

    def to_dict(self) -> dict:
        return {"scenario": self.scenario, "controller": self.controller, "status": self.status,
                "baseline": str(self.baseline), "checked": self.checked, "wall_time": self.wall_time, "notes": self.notes,
                "differences": [{"kind": d.kind, "name": d.name, "expected": json_safe(d.expected),
                                 "got": json_safe(d.got), "detail": d.detail} for d in self.differences]}


# ---------------------------------------------------------------------------------------------
# baselines: made from a result, read back strictly


def make_baseline(prepared: Prepared, compiled: Compiled, result: RunResult) -> dict:
    """The baseline document of a run. A run that stopped early keeps only what another
    machine reproduces: that it stopped, when, and its trace while every signal stayed within
    the scenario's ``regression.divergence.bound`` (no metrics: the blow-up dominates them)."""
    scenario = prepared.scenario
    trace = result.trace
    every = max(1, math.ceil(prepared.steps / scenario.regression.points))
    columns = trace.columns()
    keep = len(trace.t)
    if result.failure:
        keep = _bounded_length(trace, columns, scenario.regression.divergence_bound)
    rows = (np.column_stack([trace[c][:keep:every] for c in columns]) if keep
            else np.zeros((0, len(columns))))
    from furuta_cosim.fmu.session import model_description

    description = model_description(prepared.fmu)  # the zip checked, read once per file version
    document = {
        "format": FORMAT,
        "scenario": {"name": scenario.name, "sha256": file_hash(scenario.path)},
        "controller": {"name": compiled.name, "sha256": file_hash(compiled.cfile.path)},
        # the FMU by its model identifier and the values it ran with: its GUID changes with
        # every rebuild of the model, also one that leaves the numbers alone, so it is not stored
        "plant": {"fmu": description.coSimulation.modelIdentifier,
                  "parameters": scenario.plant or None,
                  "start": {k: _number(v) for k, v in sorted(prepared.start.items())}},
        "made_with": f"furuta-cosim {__version__}",
        "failure": result.failure,
    }
    if result.failure:
        document["stopped_at"] = _number(trace.t[-1]) if len(trace.t) else 0.0
    document["metrics"] = {} if result.failure else {
        k: _number(v) for k, v in sorted(result.metrics.items())}
    document["trace"] = {"every": every, "columns": columns,
                         "rows": [[_number(v) for v in row] for row in rows.tolist()]}
    return document


def _bounded_length(trace, columns: list[str], bound: float) -> int:
    """How many samples of the trace come before any signal leaves +-bound."""
    if not len(trace.t):
        return 0
    values = np.column_stack([np.asarray(trace[c], dtype=float) for c in columns if c != "t"])
    outside = np.flatnonzero(~np.all(np.abs(values) <= bound, axis=1))
    return int(outside[0]) if len(outside) else len(trace.t)


def baseline_text(document: dict) -> str:
    """YAML with one trace row per line (diffable), numbers to 10 significant digits."""
    import yaml

    head = {k: v for k, v in document.items() if k != "trace"}
    trace = document["trace"]
    text = ["# A regression baseline written by 'furuta-cosim regress --update'; compared by "
            "'furuta-cosim regress'.",
            yaml.safe_dump(head, sort_keys=False, default_flow_style=False, width=1000).rstrip(),
            "trace:", f"  every: {trace['every']}",
            f"  columns: [{', '.join(trace['columns'])}]", "  rows:"]
    text += ["    - [" + ", ".join(_yaml_number(v) for v in row) + "]" for row in trace["rows"]]
    return "\n".join(text) + "\n"


def read_baseline(path: Path) -> dict:
    """A baseline file, checked key by key; ConfigError naming the file and key otherwise."""
    data = load_yaml(path)
    check = Checker(path)
    top = check.mapping(data, "", required=("format", "scenario", "controller", "metrics", "trace"),
                        optional=("plant", "made_with", "failure", "stopped_at"))
    if top is None:
        check.done()
    if "format" in top and top["format"] != FORMAT:
        check.fail("format", f"expected {FORMAT}, got {top['format']!r}")
    for part in ("scenario", "controller"):
        if part in top:
            section = check.mapping(top[part], part, required=("name", "sha256"))
            if section:
                check.string(section.get("name"), f"{part}.name")
                if section.get("sha256") is not None:
                    check.string(section.get("sha256"), f"{part}.sha256")
    if top.get("failure") is not None:
        check.string(top["failure"], "failure")
        if "stopped_at" not in top:
            check.fail("stopped_at", "missing (a baseline of a run that stopped early records when)")
        else:
            check.number(top["stopped_at"], "stopped_at", minimum=0.0)
    elif "stopped_at" in top:
        check.fail("stopped_at", "only a baseline of a run that stopped early (failure) has one")
    metrics = {}
    if "metrics" in top:
        raw = top["metrics"]
        entries = check.mapping(raw, "metrics", optional=tuple(raw) if isinstance(raw, dict) else ())
        for name, value in (entries or {}).items():
            if not isinstance(name, str) or name.count(".") < 1 or not all(name.split(".")):
                check.fail(f"metrics.{excerpt(str(name))}", "expected a metric name <signal>.<metric>")
                continue
            if value is None:
                metrics[str(name)] = math.inf
            elif check.number(value, f"metrics.{name}") is not None:
                metrics[str(name)] = float(value)
    trace = None
    if "trace" in top:
        section = check.mapping(top["trace"], "trace", required=("every", "columns", "rows"))
        if section and all(k in section for k in ("every", "columns", "rows")):
            check.number(section["every"], "trace.every", minimum=1, integer=True)
            columns = check.names(section["columns"], "trace.columns")
            rows = section["rows"]
            if columns and "t" not in columns:
                check.fail("trace.columns", f"expected a column t, got {columns}")
            elif columns and _rows_ok(check, rows, len(columns)):
                values = np.array(rows, dtype=float).reshape(len(rows), len(columns))
                bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))
                if len(bad):
                    check.fail(f"trace.rows[{bad[0]}]", f"not finite ({len(bad)} of {len(rows)} "
                                                        "rows): a baseline's trace is finite")
                elif len(values) and np.any(np.diff(values[:, columns.index("t")]) <= 0):
                    check.fail("trace.rows", "the times (column t) must increase")
                else:
                    trace = {c: values[:, j] for j, c in enumerate(columns)}
    check.done()
    every = int(top["trace"]["every"]) if trace is not None else 1
    return {**top, "metrics": metrics, "trace": trace, "every": every}


def _rows_ok(check: Checker, rows, width: int) -> bool:
    if not isinstance(rows, list):
        check.fail("trace.rows", f"expected a list of rows, got {type(rows).__name__}")
        return False
    for k, row in enumerate(rows):
        if (not isinstance(row, list) or len(row) != width
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)):
            check.fail(f"trace.rows[{k}]", f"expected {width} numbers, got {_brief(row)}")
            return False
    return True


def check_versions(baseline: dict, path: Path, prepared: Prepared, compiled: Compiled) -> None:
    """A baseline made for another scenario or controller, or from another version of its
    scenario file: ConfigError. (A changed controller file is what regression is for: its
    runs are compared, and the change is noted in the report.)"""
    problems = []
    scenario = prepared.scenario
    for part, name in (("scenario", scenario.name), ("controller", compiled.name)):
        if baseline[part]["name"] != name:
            problems.append(f"{path}: {part}.name: made for {baseline[part]['name']!r}, not {name!r}")
    if not problems and baseline["scenario"].get("sha256") != file_hash(scenario.path):
        problems.append(f"{path}: scenario.sha256: made from another version of {scenario.source} "
                        f"({baseline['scenario'].get('sha256')}, now {file_hash(scenario.path)}); "
                        "check the change, then regress with `update`")
    trace = baseline["trace"]
    if not problems and trace is not None:
        # the rows are the run's samples, every ``every``-th: all of them unless it stopped early
        instants = np.asarray(prepared.t)[::baseline["every"]]
        rows = len(trace["t"])
        if baseline.get("failure") is None and rows != len(instants):
            problems.append(f"{path}: trace.rows: expected {len(instants)} rows (the run's samples, "
                            f"every {baseline['every']}), got {rows}: the baseline is damaged")
        elif rows > len(instants) or not np.allclose(trace["t"], instants[:rows], rtol=1e-9, atol=1e-12):
            problems.append(f"{path}: trace.rows: the times (column t) are not the run's sample "
                            "instants: the baseline is damaged")
    if problems:
        raise ConfigError(problems)


# ---------------------------------------------------------------------------------------------
# comparison


def compare(baseline: dict, result: RunResult, scenario: Scenario) -> tuple[list[Difference], int]:
    """What moved between ``baseline`` and ``result``, and how many things were compared.

    A baseline is compared on what it holds: a metric or signal it lacks (one added since it
    was made) is no difference (see :func:`unbaselined`); one it holds that the run lacks is.

    A baseline of a run that stopped early is compared on what is reproducible: that the run
    stops too, within ``regression.divergence.time`` of it, and its trace up to where the
    baseline's left the bound (which is where the baseline's rows end); not its metrics."""
    tolerance = scenario.regression
    differences = []
    checked = 0
    stopped = baseline.get("failure") is not None
    if stopped != (result.failure is not None):
        differences.append(Difference("run", "run", baseline.get("failure") or "to the end",
                                      result.failure or "to the end"))
    elif stopped:
        checked += 1
        allowed = (tolerance.divergence_time if tolerance.divergence_time is not None
                   else 0.05 * scenario.duration)
        at = float(result.trace.t[-1]) if len(result.trace.t) else 0.0
        if abs(at - baseline["stopped_at"]) > allowed:
            differences.append(Difference("run", "stopped_at", baseline["stopped_at"], at,
                                          f"within {allowed:g} (regression.divergence.time)"))
    for name, expected in ({} if stopped else baseline["metrics"]).items():
        checked += 1
        got = result.metrics.get(name)
        if got is None:
            differences.append(Difference("metric", name, expected, "not computed"))
            continue
        rtol, atol = tolerance.tolerance(name)
        if not _close(got, expected, rtol, atol):
            differences.append(Difference("metric", name, expected, got, f"rtol {rtol:g}, atol {atol:g}"))
    reference = baseline["trace"]
    if reference is None:
        return differences, checked
    for name in essential(result.trace):
        if name not in reference:  # the run's core: no baseline without it is one of this run
            differences.append(Difference("trace", name, "a stored signal", "missing from the baseline"))
    if len(reference["t"]) >= 2:
        t = result.trace.t
        for name, y_ref in reference.items():
            if name == "t":
                continue
            checked += 1
            try:
                y = result.trace[name]
            except KeyError:
                differences.append(Difference("trace", name, "a recorded signal", "not recorded"))
                continue
            outside = _outside_band(t, y, reference["t"], y_ref, tolerance.dy, tolerance.dx)
            if outside:
                k = outside[0]
                at = reference["t"][k]
                differences.append(Difference(
                    "trace", name, f"{_show(float(y_ref[k]))} at t = {at:.6g}",
                    float(np.interp(at, t, y)) if len(t) else "no sample",
                    f"{len(outside)} of {len(reference['t'])} baseline "
                    f"points outside the band (dy {tolerance.dy:g}, dx {tolerance.dx})"))
    return differences, checked


def essential(trace) -> list[str]:
    """The signals every baseline of a run must hold: the input, the tracked output and the
    outputs measured in its unit (a pendulum's angle beside the arm's). Others (estimates,
    controller states, disturbances) may be added to the code later: open world."""
    return ["u", trace.tracked] + [name for name in trace.watched() if name != trace.tracked]


def unbaselined(baseline: dict, result: RunResult) -> list[str]:
    """Notes for what the run has and the baseline does not hold (``regress --update`` adds it)."""
    if baseline.get("failure") is not None:
        return []
    metrics = sorted(set(result.metrics) - set(baseline["metrics"]))
    reference = baseline["trace"] or {}
    signals = [name for name in result.trace.columns() if reference and name not in reference
               and name not in essential(result.trace)]
    return [f"not in the baseline (regress with `update` adds {'it' if len(names) == 1 else 'them'}): "
            f"{kind} {', '.join(names)}" for kind, names in (("metric", metrics), ("signal", signals)) if names]


def merged(document: dict, baseline: dict | None, differences: list[Difference]) -> dict:
    """The baseline document to write on ``--update``: the new run's, except that every value
    the old baseline holds and the run still reproduces (within the scenario's tolerances) is
    kept as it was, so that an update changes only what changed (adding a metric adds its
    line) and never rewrites what another machine rounds differently."""
    if baseline is None or baseline["scenario"].get("sha256") != document["scenario"]["sha256"]:
        return document
    moved = {(d.kind, d.name) for d in differences}
    if any(kind == "run" for kind, _ in moved):
        return document
    document = dict(document)
    if document.get("failure") is not None:
        # stopped as before, as close to when: the old record of it stands, trace and all
        document["failure"], document["stopped_at"] = baseline["failure"], baseline["stopped_at"]
    else:
        document["metrics"] = {name: (_number(baseline["metrics"][name])
                                      if name in baseline["metrics"] and ("metric", name) not in moved
                                      else value) for name, value in document["metrics"].items()}
    old, new = baseline["trace"], document["trace"]
    if (old is not None and not any(kind == "trace" for kind, _ in moved) and list(old) == new["columns"]
            and baseline["every"] == new["every"] and len(old["t"]) == len(new["rows"])):
        document["trace"] = {**new, "rows": [[_number(v) for v in row] for row in np.column_stack(
            [old[c] for c in new["columns"]]).tolist()] if len(new["rows"]) else []}
    return document


def _outside_band(t, y, t_ref, y_ref, dy: float, dx: int) -> list[int]:
    """Indices of the baseline's instants where y(t), taken at those instants, lies outside
    the band around y_ref (fmpy's band). Both are compared at the baseline's instants, so that
    an unchanged run matches its downsampled baseline exactly."""
    from fmpy.util import validate_signal

    t_ref = np.array(t_ref, dtype=float)  # validate_signal may nudge duplicate times in place
    y_ref = np.asarray(y_ref, dtype=float)
    t = np.asarray(t, dtype=float)
    covered = (t_ref >= t[0]) & (t_ref <= t[-1]) if len(t) else np.zeros(len(t_ref), bool)
    t_ref, y_ref = t_ref[covered], y_ref[covered]
    if len(t_ref) < 2:
        return []
    y_at = np.interp(t_ref, t, np.asarray(y, dtype=float))
    if not np.all(np.isfinite(y_at)):
        return [int(k) for k in np.flatnonzero(~np.isfinite(y_at))]
    # fmpy's band is dy of the baseline's range: one wild value on either side would widen it
    # to everything, so its height is dy of the smaller of the two ranges
    spread = float(np.ptp(y_ref))
    if spread > 0:
        dy = dy * min(spread, float(np.ptp(y_at))) / spread
    _, _, _, out = validate_signal(t=t_ref, y=y_at, t_ref=t_ref.copy(), y_ref=y_ref,
                                   num=len(t_ref), dx=2 * dx + 1, dy=dy)
    # validate_signal leaves the first and last instants out; they count here
    out[[0, -1]] = False
    ends = [0, len(t_ref) - 1]
    band = max(spread * dy, 0.5 if not y_ref.any() else 0.0)
    for k in ends:
        out[k] = abs(y_at[k] - y_ref[k]) > band
    return [int(k) for k in np.flatnonzero(out)]


def _close(got: float, expected: float, rtol: float, atol: float) -> bool:
    if not (math.isfinite(got) and math.isfinite(expected)):  # a baseline keeps "not finite" only
        return not (math.isfinite(got) or math.isfinite(expected))
    return abs(got - expected) <= atol + rtol * abs(expected)


# ---------------------------------------------------------------------------------------------
# the run


@dataclass
class Report:
    cases: list[Case]
    update: bool
    fmu: str | None
    overrides: dict
    wall_time: float
    versions: dict
    plant: str | None = None       # --plant: the plant every applicable scenario ran on

    @property
    def failed(self) -> list[Case]:
        return [c for c in self.cases if c.failed]

    def to_dict(self) -> dict:
        return {"passed": not self.failed, "update": self.update, "fmu": self.fmu,
                "plant": self.plant, "overrides": self.overrides, "wall_time": self.wall_time, "versions": self.versions,
                "cases": [c.to_dict() for c in self.cases]}


def scenario_files(names: Sequence[str | Path] | None) -> list[Path]:
    """The scenario files named (files, names of ``scenarios/``, or folders of scenario
    files, rig checks among them: :mod:`furuta_cosim.rig.check`); none named: every shipped
    scenario: those of ``scenarios/`` and of each example tree in it (a folder of scenarios
    with its own ``baselines/``, as ``scenarios/cart-pole/``)."""
    from furuta_cosim.scenario import scenario_path

    if not names:
        examples = [b.parent for b in sorted(paths.scenarios().glob("*/baselines")) if b.parent.name != "baselines"]
        return sorted(paths.scenarios().glob("*.yaml")) + [f for tree in examples for f in sorted(tree.glob("*.yaml"))]
    found = []
    for name in names:
        path = Path(name)
        if path.is_dir():
            files = sorted(path.glob("*.yaml"))
            if not files:
                raise ConfigError([f"{path}: no scenario files (*.yaml) in this folder"])
            found += files
        else:
            found.append(scenario_path(name))
    return list(dict.fromkeys(found))


def regress(names: Sequence[str | Path] | None = None, *, update: bool = False,
            fmu: str | Path | None = None, mapping: str | Path | None = None,
            overrides: dict | None = None, plant: str | Path | None = None,
            workers: int = 1, baselines: Path | None = None,
            junit: str | Path | None = None, output: str | Path | None = None,
            progress: Callable[[int, int], None] | None = None) -> Report:
    """Run every controller of every scenario named and compare each with its baseline.

    A scenario of another model than ``plant``, or whose plant lacks a parameter of
    ``overrides``, is listed as not applicable (``n/a``).

    Parameters
    ----------
    names : sequence of str or path, optional
        Scenario files, names or folders of scenario files; default every shipped scenario.
    update : bool
        Write the baselines instead (only what moved), reporting what changed. Cannot be
        combined with ``fmu``, ``mapping``, ``plant`` or ``overrides``.
    fmu : path, optional
        Run the scenarios on this FMU (another tool's, with ``mapping``).
    mapping : path, optional
        A plant-mapping file for ``fmu``.
    overrides : dict, optional
        FMU parameters set on every run (``--params``).
    plant : str or path, optional
        Run the scenarios on this plant (a name or file) instead of their own.
    workers : int
        Local processes for the runs.
    baselines : path, optional
        The folder of the baselines, instead of ``baselines/`` beside each scenario.
    junit : path, optional
        Also write the report as JUnit XML there.
    output : path, optional
        A folder for ``regress.json`` and ``regress.xml``.
    progress : callable, optional
        ``progress(done, total)`` after every run.

    Returns
    -------
    Report
        Its ``cases``: one per scenario and controller, with status and what moved.

    Raises
    ------
    ConfigError
        For bad input of any kind, or a corrupt baseline or one of another version of its
        scenario, before any baseline is written.
    """
    import time

    from furuta_cosim.cosim.worker import check_workers

    check_workers(workers)
    if junit:
        output_file(junit, "junit")
    if output:
        output_folder(output)
    if baselines is not None and Path(baselines).exists() and not Path(baselines).is_dir():
        raise ConfigError([f"baselines {baselines}: is a file; name the folder that holds "
                           "<scenario>/<controller>.yaml baselines"])
    if update and (fmu or overrides or mapping or plant):
        raise ConfigError(["update: writes the baselines from the scenarios' own plants; "
                           "leave out `fmu`, `mapping`, `plant` and `overrides`"])
    if plant is not None and fmu is not None:
        raise ConfigError(["plant: give a plant or an FMU (`fmu`), not both"])
    if plant is not None:
        load_plant(plant)  # a bad plant is one error, not one per scenario
    if (fmu or mapping) and not names:
        raise ConfigError(["fmu: name the scenarios to run on it (the shipped scenarios are for "
                           "several plants)"])
    if mapping and not fmu:
        raise ConfigError(["mapping: maps the variables of a plant FMU given as `fmu`; give one"])
    started = time.perf_counter()
    plant_mapping = load_mapping(mapping) if mapping else None
    jobs = []   # (prepared, compiled, baseline path, baseline or None)
    problems = []
    unfit = []  # cases of scenarios the given FMU cannot run
    from furuta_cosim.rig.check import is_rig_check, run_rig_check

    for path in scenario_files(names):
        if is_rig_check(path):  # a rig log held as a baseline: the model replayed on it
            name, status, beyond, checked, notes = run_rig_check(path)
            unfit.append(Case(name, "replay", Path(path), "unchanged" if update else status,
                              [Difference("replay", f"{name} RMS", f"<= {tol:g}", rms, "simulated - logged, SI units")
                               for name, tol, rms in beyond], checked, notes=notes))
            continue
        scenario = load_scenario(path)
        try:
            if plant is not None:
                scenario = on_plant(scenario, plant)
            missing = lacks(scenario, overrides or {}) if overrides and fmu is None else []
            if missing:
                shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
                raise NotApplicable([f"{scenario.source}: its plant has no parameter {shown} (`overrides`)"])
        except NotApplicable as error:
            unfit += _cases_not_run(scenario, "n/a", error, baselines)
            continue
        if plant_mapping is not None:
            from dataclasses import replace

            scenario = replace(scenario, mapping=plant_mapping,
                               control_input=plant_mapping.control_input or scenario.control_input)
        try:
            prepared = prepare(scenario, fmu=fmu, overrides=overrides)
        except PlantUnfit as error:
            # this scenario asks what the given FMU cannot do: a failed case, the others still run
            unfit += _cases_not_run(scenario, "unfit", error, baselines)
            continue
        for compiled in scenario_controllers(prepared):
            target = baseline_path(scenario, compiled.name, baselines)
            baseline = None
            if target.exists():
                try:
                    baseline = read_baseline(target)
                    if not update:
                        check_versions(baseline, target, prepared, compiled)
                except ConfigError as error:
                    problems += error.problems
                    if update:
                        problems.append(f"{target}: refusing to overwrite a baseline that cannot be "
                                        "read; move it away or repair it first")
            jobs.append((prepared, compiled, target, baseline))
    if problems:
        raise ConfigError(problems)
    results = _run_all(jobs, workers, progress)
    cases = list(unfit)
    for (prepared, compiled, target, baseline), result in zip(jobs, results):
        case = Case(prepared.scenario.name, compiled.name, target, "pass", wall_time=result.wall_time)
        if baseline is not None:
            case.differences, case.checked = compare(baseline, result, prepared.scenario)
            case.notes += unbaselined(baseline, result)
            if baseline["controller"].get("sha256") != file_hash(compiled.cfile.path):
                case.notes.append(f"{compiled.cfile.source} changed since the baseline was made")
        if update:
            document = merged(make_baseline(prepared, compiled, result), baseline, case.differences)
            old = target.read_text() if target.exists() else None
            text = baseline_text(document)
            case.status = "new" if old is None else ("unchanged" if old == text else "updated")
            size = len(text.encode())
            if size > MAX_BYTES:  # regress would refuse to read it back
                case.status = "fail"
                case.differences.append(Difference(
                    "run", "baseline", f"at most {MAX_BYTES} bytes", f"{size} bytes",
                    f"not written: regress reads no file over {MAX_BYTES // 1_000_000} MB; lower "
                    f"regression.points in {prepared.scenario.source}"))
            elif old != text:
                write_text(target, text)
        elif baseline is None:
            case.status = "missing"
        elif case.differences:
            case.status = "fail"
        cases.append(case)
    import fmpy

    versions = {"furuta-cosim": __version__, "fmpy": fmpy.__version__, "numpy": np.__version__}
    report = Report(cases, update, str(fmu) if fmu else None, dict(overrides or {}),
                    time.perf_counter() - started, versions,
                    load_plant(plant).name if plant is not None else None)
    if junit:
        write_junit(report, junit)
    if output:
        write_text(Path(output) / "regress.json", dumps(report.to_dict(), indent=1))
        write_junit(report, Path(output) / "regress.xml")
    return report


def _cases_not_run(scenario: Scenario, status: str, error: ConfigError, baselines) -> list[Case]:
    """A case per controller of a scenario that did not run (unfit, n/a), with the reason."""
    return [Case(scenario.name, Path(name).stem, baseline_path(scenario, Path(name).stem, baselines),
                 status, notes=list(error.problems)) for name in scenario.controllers]


def _run_all(jobs, workers: int, progress) -> list[RunResult]:
    """A result per job, in order: in this process one FMU session per scenario (the jobs of a
    scenario are consecutive), else in a pool of worker processes."""
    total = len(jobs)
    if workers <= 1 or total <= 1:
        results = []
        groups: dict = {}
        for prepared, compiled, _, _ in jobs:
            groups.setdefault(prepared.key, (prepared, []))[1].append(compiled)
        for prepared, compiled in groups.values():
            for result in runs(prepared, compiled):
                results.append(result)
                if progress:
                    progress(len(results), total)
        return results
    from furuta_cosim.cosim.worker import evaluate_here, start_pool, stop_pool

    pool = start_pool(min(workers, total))
    try:
        futures = [pool.submit(evaluate_here, prepared, compiled) for prepared, compiled, _, _ in jobs]
        results = []
        for k, future in enumerate(futures):
            results.append(future.result())
            if progress:
                progress(k + 1, total)
        return results
    finally:
        stop_pool(pool)


# ---------------------------------------------------------------------------------------------
# JUnit XML


def junit_xml(report: Report) -> str:
    """The report as JUnit XML: a test suite per scenario, a test case per controller."""
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="furuta-cosim regress", tests=str(len(report.cases)),
                      failures=str(len(report.failed)), time=f"{report.wall_time:.3f}")
    suites: dict[str, ET.Element] = {}
    for case in report.cases:
        suite = suites.get(case.scenario)
        if suite is None:
            suite = suites[case.scenario] = ET.SubElement(root, "testsuite", name=case.scenario,
                                                          tests="0", failures="0")
        suite.set("tests", str(int(suite.get("tests")) + 1))
        element = ET.SubElement(suite, "testcase", classname=case.scenario, name=case.controller,
                                time=f"{case.wall_time:.3f}")
        if case.failed:
            suite.set("failures", str(int(suite.get("failures")) + 1))
            lines = case.lines()
            failure = ET.SubElement(element, "failure", message=lines[0] if lines else case.status,
                                    type={"fail": "regression", "unfit": "plant-unfit"}.get(case.status, "missing-baseline"))
            failure.text = "\n".join(lines)
        if case.status == "n/a":
            ET.SubElement(element, "skipped", message="; ".join(case.notes))
        properties = ET.SubElement(element, "properties")
        ET.SubElement(properties, "property", name="baseline", value=str(case.baseline))
        ET.SubElement(properties, "property", name="checked", value=str(case.checked))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(report: Report, path: str | Path) -> Path:
    return write_text(path, junit_xml(report))


# ---------------------------------------------------------------------------------------------


def _number(value):
    value = float(value)
    return float(f"{value:.10g}") if math.isfinite(value) else None


def _yaml_number(value) -> str:
    if value is None:
        return ".nan"
    text = repr(float(value))
    # YAML 1.1 (PyYAML) reads 1e-06 as a string: its floats need a dot
    return text.replace("e", ".0e") if "e" in text and "." not in text else text


def _show(value) -> str:
    return format(value, ".6g") if isinstance(value, float) else str(value)


def _brief(value) -> str:
    text = repr(value)
    return text if len(text) < 60 else text[:57] + "..."
