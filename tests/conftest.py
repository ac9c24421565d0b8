"""Shared fixtures. FMUs are built into a fresh cache per test run, as on a new machine."""

import os
import shutil
import tempfile

# before any furuta_cosim import reads it: every test run builds its FMUs from the sources
os.environ["FURUTA_COSIM_CACHE"] = tempfile.mkdtemp(prefix="furuta-cosim-test-cache-")

import pytest  # noqa: E402

from furuta_cosim.fmu.exporter import build_fmu  # noqa: E402
from helpers import FOREIGN, build_foreign  # noqa: E402 - the fixtures build foreign FMUs



# a test whose call takes longer than this is marked slow (``-m "not slow"`` is the quick
# loop); .ci/run sets FURUTA_COSIM_CHECK_SLOW=1, and the run fails on one that is not. A call
# counts as over the limit only when both its wall time and its CPU time (this process and the
# workers it waited for) are: a loaded machine stretches the first and not the second, and a
# test on two workers doubles the second and not the first, so neither alone fails a run.
SLOW_LIMIT = 5.0
# one at 3 s on an idle machine took 5.5 s in a CI run: those past this share of the limit are
# listed (not failed) so that they are marked before a loaded run fails on them
NEAR_LIMIT = 0.6 * SLOW_LIMIT
_UNMARKED: list[tuple[str, float, float]] = []
_NEAR: list[tuple[str, float, float]] = []


def _cpu_seconds() -> float:
    times = os.times()
    return times.user + times.system + times.children_user + times.children_system


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    start = _cpu_seconds()
    yield
    item.user_properties.append(("cpu_seconds", _cpu_seconds() - start))


def pytest_runtest_logreport(report):
    if report.when != "call" or "slow" in report.keywords:
        return
    cpu = dict(report.user_properties).get("cpu_seconds", report.duration)
    if min(report.duration, cpu) > SLOW_LIMIT:
        _UNMARKED.append((report.nodeid, report.duration, cpu))
    elif min(report.duration, cpu) > NEAR_LIMIT:
        _NEAR.append((report.nodeid, report.duration, cpu))


def _listed(calls) -> str:
    return "\n".join(f"  {nodeid}: {wall:.1f} s, {cpu:.1f} s of CPU" for nodeid, wall, cpu in calls)


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(os.environ["FURUTA_COSIM_CACHE"], ignore_errors=True)
    if os.environ.get("FURUTA_COSIM_CHECK_SLOW") != "1":
        return
    if _NEAR:
        print(f"\n{len(_NEAR)} test(s) over {NEAR_LIMIT:g} s not marked slow (not failed; mark "
              f"them before load takes them past {SLOW_LIMIT:g} s):\n{_listed(_NEAR)}")
    if _UNMARKED:
        print(f"\n{len(_UNMARKED)} test(s) over {SLOW_LIMIT:g} s not marked slow:\n{_listed(_UNMARKED)}")
        session.exitstatus = 1


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
