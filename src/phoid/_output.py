"""Safe output: every file phoid writes goes through here.

The rules, the same for every command and function that writes (``write_experiment``,
``Design.write``/``plot``, the identification, forced, free and Figure 1 plots):

* The output folder is the one the caller names (itself a link to a folder is fine: the user
  chose it); it is created, with its parents, when missing — but never through a dangling link.
* A file is never written through a symbolic link: a target that is a link (to a file, to a
  folder or to nothing) is refused, with or without ``overwrite``; so is a target whose
  subfolders lead outside the output folder (a linked subfolder, a dangling link on the way).
* An existing file is replaced only when ``overwrite`` is asked; a folder, FIFO or device in the
  way is never replaced.
* Every check is made for all targets before the first file is written, and each file is written
  atomically: into a temporary file in the same folder, flushed to disk, then renamed over the
  target (``os.replace``, which replaces a link rather than following it). A failure leaves the
  old file (or no file) and no temporary file behind.

* No file is written over one of the running command's own inputs (the set's manifest and
  data files, a schedule, a batch output read): :func:`protect_inputs` names them, and a
  target that is one of them, by its resolved path or as the same file (a hard link, a link
  to it), is refused with or without ``overwrite``, naming both.

Problems raise :class:`OutputError` (a ``ValueError``) with one line naming the path. The
remedy for an existing file is worded for the caller: ``pass overwrite=True`` from Python,
``pass --overwrite`` from the command line (:func:`cli_wording`).

What a command prints goes through here too: its text through :func:`echo_text` (escaped, in
the stream's notation, fitted to 100 columns), an error through :func:`exit_with_error` (one
line, exit status 2).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import secrets
import stat
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path, PurePosixPath
from typing import IO, Any, NoReturn

from phoid.errors import OutputError, PhoidError

__all__ = ["OutputFolder", "check_not_input", "cli_wording", "echo_text", "exit_with_error",
           "png_writer", "protect_inputs", "safe_text", "save_figure"]

# characters never printed raw: controls (a line break, ESC), format characters (the bidi
# overrides U+202A-U+202E and isolates U+2066-U+2069, zero-width ones), lone surrogates (a
# file name's undecodable bytes) and the line and paragraph separators
_UNSAFE_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Zl", "Zp"})


def exit_with_error(message: object, code: int = 2) -> NoReturn:
    """End a command: ``phoid: error: <message>`` on one line of stderr, exit status ``code``.

    The one way every ``phoid`` command reports a user's error: the message on one line (its
    whitespace runs, line breaks included, made one space), unsafe characters escaped
    (:func:`safe_text`), and spelled in ASCII where stderr cannot encode phoid's notation
    (:func:`phoid._notation.stream_text`).

    Parameters
    ----------
    message : object
        What is wrong (``str()`` of anything else), naming the file, run, field or option.
    code : int
        The exit status (2: bad input; 1: a failure after the work began).

    Raises
    ------
    typer.Exit
        Always.
    """
    import typer

    from phoid._notation import stream_text

    text = safe_text(" ".join(str(message).split()))
    typer.echo(stream_text(f"phoid: error: {text}", sys.stderr), err=True)
    raise typer.Exit(code)


def echo_text(text: str | Callable[[], str], *, err: bool = False, wrap: bool = True) -> None:
    """Print a command's text output: the one way every ``phoid`` command writes text.

    The text is made (when ``text`` is a callable: a ``report()``) inside
    :func:`phoid._notation.stream_notation`, so that its tables are laid out in the notation
    the stream can show; then unsafe characters are escaped (:func:`safe_text`, line breaks
    kept), the notation spelled in ASCII where the stream cannot encode it
    (:func:`phoid._notation.stream_text`) and lines wider than :data:`phoid._notation.WIDTH`
    wrapped (:func:`phoid._notation.fit_width`).

    Parameters
    ----------
    text : str or callable returning str
        The text, or what makes it.
    err : bool
        Write to standard error instead of standard output.
    wrap : bool
        Fit the lines to the width; False for a line a program may read as one: a status line
        naming the files written (``… written to PATH``: a path is never split from its
        line), a ``phoid: warning:`` line beside ``--json``, like an error line.
    """
    import typer

    from phoid._notation import fit_width, stream_notation, stream_text

    stream = sys.stderr if err else sys.stdout
    if callable(text):
        with stream_notation(stream):
            text = text()
    # spelled for the stream before it is fitted: ± as +/- is two columns wider
    text = stream_text(safe_text(text, newlines=True), stream)
    typer.echo(fit_width(text) if wrap else text, err=err)


def safe_text(text: object, *, newlines: bool = False) -> str:
    """``text`` for a terminal or a text report: every unsafe character escaped.

    User-supplied text (file and run names, units, paths, warnings quoting them) may hold a
    line break that splits a table row, a terminal escape sequence or a right-to-left override
    that makes a name read differently. Each character of the Unicode categories Cc, Cf, Cs,
    Zl and Zp is written as its Python escape (``\\n``, ``\\x1b``, ``\\u202e``).

    Parameters
    ----------
    text : object
        The text (``str()`` of anything else).
    newlines : bool
        Keep ``"\\n"`` as it is (a whole report of several lines); every other line break
        (``"\\r"``, U+2028, …) is still escaped.

    Returns
    -------
    str

    Examples
    --------
    >>> safe_text("a\\nb\\u202ec.csv")
    'a\\\\nb\\\\u202ec.csv'
    """
    text = str(text)
    if text.isprintable():  # the common case: nothing to escape (space is printable)
        return text
    import unicodedata

    return "".join(
        ch if (newlines and ch == "\n") or unicodedata.category(ch) not in _UNSAFE_CATEGORIES
        else ch.encode("unicode_escape", "backslashreplace").decode("ascii")
        for ch in text)

_OVERWRITE_HINT: contextvars.ContextVar[str] = contextvars.ContextVar(
    "phoid_overwrite_hint", default="overwrite=True")

# the running command's input files: (as the user names it, resolved path, (device, inode))
_Input = tuple[str, str, "tuple[int, int] | None"]
_INPUTS: contextvars.ContextVar[tuple[_Input, ...]] = contextvars.ContextVar(
    "phoid_inputs", default=())


def _identity(path: str | os.PathLike[str]) -> tuple[str, tuple[int, int] | None]:
    """A file's resolved path and, when it exists, its (device, inode), links followed."""
    try:
        real = os.path.realpath(path)
    except (OSError, ValueError):
        real = os.path.abspath(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return real, None
    return real, (st.st_dev, st.st_ino)


@contextlib.contextmanager
def protect_inputs(paths: Iterable[str | os.PathLike[str]]) -> Iterator[None]:
    """Within this context, no :class:`OutputFolder` writes over one of ``paths``.

    Parameters
    ----------
    paths : iterable of str or path
        The command's input files (a manifest, its data files, a schedule, a results file).
        Each is known by its resolved path and, when it exists, by its device and inode, so
        that a link or a hard link to it counts as the file itself. The protection adds to
        any already in force.
    """
    added = []
    for path in paths:
        real, ident = _identity(path)
        added.append((os.fspath(path), real, ident))
    token = _INPUTS.set((*_INPUTS.get(), *added))
    try:
        yield
    finally:
        _INPUTS.reset(token)


def check_not_input(target: str | os.PathLike[str],
                    error: type[PhoidError] = OutputError) -> None:
    """Refuse ``target`` when it is one of the inputs :func:`protect_inputs` names.

    Raises
    ------
    PhoidError
        ``error`` (default :class:`OutputError`): one line naming the target and the input.
    """
    inputs = _INPUTS.get()
    if not inputs:
        return
    real, ident = _identity(target)
    for shown, in_real, in_ident in inputs:
        if real == in_real or (ident is not None and ident == in_ident):
            raise _fail(target, f"is an input of this command ({shown}); phoid never "
                                "replaces its own input, even with "
                                f"{_OVERWRITE_HINT.get()} (write to another path)", error)


@contextlib.contextmanager
def cli_wording() -> Iterator[None]:
    """Within this context, refusals to replace a file say ``pass --overwrite`` (the CLI flag)."""
    token = _OVERWRITE_HINT.set("--overwrite")
    try:
        yield
    finally:
        _OVERWRITE_HINT.reset(token)


def _fail(path: Path | str, message: str, error: type[PhoidError] = OutputError) -> PhoidError:
    text = f"{path}: {message}"
    return error(" ".join(text.splitlines()))


def _inside(path: str, root: str) -> bool:
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)


Writer = Callable[[IO[bytes]], Any]


class OutputFolder:
    """A folder phoid writes files into, with the rules of this module.

    Parameters
    ----------
    folder : str or Path
        The output folder (created with its parents on the first write when missing).
    overwrite : bool
        Replace existing regular files (never links, folders or special files).
    error : type
        The :class:`phoid.errors.PhoidError` subclass raised (the caller's own, e.g.
        ``ExperimentError`` for :func:`phoid.write_experiment`); default :class:`OutputError`.

    Raises
    ------
    PhoidError
        ``error``, when ``folder`` is under a dangling link or exists and is not a folder.
    """

    def __init__(self, folder: str | Path, *, overwrite: bool = False,
                 error: type[PhoidError] = OutputError) -> None:
        self.folder = Path(folder)
        self.overwrite = bool(overwrite)
        self.error = error
        if self.folder.exists() and not self.folder.is_dir():
            raise self._fail(self.folder, "exists and is not a folder")
        for above in (self.folder, *self.folder.parents):  # the part to be created
            if above.exists():
                break
            if above.is_symlink():
                raise self._fail(above, "is a symbolic link to nothing; phoid does not "
                                        "create folders through links (remove it or choose "
                                        "another folder)")
        # the real folder (its own links resolved: the user named it), as a string prefix
        self._root = os.path.realpath(self.folder)

    def _fail(self, path: Path | str, message: str) -> PhoidError:
        return _fail(path, message, self.error)

    # ---------------------------------------------------------------------------------------
    def path(self, name: str) -> Path:
        """The target ``name`` (a relative '/'-separated path) as the caller spells it."""
        return self.folder.joinpath(*PurePosixPath(name).parts)

    def check(self, names: Iterable[str]) -> list[Path]:
        """Check every target before anything is written; returns their paths.

        Raises
        ------
        OutputError
            For the first target that is a link, leads outside the folder, is not a regular file
            or exists without ``overwrite`` (nothing is written then).
        """
        seen: set[str] = set()
        paths = []
        for name in names:
            self._check(name)
            if name in seen:
                raise self._fail(self.path(name), "is written twice")
            seen.add(name)
            paths.append(self.path(name))
        return paths

    def _check(self, name: str) -> None:
        parts = PurePosixPath(name).parts
        target = self.path(name)
        if (not parts or PurePosixPath(name).is_absolute() or ".." in parts
                or "\\" in name or "\x00" in name):
            raise self._fail(target, "must be a relative path inside the output folder")
        check_not_input(target, self.error)
        here = self._root
        for i, part in enumerate(parts):
            here = os.path.join(here, part)
            shown = self.folder.joinpath(*parts[: i + 1])
            try:
                st = os.lstat(here)
            except FileNotFoundError:
                return  # the rest is created
            except OSError as exc:
                raise self._fail(shown, f"cannot be checked: {exc.strerror or exc}") from None
            last = i == len(parts) - 1
            if stat.S_ISLNK(st.st_mode):
                if last:
                    raise self._fail(shown, "is a symbolic link; phoid does not write through "
                                            "links (remove it or choose another folder)")
                real = os.path.realpath(here)
                if not _inside(real, self._root):
                    raise self._fail(shown, "is a symbolic link leading outside the output "
                                            f"folder {str(self.folder)!r}; phoid does not "
                                            "write through it")
                if not os.path.isdir(real):
                    raise self._fail(shown, "is a symbolic link to nothing; phoid does not "
                                            "write through it")
                here = real
            elif not last and not stat.S_ISDIR(st.st_mode):
                raise self._fail(shown, "is in the way: it is not a folder")
            elif last and stat.S_ISDIR(st.st_mode):
                raise self._fail(shown, "is a folder; phoid writes a file there")
            elif last and not stat.S_ISREG(st.st_mode):
                raise self._fail(shown, "exists and is not a regular file; phoid does not "
                                        "replace it")
            elif last and not self.overwrite:
                raise self._fail(shown, f"exists already (pass {_OVERWRITE_HINT.get()} to "
                                        "replace it)")

    # ---------------------------------------------------------------------------------------
    def write(self, name: str, data: bytes | Writer) -> Path:
        """Write ``data`` (bytes, or a function writing to a binary file) atomically to ``name``.

        Returns the path written, as the caller spells it.
        """
        self._check(name)
        target = self.path(name)
        try:
            parent = self._make_parent(name)
            final = os.path.join(parent, PurePosixPath(name).name)
            tmp = self._temporary(parent, PurePosixPath(name).name)
            try:
                with os.fdopen(tmp[0], "wb") as fh:
                    if callable(data):
                        data(fh)
                    else:
                        fh.write(data)
                    fh.flush()
                    os.fsync(fh.fileno())
                os.replace(tmp[1], final)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp[1])
                raise
            _sync_folder(parent)
        except OSError as exc:
            raise self._fail(target, f"cannot be written: {exc.strerror or exc}") from None
        return target

    def _make_parent(self, name: str) -> str:
        """Create the folder and the target's subfolders (no links followed out); its real path."""
        os.makedirs(self._root, exist_ok=True)
        here = self._root
        for part in PurePosixPath(name).parts[:-1]:
            here = os.path.join(here, part)
            with contextlib.suppress(FileExistsError):
                os.mkdir(here)
            real = os.path.realpath(here)
            if not _inside(real, self._root) or not os.path.isdir(real):
                raise OSError(f"{here} changed while writing")
            here = real
        return here

    @staticmethod
    def _temporary(parent: str, name: str) -> tuple[int, str]:
        """A new file ``.NAME.XXXXXXXX.tmp`` beside the target (mode from the umask)."""
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) \
            | getattr(os, "O_BINARY", 0)
        for _ in range(100):
            path = os.path.join(parent, f".{name}.{secrets.token_hex(4)}.tmp")
            try:
                return os.open(path, flags, 0o666), path
            except FileExistsError:
                continue
        raise OSError(f"no free temporary name beside {name}")


def _sync_folder(folder: str) -> None:
    """Flush the folder's entry of the renamed file to disk (POSIX; best effort)."""
    if os.name != "posix":
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def save_figure(fig: Any, path: str | Path, *, overwrite: bool = False,
                dpi: float = 120) -> Path:
    """Save a matplotlib figure as PNG to ``path`` with the rules of this module.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        The PNG file; its folder is the output folder (created when missing).
    overwrite : bool
        Replace an existing file of that name.
    dpi : float
        Resolution, dots per inch.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    out = OutputFolder(path.parent, overwrite=overwrite)
    return out.write(path.name, png_writer(fig, dpi))


def png_writer(fig: Any, dpi: float) -> Writer:
    """A writer that renders ``fig`` as PNG (Agg canvas attached if it has none)."""

    def write(fh: IO[bytes]) -> None:
        from matplotlib.backend_bases import FigureCanvasBase

        if type(fig.canvas) is FigureCanvasBase:  # a bare Figure: draw it with Agg
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            FigureCanvasAgg(fig)
        fig.savefig(fh, format="png", dpi=dpi)

    return write
