"""``furuta-cosim report DIR``: one self-contained HTML page for a run directory.

The kind of run is told by its files: ``metrics.json`` (simulate), ``summary.json`` (tune),
``regress.json`` (regress -o), ``reproduction.md`` (reproduce). The page holds the run's
tables, verdicts and figures (inline) and its provenance: versions, seed, spec, FMU hash.
"""

from __future__ import annotations

import hashlib
import json
import platform
from pathlib import Path

from furuta_cosim import __version__
from furuta_cosim.errors import ConfigError
from furuta_cosim.files import output_file, write_text
from furuta_cosim.report.html import figure, markdown_to_html, page

KINDS = {"metrics.json": "simulate", "summary.json": "tune", "regress.json": "regress",
         "reproduction.md": "reproduce"}


def run_kind(folder: Path) -> str:
    for name, kind in KINDS.items():
        if (folder / name).is_file():
            return kind
    raise ConfigError([f"{folder}: not a run directory of simulate, tune, regress or reproduce "
                       f"(none of {', '.join(KINDS)})"])


def versions() -> dict:
    import fmpy
    import numpy
    import scipy

    return {"furuta-cosim": __version__, "python": platform.python_version(),
            "numpy": numpy.__version__, "scipy": scipy.__version__, "fmpy": fmpy.__version__}


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ConfigError([f"{path}: cannot be read as JSON ({error})"]) from None
    if not isinstance(data, dict):
        raise ConfigError([f"{path}: expected a JSON object"])
    return data


def _hash(path) -> str:
    path = Path(path)
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16] if path.is_file() else "(file not here)"


def _table(head: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "never"
    return format(value, ".5g") if isinstance(value, float) else str(value)


def _simulate(folder: Path) -> tuple[str, str, list]:
    data = _read_json(folder / "metrics.json")
    controllers = data.get("controllers", {})
    names = list(controllers)
    keys = sorted({k for c in controllers.values() for k in c.get("metrics", {})})
    md = [f"# Scenario {data.get('scenario')}", "", str(data.get("description", "")), ""]
    md += ["## Metrics", "", _table(["metric", *names],
                                    [[k, *(_cell(controllers[n]["metrics"].get(k, "")) for n in names)]
                                     for k in keys]), ""]
    md += ["## Verdicts", ""]
    verdicts = [[n, text, "PASS" if v["pass"] else "FAIL", _cell(v.get("value"))]
                for n in names for text, v in controllers[n].get("requirements", {}).items()]
    verdicts += [[n, "the run went to the end", "FAIL", controllers[n]["failure"]]
                 for n in names if controllers[n].get("failure")]
    md += [_table(["controller", "requirement", "verdict", "value"], verdicts) if verdicts
           else "No requirements.", ""]
    md += [f"- not checked: {note}" for note in data.get("unchecked", [])]
    fmu = data.get("fmu")
    provenance = {"plant": data.get("plant"), "FMU": Path(fmu).name if fmu else None,
                  "FMU sha256": (str(data["fmu_sha256"])[:16] if data.get("fmu_sha256") else
                                 _hash(fmu) if fmu else None), "control period": data.get("control_period"),
                  "steps": data.get("steps")}
    figures = [folder / Path(f).name for f in data.get("figures", []) if str(f).endswith(".svg")]
    return f"simulate {data.get('scenario')}", "\n".join(md), [provenance, figures]


def _tune(folder: Path) -> tuple[str, str, list]:
    data = _read_json(folder / "summary.json")
    summary = (folder / "summary.md").read_text() if (folder / "summary.md").is_file() else ""
    spec = (folder / "spec.yaml").read_text() if (folder / "spec.yaml").is_file() else ""
    md = summary + ("\n\n## Spec\n\n```\n" + spec.rstrip() + "\n```\n" if spec else "")
    provenance = {"spec": data.get("spec"), "method": data.get("method"), "seed": data.get("seed"),
                  "evaluations": data.get("evaluations"), "spec sha256": _hash(folder / "spec.yaml")}
    figures = [p for p in [folder / "tradeoff.svg", folder / "convergence.svg"] if p.is_file()]
    figures += sorted((folder / "responses").glob("*.svg")) + sorted((folder / "loop").glob("*.svg"))
    return f"tune {data.get('spec')}", md, [provenance, figures]


def _regress(folder: Path) -> tuple[str, str, list]:
    data = _read_json(folder / "regress.json")
    cases = data.get("cases", [])
    md = ["# Regression", "", f"{len(cases)} run(s); "
          + ("everything matches its baseline." if data.get("passed") else "**regressions found.**"), ""]
    md += [_table(["scenario", "controller", "compared", "status"],
                  [[c["scenario"], c["controller"], c["checked"], c["status"]] for c in cases]), ""]
    moved = [[c["scenario"], c["controller"], d["name"], _cell(d["expected"]), _cell(d["got"]), d["detail"]]
             for c in cases for d in c.get("differences", [])]
    if moved:
        md += ["## What moved", "", _table(["scenario", "controller", "metric or signal", "expected",
                                            "got", "tolerance"], moved), ""]
    provenance = {"FMU": data.get("fmu") or "the scenarios' own", "parameters": data.get("overrides") or "-",
                  **{f"{k} (run)": v for k, v in data.get("versions", {}).items()}}
    return "regress", "\n".join(md), [provenance, []]


def _reproduce(folder: Path) -> tuple[str, str, list]:
    md = (folder / "reproduction.md").read_text()
    figures = sorted(folder.glob("figures/*.svg"))
    return "paper reproduction", md, [{}, figures]


def write_report(folder: str | Path, output: str | Path | None = None) -> Path:
    """Write ``report.html`` (or ``output``) for the run in ``folder``; return its path."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError([f"{folder}: no such run directory"])
    kind = run_kind(folder)
    title, md, (provenance, figures) = {"simulate": _simulate, "tune": _tune, "regress": _regress,
                                        "reproduce": _reproduce}[kind](folder)
    body = [markdown_to_html(md)]
    if figures:
        body.append("<h2>Figures</h2>")
        body += [figure(p, p.stem) for p in figures]
    rows = {**{k: v for k, v in provenance.items() if v is not None}, **versions()}
    body.append("<h2>Provenance</h2>")
    body.append(markdown_to_html(_table(["", "value"], [[k, v] for k, v in rows.items()])))
    target = output_file(output if output else folder / "report.html", "output")
    return write_text(target, page(f"furuta-cosim: {title}", "\n".join(body)))
