"""The docs' generated parts, written into the pages themselves so that a page reads the same
on the repository host as on the built site, and cannot drift from the code: a test fails when
a page differs from what ``python3 tools/docs_hooks.py --write`` would write.

A generated part sits between ``<!-- generated: KIND[: ARGUMENT] -->`` and
``<!-- end generated -->``:

- ``commands``: the reference of every command, from the CLI's own parser (``--help``'s text);
- ``reference-kinds``, ``optimizer-methods``, ``fmi-versions``, ``metrics``: the tables of those
  registries;
- ``readme: HEADING``: that section of the README (the set-up commands are written once);
- ``benchmark: NAME``: the recorded output of a benchmark, ``docs/benchmarks/NAME.txt``, and
  the command that printed it;
- ``modules``: the development page's map, every module and the first sentence of its docstring;
- ``records``: the Performance page's table of every record, the commit it was measured at
  and the paths it measures.

MkDocs runs this file as a hook (``docs/mkdocs.yml``): the built Performance page also says
which records the code changed after (their figures are stale until measured again); user
pages carry no commit or staleness marker.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ROOT / "docs" / "pages"
RECORDS = ROOT / "docs" / "benchmarks"
_BLOCK = re.compile(r"(<!-- generated: ([a-z-]+)(?:: ([^>]+?))? -->\n)(.*?)(<!-- end generated -->)", re.S)
HELP_WIDTH = "100"   # the commands reference is wrapped at this width whatever the terminal


def generate(markdown: str, keep: tuple[str, ...] = ()) -> str:
    """``markdown`` with every generated part written afresh (those of the kinds in ``keep``
    left as they are)."""
    def fresh(m):
        if m.group(2) in keep:
            return m.group(0)
        return m.group(1) + _expand(m.group(2), (m.group(3) or "").strip()) + m.group(5)

    return _BLOCK.sub(fresh, markdown)


def on_page_markdown(markdown: str, page, config, files) -> str:
    markdown = generate(markdown)
    if Path(page.file.src_path).name == "performance.md":
        markdown = markdown.replace("<!-- stale records -->", stale_records())
    return markdown


def _expand(kind: str, argument: str) -> str:
    if kind == "commands":
        return commands_reference()
    if kind == "readme":
        return readme_section(argument)
    if kind == "reference-kinds":
        return reference_kinds()
    if kind == "optimizer-methods":
        return optimizer_methods()
    if kind == "fmi-versions":
        return fmi_versions()
    if kind == "benchmark":
        return benchmark(argument)
    if kind == "records":
        return records_table()
    if kind == "metrics":
        return metrics_table()
    if kind == "modules":
        return modules_table()
    raise ValueError(f"unknown generated part {kind!r}")


def commands_reference() -> str:
    """Every command's usage and options, as its ``--help`` prints them."""
    from furuta_cosim.cli import build_parser

    width = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_WIDTH  # argparse wraps at the terminal's width
    try:
        parser = build_parser()
        text = _commands_text(parser)
    finally:
        if width is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = width
    return text


def _commands_text(parser: argparse.ArgumentParser) -> str:
    parts = ["```text", _plain(parser.format_help()), "```", ""]
    for name, sub in _subcommands(parser):
        nested = list(_subcommands(sub))
        for full, command in ([(f"{name} {n}", c) for n, c in nested] if nested else [(name, sub)]):
            parts += [f"## furuta-cosim {full}", "", "```text", _plain(command.format_help()), "```", ""]
    return "\n".join(parts)


def _subcommands(parser: argparse.ArgumentParser):
    for action in parser._actions:  # argparse keeps its subparsers here; no public accessor
        if isinstance(action, argparse._SubParsersAction):
            yield from action.choices.items()


def _plain(text: str) -> str:
    return text.replace("```", "'''").rstrip()


def reference_kinds() -> str:
    """A table of the registered reference kinds, their keys and whether they settle."""
    from furuta_cosim.references import KINDS

    rows = ["| type | keys | optional | step metrics |", "| --- | --- | --- | --- |"]
    for name, kind in KINDS.items():
        rows.append(f"| `{name}` | {', '.join(kind.required)} | {', '.join(kind.optional) or '-'} | "
                    f"{'yes' if kind.settles else 'no'} |")
    return "\n".join(rows) + "\n"


def modules_table(package: Path = ROOT / "furuta_cosim") -> str:
    """Every module of the package and what it holds: the first sentence of its docstring."""
    import ast

    rows = ["| module | what it holds |", "| --- | --- |"]
    for path in sorted(package.rglob("*.py"), key=lambda p: (len(p.relative_to(package).parts), p)):
        relative = path.relative_to(package)
        if path.name == "__init__.py" or "_c" in relative.parts or "template" in relative.parts:
            continue   # C sources, and new-plant's template (a user's file, not a module)
        text = ast.get_docstring(ast.parse(path.read_text())) or ""
        paragraph = " ".join(text.split("\n\n")[0].split())
        first = re.split(r"(?<=[a-z0-9)`])\. (?=[A-Z`(])", paragraph, maxsplit=1)[0].rstrip(".:")
        if not first:
            raise ValueError(f"{relative}: a module without a docstring saying what it holds")
        rows.append(f"| `{relative.as_posix()}` | {first.replace('|', '/')} |")
    return "\n".join(rows) + "\n"


def metrics_table() -> str:
    """A table of the registered metrics (furuta_cosim/metrics.py)."""
    from furuta_cosim.metrics import METRICS

    signals = {"input": "`u`", "error": "`error`", "step": "the tracked output (and `<y>.step<k>`)",
               "signal": "every recorded signal", "regulated": "an output that starts away from 0",
               "wrapped": "an angle that starts hanging"}
    rows = ["| metric | of | what | grows | in the table | regression tolerance |",
            "| --- | --- | --- | --- | --- | --- |"]
    for (group, name), m in METRICS.items():
        tolerance = ", ".join(f"{k} {v:g}" for k, v in (("rtol", m.rtol), ("atol", m.atol)) if v) or "the scenario's"
        rows.append(f"| `{name}` | {signals[group]} | {m.description.replace('|', chr(92) + '|')} | "
                    f"{'yes' if m.grows else '-'} | "
                    f"{'yes' if m.shown else '-'} | {tolerance} |")
    return "\n".join(rows) + "\n"


def optimizer_methods() -> str:
    """A table of the registered optimizer methods."""
    from furuta_cosim.tuning.methods import METHODS

    rows = ["| method | what | a tradeoff objective |", "| --- | --- | --- |"]
    rows += [f"| `{name}` | {m.description} | {'no' if m.one_number else 'yes'} |" for name, m in METHODS.items()]
    return "\n".join(rows) + "\n"


def fmi_versions() -> str:
    """A table of the registered FMI versions."""
    from furuta_cosim.fmu.session import SESSIONS
    from furuta_cosim.fmu.versions import VERSIONS

    rows = ["| FMI | binaries | C glue | session class |", "| --- | --- | --- | --- |"]
    rows += [f"| {name} | `binaries/{v.platform}/` | {', '.join(v.glue)} | `{SESSIONS[name].__name__}` |"
             for name, v in VERSIONS.items()]
    return "\n".join(rows) + "\n"


def readme_section(heading: str) -> str:
    """The README's ``## HEADING`` section, without its heading."""
    text = (ROOT / "README.md").read_text()
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    if not match:
        raise ValueError(f"README.md has no section '## {heading}'")
    return match.group(1).strip() + "\n"


def _record(name: str, folder: Path = RECORDS) -> tuple[dict, str]:
    """A record's header fields (``command``, ``commit``, ``measures``, ``checked``) and body."""
    head, _, body = (folder / f"{name}.txt").read_text().partition("\n\n")
    return dict(line.split(": ", 1) for line in head.splitlines()), body.rstrip()


def benchmark(name: str, folder: Path = RECORDS) -> str:
    """A recorded benchmark output (tools/record.py) and the command that printed it; when it
    was measured and whether the code changed since is the Performance page's business."""
    fields, body = _record(name, folder)
    return f"Measured by `{fields['command']}`:\n\n```text\n{body}\n```\n"


def records_table(folder: Path = RECORDS) -> str:
    """Every record: the command, the commit it was measured at and the paths it measures."""
    rows = ["| record | command | measured at | measures |", "| --- | --- | --- | --- |"]
    for path in sorted(folder.glob("*.txt")):
        fields, _ = _record(path.stem, folder)
        checked = f"; checked at `{fields['checked'].split()[0]}`" if fields.get("checked") else ""
        rows.append(f"| {path.stem} | `{fields['command']}` | `{fields['commit']}`{checked} | "
                    f"{fields.get('measures', 'furuta_cosim fmu_src')} |")
    return "\n".join(rows) + "\n"


def stale_records(folder: Path = RECORDS) -> str:
    """The records whose measured code changed after they were measured (built site only)."""
    lines = []
    for path in sorted(folder.glob("*.txt")):
        fields, _ = _record(path.stem, folder)
        since = (fields.get("checked", "").split() or [fields["commit"]])[0]
        stale = _changed_since(since, fields.get("measures", "furuta_cosim fmu_src").split())
        if stale:
            lines.append(f"- **{path.stem}**: the code it measures changed in {stale} commit(s) after "
                         f"`{since}`; run `{fields['command']}` again.")
    if not lines:
        return "Every record was measured at the code it measures.\n"
    return "!!! warning \"Stale records\"\n" + "".join(f"    {line}\n" for line in lines)


def write_pages(check: bool = False, keep: tuple[str, ...] = ()) -> list[str]:
    """Write every page's generated parts; the pages that were (``check``: would be) changed.
    ``keep``: kinds of parts left as they are."""
    changed = []
    for page in sorted(PAGES.glob("*.md")):
        text = page.read_text()
        fresh = generate(text, keep)
        if fresh != text:
            changed.append(page.name)
            if not check:
                page.write_text(fresh)
    return changed


def _changed_since(commit: str, paths: list[str]) -> int:
    """How many commits after ``commit`` touched ``paths`` (0 outside a git checkout)."""
    try:
        out = subprocess.run(["git", "rev-list", "--count", f"{commit}..HEAD", "--", *paths], cwd=ROOT,
                             capture_output=True, text=True, check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return int(out.strip() or 0)


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    parser = argparse.ArgumentParser(description="write the docs' generated parts into the pages")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="write them")
    mode.add_argument("--check", action="store_true", help="only list the pages out of date (exit 1)")
    arguments = parser.parse_args()
    pages = write_pages(check=arguments.check)
    for name in pages:
        print(("out of date: " if arguments.check else "written: ") + name)
    sys.exit(1 if arguments.check and pages else 0)
