"""Which sets a batch identifies, and each set's checksum and ``[metadata]``.

A batch names its sets by folder (or manifest) paths, glob patterns and text files listing
them (:func:`expand_sets`); each set is known by its resolved path and by the SHA-256 of its
bytes (:func:`set_digest`), by which a resumed batch skips the sets it has done.
"""

from __future__ import annotations

import glob
import hashlib
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path, PureWindowsPath
from typing import Any

from phoid.errors import ExperimentError

__all__ = ["SetDigest", "expand_sets", "set_digest", "set_files"]

MANIFEST = "experiment.toml"
_GLOB_CHARS = set("*?[")
_BLOCK = 1 << 20


def _is_list_file(path: Path) -> bool:
    """A text file listing sets: a regular file that is not a TOML manifest."""
    return path.is_file() and path.suffix.lower() != ".toml"


def expand_sets(specs: Iterable[str | os.PathLike[str]]) -> list[str]:
    """The sets named by ``specs``, as resolved paths, in order, each once.

    Parameters
    ----------
    specs : str, path or iterable of them
        A single str or path is one spec. Each one of: a set's folder (holding
        ``experiment.toml``) or its manifest; a glob pattern (``*``, ``?``, ``[``; matches in
        sorted order, recursive with ``**``); or a text file (not ending in ``.toml``) listing
        one set per line (blank lines and lines starting with ``#`` skipped; relative paths
        taken from the list file's folder). A path that does not exist is kept: its row
        carries the error.

    Returns
    -------
    list of str
        Absolute paths (``Path.resolve``; a set's ``experiment.toml`` named by its folder),
        duplicates dropped.

    Raises
    ------
    ExperimentError
        One line naming a glob pattern that matches nothing, a list file that cannot be
        read or names no set, or a set whose path is not UTF-8 text.
    """
    if isinstance(specs, str | os.PathLike):  # one set or pattern, not its characters
        specs = [specs]
    out: list[str] = []
    for spec in specs:
        text = os.fspath(spec)
        path = Path(text)
        if _GLOB_CHARS & set(text) and not path.exists():
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise ExperimentError(f"{text}: the pattern matches no set")
            out += [_canonical(Path(m)) for m in matches]
        elif _is_list_file(path):
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise ExperimentError(f"{path}: the list of sets cannot be read: {exc}") from None
            listed = [line.strip() for line in lines]
            listed = [line for line in listed if line and not line.startswith("#")]
            if not listed:
                raise ExperimentError(f"{path}: the list of sets names no set (only blank "
                                      "lines and # comments)")
            for line in listed:
                entry = Path(line)
                out.append(_canonical(entry if entry.is_absolute() else path.parent / entry))
        else:
            out.append(_canonical(path))
    return list(dict.fromkeys(out))


def _canonical(path: Path) -> str:
    """A set's name in a batch: the resolved folder (for ``DIR/experiment.toml`` too).

    A manifest given by its path keeps its own name, in its resolved folder: a manifest that
    is a link is read as ``phoid identify`` reads it, with the data files beside the link
    (not beside what it points to).
    """
    try:
        resolved = path.resolve() if path.is_dir() else path.parent.resolve() / path.name
    except (OSError, RuntimeError):  # a loop of links: kept, its row carries the error
        resolved = Path(os.path.abspath(path))
    if resolved.name == MANIFEST and resolved.parent.is_dir() and not resolved.is_dir():
        resolved = resolved.parent
    name = str(resolved)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:  # bytes the file system took that are not UTF-8 text
        raise ExperimentError(f"{name!r}: the set's path is not UTF-8 text, which the batch "
                              "output (Parquet, CSV, JSON) stores; rename the folder") from None
    return name


@dataclass(frozen=True)
class SetDigest:
    """A set's identity: its manifest's path, the SHA-256 of its bytes and its metadata.

    Attributes
    ----------
    manifest : str
        The manifest's path.
    checksum : str
        SHA-256 (hex) over the manifest's bytes and then each data file's bytes, in the order
        of the manifest's ``[[run]]`` tables (a file named twice counted once; a link is
        followed while it resolves inside the set's folder; a name that would leave the
        set's folder is not read: the reader refuses such a set; a file missing, not a
        regular file or unreadable counts as a marker of its name).
    metadata : dict
        The manifest's optional ``[metadata]`` table (its scalar values), or empty.
    """

    manifest: str
    checksum: str
    metadata: dict[str, Any]
    files: tuple[str, ...] = ()


def _run_files(folder: Path, doc: Any) -> list[Path]:
    """The data files a parsed manifest names (relative names only), in its folder."""
    runs = doc.get("run", []) if isinstance(doc, dict) else []
    names = [r.get("file") for r in runs if isinstance(r, dict)] if isinstance(runs, list) \
        else []
    out = []
    for name in dict.fromkeys(n for n in names if isinstance(n, str) and n):
        if name.startswith("/") or "\0" in name or "\\" in name:
            continue
        out.append(folder / name)
    return out


def set_files(set_path: str | os.PathLike[str]) -> list[Path]:
    """A set's input files as a command reads them: its manifest and the data files it names.

    The manifest is parsed, the data are not read: a command protects these files from its
    own outputs (:func:`phoid._output.protect_inputs`) before any work. A manifest that
    cannot be read or parsed gives just itself (the reader then says what is wrong).

    Parameters
    ----------
    set_path : str or path
        The set's folder (holding ``experiment.toml``) or its manifest.

    Returns
    -------
    list of Path
    """
    from phoid.io import parse_manifest, read_manifest_bytes

    path = Path(set_path)
    manifest = path / MANIFEST if path.is_dir() else path
    try:
        doc = parse_manifest(str(manifest), read_manifest_bytes(str(manifest), manifest))
    except (ValueError, OSError):
        return [manifest]
    return [manifest, *_run_files(manifest.parent, doc)]


def _digest_data(digest: Any, folder: Path, root: Path, name: str) -> None:
    """Feed one run file's bytes to ``digest`` when ``phoid identify`` would read it.

    The reader's path rules: relative, '/'-separated, no '..', resolving (links followed)
    inside the set's folder (``root``), a regular file. A name that breaks them is not read
    here (the reader refuses the set with its own message, in the set's row); a file that is
    missing, not a regular file (a named pipe is never opened) or unreadable adds a marker,
    so that the checksum changes when it appears.
    """
    from phoid.io import open_regular

    parts = name.split("/")
    if name.startswith("/") or ".." in parts or "\\" in name or "\0" in name \
            or PureWindowsPath(name).drive:
        return  # outside the set's folder: not read here (the reader refuses it)
    where = str(folder / name)
    try:
        real = (folder / name).resolve()
    except (OSError, RuntimeError, ValueError):  # a loop of links: the reader says so
        digest.update(b"\0unreadable\0" + name.encode("utf-8"))
        return
    if not real.is_relative_to(root):
        return  # a link leading outside: not read here (the reader refuses it)
    try:
        f, _ = open_regular(where, real, "data file")
    except ExperimentError:  # missing, not a regular file, unreadable: the reader says so
        digest.update(b"\0unreadable\0" + name.encode("utf-8"))
        return
    with f:
        try:
            while block := f.read(_BLOCK):
                digest.update(block)
        except OSError as exc:
            raise ExperimentError(f"{where}: cannot be read: {exc.strerror or exc}") from None


def set_digest(set_path: str | os.PathLike[str]) -> SetDigest:
    """Checksum a set's files and read its ``[metadata]`` table, without reading its data.

    The manifest and the data files are found and opened as ``phoid identify`` opens them
    (:func:`phoid.io.read_manifest_bytes`, :func:`phoid.io.open_regular`): links followed (a
    run file's while it resolves inside the set's folder), only regular files read.

    Parameters
    ----------
    set_path : str or path
        The set's folder (holding ``experiment.toml``) or its manifest.

    Returns
    -------
    SetDigest

    Raises
    ------
    ExperimentError
        One line naming the path: no manifest, a manifest that cannot be read (not a regular
        file, too large) or is not TOML (the reader's message), a data file that fails while
        it is read.
    """
    from phoid.io import parse_manifest, read_manifest_bytes

    path = Path(set_path)
    manifest = path / MANIFEST if path.is_dir() else path
    if not manifest.exists():
        raise ExperimentError(f"{path}: no experiment set here (no {MANIFEST})")
    where = str(manifest)
    raw = read_manifest_bytes(where, manifest)
    digest = hashlib.sha256(raw)
    doc = parse_manifest(where, raw)
    runs = doc.get("run", [])
    files = [r.get("file") for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []
    folder = manifest.parent
    try:
        root = folder.resolve()
    except (OSError, RuntimeError) as exc:
        raise ExperimentError(f"{folder}: cannot be resolved: {exc}") from None
    for name in dict.fromkeys(f for f in files if isinstance(f, str)):
        _digest_data(digest, folder, root, name)
    meta = doc.get("metadata", {})
    metadata = ({k: v for k, v in meta.items() if not isinstance(v, dict | list)}
                if isinstance(meta, dict) else {})
    return SetDigest(manifest=str(manifest), checksum=digest.hexdigest(), metadata=metadata,
                     files=tuple(map(str, [manifest, *_run_files(folder, doc)])))
