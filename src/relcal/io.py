"""YAML with line numbers for error messages, validation, and file writes (through
:mod:`relcal.outputset`: whole sets, never over an input)."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from typing import Any, TypeVar

import pydantic
import yaml

from relcal.errors import RelcalError
from relcal.outputset import File, Folder, note_input, write_set

__all__ = ["File", "Folder", "note_input", "write_set"]

M = TypeVar("M", bound=pydantic.BaseModel)


def _node_at(node: yaml.Node, loc: tuple[Any, ...]) -> yaml.Node:
    """The deepest YAML node along a pydantic error location."""
    for key in loc:
        if isinstance(node, yaml.MappingNode):
            match = [v for k, v in node.value if k.value == str(key)]
            if not match:
                break
            node = match[0]
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            node = node.value[key]
        else:
            break
    return node


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for key in loc:
        out += f"[{key}]" if isinstance(key, int) else (f".{key}" if out else str(key))
    return out or "(top level)"


class TableRow(list):
    """The cells of one CSV row, with ``line``: its 1-based line number in the file."""

    line: int = 0


def read_table(path: str | Path, what: str) -> tuple[list[str], list[TableRow]]:
    """The stripped header and the data rows of a CSV file (blank lines dropped; each row keeps
    its line number in ``row.line``).

    A UTF-8 byte-order mark is skipped; a semicolon-delimited file (a header without commas) is
    read with semicolons. ``what`` names one data row in messages (``"sample"``, ``"target"``); a
    file without a header and at least one data row is an error naming the file.
    """
    path = Path(path)
    note_input(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            text = handle.read()
    except FileNotFoundError:
        raise RelcalError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise RelcalError(f"{path}: is a directory, expected a CSV file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RelcalError(f"{path}: cannot read: {exc}") from None
    first = next((line for line in text.splitlines() if line.strip()), "")
    delimiter = ";" if ";" in first and "," not in first else ","
    rows: list[TableRow] = []
    try:
        reader = csv.reader(text.splitlines(keepends=True), delimiter=delimiter)
        start = 1
        for cells in reader:
            row = TableRow(cells)
            row.line = start
            start = reader.line_num + 1
            if not rows and cells and cells[0].lstrip().startswith("#"):
                continue  # a comment before the header (a plan file's first line)
            if cells and any(c.strip() for c in cells):
                rows.append(row)
    except csv.Error as exc:
        raise RelcalError(f"{path} line {reader.line_num}: cannot read: {exc}") from None
    if not rows:
        raise RelcalError(f"{path}: empty; expected a header line and one line per {what}")
    if len(rows) < 2:
        raise RelcalError(f"{path}: no {what}s after the header line")
    return [h.strip() for h in rows[0]], rows[1:]


class _Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # libyaml's parser when built
    """PyYAML's safe loader with YAML 1.2 floats: ``1e300`` and ``2E-3`` (no dot) are numbers,
    not strings as in YAML 1.1."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def yaml_text(data: Any) -> str:
    """YAML text of ``data`` (plain types), keys in their order, with libyaml's emitter when
    PyYAML was built with it (the same text, several times faster)."""
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return yaml.dump(data, Dumper=dumper, sort_keys=False)


def load_yaml(path: str | Path) -> tuple[Any, yaml.Node | None]:
    """Parse a YAML file; return the data and its node tree (for line numbers)."""
    path = Path(path)
    note_input(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise RelcalError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RelcalError(f"{path}: cannot read: {exc}") from None
    loader = _Loader(text)
    try:  # parsed once: the node tree, then the data constructed from it
        node = loader.get_single_node()
        data = None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise RelcalError(f"{path}{where}: malformed YAML: {problem}") from None
    finally:
        loader.dispose()
    return data, node


def validate(schema: type[M], data: Any, path: str | Path, node: yaml.Node | None = None) -> M:
    """Validate ``data`` against a pydantic schema; errors name the file, line and field."""
    try:
        return schema.model_validate(data)
    except pydantic.ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = tuple(err["loc"])
            where = ""
            if node is not None:
                where = f" line {_node_at(node, loc).start_mark.line + 1}"
            lines.append(f"{path}{where}: {_format_loc(loc)}: {_message(err)}")
        raise RelcalError("\n".join(lines)) from None


def _message(err: dict) -> str:
    """pydantic's message for a person: no internal class names, no "Value error," prefix."""
    kind, value = err["type"], err.get("input")
    if kind == "model_type" or kind == "dict_type":
        return f"expected a mapping of fields (key: value), got {type(value).__name__} {value!r}"
    if kind in ("float_type", "int_type") and isinstance(value, str):
        return f"expected a number, got the text {value!r} (numbers are written without quotes)"
    msg = re.sub(r"^Value error, ", "", err["msg"])
    return re.sub(r"\b(?:an? )?instance of _?[A-Z]\w*", "a mapping", msg)


def load_validated(schema: type[M], path: str | Path) -> M:
    """Load a YAML file and validate it against ``schema``."""
    data, node = load_yaml(path)
    return validate(schema, data, path, node)


def write_text(path: str | Path, text: str, what: str = "output") -> None:
    """Write one text file as a unit (:func:`relcal.outputset.write_set`); ``what`` names the
    option or role in messages."""
    write_set(File(path, text, what))


def write_bytes(path: str | Path, data: bytes, what: str = "output") -> None:
    """Write one binary file as a unit."""
    write_set(File(path, data, what))


def json_text(data: Any) -> str:
    """JSON, indented, with NaN refused (it is not JSON)."""
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


def write_json(path: str | Path, data: Any, what: str = "--json") -> None:
    """Write JSON as a unit, indented, with NaN refused (it is not JSON)."""
    write_text(path, json_text(data), what)
