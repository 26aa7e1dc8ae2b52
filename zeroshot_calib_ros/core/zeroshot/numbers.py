"""Numbers as a user types them, on a command line or in a CSV cell: ASCII decimal notation only
(Python's float() also takes '1_18', Arabic-Indic or fullwidth digits and surrounding spaces;
those are refused). nan / inf pass: the spec checks name each field's allowed range."""
from __future__ import annotations

import math
import re

_DECIMAL = re.compile(r'[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?\Z')
_NON_FINITE = re.compile(r'[-+]?(?:inf|infinity|nan)\Z', re.IGNORECASE)
_INTEGER = re.compile(r'[-+]?[0-9]+\Z')


def is_number(text: str) -> bool:
    """Whether ``text`` is a number parse_number takes."""
    return bool(_DECIMAL.match(text) or _NON_FINITE.match(text))


def parse_number(text: str) -> float:
    """A float in ASCII decimal notation (or nan / inf); ValueError otherwise."""
    if not is_number(text):
        raise ValueError(f'not an ASCII decimal number: {text!r}')
    return float(text)


def parse_whole_number(text: str):
    """An image side: an integer, or an integral float such as 1920.0 as an int (1920.5 stays a
    float, which CameraSpec refuses naming the field and the range)."""
    if _INTEGER.match(text):
        return int(text)
    value = parse_number(text)
    return int(value) if math.isfinite(value) and value == int(value) else value


def parse_integer(text: str) -> int:
    """An integer, ASCII digits only; ValueError otherwise."""
    if not _INTEGER.match(text):
        raise ValueError(f'not an ASCII integer: {text!r}')
    return int(text)
