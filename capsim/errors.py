"""One-line error texts (numba-, numpy- and pydantic-free, so any module may import it).

Every user-facing failure in capsim is reported as one line: :func:`first_line`
is the one place that turns an exception into that line, and :func:`bounded_repr`
shows a value without ever building the repr of a huge one (an expanded YAML
alias, a 10⁶-character string).
"""

from __future__ import annotations

import reprlib
from typing import Any

__all__ = ["first_line", "bounded_repr", "SHOWN_CHARS"]

#: the most characters of a value an error message shows
SHOWN_CHARS = 60

_repr = reprlib.Repr()
_repr.maxlevel = 3
_repr.maxdict = _repr.maxlist = _repr.maxtuple = _repr.maxset = _repr.maxfrozenset = 6
_repr.maxdeque = _repr.maxarray = 6
_repr.maxstring = SHOWN_CHARS
_repr.maxlong = 40
_repr.maxother = SHOWN_CHARS


def first_line(exc: BaseException, default: str | None = None) -> str:
    """The first line of ``str(exc)``; ``default`` (else the exception's type name) when empty.

    Only the first 4000 characters of a message are looked at, so a message
    holding a huge value costs nothing more.
    """
    text = str(exc)[:4000].lstrip()
    if not text:
        return type(exc).__name__ if default is None else default
    return text.splitlines()[0].rstrip()


def bounded_repr(value: Any, limit: int = SHOWN_CHARS) -> str:
    """repr(value) cut to at most ``limit`` characters, built in bounded time and memory."""
    try:
        text = _repr.repr(value)
    except Exception:  # a hostile __repr__: name the type only
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."
