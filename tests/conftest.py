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
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(Path(__file__).parent / "foreign" / "pendulum_fmu.py"), "-d", str(folder)],
                   check=True, capture_output=True)
    return folder / "ForeignPendulum.fmu"
