"""``base.text.printable``: a peer's string as one bounded, printable log line (issue 45: a ``set_mode``
reason with a newline and ANSI escapes forged a log line; a 2 MB reason was logged whole)."""
from __future__ import annotations

import time

import pytest

from magtune_core.base.text import LIMIT, printable


def test_plain_text_is_unchanged():
    assert printable("operator: hold SAFE for the eclipse") == "operator: hold SAFE for the eclipse"
    assert printable("") == "" and printable("π ≈ 3.14, Grüße") == "π ≈ 3.14, Grüße"


def test_line_breaks_and_escape_codes_are_spelled_out():
    """A forged line and a colour code become visible text on the same line."""
    out = printable("\n[ERROR] forged\x1b[31m red\r\x00\t")
    assert out == "\\n[ERROR] forged\\x1b[31m red\\r\\x00\\t"
    assert out.isprintable() and "\n" not in out and "\x1b" not in out


@pytest.mark.parametrize("ch, shown", [("\u2028", "\\u2028"), ("\u2029", "\\u2029"), ("\u202e", "\\u202e"),
                                       ("\x85", "\\x85"), ("\x7f", "\\x7f"), ("\ud800", "\\ud800")])
def test_unicode_line_separators_and_bidi_overrides(ch, shown):
    """What str.splitlines or a terminal treats as a break or a reordering, and a lone surrogate."""
    out = printable(f"a{ch}b")
    assert out == f"a{shown}b" and out.isprintable() and len(out.splitlines()) == 1


def test_long_text_is_cut_with_a_marker_naming_what_was_dropped():
    out = printable("x" * 250)
    assert out == "x" * LIMIT + "...[50 more characters]"
    assert printable("abcdef", limit=3) == "abc...[3 more characters]"
    assert printable("abc", limit=3) == "abc"


def test_an_escape_is_never_cut_in_half():
    """The limit counts escaped characters; an escape that would cross it is left out whole."""
    assert printable("ab\n", limit=3) == "ab...[1 more characters]"
    assert printable("ab\n", limit=4) == "ab\\n"


def test_two_megabytes_are_cut_in_bounded_time():
    """Only about ``limit`` characters are read: a 2 MB string costs what a short one does."""
    big = "\n" * (2 * 1024 * 1024)
    t0 = time.perf_counter()
    out = printable(big)
    assert time.perf_counter() - t0 < 0.05
    assert out == "\\n" * (LIMIT // 2) + f"...[{len(big) - LIMIT // 2} more characters]"
    assert len(out) < LIMIT + 40 and out.isprintable()


def test_non_strings_are_logged_as_str_and_bad_limits_refused():
    assert printable(b"\n") == "b'\\n'" and printable(42) == "42"
    for bad in (0, -1, 2.5, True, None):
        with pytest.raises(ValueError, match="limit must be a positive integer"):
            printable("x", limit=bad)
