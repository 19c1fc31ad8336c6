"""A line link over a socket: whole lines (or binary frames) in, bytes out, with timeouts (both
rig sides use it).

:class:`Link` buffers what the socket delivers and hands out one line (LF included) at a time,
so a caller can poll for a line without blocking (the virtual rig looks for ``ABORT`` between
samples) or wait for one with a bounded timeout (the host). Nothing it does is unbounded: a
line is at most :data:`~phoid.rig.protocol.MAX_LINE` bytes, and a binary frame
(:meth:`Link.read_frame`, after ``FRAMING cobs``) at most :data:`~phoid.rig.frames.MAX_FRAME`
(a longer one is handed out in pieces the parser refuses), a wait for a line ends at its
timeout however many bytes arrive meanwhile, and the host's links (:func:`connect`,
:func:`open_serial`) give up sending after their timeout when the other side does not take
the bytes.
"""

from __future__ import annotations

import os
import select
import socket
import sys
import time

from phoid.rig.frames import MAX_FRAME
from phoid.rig.protocol import MAX_LINE, ProtocolError

__all__ = ["FdStream", "Link", "LinkClosed", "connect", "open_serial"]


class LinkClosed(ProtocolError):
    """The other side closed the connection (or it dropped)."""


class Link:
    """Lines over a connected socket.

    Parameters
    ----------
    sock : socket.socket or FdStream
        A connected stream socket, or a serial line (:func:`open_serial`); the link owns it
        and closes it in :meth:`close`.
    """

    byte_time = 0.0
    """Seconds one byte takes on the line (a serial line's 10/baud; 0 for a socket)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self._buf = bytearray()
        self._eof = False
        self._skip = False  # inside a line longer than MAX_LINE: its rest is dropped

    def send(self, data: bytes) -> None:
        """Send bytes (whole lines); a dropped connection raises :class:`LinkClosed`."""
        try:
            self.sock.sendall(data)
        except OSError as exc:
            raise LinkClosed(f"the connection dropped while sending ({exc.strerror or exc})") \
                from None

    def _fill(self, timeout: float) -> None:
        ready, _, _ = select.select([self.sock], [], [], max(timeout, 0.0))
        if not ready:
            return
        try:
            chunk = self.sock.recv(65536)
        except OSError as exc:
            raise LinkClosed(f"the connection dropped ({exc.strerror or exc})") from None
        if not chunk:
            self._eof = True
        self._buf += chunk

    def readline(self, timeout: float | None) -> bytes | None:
        """The next line (with its LF), or None when none came within ``timeout`` s.

        ``timeout`` 0 polls; None waits for ever. A line longer than ``MAX_LINE`` bytes is
        handed out as its first ``MAX_LINE + 1`` bytes (no LF: the parser refuses it); the rest
        of it, up to its LF, is dropped, and every further ``MAX_LINE + 1`` bytes of it without
        an LF are handed out the same way, so that each call returns within its timeout and at
        most that many bytes. At the end of the stream a last partial line is returned as it is
        (without LF: the parser calls it truncated); after that :class:`LinkClosed` is raised.
        """
        return self._read(b"\n", MAX_LINE, timeout)

    def read_frame(self, timeout: float | None) -> bytes | None:
        """The next binary frame (with its 0x00 delimiter), or None when none came within
        ``timeout`` s: :meth:`readline`'s rules with 0x00 for the LF and ``MAX_FRAME`` (the
        longest encoded frame, :mod:`phoid.rig.frames`) for ``MAX_LINE``.

        0x00 bytes between frames (empty frames, a sender's resynchronisation) are skipped. A
        frame longer than ``MAX_FRAME`` is handed out as its first ``MAX_FRAME + 1`` bytes
        (the decoder refuses it) and its rest, up to the next 0x00, dropped; at the end of the
        stream a last partial frame is returned without its 0x00 (the decoder refuses it when
        it does not check out).
        """
        return self._read(b"\0", MAX_FRAME, timeout)

    def _read(self, delim: bytes, limit: int, timeout: float | None) -> bytes | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if delim == b"\0" and not self._skip and self._buf[:1] == b"\0":
                start = len(self._buf) - len(self._buf.lstrip(b"\0"))  # empty frames: skipped
                del self._buf[:start]
            i = self._buf.find(delim, 0, limit + 1)
            if self._skip and i >= 0:  # the end of an over-long line: drop its rest
                del self._buf[:i + 1]
                self._skip = False
                continue
            if i >= 0:
                line = bytes(self._buf[:i + 1])
                del self._buf[:i + 1]
                return line
            if len(self._buf) > limit:
                line = bytes(self._buf[:limit + 1])
                del self._buf[:limit + 1]
                self._skip = True
                return line  # too long: the parser refuses it
            if self._eof:
                if self._buf:
                    line = bytes(self._buf)
                    self._buf.clear()
                    return line
                raise LinkClosed("the connection was closed by the other side")
            left = 1.0 if deadline is None else deadline - time.monotonic()
            if left <= 0 and timeout != 0:
                return None
            self._fill(max(left, 0.0) if deadline is not None else 1.0)
            if timeout == 0 and delim not in self._buf and not self._eof \
                    and len(self._buf) <= limit:
                return None

    def close(self) -> None:
        """Close the socket (no error when it is closed already)."""
        try:
            self.sock.close()
        except OSError:
            pass


def connect(host: str, port: int, timeout: float) -> Link:
    """Connect to ``host:port`` within ``timeout`` s; a :class:`LinkClosed` names the address.

    A refused connection is retried every 0.1 s until the timeout: a rig just started (the
    virtual rig compiles its controller first) listens a moment later. Sending on the link
    gives up (:class:`LinkClosed`) when the rig takes no byte for ``timeout`` s.
    """
    deadline = time.monotonic() + timeout
    while True:
        try:
            sock = socket.create_connection((host, port),
                                            timeout=max(deadline - time.monotonic(), 0.05))
            break
        except ConnectionRefusedError as exc:
            if time.monotonic() + 0.1 >= deadline:
                raise LinkClosed(f"cannot connect to the rig at tcp://{host}:{port}: "
                                 f"{exc.strerror or exc} (for {timeout:g} s)") from None
            time.sleep(0.1)
        except (OSError, UnicodeError) as exc:  # UnicodeError: a name the resolver refuses
            raise LinkClosed(f"cannot connect to the rig at tcp://{host}:{port}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None
    sock.settimeout(timeout)  # a send the rig does not take gives up (reads wait in select)
    return Link(sock)


class FdStream:
    """A file descriptor (a serial line) with the socket methods :class:`Link` uses.

    Parameters
    ----------
    fd : int
        The open descriptor (owned: :meth:`close` closes it).
    timeout : float, optional
        Seconds :meth:`sendall` waits for the line to take a byte before it gives up
        (``TimeoutError``); None waits for ever.
    """

    def __init__(self, fd: int, timeout: float | None = None) -> None:
        self.fd = fd
        self.timeout = timeout

    def fileno(self) -> int:
        return self.fd

    def sendall(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            _, ready, _ = select.select([], [self.fd], [], self.timeout)
            if not ready:
                raise TimeoutError(f"the line took no byte for {self.timeout:g} s")
            n = os.write(self.fd, view[:256])  # a small piece: the write cannot block long
            view = view[n:]

    def recv(self, size: int) -> bytes:
        return os.read(self.fd, size)

    def shutdown(self, how: int) -> None:
        pass

    def close(self) -> None:
        os.close(self.fd)


def open_serial(path: str, baud: int, timeout: float | None = None) -> Link:
    """Open a serial line (POSIX: a tty device) raw at ``baud``, 8 data bits, no parity.

    The device is opened without waiting for a carrier and set to ignore the modem lines
    (``CLOCAL``); sending gives up after ``timeout`` s without progress (None: never). The
    link's :attr:`Link.byte_time` is 10/``baud`` s.

    Raises
    ------
    LinkClosed
        One line naming the device when it cannot be opened or configured.
    """
    if sys.platform == "win32":
        raise LinkClosed("serial ports are supported on POSIX systems only; use tcp://")
    import termios
    import tty

    speed = getattr(termios, f"B{baud}", None)
    if speed is None:
        raise LinkClosed(f"serial://{path}: baud rate {baud} is not one this system knows")
    try:  # O_NONBLOCK: a port waiting for its carrier does not hold the open
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as exc:
        raise LinkClosed(f"cannot open the rig's serial port {path}: {exc.strerror or exc}") \
            from None
    try:
        if not os.isatty(fd):
            raise OSError("not a terminal device")
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[2] |= termios.CLOCAL | termios.CREAD
        attrs[4] = attrs[5] = speed
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        os.set_blocking(fd, True)
    except (OSError, termios.error) as exc:
        os.close(fd)
        raise LinkClosed(f"{path} is not a serial port that can be configured: {exc}") from None
    link = Link(FdStream(fd, timeout))  # type: ignore[arg-type]
    link.byte_time = 10.0 / baud
    return link
