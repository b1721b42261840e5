"""Limits on what enters the station: every number finite and in its range, every nested
document shallow enough to walk, before any work is done with it.

One module for every entry (issue 30): the session metadata that `station resume` rebuilds a
bench from, calibration files, session metadata and event details, imported arrays. A refusal is
one line naming the field and the allowed range or type, raised as the caller's `InputError`
subclass (exit code 2). Nothing here recurses: a document nested 100,000 deep is refused from its
text, before a parser that recurses sees it.

    number(value, "virtual_bench.speed", 0.1, 1e4)   -> float, or InputError naming it
    positive(value, "rotary setting static", 3600)     -> float in (0, 3600]
    whole(value, "virtual_bench.seed", 0, 2**32 - 1)   -> int
    choice(value, "virtual_bench.imu", ("serial", "can"))
    json_loads(text, "session metadata")               -> a document within MAX_DEPTH, every
                                                          number finite and in float range
                                                          (`finite` names the first one that is not)

Elsewhere, where the input's own format is read: the sizes of `.npz` arrays from their zip and
.npy headers (`station.imports.npz.headers`); TOML nesting, size and channel count of profiles
(`drivers.profile`: the drivers never import the station).

Sits outside the layers (as `station.errors`): every room may use it.
"""

import json
import math
import re

from station.errors import InputError

MAX_DEPTH = 64
"""Deepest nesting of lists and objects a JSON document may have (session metadata, event
details, calibration files: their deepest is under 10)."""
MAX_FLOAT = 1.7976931348623157e308
"""Largest magnitude of a JSON number: a float64's; an integer beyond it cannot become a float."""
_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')
"""A JSON string (skipped whole: brackets in it do not nest) or a bracket."""


def number(value, field: str, low: float, high: float, error=InputError) -> float:
    """`value` as a float when it is a number (not a bool), finite and in [low, high]; else
    `error` naming `field` and the range."""
    if type(value) not in (int, float) or not _within(value, low, high):
        raise error(f"{field} = {_shown(value)}: give a finite number in [{low:g}, {high:g}]")
    return float(value)


def positive(value, field: str, high: float, error=InputError) -> float:
    """`value` as a float when it is a number (not a bool) in (0, high]; else `error` naming
    `field` (a duration, a tolerance: zero would never end or never pass)."""
    if type(value) not in (int, float) or not _within(value, 0.0, high) or value == 0:
        raise error(f"{field} = {_shown(value)}: must be positive and at most {high:g}")
    return float(value)


def whole(value, field: str, low: int, high: int, error=InputError) -> int:
    """`value` when it is an int (not a bool) in [low, high]; else `error` naming `field`."""
    if type(value) is not int or not low <= value <= high:
        raise error(f"{field} = {_shown(value)}: give a whole number in [{low}, {high}]")
    return value


def choice(value, field: str, choices: tuple, error=InputError):
    """`value` when it is one of `choices` (compared with its type: True is not 1)."""
    if not any(type(value) is type(c) and value == c for c in choices):
        raise error(f"{field} = {_shown(value)}: give one of {', '.join(map(repr, choices))}")
    return value


def _within(value, low: float, high: float) -> bool:
    """True when the int or float `value` is finite and in [low, high] (an int beyond float
    range is compared exactly, never converted)."""
    return (isinstance(value, int) or math.isfinite(value)) and low <= value <= high


def _shown(value) -> str:
    """`value` for a message: its repr, cut to 60 characters (a huge integer or list)."""
    text = repr(value) if not isinstance(value, int) or abs(value) < 10**30 else \
        f"an integer of {len(str(abs(value)))} digits"
    return text if len(text) <= 60 else text[:57] + "..."


def json_depth(text: str | bytes, what: str, limit: int = MAX_DEPTH, error=InputError) -> None:
    """Refuse JSON text nested deeper than `limit` (lists and objects), counted from its text
    without parsing it (no recursion, linear time)."""
    if isinstance(text, bytes | bytearray):
        text = text.decode("utf-8", "replace")
    depth = 0
    for match in _TOKENS.finditer(text):
        token = match.group()
        if token in "[{":
            depth += 1
            if depth > limit:
                raise error(f"{what} is nested more than {limit} deep (lists and objects); "
                            "the file is damaged or not this station's")
        elif token in "]}":
            depth -= 1


def json_loads(text: str | bytes, what: str, limit: int = MAX_DEPTH, error=InputError, **hooks):
    """Parse JSON text that is at most `limit` deep and whose every number is finite and within
    float range (`finite`: `1e999`, `NaN`, `Infinity`, 10**400 refused, naming where); `hooks`
    go to `json.loads` (e.g. object_pairs_hook). `error` for anything that is not valid JSON."""
    json_depth(text, what, limit, error)
    try:
        doc = json.loads(text, parse_constant=float, **hooks)
    except (ValueError, UnicodeDecodeError) as exc:
        if isinstance(exc, error):
            raise
        raise error(f"{what} is not valid JSON ({' '.join(str(exc).split())[:160]})") from None
    finite(doc, what, error)
    return doc


def finite(doc, what: str, error=InputError) -> None:
    """Refuse a parsed document (dicts, lists, numbers, strings) holding a number that is not
    finite or beyond float range, naming its place (e.g. `sensitivity.a[0][2]`). Iterative."""
    stack = [("", doc)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, dict):
            stack.extend((f"{where}.{k}" if where else str(k), v) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((f"{where}[{i}]", v) for i, v in enumerate(value))
        elif type(value) in (int, float) and not _within(value, -MAX_FLOAT, MAX_FLOAT):
            raise error(f"{what}: {where or 'the value'} = {_shown(value)}: give a finite "
                        f"number (|x| <= {MAX_FLOAT:.4g})")
