r"""The rig's line protocol ``PHOID-RIG 1``: encoding and parsing, pure functions.

Every message is one line of printable ASCII ending in LF::

    <payload> *<crc>\n

``crc`` is the CRC-32 (IEEE 802.3, :func:`zlib.crc32`) of the payload's bytes, as 8 lower-case
hex digits, so a corrupted or truncated line is detected. The payload is words separated by
single spaces; numbers are written in the shortest form that reads back to the same double
(``repr``). docs/rig-protocol.md is the contract; this module implements it.

Messages (host → rig): ``PHOID-RIG 1`` (hello), ``FRAMING cobs`` (binary frames from then on,
when the rig answers ``OK``: :mod:`phoid.rig.frames`), ``CONFIG key=value …``, ``START``,
``ABORT reason``, ``CLEAR``, ``BYE``. (rig → host): ``PHOID-RIG 1`` (hello), ``OK``,
``SAMPLE index t x u state [force]``, ``EVENT index name value``, ``END reason``, ``ERROR message``.
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Mapping
from dataclasses import dataclass

from phoid.errors import PhoidError

__all__ = [
    "CONFIG_FIELDS",
    "MAX_LINE",
    "VERSION",
    "Message",
    "ProtocolError",
    "check_hello",
    "encode",
    "encode_config",
    "hello",
    "parse",
    "parse_config",
    "text_field",
]

VERSION = 1
HELLO = "PHOID-RIG"
MAX_LINE = 4096  # bytes, LF included: a longer line is an error

# CONFIG's fields: the C controller's phoid_config (phoid_ctrl.h); True marks whole numbers
CONFIG_FIELDS: dict[str, bool] = {
    "sample_time": False, "P": False, "D": False, "gain": False, "command_gain": False,
    "velocity": True, "filter_pole": False, "delay_samples": True, "hold_P": False,
    "hold_D": False, "x_start": False, "hold_samples": True, "run_samples": True,
    "x_min": False, "x_max": False, "u_max": False, "growth_limit": False,
    "stall_samples": True, "stall_epsilon": False, "has_force": True,
}
STATES = ("idle", "hold", "run", "done", "fault")

# the decimal numbers the protocol allows (no `_` separators, no hex, no words like `inf`)
_INT = re.compile(r"[+-]?[0-9]+")
_CRC = re.compile(rb"[0-9a-f]{8}")  # lower case only (the docs: exactly 8 lower-case hex digits)
_VERSION = re.compile(r"0|[1-9][0-9]*")  # a version number, without leading zeros
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")

# each kind: the names of its fields and their types ("i" whole number, "f" finite number,
# "w" a word, "r" the rest of the line, free text)
_KINDS: dict[str, tuple[tuple[str, str], ...]] = {
    "OK": (),
    "START": (),
    "FRAMING": (("name", "w"),),
    "CLEAR": (),
    "BYE": (),
    "ABORT": (("reason", "f"),),
    "SAMPLE": (("index", "i"), ("t", "f"), ("x", "f"), ("u", "f"), ("state", "w"),
               ("force", "f")),
    "EVENT": (("index", "i"), ("name", "w"), ("value", "f")),
    "END": (("reason", "w"),),
    "ERROR": (("message", "r"),),
}
# trailing fields a line may leave out (SAMPLE's measured force: a rig without a force sensor)
_OPTIONAL: dict[str, int] = {"SAMPLE": 1}


class ProtocolError(PhoidError):
    """A line that breaks the protocol (checksum, syntax, field, version): one line of text."""


@dataclass(frozen=True)
class Message:
    """One parsed line.

    Attributes
    ----------
    kind : str
        ``"HELLO"``, ``"CONFIG"``, ``"FRAMING"``, ``"OK"``, ``"START"``, ``"ABORT"``,
        ``"CLEAR"``, ``"BYE"``, ``"SAMPLE"``, ``"EVENT"``, ``"END"`` or ``"ERROR"``.
    fields : dict
        The fields by name (SAMPLE: ``index`` int, ``t`` s, ``x`` m, ``u`` command units,
        ``state``, and ``force`` N only when the line carries the measured force; EVENT:
        ``index``, ``name``, ``value``; END: ``reason``; ERROR: ``message``;
        ABORT: ``reason``; FRAMING: ``name``; HELLO: ``version``; CONFIG: the
        configuration's fields).
    """

    kind: str
    fields: dict[str, object]


def _num(value: float | int) -> str:
    if isinstance(value, bool):
        raise ProtocolError(f"a number is expected; got {value!r}")
    if isinstance(value, int):
        return str(value)
    v = float(value)
    if not math.isfinite(v):
        raise ProtocolError(f"numbers must be finite; got {v!r}")
    return repr(v)


def _count(kind: str, spec: tuple[tuple[str, str], ...]) -> str:
    opt = _OPTIONAL.get(kind, 0)
    return f"{len(spec) - opt} or {len(spec)}" if opt else str(len(spec))


def _frame(payload: str) -> bytes:
    if not payload.isascii() or not payload.isprintable() or "*" in payload:
        raise ProtocolError(f"a line must be printable ASCII without '*': {payload[:60]!r}")
    data = payload.encode("ascii")
    line = data + b" *" + f"{zlib.crc32(data):08x}".encode() + b"\n"
    if len(line) > MAX_LINE:
        raise ProtocolError(f"a line is longer than {MAX_LINE} bytes")
    return line


def hello(version: int = VERSION) -> bytes:
    """The hello line ``PHOID-RIG <version>`` both sides send first."""
    return _frame(f"{HELLO} {int(version)}")


def encode(kind: str, *values: object) -> bytes:
    """One line of ``kind`` (not HELLO or CONFIG) with its fields in order.

    ``encode("SAMPLE", 12, 0.024, 0.0031, -1.5, "run")`` →
    ``b"SAMPLE 12 0.024 0.0031 -1.5 run *xxxxxxxx\\n"``; a trailing optional field (SAMPLE's
    ``force``) is written when given.
    """
    spec = _KINDS.get(kind)
    if spec is None:
        raise ProtocolError(f"unknown message kind {kind!r}")
    least = len(spec) - _OPTIONAL.get(kind, 0)
    if not least <= len(values) <= len(spec):
        raise ProtocolError(f"{kind} takes {_count(kind, spec)} fields "
                            f"({', '.join(n for n, _ in spec) or 'none'}); got {len(values)}")
    spec = spec[:len(values)]
    words = [kind]
    for (name, typ), val in zip(spec, values, strict=True):
        if typ == "i":
            if isinstance(val, bool) or not isinstance(val, int):
                raise ProtocolError(f"{kind} field `{name}` must be a whole number; got {val!r}")
            words.append(str(val))
        elif typ == "f":
            try:
                words.append(_num(float(val)))  # type: ignore[arg-type]
            except (TypeError, ValueError, ProtocolError):
                raise ProtocolError(f"{kind} field `{name}` must be a finite number; "
                                    f"got {val!r}") from None
        elif typ == "w":
            text = str(val)
            if not text or any(ch.isspace() for ch in text):
                raise ProtocolError(f"{kind} field `{name}` must be one word; got {text!r}")
            words.append(text)
        else:
            words.append(text_field(str(val)))
    payload = " ".join(words)
    if spec and spec[-1][1] == "r":  # free text: cut to fit the line (docs: at most MAX_LINE)
        room = MAX_LINE - len(" *xxxxxxxx\n")
        if len(payload) > room:
            payload = payload[:room - 3].rstrip() + "..."
    return _frame(payload)


def text_field(text: str) -> str:
    """Free text made sendable: one line of printable ASCII without ``*`` (never raises).

    Whitespace runs become one space; any other character the protocol forbids (``*``,
    control characters, non-ASCII) is written as its Python escape (``\\x2a`` for ``*``),
    so an error message that quotes a hostile line can always be sent. Empty text is ``-``.
    """
    out = []
    for ch in " ".join(text.split()):
        if ch == "*" or not (ch.isascii() and ch.isprintable()):
            code = ord(ch)
            out.append(f"\\x{code:02x}" if code < 0x100 else
                       f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")
        else:
            out.append(ch)
    return "".join(out) or "-"


def encode_config(config: Mapping[str, object]) -> bytes:
    """The ``CONFIG key=value …`` line of a configuration (fields of :data:`CONFIG_FIELDS`)."""
    words = ["CONFIG"]
    for key, val in config.items():
        whole = CONFIG_FIELDS.get(key)
        if whole is None:
            raise ProtocolError(f"CONFIG: unknown field `{key}`; the fields are "
                                f"{', '.join(CONFIG_FIELDS)}")
        if whole and (isinstance(val, bool) or not isinstance(val, int)):
            raise ProtocolError(f"CONFIG field `{key}` must be a whole number; got {val!r}")
        try:
            words.append(f"{key}={_num(val)}")  # type: ignore[arg-type]
        except (TypeError, ValueError, ProtocolError):
            raise ProtocolError(f"CONFIG field `{key}` must be a finite number; "
                                f"got {val!r}") from None
    return _frame(" ".join(words))


def _unframe(line: bytes | str) -> str:
    try:
        raw = line.encode("latin-1") if isinstance(line, str) else bytes(line)
    except UnicodeEncodeError:
        raise ProtocolError(f"line is not ASCII: {line[:60]!a}") from None
    shown = ascii(raw[:60].decode("latin-1"))  # quoted, ASCII: the rig can send it back
    if len(raw) > MAX_LINE:
        raise ProtocolError(f"line longer than {MAX_LINE} bytes: {shown}...")
    if not raw.endswith(b"\n"):
        raise ProtocolError(f"truncated line (no end of line): {shown}")
    body = raw[:-1].rstrip(b"\r")
    payload, sep, crc = body.rpartition(b" *")
    if not sep or len(crc) != 8:
        raise ProtocolError("line without its checksum (a space, an asterisk and 8 hex digits "
                            f"at its end; truncated?): {shown}")
    if not _CRC.fullmatch(crc):
        raise ProtocolError(f"checksum is not 8 lower-case hex digits: {shown}")
    want = int(crc, 16)
    if zlib.crc32(payload) != want:
        raise ProtocolError(f"checksum mismatch (a corrupted line): {shown}")
    try:
        text = payload.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"line is not ASCII: {shown}") from None
    if not text.isprintable():
        raise ProtocolError(f"line holds control characters: {shown}")
    return text


def _field(kind: str, name: str, typ: str, word: str) -> object:
    if typ == "w":
        return word
    what = "a whole number" if typ == "i" else "a number"
    if not (_INT if typ == "i" else _FLOAT).fullmatch(word):
        if typ == "f" and word.lower().lstrip("+-") in ("inf", "infinity", "nan"):
            raise ProtocolError(f"{kind} field `{name}` must be finite; got {word!r}")
        raise ProtocolError(f"{kind} field `{name}` must be {what} (decimal); got {word!r}")
    try:
        if typ == "i":
            return int(word)
        val = float(word)
    except ValueError:  # more digits than int() converts
        raise ProtocolError(f"{kind} field `{name}` must be {what}; got {word!r}") from None
    if not math.isfinite(val):
        raise ProtocolError(f"{kind} field `{name}` must be finite; got {word!r}")
    return val


def parse(line: bytes | str) -> Message:
    """Check a line's checksum and parse it.

    Raises
    ------
    ProtocolError
        One line naming what is wrong: a truncated line, a checksum mismatch, an unknown kind,
        a missing or extra field, a field that is not what it must be (named).
    """
    text = _unframe(line)
    words = text.split(" ")
    kind = words[0]
    if kind == HELLO:
        if len(words) != 2 or not _VERSION.fullmatch(words[1]):
            raise ProtocolError(f"hello must be '{HELLO} <version>' (a whole number without "
                                f"leading zeros); got {text!r}")
        return Message("HELLO", {"version": int(words[1])})
    if kind == "CONFIG":
        return Message("CONFIG", parse_config(words[1:]))
    spec = _KINDS.get(kind)
    if spec is None:
        raise ProtocolError(f"unknown message {kind!r}")
    if spec and spec[-1][1] == "r":
        return Message(kind, {spec[-1][0]: " ".join(words[1:])})
    least = len(spec) - _OPTIONAL.get(kind, 0)
    if not least <= len(words) - 1 <= len(spec):
        raise ProtocolError(f"{kind} has {_count(kind, spec)} fields "
                            f"({', '.join(n for n, _ in spec) or 'none'}); got {len(words) - 1}")
    spec = spec[:len(words) - 1]
    fields = {name: _field(kind, name, typ, word)
              for (name, typ), word in zip(spec, words[1:], strict=True)}
    if kind == "SAMPLE" and fields["state"] not in STATES:
        raise ProtocolError(f"SAMPLE field `state` must be one of {', '.join(STATES)}; "
                            f"got {fields['state']!r}")
    if "index" in fields and int(fields["index"]) < 0:  # type: ignore[call-overload]
        raise ProtocolError(f"{kind} field `index` must be ≥ 0; got {fields['index']}")
    return Message(kind, fields)


def parse_config(words: list[str]) -> dict[str, object]:
    """The fields of ``CONFIG key=value …`` (the words after CONFIG)."""
    out: dict[str, object] = {}
    for word in words:
        key, sep, val = word.partition("=")
        if not sep:
            raise ProtocolError(f"CONFIG: expected key=value; got {word!r}")
        whole = CONFIG_FIELDS.get(key)
        if whole is None:
            raise ProtocolError(f"CONFIG: unknown field `{key}`")
        if key in out:
            raise ProtocolError(f"CONFIG: field `{key}` given twice")
        out[key] = _field("CONFIG", key, "i" if whole else "f", val)
    return out


def check_hello(msg: Message, who: str) -> None:
    """Refuse a first message that is not ``PHOID-RIG 1``, naming ``who`` sent it."""
    if msg.kind == "ERROR":
        raise ProtocolError(f"{who} refused the connection: {msg.fields['message']}")
    if msg.kind != "HELLO":
        raise ProtocolError(f"{who} did not say hello ('{HELLO} {VERSION}'); it sent {msg.kind}")
    if msg.fields["version"] != VERSION:
        raise ProtocolError(f"{who} speaks protocol version {msg.fields['version']}; this phoid "
                            f"speaks {HELLO} {VERSION} only")
