"""Shared fixtures. FMUs are built into a fresh cache per test run, as on a new machine."""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# before any furuta_cosim import reads it: every test run builds its FMUs from the sources
os.environ["FURUTA_COSIM_CACHE"] = tempfile.mkdtemp(prefix="furuta-cosim-test-cache-")

import pytest  # noqa: E402

from furuta_cosim.cli import main  # noqa: E402
from furuta_cosim.fmu.exporter import build_fmu  # noqa: E402

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


def run_cli(capsys, *argv):
    """``furuta-cosim ARGV`` in-process: (exit code, stdout, stderr)."""
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(os.environ["FURUTA_COSIM_CACHE"], ignore_errors=True)


@pytest.fixture(scope="session")
def furuta_fmu():
    return build_fmu("furuta")


@pytest.fixture(scope="session")
def toy_fmu():
    return build_fmu("toy")


@pytest.fixture(scope="session")
def foreign_fmu(tmp_path_factory):
    """The pendulum built by another exporter (pythonfmu) from tests/foreign/pendulum_fmu.py,
    written independently of fmu_src/furuta, under other variable names."""
    folder = tmp_path_factory.mktemp("foreign-fmu")
    build_foreign("pythonfmu", FOREIGN / "pendulum_fmu.py", folder, FOREIGN / "pendulum_physics.py")
    return folder / "ForeignPendulum.fmu"
