"""A MATLAB v5 file, listed and read without :func:`scipy.io.whosmat` or :func:`~scipy.io.loadmat`.

The file's top-level elements are walked (from byte 128, each element's tag giving the next
one's position), the header of every variable decoded (at most :data:`HEAD` bytes of it,
decompressed where it is compressed) and the tag of a numeric variable's values checked: a
numeric data type, as many bytes as its dimensions need. :func:`read_values` then reads the
values of the variables asked for, in blocks (a compressed element decompressed
:data:`~phoid.io.limits.BLOCK` bytes at a time), each block checked by the caller as it comes.
Documented in the MAT-file format (MathWorks, "MAT-File Format", version 7, chapter 1).

Why not scipy (1.17): ``loadmat`` trusts the data type in a value tag (an invalid one, one
corrupted byte, crashes the interpreter with a segmentation fault), takes a cut or overlong
zlib stream without a word, and decompresses and holds a whole variable before a value can
be checked (a 1.4 MB file of zeros cost 3.2 GB and 27 s); ``whosmat`` decompresses each
compressed element in unbounded steps and stops listing, silently, at an element that runs
past the end of the file.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

import phoid.io.limits as limits
from phoid.io._format import fail, show

__all__ = ["HEAD", "MAX_VARIABLES", "Values", "check_mat5", "read_values"]

HEAD = 1 << 12
"""Most bytes of one variable's header decoded (flags, dimensions, name, first value tag):
a numeric variable's takes at most about 250 (32 dimensions, a name of 63 characters)."""
MAX_VARIABLES = 100_000
"""Most variables listed in one MATLAB file (each costs the decoding of its header)."""

_MI_MATRIX, _MI_COMPRESSED = 14, 15
_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8",
           13: "u8"}  # the numeric mi types
_ITEMSIZE = {k: int(v[1]) for k, v in _DTYPES.items()}
_NUMERIC_CLASSES = range(6, 16)  # mxDOUBLE … mxUINT64
_CLASSES = dict(enumerate(("", "cell", "struct", "object", "char", "sparse", "double",
                           "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                           "int64", "uint64", "function", "opaque")))
_MAX_DIMS = 32


@dataclass(frozen=True)
class Values:
    """Where a numeric variable's real values lie in a MATLAB v5 file.

    ``offset`` counts from the start of the variable's miMATRIX element (its 8-byte tag): in
    the file at ``pos`` for a plain element, in the decompressed stream for a compressed one
    (whose compressed bytes are the ``nbytes`` after the tag at ``pos``).
    """

    pos: int
    nbytes: int
    compressed: bool
    offset: int
    mdtype: int
    size: int
    """Bytes of the real values."""
    complex: bool
    endian: str

    @property
    def dtype(self) -> np.dtype:
        """The values' type as stored (a double array may store small integers as uint8)."""
        return np.dtype(self.endian + _DTYPES[self.mdtype])

    @property
    def count(self) -> int:
        """Number of values."""
        return self.size // _ITEMSIZE[self.mdtype]


def check_mat5(where: str, f: BinaryIO, size: int
               ) -> tuple[list[tuple[str, tuple[int, ...], str]], dict[str, Values]]:
    """List a MATLAB v5 file's variables, refusing a file that is cut short or damaged where
    a value would be read; return where its numeric variables' values lie.

    This replaces :func:`scipy.io.whosmat`, which decompresses each compressed element in
    unbounded steps (128 KiB of zlib input can expand to 128 MiB, and a file of many such
    elements would cost minutes) and stops listing, without a word, at an element that runs
    past the end of the file (the variable seemed missing). Every top-level element must
    fit in the file; at most :data:`MAX_VARIABLES` are listed; of each, at most :data:`HEAD`
    bytes are read (decompressed).

    Returns
    -------
    listing : list of (name, shape, class)
        Every variable, in the file's order, as :func:`scipy.io.whosmat` lists it: the name
        decoded latin-1, the dimensions (empty where not decoded) and the MATLAB class
        ("double", "char", "logical", …).
    values : dict
        Name → where the real values of the first numeric variable of that name lie
        (:func:`read_values` reads them).

    Raises :class:`~phoid.errors.ExperimentError` naming the variable (or the file offset)
    at fault.
    """
    f.seek(126)
    endian = ">" if f.read(2) == b"MI" else "<"
    pos = 128
    listing: list[tuple[str, tuple[int, ...], str]] = []
    found: dict[str, Values] = {}
    while pos + 8 <= size:
        if len(listing) >= MAX_VARIABLES:
            fail(where, f"the MATLAB file holds more than {MAX_VARIABLES:,} variables, phoid's "
                         "limit for one file")
        f.seek(pos)
        mdtype, nbytes = struct.unpack(endian + "II", f.read(8))
        if nbytes == 0:
            fail(where, f"the MATLAB file's element at byte {pos} is empty (0 bytes): the file "
                         "is damaged")
        if pos + 8 + nbytes > size:
            fail(where, f"the MATLAB file is cut short (truncated): its element at byte {pos} "
                         f"declares {nbytes} bytes, but the file ends {size - pos - 8} bytes "
                         "after the element's tag: the file is damaged")
        compressed = mdtype == _MI_COMPRESSED
        if compressed:
            body = _inflate(where, f, nbytes, pos)
            if len(body) < 8:
                fail(where, f"the MATLAB file's compressed element at byte {pos} "
                             f"decompresses to {len(body)} bytes, too few for a variable: the "
                             "file is damaged")
            mdtype = struct.unpack(endian + "I", body[:4])[0]
            body = body[8:]
        elif mdtype == _MI_MATRIX:
            body = f.read(min(nbytes, HEAD))
        if mdtype != _MI_MATRIX:
            fail(where, f"the MATLAB file's element at byte {pos} has the data type {mdtype}, "
                         "not a variable (miMATRIX, 14): the file is damaged")
        name, shape, cls, located = _check_matrix(where, body, endian, pos)
        listing.append((name, shape, cls))
        if located is not None:
            offset, value_type, value_bytes, is_complex = located
            found.setdefault(name, Values(pos, nbytes, compressed, 8 + offset, value_type,
                                          value_bytes, is_complex, endian))
        pos += 8 + nbytes
    return listing, found


def read_values(where: str, f: BinaryIO, values: Values, name: str) -> Iterator[np.ndarray]:
    """A numeric variable's real values, in pieces of at most about one block, as stored.

    The pieces are views of the file's bytes in the stored type (:attr:`Values.dtype`). A
    compressed element is decompressed :data:`~phoid.io.limits.BLOCK` bytes at a time and
    checked whole once its values are read: it must hold one zlib stream that ends within
    the element and decompresses to the inner element's 8-byte tag plus the bytes that tag
    declares (7 bytes of padding tolerated), at most
    :data:`~phoid.io.limits.MAX_DATA_BYTES` — scipy took a cut or overlong stream without a
    word.
    """
    dtype = values.dtype
    skip, left, rest = values.offset, values.size, b""
    blocks = _inflated(where, f, values, name) if values.compressed else _plain(f, values)
    for block in blocks:
        if skip >= len(block):
            skip -= len(block)
            continue
        if skip:
            block, skip = block[skip:], 0
        if not left:
            continue  # the padding after the values, read for the checks at the end
        take = block[:left]
        left -= len(take)
        buf = rest + take if rest else take
        cut = len(buf) - len(buf) % dtype.itemsize
        if cut:
            yield np.frombuffer(buf, dtype=dtype, count=cut // dtype.itemsize)
        rest = buf[cut:]
    if left or rest:  # pragma: no cover - the checks of the element's size come first
        fail(where, f"variable {show(name, 60)}: its values end before the {values.size} "
                     "bytes its tag declares: the file is damaged")


def _plain(f: BinaryIO, values: Values) -> Iterator[bytes]:
    """An uncompressed element's bytes from its tag, in blocks (the walk checked that it
    fits in the file)."""
    f.seek(values.pos)
    left = 8 + values.nbytes
    while left:
        block = f.read(min(left, limits.BLOCK))
        if not block:  # pragma: no cover - the file shrank since it was walked
            return
        left -= len(block)
        yield block


def _inflated(where: str, f: BinaryIO, values: Values, name: str) -> Iterator[bytes]:
    """A compressed element's decompressed stream, in blocks, checked whole at its end."""
    pos, nbytes, endian = values.pos, values.nbytes, values.endian
    damaged = (f"variable {show(name, 60)}: its compressed element (byte {pos} of the file) "
               "is damaged")
    f.seek(pos + 8)
    d = zlib.decompressobj()
    head = b""
    total = 0
    left = nbytes
    pending = b""
    cap = limits.MAX_DATA_BYTES
    while not d.eof:
        if not pending:
            pending = f.read(min(left, limits.BLOCK)) if left else b""
            if not pending:
                break
            left -= len(pending)
        try:
            piece = d.decompress(pending, limits.BLOCK)
        except zlib.error as exc:
            fail(where, f"{damaged}: {exc}")
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
        if piece:
            yield piece
    if not d.eof:
        fail(where, f"{damaged}: its zlib stream does not end within the element (the file "
                     "is truncated or damaged)")
    if len(head) < 8 or total < cap - 7:
        fail(where, f"{damaged}: it decompresses to {total} bytes, fewer than its variable "
                     "declares (the file is truncated or damaged)")


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
    decoded bytes, or for a small element (byte count in the tag's upper half) that claims
    more than the 4 bytes it can hold (the format allows no more: a damaged tag)."""
    if at + 8 > len(body):
        return None
    first, second = struct.unpack(endian + "II", body[at:at + 8])
    if first >> 16:
        if first >> 16 > 4:
            return None
        return first & 0xFFFF, first >> 16, at + 4, at + 8
    return first, second, at + 8, at + 8 + second + (-second) % 8


def _check_matrix(where: str, body: bytes, endian: str, pos: int
                  ) -> tuple[str, tuple[int, ...], str, tuple[int, int, int, bool] | None]:
    """Decode one miMATRIX's header (``body`` follows its tag) and check the tag of a numeric
    variable's real values.

    A numeric variable's header (flags, at most 32 dimensions, a name of at most 63
    characters) takes a few hundred bytes; one that does not fit in its element, or in
    :data:`HEAD` bytes, is damaged. Another variable (a cell, a struct, text, an object)
    is only listed: its name and dimensions where they decode, never read.

    Returns the variable's name (latin-1, as scipy decodes it), its dimensions, its MATLAB
    class, and, for a numeric one, its real values' offset in ``body``, data type and byte
    count and whether it is complex (None for another).
    """
    damaged = f"the MATLAB variable at byte {pos} has a damaged header: the file is damaged"
    if len(body) < 16:
        fail(where, damaged)
    flags = struct.unpack(endian + "I", body[8:12])[0]
    mclass = flags & 0xFF
    cls = "logical" if flags & 0x0200 else _CLASSES.get(mclass, "unknown")
    numeric = mclass in _NUMERIC_CLASSES and not flags & 0x0200  # logical: refused later
    dims = _element(body, 16, endian)
    if dims is None or dims[0] != 5 or dims[1] > 4 * _MAX_DIMS or dims[2] + dims[1] > len(body):
        if numeric:
            fail(where, damaged)
        return f"(unnamed, byte {pos})", (), cls, None
    shape = struct.unpack(endian + f"{dims[1] // 4}i", body[dims[2]:dims[2] + dims[1] // 4 * 4])
    name_el = _element(body, dims[3], endian)
    if name_el is None or name_el[2] + name_el[1] > len(body):
        if numeric:
            fail(where, damaged)
        return f"(unnamed, byte {pos})", shape, cls, None
    raw = body[name_el[2]:name_el[2] + name_el[1]]
    name = raw.decode("latin1") or "__function_workspace__"
    if not numeric:
        return name, shape, cls, None
    shown = show(raw.decode("utf-8", "replace"), 60)
    count = 1
    for d in shape:
        count *= max(d, 0)
    values = _element(body, name_el[3], endian)
    if values is None:
        fail(where, f"variable {shown}: the tag of its real values is missing or invalid: the "
                     "file is damaged")
    mdtype, nbytes = values[0], values[1]
    if mdtype not in _ITEMSIZE:
        fail(where, f"variable {shown}: its real values have the invalid MATLAB data type "
                     f"{mdtype} (byte {pos} of the file): the file is damaged")
    if nbytes != count * _ITEMSIZE[mdtype]:
        fail(where, f"variable {shown}: its real values take {nbytes} bytes, but its "
                     f"dimensions {'×'.join(map(str, shape))} need "
                     f"{count * _ITEMSIZE[mdtype]}: the file is damaged")
    return name, shape, cls, (values[2], mdtype, nbytes, bool(flags & 0x0800))
