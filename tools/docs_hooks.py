"""MkDocs hooks of the docs site (``docs/mkdocs.yml``): the pages that are generated from the
code, so that they cannot drift from it.

- ``<!-- commands -->`` becomes the reference of every command, from the CLI's own parser
  (the text ``--help`` prints).
- ``<!-- reference-kinds -->``, ``<!-- optimizer-methods -->``, ``<!-- fmi-versions -->``
  become the tables of those registries.
- ``<!-- readme: HEADING -->`` becomes that section of the README (the set-up commands are
  written once, in the README).
- ``<!-- benchmark: NAME -->`` becomes the recorded output of a benchmark,
  ``docs/benchmarks/NAME.txt``, with the command and commit it came from, and a warning when
  the code it measures changed after that commit (a stale figure shows as stale).
"""

from __future__ import annotations

import argparse
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
_MARK = re.compile(r"<!-- (commands|readme|benchmark|reference-kinds|optimizer-methods|fmi-versions)"
                   r"(?:: ([^>]+?))? -->")


def on_page_markdown(markdown: str, page, config, files) -> str:
    return _MARK.sub(lambda m: _expand(m.group(1), (m.group(2) or "").strip()), markdown)


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
    return benchmark(argument)


def commands_reference() -> str:
    """Every command's usage and options, as its ``--help`` prints them."""
    from furuta_cosim.cli import build_parser

    parser = build_parser()
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


def benchmark(name: str, folder: Path = ROOT / "docs" / "benchmarks") -> str:
    """A recorded benchmark output (tools/record.py): its header lines ``command:``,
    ``commit:``, ``measures:`` (the paths whose change makes the figures stale), then the
    output as printed."""
    path = folder / f"{name}.txt"
    head, _, body = path.read_text().partition("\n\n")
    fields = dict(line.split(": ", 1) for line in head.splitlines())
    command, commit = fields["command"], fields["commit"]
    # ``checked: COMMIT WHAT``: a long benchmark checked later to reproduce (WHAT says how)
    checked, _, how = fields.get("checked", "").partition(" ")
    since = checked or commit
    stale = _changed_since(since, fields.get("measures", "furuta_cosim fmu_src").split())
    note = (f"!!! warning \"Stale\"\n    The code these figures measure changed in {stale} commit(s) "
            f"after {since}; run `{command}` again.\n\n" if stale else "")
    also = f"; checked at `{checked}`: {how}" if checked else ""
    return (f"{note}Recorded at commit `{commit}` by `{command}`{also}:\n\n```text\n{body.rstrip()}\n```\n")


def _changed_since(commit: str, paths: list[str]) -> int:
    """How many commits after ``commit`` touched ``paths`` (0 outside a git checkout)."""
    try:
        out = subprocess.run(["git", "rev-list", "--count", f"{commit}..HEAD", "--", *paths], cwd=ROOT,
                             capture_output=True, text=True, check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return int(out.strip() or 0)
