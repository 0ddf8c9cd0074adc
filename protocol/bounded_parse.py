"""Parsing a structured setting (a scenario, a setting group, an FMU mapping,
a fault scenario, a sweep spec) within bounds: its size, how deep its lists
and mappings nest, and how many values it holds (a YAML alias counts each
time it is used, so a "billion laughs" document is refused, not expanded).

The depth is checked on the text before the parser sees it (an unclosed run
of 90,000 ``[`` would otherwise end in a ``RecursionError`` of the parser),
then on the parsed value. Every excess is one :class:`TooLarge` line naming
the setting and the limit.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["MAX_DEPTH", "MAX_TEXT_BYTES", "MAX_VALUES", "TooLarge", "check_nesting", "check_value", "load_json", "load_yaml"]

MAX_DEPTH = 32
"""The deepest nesting of lists and mappings a setting may have (a scenario or mapping needs 4)."""
MAX_TEXT_BYTES = 1024 * 1024
"""The longest structured setting's text (the longest in the project's examples: a few kB)."""
MAX_VALUES = 200_000
"""The most values (list items, mapping entries, scalars) a parsed setting may hold."""


class TooLarge(ValueError):
    """A structured setting past a size, depth or value-count limit (one line)."""


def check_nesting(text: str, what: str, max_depth: int = MAX_DEPTH) -> None:
    """Refuse ``text`` whose brackets (``[``/``{``, outside quoted strings) nest deeper than ``max_depth``."""
    depth = 0
    quote = ""
    escaped = False
    for ch in text:
        if quote:
            if escaped:
                escaped = False
            elif ch == "\\" and quote == '"':
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "[{":
            depth += 1
            if depth > max_depth:
                raise TooLarge(f"{what} nests lists or mappings deeper than {max_depth} levels")
        elif ch in "]}":
            depth = max(0, depth - 1)
        elif ch == '"':
            quote = ch
    return None


def check_value(value: Any, what: str, max_depth: int = MAX_DEPTH, max_values: int = MAX_VALUES) -> Any:
    """``value`` if it nests at most ``max_depth`` deep and holds at most ``max_values`` values (shared ones counted at each use)."""
    count = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        count += 1
        if count > max_values:
            raise TooLarge(f"{what} holds more than {max_values} values")
        if isinstance(item, dict | list | tuple):
            if depth > max_depth:
                raise TooLarge(f"{what} nests lists or mappings deeper than {max_depth} levels")
            children = list(item.keys()) + list(item.values()) if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children)
    return value


def _size(text: str, what: str, max_bytes: int) -> None:
    if len(text) > max_bytes:
        raise TooLarge(f"{what} is {len(text)} characters long, more than the {max_bytes} a setting may have")


def load_json(text: str, what: str, max_bytes: int = MAX_TEXT_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(text)`` within the limits; a :class:`TooLarge` line past them (``json.JSONDecodeError`` as ``json`` raises it)."""
    _size(text, what, max_bytes)
    check_nesting(text, what, max_depth)
    try:
        data = json.loads(text)
    except RecursionError:
        raise TooLarge(f"{what} nests too deep to parse") from None
    return check_value(data, what, max_depth)


def load_yaml(text: str, what: str, max_bytes: int = MAX_TEXT_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """``yaml.safe_load(text)`` within the limits (flow and block nesting, aliases counted at each use); ``yaml.YAMLError`` as PyYAML raises it."""
    import yaml

    _size(text, what, max_bytes)
    check_nesting(text, what, max_depth)
    try:
        data = yaml.safe_load(text)
    except RecursionError:
        raise TooLarge(f"{what} nests too deep to parse") from None
    return check_value(data, what, max_depth)
