"""Strict reading of the project's YAML files.

Every problem is collected with its place (``file: key.path: what was expected``) and all
are raised at once as one :class:`~furuta_cosim.errors.ConfigError`; unknown keys are
problems, never silently skipped.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Iterator, Mapping

import yaml

from furuta_cosim.defaults import MAX_MAGNITUDE, MAX_PERIOD, MIN_PERIOD
from furuta_cosim.errors import ConfigError

# libyaml's safe loader when PyYAML was built with it: the same documents, several times faster
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
# a project file is a few kilobytes; these bounds keep a hostile one from taking the machine
MAX_BYTES = 1_000_000
MAX_NODES = 200_000     # nodes with every alias expanded (an alias bomb has billions)
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")  # all but tab and newline


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key, first: int, again: int):
        super().__init__(f"duplicate key {key!r}")
        self.key, self.first, self.again = key, first, again


_BOOL = "tag:yaml.org,2002:bool"


class _StrictLoader(_SAFE_LOADER):
    """The safe loader, refusing a key that appears twice in one mapping (PyYAML keeps the
    last one silently). A plain key that YAML 1.1 reads as a boolean (``on``, ``off``,
    ``yes``, ``no``) stays the word it is, as YAML 1.2 reads it: no key of a project file is a
    boolean, and ``derivative: {on: error}`` means the word ``on``. Values keep 1.1's reading."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                if key_node.tag == _BOOL and isinstance(key_node, yaml.ScalarNode) and not key_node.style:
                    key_node.tag = "tag:yaml.org,2002:str"
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    first = seen.get(key)
                except TypeError:
                    continue  # an unhashable key: the base constructor reports it
                if first is not None:
                    raise _DuplicateKey(key, first, line)
                seen[key] = line
        return super().construct_mapping(node, deep=deep)


def _expanded_size(node, sizes: dict) -> int:
    """The number of nodes with every alias expanded, counted without expanding them."""
    known = sizes.get(id(node))
    if known is not None:
        return known
    sizes[id(node)] = 1  # a recursive alias counts once: the constructor refuses nothing here
    if isinstance(node, yaml.SequenceNode):
        total = 1 + sum(_expanded_size(child, sizes) for child in node.value)
    elif isinstance(node, yaml.MappingNode):
        total = 1 + sum(_expanded_size(k, sizes) + _expanded_size(v, sizes) for k, v in node.value)
    else:
        total = 1
    sizes[id(node)] = total
    return total


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file with a safe loader. A missing file, a syntax error, a duplicate key,
    a file over 1 MB or one whose aliases expand to over 200,000 nodes is a ConfigError."""
    from furuta_cosim.inputs import read_input

    path = Path(path)
    raw = read_input(path, MAX_BYTES, beyond="not a furuta-cosim file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError([f"{path}: cannot be read (not UTF-8 text)"]) from None
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        nodes = _expanded_size(node, {})
        if nodes > MAX_NODES:
            raise ConfigError([f"{path}: its aliases expand to {nodes:,} nodes (at most "
                               f"{MAX_NODES:,}): not a furuta-cosim file"])
        return loader.construct_document(node)
    except _DuplicateKey as error:
        raise ConfigError([f"{path}: line {error.again}: duplicate key {excerpt(str(error.key))} "
                           f"(first at line {error.first})"]) from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else "?"
        reason = excerpt(getattr(error, "problem", None) or str(error), 80).strip("'\"")
        raise ConfigError([f"{path}: {where}: invalid YAML ({reason})"]) from None
    except RecursionError:
        raise ConfigError([f"{path}: nested too deeply: not a furuta-cosim file"]) from None
    finally:
        loader.dispose()


# the kinds of file a scenario tree holds in folders of their own; scenarios are at its top
KIND_FOLDERS = ("controllers", "plants", "tuning")


def key_line(path: str | Path, keys: tuple) -> int | None:
    """The line (1-based) of the nested key ``keys`` in the YAML file ``path``, or None when the
    file or the key cannot be found (a message then says the key alone)."""
    try:
        node = yaml.compose(Path(path).read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    line = None
    for key in keys:
        if not isinstance(node, yaml.MappingNode):
            return None
        for key_node, value in node.value:
            if getattr(key_node, "value", None) == str(key):
                node, line = value, key_node.start_mark.line + 1
                break
        else:
            return None
    return line


def resolve_file(name: str | Path, folder: Path, kind: str, *, beside: Path | None = None,
                 also: tuple[str, ...] = ()) -> Path:
    """A file path, or a name of ``<folder>/<name>.yaml`` (``folder``: the shipped files of
    this kind). The one rule: files resolve beside the file that names them.

    A relative path (it ends in .yaml/.yml or has a folder in it) is taken beside the file that
    names it (``beside``: that file's folder) when there is one, else from the working
    directory. A plain name named in a file is looked up first in that file's own scenario
    tree (the file's folder, or its parent for a file in ``controllers/``, ``plants/`` or
    ``tuning/``; there in the kind's folder), then among the shipped files. An unknown name is
    a ConfigError listing every valid name, with the names ``also`` that the caller resolves
    itself.
    """
    path = Path(name)
    looks_like_path = path.suffix in (".yaml", ".yml") or len(path.parts) > 1
    if looks_like_path:
        if beside is not None and not path.is_absolute():
            return beside / path
        return path
    if beside is None and path.is_file():
        return path
    folders = [folder]
    if beside is not None:
        tree = beside.parent if beside.name in KIND_FOLDERS else beside
        own = tree / folder.name if folder.name in KIND_FOLDERS else tree
        if own.resolve() != folder.resolve():
            folders.insert(0, own)
    for place in folders:
        candidate = place / f"{name}.yaml"
        if candidate.is_file():
            return candidate
    known = sorted({p.stem for place in folders for p in place.glob("*.yaml")} | set(also))
    raise ConfigError([f"{name}: no such {kind} file or name (known: {', '.join(known)})"
                       f"{did_you_mean(str(name), known)}"])


def did_you_mean(name: str, known) -> str:
    """``; did you mean 'x'?`` for the closest of ``known`` to a misspelt ``name``, or ''."""
    import difflib

    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


class Frozen(Mapping):
    """A read-only mapping that pickles (``types.MappingProxyType`` does not), so that
    scenarios and plant sets can be shipped to worker processes."""

    __slots__ = ("_data",)

    def __init__(self, data: Mapping | None = None):
        object.__setattr__(self, "_data", dict(data or {}))

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self) -> Iterator:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __repr__(self) -> str:
        return f"Frozen({self._data!r})"

    def __hash__(self) -> int:
        return hash(tuple(sorted(self._data.items(), key=repr)))

    def __getstate__(self):
        return self._data

    def __setstate__(self, state):
        object.__setattr__(self, "_data", dict(state))


class Checker:
    """Collects the problems of one file; each method returns None for a bad value."""

    def __init__(self, source: str | Path):
        self.source = str(source)
        self.problems: list[str] = []

    def fail(self, key: str, message: str) -> None:
        self.problems.append(f"{self.source}: {key}: {message}" if key else f"{self.source}: {message}")

    def done(self) -> None:
        if self.problems:
            raise ConfigError(self.problems)

    def mapping(self, value: Any, key: str, required: tuple = (), optional: tuple = ()) -> dict | None:
        if not isinstance(value, dict):
            if not key and isinstance(value, str):  # a whole file of text: maybe not ours, unquoted
                self.fail(key, f"expected a mapping, got text of {len(value)} characters: not a "
                               "furuta-cosim file")
            else:
                self.fail(key, f"expected a mapping, got {_kind(value)}")
            return None
        allowed = set(required) | set(optional)
        for name in value:
            if name not in allowed:
                self.fail(_join(key, name), f"unknown key (expected one of: {', '.join(sorted(allowed))})"
                                            f"{did_you_mean(str(name), allowed)}")
        for name in required:
            if name not in value:
                self.fail(_join(key, name), "missing")
        return value

    def number(self, value: Any, key: str, *, positive: bool = False, minimum: float | None = None,
               maximum: float | None = None, integer: bool = False) -> float | None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {_kind(value)}")
            return None
        if not math.isfinite(value):
            self.fail(key, f"must be finite, got {value}")
            return None
        if integer and value != int(value):
            self.fail(key, f"expected a whole number, got {value}")
            return None
        if positive and not value > 0:
            self.fail(key, f"must be > 0, got {value}")
            return None
        if minimum is not None and value < minimum:
            self.fail(key, f"must be >= {minimum:g}, got {value:g}")
            return None
        if maximum is not None and value > maximum:
            self.fail(key, f"must be <= {maximum:g}, got {value:g}")
            return None
        return int(value) if integer else float(value)

    def period(self, value: Any, key: str) -> float | None:
        """A period (control, sample, communication step): from 1e-9 to 1e6."""
        number = self.number(value, key, positive=True)
        if number is not None and not MIN_PERIOD <= number <= MAX_PERIOD:
            self.fail(key, f"expected a period from {MIN_PERIOD:g} to {MAX_PERIOD:g}, got {number:g}")
            return None
        return number

    def numbers(self, value: Any, key: str, **bounds) -> Mapping[str, float]:
        """A mapping of names to numbers (the names are free); the good entries, read-only."""
        section = self.mapping(value, key, optional=tuple(value) if isinstance(value, dict) else ())
        result = {}
        for name, number in (section or {}).items():
            number = self.number(number, _join(key, name), **bounds)
            if number is not None:
                result[str(name)] = number
        return Frozen(result)

    def string(self, value: Any, key: str, choices: tuple | None = None) -> str | None:
        if not isinstance(value, str) or not value:
            self.fail(key, f"expected a non-empty string, got {_kind(value)}")
            return None
        if choices and value not in choices:
            self.fail(key, f"expected one of {', '.join(choices)}, got {excerpt(value)}"
                           f"{did_you_mean(value, choices)}")
            return None
        return value

    def file_name(self, value: Any, key: str) -> str | None:
        """A name that becomes part of file names (traces, figures): a plain name."""
        text = self.string(value, key)
        if text is not None and not _NAME.fullmatch(text):
            self.fail(key, f"must be a plain name (letters, digits, '.', '_', '+', '-'; it names "
                           f"output files), got {excerpt(text)}")
            return None
        return text

    def text(self, value: Any, key: str) -> str:
        """Free text (a description); anything but a string is a problem."""
        if not isinstance(value, str):
            self.fail(key, f"expected text, got {_kind(value)}")
            return ""
        control = _CONTROL.search(value)
        if control:
            self.fail(key, f"contains a control character ({control.group()!r}): plain text only")
            return ""
        return value

    def names(self, value: Any, key: str, length: int | None = None) -> list[str] | None:
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            self.fail(key, f"expected a list of names, got {_kind(value)}")
            return None
        if length is not None and len(value) != length:
            self.fail(key, f"expected {length} names, got {len(value)}")
            return None
        if len(set(value)) != len(value):
            self.fail(key, "names must be unique")
            return None
        return list(value)

    def vector(self, value: Any, key: str, length: int | None = None) -> list[float] | None:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value]
        if not isinstance(value, list):
            self.fail(key, f"expected a list of numbers, got {_kind(value)}")
            return None
        if length is not None and len(value) != length:
            self.fail(key, f"expected {length} values, got {len(value)}")
            return None
        numbers = [self.number(v, f"{key}[{k}]") for k, v in enumerate(value)]
        return None if any(v is None for v in numbers) else numbers

    def matrix(self, value: Any, key: str, rows: int | None = None,
               cols: int | None = None) -> list[list[float]] | None:
        """A list of rows; a scalar is a 1x1 matrix, a flat list one row."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [[value]]
        if isinstance(value, list) and value and not any(isinstance(v, list) for v in value):
            value = [value]
        if not isinstance(value, list) or not value or not all(isinstance(r, list) for r in value):
            self.fail(key, f"expected a matrix (a list of rows), got {_kind(value)}")
            return None
        widths = {len(r) for r in value}
        if 0 in widths:
            self.fail(key, "expected a matrix with at least one entry in each row, got an empty row")
            return None
        if len(widths) != 1:
            self.fail(key, f"rows have different lengths {sorted(widths)}")
            return None
        if rows is not None and len(value) != rows:
            self.fail(key, f"expected {rows} rows, got {len(value)}")
            return None
        if cols is not None and len(value[0]) != cols:
            self.fail(key, f"expected {cols} columns, got {len(value[0])}")
            return None
        numbers = [[self.number(v, f"{key}[{i}][{j}]") for j, v in enumerate(r)]
                   for i, r in enumerate(value)]
        if any(v is None for r in numbers for v in r):
            return None
        largest = max(abs(v) for r in numbers for v in r)
        if largest > MAX_MAGNITUDE:
            self.fail(key, f"entries must be within +-{MAX_MAGNITUDE:g}, got {largest:g}")
            return None
        return numbers


def plain_name(text: str) -> bool:
    """A name that may become part of a file name: letters, digits, '.', '_', '+', '-', not
    starting with a dot (so never '.' or '..')."""
    return bool(_NAME.fullmatch(text))


def excerpt(text: str, limit: int = 30) -> str:
    """A short, printable quotation of a value read from a file: an error never repeats more
    of a file it could not use than this (it may not even be ours: ``../../etc/passwd``)."""
    shown = repr(text[:limit])
    return shown + ("..." if len(text) > limit else "")


def _join(key: str, name: Any) -> str:
    return f"{key}.{name}" if key else str(name)


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"a boolean ({value})"
    if isinstance(value, (int, float)):
        return f"a number ({value})"
    if isinstance(value, str):
        return f"a string ({excerpt(value)})"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "a mapping"
    return type(value).__name__
