"""The docs site: it builds with warnings as errors (links and anchors checked), its command
reference is the parser's own help, the README stays a front page, and every function of the
API reference documents each of its parameters."""

import importlib
import inspect
import re
import subprocess
import sys

import pytest
from helpers import PAGES, ROOT, documentation, python_blocks

API = re.findall(r"^::: (\S+)$", (PAGES / "api.md").read_text(), re.M)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                             str(ROOT / "docs" / "mkdocs.yml"), "-d", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
    return out


@pytest.mark.slow
def test_the_site_builds_strict_and_its_command_reference_is_the_parsers_help(site):
    from furuta_cosim.cli import build_parser

    html = (site / "commands" / "index.html").read_text()
    parser = build_parser()
    for action in parser._actions:
        for name in getattr(action, "choices", None) or {}:
            if isinstance(action.choices, dict):
                assert f"furuta-cosim {name}" in html, name
    # an option of a command, as --help prints it
    assert "--from-fit" in html and "--variants-seed" in html
    assert (site / "api" / "index.html").read_text().count("furuta_cosim.tuning.run.tune") >= 1
    # the set-up commands come from the README, written once
    assert "python3 -m pip install -e . &amp;&amp; furuta-cosim tune effort" in (site / "setup" / "index.html").read_text()


def test_the_readme_is_a_front_page():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    quick = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    assert "pip install" in quick and "furuta-cosim tune effort" in quick
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (ROOT / link).is_file(), link


def _documented(docstring: str) -> set[str]:
    section = re.search(r"Parameters\n\s*-+\n(.*?)(?:\n\s*\n\s*[A-Z][a-z]+\n\s*-+\n|\Z)", docstring, re.S)
    return set(re.findall(r"^\s{0,8}(\w+)\s*(?::|$)", section.group(1), re.M)) if section else set()


def _resolve(name: str):
    module, attribute = name.rsplit(".", 1)
    return getattr(importlib.import_module(module), attribute)


def _imported_by_the_docs() -> set[str]:
    names = set()
    for _, code in python_blocks():
        for module, items in re.findall(r"^from (furuta_cosim[\w.]*) import ([\w, ]+)$", code, re.M):
            names |= {f"{module}.{item.strip()}" for item in items.split(",")}
    return names


def test_every_name_the_docs_import_is_on_the_api_page():
    on_page = {id(_resolve(name)) for name in API}
    missing = sorted(name for name in _imported_by_the_docs() if id(_resolve(name)) not in on_page)
    assert not missing, f"imported in the docs but not in docs/pages/api.md: {missing}"


def _with_methods(name: str):
    obj = _resolve(name)
    yield name, obj
    if inspect.isclass(obj):
        for attribute, value in vars(obj).items():
            if isinstance(value, (classmethod, staticmethod)):
                value = value.__func__
            if not attribute.startswith("_") and inspect.isfunction(value):
                yield f"{name}.{attribute}", value


@pytest.mark.parametrize("name", API)
def test_every_parameter_of_the_api_is_documented(name):
    for where, obj in _with_methods(name):
        doc = inspect.getdoc(obj)
        assert doc, f"{where}: no docstring"
        parameters = [p for p in inspect.signature(obj).parameters if p not in ("self", "cls")]
        missing = [p for p in parameters if p not in _documented(doc)]
        assert not missing, f"{where}: undocumented parameter(s) {missing}"


def test_the_parameter_check_finds_an_undocumented_one():
    def f(a, b):
        """Do.

        Parameters
        ----------
        a : int
            A.
        """
    assert _documented(inspect.getdoc(f)) == {"a"}


def _hooks():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import docs_hooks
    finally:
        sys.path.pop(0)
    return docs_hooks


def test_a_recorded_benchmark_shows_as_stale_on_the_performance_page_once_its_code_changed(tmp_path):
    docs_hooks = _hooks()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()
    first = subprocess.run(["git", "rev-list", "--max-parents=0", "HEAD"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()[0][:12]
    for name, commit in (("fresh", head), ("old", first)):
        (tmp_path / f"{name}.txt").write_text(f"command: python tools/bench_x.py\ncommit: {commit}\n"
                                              "measures: furuta_cosim\n\n| a | b |\n")
    # a user page shows the figures and the command, never a commit or a staleness marker
    for name in ("fresh", "old"):
        shown = docs_hooks.benchmark(name, tmp_path)
        assert shown.startswith("Measured by `python tools/bench_x.py`") and "| a | b |" in shown
        assert head not in shown and first not in shown and "Stale" not in shown
    table = docs_hooks.records_table(tmp_path)
    assert f"| fresh | `python tools/bench_x.py` | `{head}` |" in table and f"`{first}`" in table
    stale = docs_hooks.stale_records(tmp_path)
    assert stale.startswith('!!! warning "Stale records"') and "**old**" in stale and "**fresh**" not in stale


def test_every_page_reads_on_the_repository_host_as_on_the_site():
    """The generated parts (the commands reference, the registries' tables, the set-up commands,
    the benchmarks' figures) are written into the pages, so the repository host shows them too:
    each is what the code and the records give now."""
    # argparse's help layout changes between Python releases: the commands reference is checked
    # for every command and option below, the other parts to the character
    assert _hooks().write_pages(check=True, keep=("commands",)) == [], \
        "run: python3 tools/docs_hooks.py --write"
    from furuta_cosim.cli import build_parser

    reference = (ROOT / "docs" / "pages" / "commands.md").read_text()
    for action in build_parser()._actions:
        for name, sub in (action.choices or {}).items() if isinstance(action.choices, dict) else ():
            assert f"## furuta-cosim {name}" in reference or f"## furuta-cosim {name} " in reference, name
            for option in sub._actions:
                for string in option.option_strings:
                    assert string in reference, (name, string)
    for page in (ROOT / "docs" / "pages").glob("*.md"):
        text = page.read_text()
        assert "<!-- generated:" not in text or "<!-- end generated -->" in text, page.name
        if page.name not in ("performance.md",):
            # commit hashes, issue numbers and staleness markers live on the Performance page
            assert "Stale" not in text and not re.search(r"\bissue \d+", text, re.I), page.name
            assert not re.search(r"commit `[0-9a-f]{7,}`", text), page.name


def _keys(value):
    """Every mapping key in a loaded YAML document, at any depth."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield key
            yield from _keys(item)
    elif isinstance(value, list):
        for item in value:
            yield from _keys(item)


def test_every_yaml_block_of_the_docs_loads_with_its_keys_as_written(tmp_path):
    # YAML 1.1 reads a plain `on`, `off`, `yes` or `no` as a boolean; as a key of ours it is the
    # word (the foreign-log law's `derivative: {on: error}`)
    from furuta_cosim.config import load_yaml

    blocks = [(where, block) for where, text in documentation().items()
              for block in re.findall(r"```yaml\n(.*?)```", text, re.S)]
    assert len(blocks) >= 20
    for k, (where, block) in enumerate(blocks):
        path = tmp_path / f"block-{k}.yaml"
        path.write_text(block)
        data = load_yaml(path)
        assert isinstance(data, dict), where
        assert all(isinstance(key, str) for key in _keys(data)), (where, [k for k in _keys(data) if not isinstance(k, str)])
