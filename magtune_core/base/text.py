"""Text from outside the process, made safe to log: one bounded line.

A string a peer sends (a ``set_mode`` reason, a lifecycle transition label) goes into log lines and
recorded messages. Left as sent, a newline forges a log line, an ANSI escape (``\\x1b[31m``) recolours
or erases the terminal, a bidirectional override (U+202E) reorders what a reader sees, and a 2 MB
string fills the log. :func:`printable` is the one place that turns such a string into one line of
bounded length.
"""
from __future__ import annotations

#: Default largest number of characters :func:`printable` keeps (before its truncation marker).
LIMIT = 200


def printable(s, limit: int = LIMIT) -> str:
    """One printable line of at most ``limit`` characters (plus a marker) from a string sent by a peer.

    Every character that :meth:`str.isprintable` rejects (control characters such as ``\\n``, ``\\r``,
    ``\\t`` and ``\\x1b``, format characters such as the bidirectional overrides, the line and paragraph
    separators, unassigned code points) is replaced by its Python escape (``\\n`` becomes the two
    characters backslash and n; ``\\x1b`` becomes ``\\x1b`` spelled out), so the line shows what was sent
    and cannot start a new line or drive the terminal. Past ``limit`` characters (counted after
    escaping) the rest is cut and ``...[N more characters]`` appended, N counted in the input; only
    about ``limit`` characters of the input are read, whatever its length.

    Parameters
    ----------
    s : str or object
        The text; another object is logged as ``str(s)``.
    limit : int
        Largest number of characters kept before the marker (at least 1).

    Returns
    -------
    str
        The escaped, truncated text: printable characters only, no line break; ``""`` for ``""``.

    Raises
    ------
    ValueError
        If ``limit`` is not a positive integer.
    """
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
        raise ValueError(f"limit must be a positive integer, got {limit!r}")
    text = s if isinstance(s, str) else str(s)
    out: list[str] = []
    n = 0
    for i, ch in enumerate(text):
        piece = ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii")
        if n + len(piece) > limit:
            return "".join(out) + f"...[{len(text) - i} more characters]"
        out.append(piece)
        n += len(piece)
    return "".join(out)
