"""A MATLAB v5 file's structure, checked before :func:`scipy.io.loadmat` reads its values.

scipy's MAT v5 reader trusts the data type in the tag of a variable's values: a tag with an
invalid type (one corrupted byte) makes it index past a table and crash the interpreter with a
segmentation fault (scipy 1.17), where every other damage raises an exception. So, before
scipy reads any value, this module walks the file's top-level elements as scipy does (from
byte 128, each element's tag giving the next one's position), decodes the header of every
numeric variable (decompressing at most :data:`HEAD` bytes of a compressed one) and checks the
tags of its values: a numeric data type, as many bytes as its dimensions need. Documented in
the MAT-file format (MathWorks, "MAT-File Format", version 7, chapter 1).
"""

from __future__ import annotations

import struct
import zlib
from typing import BinaryIO

import phoid.io.limits as limits
from phoid.io._format import fail, show

__all__ = ["HEAD", "check_mat5", "check_stream"]

HEAD = 1 << 16
"""Most bytes of one variable's header decoded (flags, dimensions, name, first value tags)."""

_MI_MATRIX, _MI_COMPRESSED = 14, 15
_ITEMSIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8}  # numeric mi types
_NUMERIC_CLASSES = range(6, 16)  # mxDOUBLE … mxUINT64
_MAX_DIMS = 32


def check_mat5(where: str, f: BinaryIO, size: int) -> dict[str, tuple[int, int]]:
    """Refuse a MATLAB v5 file that is cut short, or whose numeric variables' value tags
    scipy could not survive; return where its compressed variables lie.

    A cut file is refused here because scipy does not notice it: ``whosmat`` stops listing
    at an element that runs past the end of the file (the variable seems missing). Every
    top-level element must fit in the file.

    Returns
    -------
    dict
        Variable name (as scipy decodes it, latin-1) → (byte offset, byte count) of its
        compressed element: :func:`check_stream` checks one before scipy reads it.

    Raises :class:`~phoid.errors.ExperimentError` naming the variable (or the file offset)
    at fault. Other damage (bad headers) is left to scipy, which raises on it.
    """
    f.seek(126)
    endian = ">" if f.read(2) == b"MI" else "<"
    pos = 128
    compressed: dict[str, tuple[int, int]] = {}
    while pos + 8 <= size:
        f.seek(pos)
        mdtype, nbytes = struct.unpack(endian + "II", f.read(8))
        if nbytes == 0:
            break  # scipy stops here with an error of its own
        if pos + 8 + nbytes > size:
            fail(where, f"the MATLAB file is cut short (truncated): its element at byte {pos} "
                         f"declares {nbytes} bytes, but the file ends {size - pos - 8} bytes "
                         "after the element's tag: the file is damaged")
        if mdtype == _MI_COMPRESSED:
            body = _inflate(where, f, nbytes, pos)
            if len(body) < 8:
                fail(where, f"the MATLAB file's compressed element at byte {pos} "
                             f"decompresses to {len(body)} bytes, too few for a variable: the "
                             "file is damaged")
            mdtype = struct.unpack(endian + "I", body[:4])[0]
            body = body[8:]
            name = _name(body, endian)
            if name is not None:
                compressed.setdefault(name, (pos, nbytes))
        elif mdtype == _MI_MATRIX:
            body = f.read(min(nbytes, HEAD))
        else:
            break  # scipy raises "Expecting miMATRIX type here"
        if mdtype == _MI_MATRIX:
            _check_matrix(where, body, endian, pos)
        pos += 8 + nbytes
    return compressed


def check_stream(where: str, f: BinaryIO, pos: int, nbytes: int, name: str) -> None:
    """Check a whole compressed element before scipy decompresses it for a variable read.

    scipy decompresses a variable's element only as far as the variable's values need, and
    takes a zlib stream cut short, or longer than its variable, without a word. The
    element's ``nbytes`` bytes at ``pos`` are read and decompressed here in blocks (output
    bounded per step, not kept): they must hold one zlib stream that ends within them and
    decompresses to the inner element's 8-byte tag plus the bytes that tag declares (7
    bytes of padding tolerated), at most :data:`~phoid.io.limits.MAX_DATA_BYTES`.
    """
    damaged = (f"variable {show(name, 60)}: its compressed element (byte {pos} of the file) "
               "is damaged")
    f.seek(126)
    endian = ">" if f.read(2) == b"MI" else "<"
    f.seek(pos + 8)
    d = zlib.decompressobj()
    head = b""
    total = 0
    left = nbytes
    pending = b""
    cap = limits.MAX_DATA_BYTES
    try:
        while not d.eof:
            if not pending:
                pending = f.read(min(left, limits.BLOCK)) if left else b""
                if not pending:
                    break
                left -= len(pending)
            piece = d.decompress(pending, limits.BLOCK)
            pending = d.unconsumed_tail
            total += len(piece)
            if len(head) < 8:
                head += piece[:8 - len(head)]
                if len(head) == 8:
                    cap = min(cap, 8 + struct.unpack(endian + "I", head[4:8])[0] + 7)
            if total > cap:
                fail(where, f"{damaged}: it decompresses to more than "
                             + (f"the {cap - 7} bytes its variable declares"
                                if cap < limits.MAX_DATA_BYTES else
                                f"{limits.MAX_DATA_BYTES // 2**30} GiB, phoid's limit for "
                                "one run (MAX_DATA_BYTES)"))
    except zlib.error as exc:
        fail(where, f"{damaged}: {exc}")
    if not d.eof:
        fail(where, f"{damaged}: its zlib stream does not end within the element (the file "
                     "is truncated or damaged)")
    if len(head) < 8 or total < cap - 7:
        fail(where, f"{damaged}: it decompresses to {total} bytes, fewer than its variable "
                     "declares (the file is truncated or damaged)")


def _name(body: bytes, endian: str) -> str | None:
    """A variable's name from its miMATRIX header (``body`` follows its tag); None where the
    header is not whole."""
    dims = _element(body, 16, endian)
    name = _element(body, dims[3], endian) if dims is not None else None
    if name is None or name[2] + name[1] > len(body):
        return None
    return body[name[2]:name[2] + name[1]].decode("latin1")


def _inflate(where: str, f: BinaryIO, nbytes: int, pos: int) -> bytes:
    """The first HEAD bytes (at most) of a compressed element, reading its input in blocks."""
    d = zlib.decompressobj()
    out = b""
    left = nbytes
    try:
        while left and len(out) < HEAD:
            chunk = f.read(min(left, 1 << 14))
            if not chunk:
                break
            left -= len(chunk)
            out += d.decompress(chunk, HEAD - len(out))
            while d.unconsumed_tail and len(out) < HEAD:
                out += d.decompress(d.unconsumed_tail, HEAD - len(out))
            if d.eof:
                break
    except zlib.error as exc:
        fail(where, f"the MATLAB file's compressed element at byte {pos} is damaged: {exc}")
    return out


def _element(body: bytes, at: int, endian: str) -> tuple[int, int, int, int] | None:
    """(type, byte count, data offset, next offset) of the element at ``at``; None past the
    decoded bytes. A small element (byte count in the tag's upper half) holds ≤ 4 bytes."""
    if at + 8 > len(body):
        return None
    first, second = struct.unpack(endian + "II", body[at:at + 8])
    if first >> 16:
        return first & 0xFFFF, first >> 16, at + 4, at + 8
    return first, second, at + 8, at + 8 + second + (-second) % 8


def _check_matrix(where: str, body: bytes, endian: str, pos: int) -> None:
    """Check the value tags of one numeric miMATRIX (``body`` follows its tag).

    A numeric variable's header (flags, at most 32 dimensions, a name of at most 63
    characters) takes a few hundred bytes; one that does not fit in its element, or in
    :data:`HEAD` bytes, is damaged.
    """
    damaged = f"the MATLAB variable at byte {pos} has a damaged header: the file is damaged"
    if len(body) < 16:
        fail(where, damaged)
    flags = struct.unpack(endian + "I", body[8:12])[0]
    if (flags & 0xFF) not in _NUMERIC_CLASSES or flags & 0x0200:  # logical: refused later
        return
    dims = _element(body, 16, endian)
    if dims is None or dims[0] != 5 or dims[1] > 4 * _MAX_DIMS or dims[2] + dims[1] > len(body):
        fail(where, damaged)
    shape = struct.unpack(endian + f"{dims[1] // 4}i", body[dims[2]:dims[2] + dims[1] // 4 * 4])
    name_el = _element(body, dims[3], endian)
    if name_el is None:
        fail(where, damaged)
    raw = body[name_el[2]:name_el[2] + name_el[1]]
    name = show(raw.decode("utf-8", "replace"), 60)
    count = 1
    for d in shape:
        count *= max(d, 0)
    at = name_el[3]
    for part in ("real", "imaginary") if flags & 0x0800 else ("real",):
        values = _element(body, at, endian)
        if values is None:
            fail(where, f"variable {name}: the tag of its {part} values is missing: the file "
                         "is damaged")
        mdtype, nbytes = values[0], values[1]
        if mdtype not in _ITEMSIZE:
            fail(where, f"variable {name}: its {part} values have the invalid MATLAB data type "
                         f"{mdtype} (byte {pos} of the file): the file is damaged")
        if nbytes != count * _ITEMSIZE[mdtype]:
            fail(where, f"variable {name}: its {part} values take {nbytes} bytes, but its "
                         f"dimensions {'×'.join(map(str, shape))} need "
                         f"{count * _ITEMSIZE[mdtype]}: the file is damaged")
        at = values[3]
