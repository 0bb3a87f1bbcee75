r"""Values written into Hydra override lines (``key=value``): :func:`quote_override_value`, the one
quoting function of the project's commands (the ORP sweeper's jobs, ``python -m imls_lightning.bench``
and the non-ASCII values of every command line, :func:`imls_lightning.base.errors.quote_non_ascii`).

Hydra's override grammar reads a bare word as a number, a boolean or ``null`` where it can, stops
at its own syntax (``=``, ``,``, brackets, quotes, spaces) and takes non-ASCII characters only
inside quotes. Inside single quotes it reads a backslash literally, unless a run of backslashes
precedes a quote: that run is halved (``\\'`` is one backslash, then the closing quote).
"""
from __future__ import annotations

import re
from typing import Any, Mapping

# a string written bare reads back as itself unless it reads as a number, a boolean or null
_BARE = re.compile(r"[A-Za-z0-9_./+\-]+")
_NOT_STRINGS = {"true", "false", "null", "inf", "+inf", "-inf", "nan", "+nan", "-nan"}


def _reads_as_string(text: str) -> bool:
    """Whether Hydra reads ``text``, written bare, as that string (conservative: anything
    Python reads as a float, with or without ``_``, is taken for a number)."""
    if not _BARE.fullmatch(text) or text.lower() in _NOT_STRINGS:
        return False
    try:
        float(text.replace("_", ""))
    except ValueError:
        return True
    return False


def quote_override_value(value: Any) -> str:
    r"""``value`` written so that Hydra's override grammar reads it back unchanged.

    A string is written bare where that reads back as the same string (``/runs/a.ckpt``), else
    single-quoted: each run of backslashes that precedes a quote or the end doubled, each ``'``
    escaped. Lists and dicts recursively, ``None`` as ``null``, numbers and booleans as such.

    Example:
        >>> quote_override_value({"a": [1, "x=y"], "b": None, "c": True})
        "{a:[1,'x=y'],b:null,c:true}"
        >>> print(quote_override_value("/runs/a.ckpt"), quote_override_value("1e5"), quote_override_value("C:\\it's\\"))
        /runs/a.ckpt '1e5' 'C:\it\'s\\'
    """
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, Mapping):
        return "{" + ",".join(f"{k}:{quote_override_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(quote_override_value(v) for v in value) + "]"
    text = str(value)
    if _reads_as_string(text):
        return text
    text = re.sub(r"(\\+)(?='|$)", lambda m: m.group(1) * 2, text)
    return "'" + text.replace("'", "\\'") + "'"
