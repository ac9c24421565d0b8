"""Helpers shared by the tests (imported as ``helpers``; fixtures stay in conftest.py)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ROOT / "docs" / "pages"


def documentation() -> dict[str, str]:
    """The README and every page of the docs site, by path relative to the repository."""
    files = [ROOT / "README.md"] + sorted(PAGES.glob("*.md"))
    return {str(p.relative_to(ROOT)): p.read_text() for p in files}


def page(name: str) -> str:
    """One page of the docs site (``tuning.md``)."""
    return (PAGES / name).read_text()


def section(text: str, heading: str) -> str:
    """The section of ``text`` under the heading ``heading`` (any level), up to the next
    heading of the same or a higher level."""
    match = re.search(rf"^(#+) {re.escape(heading)}\n", text, re.M)
    if not match:
        raise AssertionError(f"no heading {heading!r}")
    level = len(match.group(1))
    rest = text[match.end():]
    end = re.search(rf"^#{{1,{level}}} ", rest, re.M)
    return rest[:end.start()] if end else rest


def python_blocks() -> list[tuple[str, str]]:
    """Every ```python block of the documentation, as (where, code)."""
    return [(f"{name} python block {k}", block) for name, text in documentation().items()
            for k, block in enumerate(re.findall(r"```python\n(.*?)```", text, re.S))]


# a dynamic controller whose state sees the plant (Bc != 0), unlike the published ones: the
# exported controller FMU and SSP loops are checked with it
DYNAMIC = """\
name: dynamic
type: generalized
time: continuous
period: 0.002
Ac: [[-20]]
Bc: [[0.5, 0.1, -0.3, 0.05, 0]]
Cc: [[1.0]]
Dc: [[-0.3105, -5.2621, 70.7488, 8.9224, 0.1772]]
model: paper-printed
prefilter: {output: theta0}
"""

STATES = ["theta0", "dtheta0", "theta1", "dtheta1", "i"]
FOREIGN = Path(__file__).parent / "foreign"


def build_foreign(tool: str, script: Path, folder: Path, *project_files: Path) -> None:
    """Build an FMU with another exporter (``pythonfmu`` or ``pythonfmu3``) into ``folder``;
    a failed build shows the exporter's own output."""
    # the exporter imports the script, which imports its project files
    path = os.pathsep.join([str(Path(f).parent) for f in project_files] + [os.environ.get("PYTHONPATH", "")])
    done = subprocess.run([sys.executable, "-m", tool, "build", "-f", str(script), *map(str, project_files),
                           "-d", str(folder)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": path})
    assert done.returncode == 0, done.stdout + done.stderr


def scheduled_only(source: Path, target: Path) -> Path:
    """A copy of the FMI 3.0 FMU ``source`` as a clocked FMU would come: its co-simulation
    interface renamed to scheduled execution, model exchange removed."""
    import re
    import zipfile

    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as out:
        for name in archive.namelist():
            data = archive.read(name)
            if name == "modelDescription.xml":
                text = re.sub(r"<CoSimulation\b", "<ScheduledExecution", data.decode())
                text = text.replace("</CoSimulation>", "</ScheduledExecution>")
                data = re.sub(r"<ModelExchange\b[^>]*?/>|<ModelExchange\b.*?</ModelExchange>", "", text,
                              flags=re.S).encode()
            out.writestr(name, data)
    return target


def rewritten(source: Path, target: Path, description=None, extra: dict | None = None) -> Path:
    """A copy of the FMU ``source`` with its modelDescription.xml passed through
    ``description`` (text to text) and the zip entries ``extra`` (name: bytes) added."""
    import zipfile

    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as out:
        for name in archive.namelist():
            data = archive.read(name)
            if name == "modelDescription.xml" and description:
                data = description(data.decode()).encode()
            out.writestr(name, data)
        for name, data in (extra or {}).items():
            out.writestr(name, data)
    return target


def with_a_clock(source: Path, target: Path) -> Path:
    """A copy of the FMI 3.0 FMU ``source`` that declares a Clock input."""
    return rewritten(source, target, lambda text: text.replace(
        "<ModelVariables>", '<ModelVariables>\n    <Clock name="tick" valueReference="9999" '
        'causality="input" intervalVariability="triggered"/>', 1))


def crash_with(signal_name: str) -> None:
    """Kill this process with a signal, as a crashing engine would (for the containment tests)."""
    import signal

    os.kill(os.getpid(), getattr(signal, signal_name))


def run_cli(capsys, *argv):
    """``furuta-cosim ARGV`` in-process: (exit code, stdout, stderr)."""
    from furuta_cosim.cli import main

    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line(capsys, *argv) -> str:
    """``furuta-cosim ARGV`` refused as bad input: exit 2 and one line, never a traceback."""
    code, out, err = run_cli(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (code, out, err)
    return lines[0]


# -- a synthetic identification problem ------------------------------------------------------
QUANTUM = 2 * math.pi / 2048
TRUE = {"R_a": 7.9, "M_f": 0.040, "I_a": 1.2e-4, "C0": 6.0e-4}


def synthetic_log(folder: Path, seed: int = 0) -> Path:
    """A 3 s PRBS voltage on the QUBE plant with known parameters, logged as a 2048-count
    encoder and a current sensor with 4 mA of noise."""
    import numpy as np

    from furuta_cosim.identify.replay import target_for
    from furuta_cosim.fmu.session import PlantSession

    rng = np.random.default_rng(seed)
    h, n = 0.002, 1501
    t = np.arange(n) * h
    V = np.repeat(rng.choice([-3.0, 3.0], size=n // 25 + 1), 25)[:n]
    target = target_for(plant="qube-servo-3")
    with PlantSession.open(target.fmu) as session:
        session.reset(parameters={**TRUE, "theta1_start": math.pi})  # hanging, as the log says
        session.set_io(inputs=["V"], outputs=["theta0", "i"])
        rows = [session.get(["theta0", "i"])] + [session.step([v], h) for v in V[:-1]]
    y = np.array(rows)
    theta = np.round(y[:, 0] / QUANTUM) * QUANTUM
    current = y[:, 1] + rng.normal(0.0, 0.004, n)
    (folder / "prbs.csv").write_text("t,V,theta,I\n" + "".join(
        f"{a!r},{b!r},{c!r},{d!r}\n" for a, b, c, d in zip(t.tolist(), V.tolist(), theta.tolist(), current.tolist())))
    (folder / "prbs.yaml").write_text(
        "data: prbs.csv\ncolumns: [t, V, theta, I]\ntime: t\ninputs: {V: {column: V, unit: V}}\n"
        f"outputs:\n  theta0: {{column: theta, unit: rad, quantum: {QUANTUM!r}}}\n  i: {{column: I, unit: A, noise: 0.004}}\n"
        "start: {theta0: 0.0, dtheta0: 0.0, theta1: 3.141592653589793, dtheta1: 0.0, i: 0.0}\n")
    spec = folder / "spec.yaml"
    spec.write_text("name: synthetic\nplant: qube-servo-3\nexperiments: [prbs.yaml]\nfree:\n"
                    "  R_a: {start: 6.0, bounds: [1.0, 30.0]}\n  M_f: {start: 0.05, bounds: [0.005, 0.2]}\n"
                    "  I_a: {start: 2.0e-4, bounds: [1.0e-6, 1.0e-2]}\n  C0: {start: 2.0e-4, bounds: [0.0, 1.0e-2]}\n")
    return spec


def fit_folder(folder: Path, parameters: dict, correlation: dict, plant_text: str | None = None,
               **change) -> Path:
    """A fit.json of identify with its plant.yaml beside it (the fitted values on
    qube-servo-3), consistent as identify writes them: fitted_plant names the plant's sha256."""
    import json

    from furuta_cosim.fmu.plants import content_sha256, load_plant

    values = {n: p["value"] for n, p in parameters.items() if "." not in n and isinstance(p, dict)
              and isinstance(p.get("value"), float) and math.isfinite(p["value"])}
    plant = folder / "plant.yaml"
    plant.write_text(plant_text or ("model: furuta\nextends: qube-servo-3\nparameters: "
                                    + json.dumps(values) + "\n"))
    document = {"name": "synthetic", "plant": "qube-servo-3", "parameters": parameters,
                "correlation": correlation,
                "fitted_plant": {"file": "plant.yaml", "sha256": content_sha256(load_plant(plant))}}
    document.update(change)
    path = folder / "fit.json"
    path.write_text(json.dumps(document))
    return path
