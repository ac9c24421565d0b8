"""The FMU cache under faults: damaged entries are rebuilt with one line said, a warm cache
needs no compiler, a cache that cannot be written is one line, and nothing leaks."""

import os
import subprocess
import sys
import zipfile

import pytest

pytestmark = pytest.mark.slow
RUN = ["simulate", "paper-step", "--controller", "lqr-paper", "--no-trace"]


def cli(tmp_path, *argv, cache=None, **env):
    temporary = tmp_path / "tmp"
    temporary.mkdir(exist_ok=True)
    environment = {**os.environ, "FURUTA_COSIM_CACHE": str(cache or tmp_path / "cache"),
                   "TMPDIR": str(temporary), **env}
    result = subprocess.run([sys.executable, "-m", "furuta_cosim.cli", *argv, "-o", str(tmp_path / "out")]
                            if argv[0] == "simulate" else [sys.executable, "-m", "furuta_cosim.cli", *argv],
                            capture_output=True, text=True, env=environment)
    assert list(temporary.iterdir()) == [], "a temporary folder was left behind"
    return result


@pytest.fixture
def warm(tmp_path):
    result = cli(tmp_path, *RUN)
    assert result.returncode == 0, result.stderr
    return tmp_path / "cache"


def damaged_lines(result):
    return [line for line in result.stderr.splitlines() if "damaged" in line]


def test_a_truncated_helper_is_rebuilt(tmp_path, warm):
    (helper,) = warm.glob("step_io-*.so")
    helper.write_bytes(helper.read_bytes()[:1000])
    result = cli(tmp_path, *RUN)
    assert result.returncode == 0, result.stderr
    assert len(damaged_lines(result)) == 1 and "step_io" in damaged_lines(result)[0]
    again = cli(tmp_path, *RUN)
    assert again.returncode == 0 and not damaged_lines(again)


@pytest.mark.parametrize("damage", ["garbage binary", "truncated"])
@pytest.mark.slow
def test_a_damaged_cached_fmu_is_rebuilt(tmp_path, warm, damage):
    (fmu,) = warm.glob("Furuta-*.fmu")
    if damage == "truncated":
        fmu.write_bytes(fmu.read_bytes()[: fmu.stat().st_size // 2])
    else:
        with zipfile.ZipFile(fmu) as archive:
            entries = {name: archive.read(name) for name in archive.namelist()}
        entries[next(n for n in entries if n.endswith(".so"))] = b"not an ELF file" * 100
        with zipfile.ZipFile(fmu, "w") as archive:
            for name, data in entries.items():
                archive.writestr(name, data)
    result = cli(tmp_path, *RUN)
    assert result.returncode == 0, result.stderr
    assert len(damaged_lines(result)) == 1 and "Furuta-" in damaged_lines(result)[0]


def test_a_warm_cache_needs_no_compiler(tmp_path, warm):
    result = cli(tmp_path, *RUN, CC="/nonexistent/cc")
    assert result.returncode == 0 and result.stderr.count("\n") <= 3, result.stderr


def test_a_missing_compiler_is_one_line(tmp_path):
    result = cli(tmp_path, *RUN, CC="/nonexistent/cc")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1] == \
        "error: CC=/nonexistent/cc: no such compiler (unset CC to use gcc)"
    cache = tmp_path / "cache"
    assert not cache.exists() or not [p for p in cache.iterdir() if p.name.endswith(".partial")]


def test_a_cache_that_cannot_be_written_is_one_line(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    result = cli(tmp_path, *RUN, cache=blocker / "cache")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"error: cannot write the FMU cache {blocker / 'cache'}")
    assert "FURUTA_COSIM_CACHE" in last


def test_an_fmu_whose_binary_cannot_load_is_one_line(tmp_path, warm):
    (fmu,) = warm.glob("Furuta-*.fmu")
    broken = tmp_path / "Broken.fmu"
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(broken, "w") as target:
        for name in source.namelist():
            target.writestr(name, b"garbage" if name.endswith(".so") else source.read(name))
    result = cli(tmp_path, *RUN, "--fmu", str(broken))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"{broken}: its binary cannot be loaded" in result.stderr
