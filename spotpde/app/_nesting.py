"""How deep a case may nest, checked before it is parsed or walked (private; users:
:mod:`.cases` and :mod:`._schema`).

A case nests tables and lists at most three deep (``orifice.rate.times[0]``: the table
``orifice``, the inline table ``rate``, the list ``times``); :data:`MAX_NESTING` allows
more than twice that and refuses anything deeper, by name, in time proportional to the
input:

* :func:`text_problem` scans TOML text before :mod:`tomllib` reads it. tomllib parses
  nested arrays and inline tables recursively (100,000 nested ``[`` end in a
  ``RecursionError``) and dotted keys in time quadratic in their number of parts (a
  key of 20,000 parts takes 12 s, 2,000 table headers each one part deeper 15 s), so
  such text is refused before it reaches the parser.
* :func:`plain` walks a parsed or given mapping (numpy values to plain Python ones)
  to at most :data:`MAX_NESTING` levels, so a deeply nested or self-containing
  mapping is refused instead of overflowing the stack.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import CaseError

#: The deepest nesting of tables and lists a case may have: a value inside at most this
#: many tables and lists (the top-level table counts, the document does not). A case
#: needs 3 (docs/cases.md, Validation).
MAX_NESTING = 8

#: TOML tokens: strings and comments whole (their brackets and dots are not structure),
#: then brackets, dots, runs of bare-key or value characters, and anything else.
_TOKENS = re.compile(r'''
      (?P<string> """(?:[^"\\]|\\.|"(?!""))*"""(?:""?)?
                | \'\'\'(?:[^']|'(?!''))*\'\'\'(?:''?)?
                | "(?:[^"\\\n]|\\.)*"
                | '[^'\n]*' )
    | (?P<comment> \#[^\n]* )
    | (?P<open> [\[{] )
    | (?P<close> [\]}] )
    | (?P<dot> \. )
    | (?P<space> [ \t]+ )
    | (?P<bare> [A-Za-z0-9_+:-]+ )
    | (?P<other> . )
''', re.VERBOSE | re.DOTALL)

_ADVICE = f"(at most {MAX_NESTING} in a case, docs/cases.md)"


def text_problem(text: str) -> str | None:
    """The first place where TOML ``text`` nests deeper than :data:`MAX_NESTING`, as
    ``"line N: ..."``, or ``None``.

    Counts open brackets and braces (arrays, inline tables, table headers) and the parts
    of each dotted key (``a.b.c``: 3), outside strings and comments. A number has at most
    one dot, so only keys reach the limit. Stops at the first excess: the work is at most
    proportional to the length of ``text``.
    """
    depth = 0
    dots = 0          # dots in the current chain ``part . part . part`` (a key)
    chain = 0         # where that chain starts
    for m in _TOKENS.finditer(text):
        kind = m.lastgroup
        if kind == "space":
            continue
        if kind in ("bare", "string"):
            if dots == 0:
                chain = m.start()
            continue
        if kind == "dot":
            dots += 1
            if dots >= MAX_NESTING:
                line = text.count("\n", 0, m.start()) + 1
                shown = text[chain:m.start()][:40]
                return (f"line {line}: the dotted key starting {shown!r} has more than "
                        f"{MAX_NESTING} parts {_ADVICE}")
            continue
        dots = 0
        if kind == "open":
            depth += 1
            if depth > MAX_NESTING:
                line = text.count("\n", 0, m.start()) + 1
                return f"line {line}: more than {MAX_NESTING} nested arrays or tables {_ADVICE}"
        elif kind == "close":
            depth = max(depth - 1, 0)
    return None


def _name(path: tuple) -> str:
    """A path of keys (str) and list indexes (int) as a dotted name, at most 80
    characters."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out if len(out) <= 80 else out[:77] + "..."


def plain(value: Any, _path: tuple = ()) -> Any:
    """A case mapping from Python code with plain TOML types: numpy scalars become
    ``int``/``float``/``bool``, numpy arrays and tuples lists, paths strings (so that
    ``{"domain": {"dims": np.int64(2), "x": np.array([-4.0, 4.0])}}`` and
    ``{"output": {"path": pathlib.Path("r.nc")}}`` are accepted).

    Raises:
        spotpde.CaseError: a table or list nested more than :data:`MAX_NESTING` deep
            (also a mapping that contains itself), naming its dotted key.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (Mapping, list, tuple)) and len(_path) > MAX_NESTING:
        raise CaseError(f"{_name(_path)}: more than {MAX_NESTING} nested tables or lists "
                        f"{_ADVICE}")
    if isinstance(value, Mapping):
        return {k: plain(v, _path + (k,)) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v, _path + (i,)) for i, v in enumerate(value)]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value
