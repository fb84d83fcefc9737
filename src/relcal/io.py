"""YAML with line numbers for error messages, validation, and file writes (through
:mod:`relcal.outputset`: whole sets, never over an input)."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path
from typing import Any, TypeVar

import pydantic
import yaml

from relcal.errors import RelcalError, excerpt, printable
from relcal.limits import check_yaml_nodes, read_input
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

    __slots__ = ("line",)

    def __init__(self, cells=(), line: int = 0) -> None:
        super().__init__(cells)
        self.line = line


DELIMITERS = {",": "commas", ";": "semicolons", "\t": "tabs", "|": "vertical bars"}


def _delimiter(path: Path, header: str) -> str:
    """The delimiter of a table from its header line: the most frequent of comma, semicolon,
    tab and vertical bar (a comma on a tie: decimal commas come with semicolons)."""
    counts = {d: header.count(d) for d in DELIMITERS}
    best = max(counts, key=lambda d: (counts[d], d == ","))
    if counts[best] == 0 and len(header.split()) > 1:
        raise RelcalError(
            f"{path} line 1: header: one field {excerpt(header)}: columns separated by spaces? "
            "relcal reads tables separated by commas, semicolons or tabs"
        )
    return best


def table_delimiter(path: str | Path) -> str:
    """The delimiter :func:`read_table` reads ``path`` with (call it after :func:`read_table`,
    which checks the file)."""
    with open(path, newline="", encoding="utf-8-sig") as handle:
        for raw in handle:
            if raw.strip() and not raw.lstrip().startswith("#"):
                return _delimiter(Path(path), raw)
    return ","


def read_table(path: str | Path, what: str) -> tuple[list[str], list[TableRow]]:
    """The stripped header and the data rows of a CSV file (blank lines dropped; each row keeps
    its line number in ``row.line``).

    A UTF-8 byte-order mark is skipped; the delimiter is the header's: commas, semicolons
    (with decimal commas named in messages), tabs or vertical bars. ``what`` names one data row
    in messages (``"sample"``, ``"target"``); a file without a header and at least one data row
    is an error naming the file. The file's size is capped before reading (:mod:`relcal.limits`).
    """
    path = Path(path)
    note_input(path)
    if path.is_dir():
        raise RelcalError(f"{path}: is a directory, expected a CSV file")
    rows: list[TableRow] = []
    line_num = 0
    try:
        data = read_input(path, "csv")
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            line_num = data[: exc.start].count(b"\n")
            raise
        with io.StringIO(text, newline="") as handle:
            first = ""
            for raw in handle:
                if raw.strip() and not raw.lstrip().startswith("#"):
                    first = raw
                    break
            handle.seek(0)
            delimiter = _delimiter(path, first) if first else ","
            reader = csv.reader(handle, delimiter=delimiter)
            start = 1
            for cells in reader:
                line_num = reader.line_num
                comment = not rows and cells and cells[0].lstrip().startswith("#")
                if cells and any(c.strip() for c in cells) and not comment:
                    spans = [c for c in cells if "\n" in c or "\r" in c]
                    if spans:  # a quote left open swallows the rows up to the next quote
                        raise RelcalError(
                            f"{path} line {start}: a quoted field runs on to line "
                            f"{reader.line_num} ({excerpt(spans[0])}): a quote left open? "
                            "(a field never spans lines)"
                        )
                    rows.append(TableRow(cells, start))  # (comments: a plan file's first line)
                start = reader.line_num + 1
    except FileNotFoundError:
        raise RelcalError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise RelcalError(
            f"{path}: not a text file (not UTF-8 at line {line_num + 1}); expected a CSV table"
        ) from None
    except csv.Error as exc:
        raise RelcalError(f"{path} line {line_num + 1}: cannot read: {exc}") from None
    except OSError as exc:
        raise RelcalError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not rows:
        raise RelcalError(f"{path}: empty; expected a header line and one line per {what}")
    if len(rows) < 2:
        raise RelcalError(f"{path}: no {what}s after the header line")
    _check_separators(path, rows, delimiter)
    return [h.strip() for h in rows[0]], rows[1:]


def csv_line(cells: list[str]) -> str:
    """One CSV line (no line end) of ``cells``, quoted where a cell needs it (a comma, a quote
    or a line break, as in an id taken from a file: ``"a,b"``), so that :func:`read_table` reads
    the same cells back."""
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(cells)  # (a cell with "\n" is quoted)
    return out.getvalue()[:-1]


def other_separator(line: str, delimiter: str, width: int) -> str | None:
    """The separator other than ``delimiter`` that splits ``line`` into ``width`` fields, when
    ``delimiter`` does not split it at all (a tab-separated row in a comma-separated file reads
    as one field holding them all); else None."""
    if width == 1 or len(line.split(delimiter)) != 1:
        return None
    return next((d for d in DELIMITERS if d != delimiter and len(line.split(d)) == width), None)


def _check_separators(path: Path, rows: list[TableRow], delimiter: str) -> None:
    """Refuse a data row whose fields are separated by another character than the header's,
    naming both separators (:func:`other_separator`); any other miscount is left to the
    reader's own message."""
    width = len(rows[0])
    for row in rows[1:]:
        if len(row) != 1:  # (a row the header's separator splits at all: its own)
            continue
        other = other_separator(delimiter.join(row), delimiter, width)
        if other is not None:
            raise RelcalError(
                f"{path} line {row.line}: fields separated by {DELIMITERS[other]}, but the "
                f"header (line {rows[0].line}) by {DELIMITERS[delimiter]}; use one separator "
                "throughout the file"
            )


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
    """Parse a YAML file; return the data and its node tree (for line numbers).

    The one YAML reader of relcal: the file's size is capped before reading and its aliases'
    expansion before anything walks it (:mod:`relcal.limits`)."""
    path = Path(path)
    note_input(path)
    if path.is_dir():
        raise RelcalError(f"{path}: is a folder, expected a YAML file")
    try:
        text = read_input(path, "yaml").decode("utf-8-sig")
    except FileNotFoundError:
        raise RelcalError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise RelcalError(f"{path}: not a text file (not UTF-8); expected YAML") from None
    except OSError as exc:
        raise RelcalError(f"{path}: cannot read: {exc.strerror or exc}") from None
    loader = _Loader(text)
    try:  # parsed once: the node tree, bounded, then the data constructed from it
        node = loader.get_single_node()
        if node is not None:
            check_yaml_nodes(path, node)
        data = None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise RelcalError(f"{path}{where}: malformed YAML: {printable(problem)}") from None
    except RecursionError:
        raise RelcalError(f"{path}: YAML nested too deeply; not a relcal file") from None
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
        return f"expected a mapping of fields (key: value), got {_kind(value)}"
    if kind in ("float_type", "int_type") and isinstance(value, str):
        return (
            f"expected a number, got the text {excerpt(value)} (numbers are written without quotes)"
        )
    msg = re.sub(r"^Value error, ", "", err["msg"])
    return printable(re.sub(r"\b(?:an? )?instance of _?[A-Z]\w*", "a mapping", msg), 300)


def _kind(value: Any) -> str:
    """What a YAML value is, for a message, without showing a long text (a file named in the
    wrong place must not have its content printed)."""
    if value is None:
        return "nothing (an empty document or field)"
    if isinstance(value, str):
        return (
            f"the text {excerpt(value)}"
            if len(value) <= 40
            else f"a text of {len(value)} characters"
        )
    if isinstance(value, list):
        return f"a list of {len(value)} items"
    return f"{type(value).__name__} {excerpt(value)}"


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
