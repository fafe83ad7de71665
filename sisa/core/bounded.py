"""Parsers that bound what they accept: how deep a document may nest, how large a settings
file may be. Every reader of JSON (flight-log messages and schemas, endpoints files) and TOML
(scenario and sensor files) goes through these, so a hostile file (a table nested 10 000 levels
deep, a 100 MB key) is a one-line error, or a message counted and skipped, never a
RecursionError traceback or a gigabyte of memory.

The parsers themselves (json's C scanner, tomllib) are used as they are: both refuse a
document nested past the interpreter's recursion limit with a RecursionError, turned here into
a ValueError like any other malformed input; what they did parse is then measured without
recursion (`nesting_depth`), as nothing in SISA needs more than `MAX_NESTING` levels (the
deepest, a JSON Schema, needs 4). TOML is measured before it is parsed as well
(`toml_nesting_bound`, one linear pass): tomllib takes time quadratic in the length of a dotted
key (`a.a.a…` 10 000 segments long: 2 s; the 500 000 a settings file could hold: hours).
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path
from typing import Any

MAX_NESTING = 64  # levels of arrays / objects / tables in any document SISA reads
MAX_SETTINGS_BYTES = 1 << 20  # a scenario or sensor file: the presets are ~3 kB


class NestingError(ValueError):
    """A document nested deeper than its reader allows."""


def nesting_depth(value: Any, limit: int = MAX_NESTING) -> int:
    """How many levels of lists and dicts `value` nests (0 for a scalar), counted without
    recursion; counting stops past `limit` (the result is then limit + 1)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children: Any = item.values()
        elif isinstance(item, list | tuple):
            children = item
        else:
            continue
        depth += 1
        if depth > limit:
            return depth
        deepest = max(deepest, depth)
        stack.extend((child, depth) for child in children if isinstance(child, dict | list))
    return deepest


def _check_nesting(value: Any, limit: int) -> Any:
    if nesting_depth(value, limit) > limit:
        raise NestingError(f"nested deeper than {limit} levels")
    return value


def json_loads(data: bytes | str, limit: int = MAX_NESTING) -> Any:
    """`json.loads`, with nesting bounded: ValueError (NestingError) for a document nested
    deeper than `limit`. A document with no more brackets than `limit` cannot be, and is not
    measured (every message of a flight log but a hostile one)."""
    brackets = (data.count(b"[") + data.count(b"{") if isinstance(data, bytes)
                else data.count("[") + data.count("{"))
    try:
        value = json.loads(data)
    except RecursionError:
        raise NestingError(f"nested deeper than {limit} levels") from None
    return value if brackets <= limit else _check_nesting(value, limit)


# TOML's tokens as far as nesting goes: what cannot nest (comments, strings, words, numbers)
# is skipped whole; every alternative matches whatever follows its first character (a string
# left open ends at its line's end), so the scan never goes back: linear in the text
_TOML_TOKENS = re.compile(r"""
    \#[^\n]*
  | "{3}(?:\\[\s\S]|[^\\])*?(?:"{3}|\\?\Z)
  | '{3}[\s\S]*?(?:'{3}|\Z)
  | "(?:\\[^\n]|[^"\\\n])*(?:"|\\?(?=\n)|\\?\Z)
  | '[^'\n]*(?:'|(?=\n)|\Z)
  | [^\[\]{}=,.\n"'\#]+
  | (?P<mark>[\[\]{}=,.\n])
""", re.VERBOSE)


def toml_nesting_bound(text: str, limit: int = MAX_NESTING) -> int:
    """An upper bound of how deep a TOML document nests (tables, dotted keys, arrays, inline
    tables), from its text in one pass; the pass stops once it passes `limit`."""
    deepest = table = 1  # the depth of the [table] being filled (the document's own: 1)
    extra = value = 0  # the keys' levels above the current value, and a new value's
    stack: list[int] = []  # the open arrays / inline tables: `extra` outside each
    key, header, dots = True, 0, 0
    for match in _TOML_TOKENS.finditer(text):
        mark = match["mark"]
        if mark is None:
            continue
        if mark == "\n":
            if not stack:
                key, dots, extra = True, 0, 0
        elif mark == ".":
            dots += key or header > 0
        elif mark == "=":
            key, value, dots = False, extra + dots + 1, 0
        elif mark == "[" and key and not stack:  # a table header: [a.b] or [[a.b]]
            header, dots = header + 1, 0
        elif mark == "]" and header:
            header -= 1
            if not header:
                table, key, dots = dots + 3, False, 0
        elif mark in "[{":
            stack.append(extra)
            extra = value
            key, dots = mark == "{", 0
        elif mark in "]}":
            extra = stack.pop() if stack else 0
            key = False
        elif mark == "," and stack:
            key, dots = True, 0
        deepest = max(deepest, table + extra + len(stack) + dots + header)
        if deepest > limit:
            break
    return deepest


def toml_loads(text: str, limit: int = MAX_NESTING) -> dict[str, Any]:
    """`tomllib.loads`, with nesting bounded (arrays, inline tables, and tables made by dotted
    keys alike): ValueError for a deeper document, as for any malformed one."""
    if toml_nesting_bound(text, limit) > limit:
        raise NestingError(f"nested deeper than {limit} levels")
    try:
        table = tomllib.loads(text)
    except RecursionError:
        raise NestingError(f"nested deeper than {limit} levels") from None
    return _check_nesting(table, limit)  # type: ignore[no-any-return]


def read_settings_text(path: Path, limit_bytes: int = MAX_SETTINGS_BYTES) -> str:
    """A settings file's text (UTF-8); ValueError if it is larger than `limit_bytes` (a
    settings file is a few kB: a larger one is not one, and is not read whole)."""
    with open(path, "rb") as fh:
        data = fh.read(limit_bytes + 1)
    if len(data) > limit_bytes:
        raise ValueError(f"larger than {limit_bytes >> 20} MiB: not a settings file")
    return data.decode("utf-8")
