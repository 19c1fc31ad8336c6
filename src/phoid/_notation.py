"""One notation and one width for phoid's text output, and its ASCII spelling where a stream
cannot show it.

σ is a decay rate (1/s), ω₀ and ω_d angular frequencies, ζ a damping ratio, and a standard
error is written "stderr" or "±" (never σ). Where the stream's encoding cannot write them
(``PYTHONIOENCODING=ascii``, a Latin-1 terminal), :func:`stream_text` spells them out:
``omega0``, ``zeta``, ``+/-``, ``chi2``; inside :func:`stream_notation` the text reports lay out
their tables in that spelling already, so that the columns stay aligned. No line of a report
is wider than :data:`WIDTH` columns: the tables are laid out to fit
(:func:`phoid.reports.text.text_table`) and :func:`fit_width` wraps the prose.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from typing import TextIO

__all__ = ["WIDTH", "ascii_text", "fit_width", "notation", "stream_notation", "stream_text",
           "unit_text"]

#: The widest line phoid prints in a report (a terminal's 100 columns).
WIDTH = 100

# the notation's unicode and its ASCII spelling, longest first (ω₀ before ω)
_ASCII = (
    ("Δχ²", "delta chi2"), ("χ²", "chi2"), ("ω₀", "omega0"), ("ω_d", "omega_d"),
    ("ω", "omega"), ("σ̂", "sigma_hat"), ("σ", "sigma"), ("ζ", "zeta"), ("ρ", "rho"),
    ("ŷ", "y_hat"), ("Δ", "delta "), ("±", "+/-"), ("′", "'"), ("²", "^2"), ("³", "^3"),
    ("≥", ">="), ("≤", "<="), ("≈", "~"), ("≠", "!="), ("−", "-"), ("–", "-"), ("—", "--"),
    ("…", "..."), ("×", "x"), ("·", "*"), ("‖", "||"), ("√", "sqrt"), ("→", "->"),
    ("₀", "0"), ("₁", "1"), ("₂", "2"), ("ᵢ", "_i"), ("µ", "u"), ("μ", "u"), ("°", " deg"),
    ("⚠", "!"),
)
# a power in a unit as phoid's SI strings write it (1/s^2, kg m^2, rad/s^2) and its superscript
_POWERS = {"2": "²", "3": "³"}
_ASCII_NOTATION: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "phoid_ascii_notation", default=False)


def ascii_text(text: str) -> str:
    """``text`` in ASCII: phoid's notation spelt out (ω₀ → omega0, ζ → zeta, ± → +/-,
    χ² → chi2, …), a letter with an accent without it (é → e), any other non-ASCII character
    as ``?``.

    Parameters
    ----------
    text : str

    Returns
    -------
    str

    Examples
    --------
    >>> ascii_text("ω₀ = 5.6567 ± 0.0002 rad/s,  ζ = 0.0442")
    'omega0 = 5.6567 +/- 0.0002 rad/s,  zeta = 0.0442'
    """
    import unicodedata

    for uni, asc in _ASCII:
        text = text.replace(uni, asc)
    if not text.isascii():  # a letter with an accent without it (Cramér → Cramer)
        text = "".join(c for c in unicodedata.normalize("NFKD", text)
                       if not unicodedata.combining(c))
    return text.encode("ascii", "replace").decode("ascii")


def unit_text(unit: str) -> str:
    """A unit in phoid's notation: its powers as superscripts (``1/s^2`` → ``1/s²``,
    ``kg m^2`` → ``kg m²``), as the text reports print it; :func:`ascii_text` spells them
    back (``1/s^2``) for a stream that cannot show them. The JSON keeps the ASCII unit
    strings.

    Parameters
    ----------
    unit : str

    Returns
    -------
    str

    Examples
    --------
    >>> unit_text("1/s^2"), unit_text("kg m^2"), unit_text("N s/m")
    ('1/s²', 'kg m²', 'N s/m')
    """
    import re

    return re.sub(r"\^([23])(?![0-9])", lambda m: _POWERS[m.group(1)], str(unit))


def _encodes(stream: TextIO | None, text: str) -> bool:
    """Whether ``stream``'s encoding (UTF-8 where it names none) can write ``text``."""
    encoding = getattr(stream, "encoding", None) or "utf-8"
    try:
        text.encode(encoding)
    except (UnicodeEncodeError, LookupError):
        return False
    return True


def stream_text(text: str, stream: TextIO | None = None) -> str:
    """``text`` as ``stream`` can show it: unchanged where its encoding writes it (UTF-8),
    else in ASCII (:func:`ascii_text`: ``PYTHONIOENCODING=ascii``, a Latin-1 terminal).

    The one place where phoid's output falls back to ASCII; the command line passes every
    report, warning and error through it.

    Parameters
    ----------
    text : str
    stream : text stream, optional
        Default: standard output.

    Returns
    -------
    str
    """
    import sys

    stream = sys.stdout if stream is None else stream
    return text if _encodes(stream, text) else ascii_text(text)


@contextlib.contextmanager
def stream_notation(stream: TextIO | None = None) -> Iterator[None]:
    """Within it, the text reports write their tables in ASCII when ``stream`` cannot show
    phoid's notation (so that columns stay aligned once :func:`stream_text` spells it out).

    Parameters
    ----------
    stream : text stream, optional
        Default: standard output.
    """
    import sys

    stream = sys.stdout if stream is None else stream
    token = _ASCII_NOTATION.set(not _encodes(stream, "σω₀ζ±χ²′"))
    try:
        yield
    finally:
        _ASCII_NOTATION.reset(token)


def notation(text: str) -> str:
    """``text`` in the notation of the report being written: unicode, or ASCII inside
    :func:`stream_notation` for a stream that cannot show it."""
    return ascii_text(text) if _ASCII_NOTATION.get() else text


def fit_width(text: str, width: int = WIDTH) -> str:
    """``text`` with every line wider than ``width`` wrapped at spaces: the continuation
    indented two more than the line (a ``- `` item's under its text). A word longer than the
    width (a path) is kept whole, never cut.

    The one width-fitting function of phoid's text: every ``report()`` and every command's
    text output passes through it (tables are laid out to fit before, so that it only wraps
    prose). The text is first put in the report's :func:`notation` (ASCII inside
    :func:`stream_notation` for a stream that cannot show it), so that it is wrapped where
    the lines are as printed (``≤`` spelled ``<=`` is a column wider).

    Parameters
    ----------
    text : str
    width : int

    Returns
    -------
    str

    Examples
    --------
    >>> print(fit_width("warnings:\\n  - " + "word " * 6, 20))
    warnings:
      - word word word
        word word word
    """
    import textwrap

    out: list[str] = []
    for line in notation(text).split("\n"):
        if len(line) <= width:
            out.append(line)
            continue
        body = line.lstrip(" ")
        indent = " " * (len(line) - len(body))
        more = indent + "  "
        out.extend(textwrap.wrap(body, width, initial_indent=indent, subsequent_indent=more,
                                 break_long_words=False, break_on_hyphens=False)
                   or [line])
    return "\n".join(out)
