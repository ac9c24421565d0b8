"""House rules that a review would otherwise have to catch: no function parameter that its
body never reads, tests over 5 s marked slow, no test importing from conftest."""

import ast
import re
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent


def _interface_default(node) -> bool:
    """A body that ignores its parameters on purpose: a docstring, pass, raise, or one
    ``return`` of a constant (``None``, or a module's ``UPPER_CASE`` name): a base class's
    default."""
    body = [s for s in node.body if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))]
    if len(body) == 1 and isinstance(body[0], ast.Return):
        value = body[0].value
        empty = isinstance(value, (ast.Dict, ast.List, ast.Tuple)) and not (
            value.keys if isinstance(value, ast.Dict) else value.elts)
        return value is None or empty or isinstance(value, ast.Constant) or (
            isinstance(value, ast.Name) and value.id.isupper())
    return all(isinstance(s, (ast.Pass, ast.Raise)) for s in body)


def unused_parameters(source: str, where: str = "") -> list[str]:
    """``where:line: function(parameter)`` for every parameter a function never reads
    (``self``, ``cls`` and names starting with ``_`` excepted: an interface's signature)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or _interface_default(node):
            continue
        used = {n.id for s in node.body for n in ast.walk(s) if isinstance(n, ast.Name)}
        args = node.args
        for a in args.posonlyargs + args.args + args.kwonlyargs:
            if a.arg not in ("self", "cls") and not a.arg.startswith("_") and a.arg not in used:
                found.append(f"{where}:{node.lineno}: {node.name}({a.arg})")
    return found


def test_no_function_has_a_parameter_it_never_reads():
    found = []
    for path in sorted((ROOT / "furuta_cosim").rglob("*.py")):
        found += unused_parameters(path.read_text(), str(path.relative_to(ROOT)))
    assert not found, "\n".join(found)


def test_the_check_finds_an_unused_parameter():
    assert unused_parameters("def f(a, b, _c):\n    return a\n") == [":1: f(b)"]
    assert unused_parameters("class K:\n    def g(self, x):\n        return 1\n") == []


def test_no_test_imports_from_conftest():
    offenders = [p.name for p in sorted((ROOT / "tests").glob("*.py"))
                 if re.search(r"^\s*(from conftest import|import conftest)", p.read_text(), re.M)]
    assert not offenders, offenders


def test_the_parser_imports_no_heavy_module():
    """--help and the CLI's choices (which read the registries) stay instant: building the
    parser imports neither numpy nor the FMU, tuning or plotting libraries."""
    import subprocess
    import sys

    code = ("import sys; from furuta_cosim.cli import build_parser; build_parser(); "
            "print(' '.join(sorted(m for m in ('numpy', 'scipy', 'fmpy', 'matplotlib', 'sklearn', 'yaml') "
            "if m in sys.modules)))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert loaded == [], loaded
