"""The FMU's C code under AddressSanitizer and UndefinedBehaviorSanitizer: the FMU tests
(hostile calls included) run against a sanitized build with no finding."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parent.parent
FLAGS = "-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all"


def sanitizer_environment(tmp_path):
    libraries = []
    for name in ("libasan.so", "libubsan.so"):
        found = subprocess.run(["gcc", f"-print-file-name={name}"], capture_output=True,
                               text=True, check=True).stdout.strip()
        assert Path(found).is_absolute(), f"gcc has no {name}: install gcc's sanitizer runtimes"
        libraries.append(found)
    # a sanitized build runs several times slower: the slow-test check is not for this run
    outer = {k: v for k, v in os.environ.items() if k != "FURUTA_COSIM_CHECK_SLOW"}
    return {**outer, "LD_PRELOAD": " ".join(libraries), "FURUTA_COSIM_EXTRA_CFLAGS": FLAGS,
            "ASAN_OPTIONS": "detect_leaks=0", "UBSAN_OPTIONS": "print_stacktrace=1",
            "FURUTA_COSIM_CACHE": str(tmp_path / "cache")}


@pytest.mark.parametrize("function, report", [("index", "runtime error: index 5 out of bounds"),
                                               ("heap", "AddressSanitizer: heap-buffer-overflow")])
def test_the_sanitizers_catch_a_bug_here(tmp_path, function, report):
    """The control: the same set-up reports bugs in a library built alike."""
    source = tmp_path / "bug.c"
    source.write_text("#include <stdlib.h>\n"
                      "int index(int i) { int a[2] = {1, 2}; return a[i]; }\n"
                      "int heap(int i) { int *a = malloc(2 * sizeof *a); int v; a[0] = a[1] = 0;"
                      " v = a[i]; free(a); return v; }\n")
    library = tmp_path / "bug.so"
    subprocess.run(["gcc", "-shared", "-fPIC", *FLAGS.split(), str(source), "-o", str(library)], check=True)
    result = subprocess.run([sys.executable, "-c", f"import ctypes; ctypes.CDLL({str(library)!r}).{function}(5)"],
                            env=sanitizer_environment(tmp_path), capture_output=True, text=True)
    assert result.returncode != 0 and report in result.stderr, result.stderr[-2000:]


@pytest.mark.slow
def test_the_fmu_tests_run_clean_on_a_sanitized_build(tmp_path):
    tests = ["tests/test_fmu_faults.py", "tests/test_fmu_bad_input.py", "tests/test_session.py",
             "tests/test_linearize.py"]
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             "-m", "not slow", *tests], cwd=ROOT, env=sanitizer_environment(tmp_path),
                            capture_output=True, text=True)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    assert "AddressSanitizer" not in output and "runtime error" not in output
    assert " passed" in output.splitlines()[-1]
    # and the FMU those tests built was the sanitized one
    probe = ("import zipfile; from furuta_cosim.fmu.exporter import build_fmu; "
             "archive = zipfile.ZipFile(build_fmu('furuta')); "
             "print(any(b'__asan_report' in archive.read(n) for n in archive.namelist() if n.endswith('.so')))")
    built = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=sanitizer_environment(tmp_path),
                           capture_output=True, text=True, check=True)
    assert built.stdout.strip() == "True"
