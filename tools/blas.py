"""The BLAS kernel a process runs numpy on, for the benchmarks' ``--kernel NAME``.

OpenBLAS reads OPENBLAS_CORETYPE at load time and silently keeps its default kernel for a
name it does not know (or a kernel this machine's CPU cannot run), and some names load a
kernel of another name (Prescott runs as Katmai). A comparison between two kernels is only
one when the child's kernel differs from ours: :func:`check_kernel` asks a child process.
"""

from __future__ import annotations

import os
import subprocess
import sys

_PROBE = ("import numpy, threadpoolctl; print(', '.join(sorted('%s %s' % (i['internal_api'], "
          "i.get('architecture') or '?') for i in threadpoolctl.threadpool_info() "
          "if i.get('user_api') == 'blas')) or 'none')")


def kernel_of(env: dict) -> str:
    """The BLAS library and kernel a Python process started with ``env`` runs numpy on."""
    done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True)
    return done.stdout.strip()


def check_kernel(name: str) -> str:
    """The kernel OPENBLAS_CORETYPE=``name`` gives a child process; SystemExit (one line) when
    that is the kernel this process already has, so the comparison would measure nothing."""
    mine, theirs = kernel_of(dict(os.environ)), kernel_of({**os.environ, "OPENBLAS_CORETYPE": name})
    if mine == theirs:
        raise SystemExit(f"--kernel {name}: OPENBLAS_CORETYPE={name} leaves the BLAS kernel as it is "
                         f"({mine}); name a kernel this machine's OpenBLAS runs differently "
                         "(Haswell or Nehalem on most x86-64 machines)")
    return theirs
