r"""The rig protocol's binary framing (``FRAMING cobs``): frames and messages, pure functions.

After the text hello a host may send ``FRAMING cobs``; a rig that answers ``OK`` speaks binary
frames from the byte after that line's LF on, both ways (docs/rig-protocol.md, "Binary
framing"). One frame on the wire is::

    COBS(payload ‖ CRC-32(payload), 4 bytes little-endian) 0x00

CRC-32 is :func:`zlib.crc32` (IEEE 802.3, the text lines' checksum). The payload is at most
:data:`MAX_PAYLOAD` bytes, so COBS adds exactly one byte and a frame is at most
:data:`MAX_FRAME` bytes before its delimiter. The payload is one type byte (an ASCII letter)
and the message's fields, little-endian: ``C`` CONFIG, ``S`` START, ``L`` CLEAR, ``B`` BYE,
``A`` ABORT (host → rig); ``K`` OK, ``E`` ERROR, ``X`` SAMPLE, ``V`` EVENT, ``D`` END
(rig → host). The parsers give the text parser's :class:`~phoid.rig.protocol.Message` kinds
and field names, so that both framings feed the same checks; a SAMPLE carries no time (the host
sets t = index·T: the controller's clock is its sample count).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Mapping

from phoid.rig.protocol import CONFIG_FIELDS, STATES, Message, ProtocolError, text_field

__all__ = [
    "CONFIG_DEFAULTS",
    "CONFIG_SIZE",
    "EVENT_CODES",
    "EVENT_NAMES",
    "FLAG_F4",
    "FLAG_FORCE",
    "MAX_FRAME",
    "MAX_PAYLOAD",
    "NO_LIMIT",
    "abort_frame",
    "cobs_decode",
    "cobs_encode",
    "config_frame",
    "decode_frame",
    "encode_frame",
    "end_frame",
    "error_frame",
    "event_frame",
    "message_frame",
    "parse_host_frame",
    "parse_rig_frame",
    "sample_frame",
]

MAX_PAYLOAD = 250  # bytes: payload + CRC ≤ 254, so COBS adds exactly one byte
MAX_FRAME = MAX_PAYLOAD + 4 + 1  # bytes of one encoded frame, its 0x00 delimiter not counted
FLAG_F4 = 0x01  # SAMPLE/EVENT flags bit0: the reals are binary32 (else binary64)
FLAG_FORCE = 0x02  # SAMPLE flags bit1: a measured force follows u
NO_LIMIT = 3.4028234663852886e38  # FLT_MAX: u_max "none" (a float rig holds it exactly)

# enum phoid_event_code (phoid_ctrl.h); 0 is END's "a fault whose event was lost"
EVENT_NAMES: dict[int, str] = {
    1: "start", 2: "release", 3: "done", 4: "clip", 5: "fault-position", 6: "fault-growth",
    7: "fault-stall", 8: "fault-input", 9: "fault-host", 10: "clear", 11: "fault-command",
}
EVENT_CODES: dict[str, int] = {name: code for code, name in EVENT_NAMES.items()}
_END_NAMES = {0: "fault", **{c: n for c, n in EVENT_NAMES.items()
                             if c == 3 or n.startswith("fault-")}}

# CONFIG's fields in wire order with their struct codes (d f8, B u1, H u2, I u4)
_CONFIG_LAYOUT: tuple[tuple[str, str], ...] = (
    ("sample_time", "d"), ("P", "d"), ("D", "d"), ("gain", "d"), ("command_gain", "d"),
    ("velocity", "B"), ("filter_pole", "d"), ("delay_samples", "H"), ("hold_P", "d"),
    ("hold_D", "d"), ("x_start", "d"), ("hold_samples", "I"), ("run_samples", "I"),
    ("x_min", "d"), ("x_max", "d"), ("u_max", "d"), ("growth_limit", "d"),
    ("stall_samples", "I"), ("stall_epsilon", "d"), ("has_force", "B"),
)
_CONFIG = struct.Struct("<" + "".join(code for _, code in _CONFIG_LAYOUT))
CONFIG_SIZE = 1 + _CONFIG.size  # 129 bytes: the type byte and the fields
# the controller's defaults (phoid_config_default) for the fields a host leaves out
CONFIG_DEFAULTS: dict[str, float | int] = {
    "sample_time": 1e-3, "P": 0.0, "D": 0.0, "gain": 1.0, "command_gain": 1.0, "velocity": 0,
    "filter_pole": 0.0, "delay_samples": 0, "hold_P": 0.0, "hold_D": 0.0, "x_start": 0.0,
    "hold_samples": 0, "run_samples": 1, "x_min": -NO_LIMIT, "x_max": NO_LIMIT,
    "u_max": NO_LIMIT, "growth_limit": 0.0, "stall_samples": 0, "stall_epsilon": 0.0,
    "has_force": 0,
}
_MAX_INT = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF}
_HEAD = struct.Struct("<BIBB")  # type, index, state/code, flags
_REALS = {False: "d", True: "f"}
_F8, _F4 = struct.Struct("<d"), struct.Struct("<f")
_END = struct.Struct("<BB")


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: ``data`` without a 0x00 byte (delimiter not added).

    At most one byte in 254 is added (exactly one for 1 to 254 bytes).
    """
    out = bytearray()
    pieces = bytes(data).split(b"\0")
    for j, piece in enumerate(pieces):
        full = False
        while len(piece) >= 0xFE:  # a full block: code 0xFF, no zero after it
            out.append(0xFF)
            out += piece[:0xFE]
            piece = piece[0xFE:]
            full = True
        if full and not piece and j == len(pieces) - 1:
            break  # the data ends with a full block: no code after it (standard COBS)
        out.append(len(piece) + 1)
        out += piece
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Undo :func:`cobs_encode`; a :class:`ProtocolError` in one line for bytes it cannot
    have made (a 0x00 byte, a block running past the end, nothing at all)."""
    data = bytes(data)
    if not data:
        raise ProtocolError("an empty COBS frame")
    if 0 in data:
        raise ProtocolError("a COBS frame holds a 0x00 byte")
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if end > n:
            raise ProtocolError(f"bad COBS: a block of {code - 1} bytes runs past the frame's "
                                f"end (byte {i} of {n})")
        out += data[i + 1:end]
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def _shown(frame: bytes) -> str:
    head = frame[:24].hex()
    return head + ("..." if len(frame) > 24 else "")


def encode_frame(payload: bytes) -> bytes:
    """One frame on the wire: COBS(payload ‖ CRC-32 LE) and its 0x00 delimiter."""
    payload = bytes(payload)
    if not 1 <= len(payload) <= MAX_PAYLOAD:
        raise ProtocolError(f"a frame's payload must be 1 to {MAX_PAYLOAD} bytes; got "
                            f"{len(payload)}")
    return cobs_encode(payload + zlib.crc32(payload).to_bytes(4, "little")) + b"\0"


def decode_frame(frame: bytes) -> bytes:
    """The payload of one frame: its bytes up to and with its 0x00 delimiter.

    Raises
    ------
    ProtocolError
        One line: a frame longer than :data:`MAX_FRAME` bytes, one without its 0x00
        (truncated: the stream ended inside it), bad COBS, too short for a type and its CRC,
        or a CRC mismatch (a corrupted frame).
    """
    frame = bytes(frame)
    if len(frame) > MAX_FRAME + (frame[-1:] == b"\0"):
        raise ProtocolError(f"frame longer than {MAX_FRAME} bytes: {_shown(frame)}")
    if not frame.endswith(b"\0"):
        raise ProtocolError(f"truncated frame (no 0x00 at its end): {_shown(frame)}")
    frame = frame[:-1]
    try:
        raw = cobs_decode(frame)
    except ProtocolError as exc:
        raise ProtocolError(f"{exc}: {_shown(frame)}") from None
    if len(raw) < 5:
        raise ProtocolError(f"frame too short ({len(raw)} bytes; a type byte and a 4-byte "
                            f"CRC at least; truncated?): {_shown(frame)}")
    payload, crc = raw[:-4], raw[-4:]
    if zlib.crc32(payload) != int.from_bytes(crc, "little"):
        raise ProtocolError(f"frame CRC mismatch (a corrupted frame): {_shown(frame)}")
    return payload


def _finite(kind: str, name: str, value: float) -> float:
    if not math.isfinite(value):
        raise ProtocolError(f"{kind} field `{name}` must be finite; got {value!r}")
    return value


def _real(kind: str, name: str, value: object) -> float:
    if isinstance(value, bool):
        raise ProtocolError(f"{kind} field `{name}` must be a finite number; got {value!r}")
    try:
        return _finite(kind, name, float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ProtocolError(f"{kind} field `{name}` must be a finite number; "
                            f"got {value!r}") from None


def _whole(kind: str, name: str, value: object, top: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
        raise ProtocolError(f"{kind} field `{name}` must be a whole number from 0 to {top}; "
                            f"got {value!r}")
    return value


# ------------------------------------------------------------------ host → rig
def config_frame(config: Mapping[str, object]) -> bytes:
    """The ``C`` frame of a configuration: every field, those not given the controller's
    default (:data:`CONFIG_DEFAULTS`; ``u_max`` none: :data:`NO_LIMIT`)."""
    for key in config:
        if key not in CONFIG_FIELDS:
            raise ProtocolError(f"CONFIG: unknown field `{key}`; the fields are "
                                f"{', '.join(CONFIG_FIELDS)}")
    values = []
    for name, code in _CONFIG_LAYOUT:
        val = config.get(name, CONFIG_DEFAULTS[name])
        values.append(_real("CONFIG", name, val) if code == "d"
                      else _whole("CONFIG", name, val, _MAX_INT[code]))
    return encode_frame(b"C" + _CONFIG.pack(*values))


def message_frame(kind: str) -> bytes:
    """A frame without fields: ``START``, ``CLEAR``, ``BYE`` (host) or ``OK`` (rig)."""
    code = {"START": b"S", "CLEAR": b"L", "BYE": b"B", "OK": b"K"}.get(kind)
    if code is None:
        raise ProtocolError(f"{kind!r} is not a message without fields")
    return encode_frame(code)


def abort_frame(reason: float) -> bytes:
    """The ``A`` frame: ABORT with the controller's ``fault-host`` value."""
    return encode_frame(b"A" + _F8.pack(_real("ABORT", "reason", reason)))


def parse_host_frame(payload: bytes) -> Message:
    """A host's frame (its payload, :func:`decode_frame`) as the text parser's Message:
    ``CONFIG`` (every field: the whole numbers as int), ``START``, ``CLEAR``, ``BYE``,
    ``ABORT``. A ProtocolError in one line for an unknown type, a wrong length or a value
    that is not finite."""
    kind = payload[:1]
    if kind == b"C":
        if len(payload) != CONFIG_SIZE:
            raise ProtocolError(f"CONFIG frame of {len(payload)} bytes; it has {CONFIG_SIZE}")
        fields: dict[str, object] = {}
        for (name, code), val in zip(_CONFIG_LAYOUT, _CONFIG.unpack_from(payload, 1),
                                     strict=True):
            fields[name] = _finite("CONFIG", name, val) if code == "d" else val
        return Message("CONFIG", fields)
    simple = {b"S": "START", b"L": "CLEAR", b"B": "BYE"}.get(kind)
    if simple is not None:
        if len(payload) != 1:
            raise ProtocolError(f"{simple} frame of {len(payload)} bytes; it has 1")
        return Message(simple, {})
    if kind == b"A":
        if len(payload) != 1 + _F8.size:
            raise ProtocolError(f"ABORT frame of {len(payload)} bytes; it has {1 + _F8.size}")
        return Message("ABORT", {"reason": _finite("ABORT", "reason",
                                                   _F8.unpack_from(payload, 1)[0])})
    raise ProtocolError(f"unknown frame type {payload[:1]!a} (a host sends C, S, L, B, A)")


# ------------------------------------------------------------------ rig → host
def error_frame(message: str) -> bytes:
    """The ``E`` frame: a refusal, its text made sendable (:func:`text_field`) and cut to
    fit the payload."""
    text = text_field(message).encode("ascii")
    if len(text) > MAX_PAYLOAD - 1:
        text = text[:MAX_PAYLOAD - 4].rstrip() + b"..."
    return encode_frame(b"E" + text)


def sample_frame(index: int, state: str, x: float, u: float, force: float | None = None,
                 *, f4: bool = False) -> bytes:
    """The ``X`` frame of one controller step (f4: the reals as binary32, as a float rig
    sends them)."""
    if state not in STATES:
        raise ProtocolError(f"SAMPLE field `state` must be one of {', '.join(STATES)}; "
                            f"got {state!r}")
    flags = (FLAG_F4 if f4 else 0) | (0 if force is None else FLAG_FORCE)
    reals = [_real("SAMPLE", "x", x), _real("SAMPLE", "u", u)]
    if force is not None:
        reals.append(_real("SAMPLE", "force", force))
    head = _HEAD.pack(ord("X"), _whole("SAMPLE", "index", index, 0xFFFFFFFF),
                      STATES.index(state), flags)
    return encode_frame(head + struct.pack(f"<{len(reals)}{_REALS[f4]}", *reals))


def event_frame(index: int, code: int, value: float, *, f4: bool = False) -> bytes:
    """The ``V`` frame of one event of the controller's log (``code``: the C event code)."""
    if code not in EVENT_NAMES:
        raise ProtocolError(f"EVENT: unknown event code {code!r}")
    head = _HEAD.pack(ord("V"), _whole("EVENT", "index", index, 0xFFFFFFFF), code,
                      FLAG_F4 if f4 else 0)
    return encode_frame(head + (_F4 if f4 else _F8).pack(_real("EVENT", "value", value)))


def end_frame(reason: str) -> bytes:
    """The ``D`` frame: END with the name of what ended the run (``done``, ``fault-…``, or
    ``fault``: a fault whose event was lost, code 0)."""
    code = next((c for c, n in _END_NAMES.items() if n == reason), None)
    if code is None:
        raise ProtocolError(f"END: {reason!r} is not done or a fault")
    return encode_frame(_END.pack(ord("D"), code))


def _reals(kind: str, payload: bytes, flags: int, allowed: int, names: tuple[str, ...]
           ) -> dict[str, float]:
    if flags & ~allowed:
        raise ProtocolError(f"{kind} frame with unknown flags 0x{flags:02x} (known: "
                            f"0x{allowed:02x})")
    if flags & FLAG_FORCE:
        names += ("force",)
    f4 = bool(flags & FLAG_F4)
    size = (4 if f4 else 8) * len(names)
    if len(payload) != _HEAD.size + size:
        raise ProtocolError(f"{kind} frame of {len(payload)} bytes; with flags 0x{flags:02x} "
                            f"it has {_HEAD.size + size}")
    vals = struct.unpack_from(f"<{len(names)}{_REALS[f4]}", payload, _HEAD.size)
    return {name: _finite(kind, name, val) for name, val in zip(names, vals, strict=True)}


def parse_rig_frame(payload: bytes, sample_time: float | None = None) -> Message:
    """A rig's frame (its payload, :func:`decode_frame`) as the text parser's Message.

    ``SAMPLE`` has ``index``, ``t`` (index·``sample_time``; only when ``sample_time`` is
    given), ``x``, ``u``, ``state`` and, with flags bit1, ``force``; ``EVENT`` ``index``,
    ``name``, ``value``; ``END`` ``reason``; ``ERROR`` ``message``; ``OK``.

    Raises
    ------
    ProtocolError
        One line: an unknown type, a length wrong for the type and its flags, unknown flags,
        a state or event code out of range, a value that is not finite.
    """
    kind = payload[:1]
    if kind == b"X":
        if len(payload) < _HEAD.size:
            raise ProtocolError(f"SAMPLE frame of {len(payload)} bytes; it has at least "
                                f"{_HEAD.size + 8}")
        _, index, state, flags = _HEAD.unpack_from(payload)
        if state >= len(STATES):
            raise ProtocolError(f"SAMPLE field `state` must be 0 to {len(STATES) - 1} "
                                f"({', '.join(STATES)}); got {state}")
        reals = _reals("SAMPLE", payload, flags, FLAG_F4 | FLAG_FORCE, ("x", "u"))
        fields: dict[str, object] = {"index": index}
        if sample_time is not None:
            fields["t"] = index * sample_time
        fields.update(x=reals["x"], u=reals["u"], state=STATES[state])
        if "force" in reals:
            fields["force"] = reals["force"]
        return Message("SAMPLE", fields)
    if kind == b"V":
        if len(payload) < _HEAD.size:
            raise ProtocolError(f"EVENT frame of {len(payload)} bytes; it has at least "
                                f"{_HEAD.size + 4}")
        _, index, code, flags = _HEAD.unpack_from(payload)
        name = EVENT_NAMES.get(code)
        if name is None:
            raise ProtocolError(f"EVENT with unknown event code {code}")
        value = _reals("EVENT", payload, flags, FLAG_F4, ("value",))["value"]
        return Message("EVENT", {"index": index, "name": name, "value": value})
    if kind == b"D":
        if len(payload) != _END.size:
            raise ProtocolError(f"END frame of {len(payload)} bytes; it has {_END.size}")
        reason = _END_NAMES.get(payload[1])
        if reason is None:
            raise ProtocolError(f"END with reason code {payload[1]}, neither done (3) nor a "
                                "fault (0, 5 to 9, 11)")
        return Message("END", {"reason": reason})
    if kind == b"K":
        if len(payload) != 1:
            raise ProtocolError(f"OK frame of {len(payload)} bytes; it has 1")
        return Message("OK", {})
    if kind == b"E":
        return Message("ERROR", {"message": text_field(payload[1:].decode("latin-1"))})
    raise ProtocolError(f"unknown frame type {payload[:1]!a} (a rig sends K, E, X, V, D)")
