"""The one manifest reader: a bounded, regular, UTF-8 TOML file (docs/limits.md)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import phoid.io.limits as limits
from phoid.io._files import open_regular
from phoid.io._format import fail

__all__ = ["parse_manifest", "read_manifest", "read_manifest_bytes"]


def read_manifest(where: str, manifest: Path) -> dict[str, Any]:
    """Read and parse a manifest: a regular file of at most MAX_MANIFEST_BYTES, UTF-8 TOML,
    nested at most MAX_NESTING levels deep, with at most MAX_RUNS ``[[run]]`` tables
    (docs/limits.md).

    The one manifest reader: :func:`~phoid.io.reading.read_experiment`,
    :func:`phoid.planning.schedule.read_schedule` and the batch's checksum
    (:func:`read_manifest_bytes`, :func:`parse_manifest`) all read through it.

    Parameters
    ----------
    where : str
        Prefix of the one-line :class:`~phoid.errors.ExperimentError` it raises (the
        manifest's path, as messages name it).
    manifest : pathlib.Path
        The manifest's path.

    Returns
    -------
    dict
        The parsed TOML document, unchecked beyond the limits.
    """
    return parse_manifest(where, read_manifest_bytes(where, manifest))


def read_manifest_bytes(where: str, manifest: Path) -> bytes:
    """A manifest's bytes: a regular file (symbolic links followed; a named pipe, a device or
    a socket refused before it is read) of at most MAX_MANIFEST_BYTES.

    Raises :class:`~phoid.errors.ExperimentError` (one line, prefixed with ``where``).
    """
    f, st = open_regular(where, manifest, "manifest")
    with f:
        if st.st_size > limits.MAX_MANIFEST_BYTES:
            raw = b""
        else:
            try:
                raw = f.read(limits.MAX_MANIFEST_BYTES + 1)
            except OSError as exc:
                fail(where, f"cannot read the manifest: {exc.strerror or exc}")
    if st.st_size > limits.MAX_MANIFEST_BYTES or len(raw) > limits.MAX_MANIFEST_BYTES:
        fail(where, f"the manifest is larger than {limits.MAX_MANIFEST_BYTES // 2**20} MiB, "
                     "phoid's limit for experiment.toml (MAX_MANIFEST_BYTES)")
    return raw


def parse_manifest(where: str, raw: bytes) -> dict[str, Any]:
    """Parse a manifest's bytes (:func:`read_manifest_bytes`): UTF-8 TOML, nested at most
    MAX_NESTING levels deep, with at most MAX_RUNS ``[[run]]`` tables.

    Raises :class:`~phoid.errors.ExperimentError` (one line, prefixed with ``where``).
    """
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        fail(where, f"the manifest is not UTF-8 text (bad byte at line {line})")
    too_deep = (f"the manifest nests tables or arrays more than {limits.MAX_NESTING} levels deep, "
                "phoid's limit (MAX_NESTING)")
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        fail(where, f"not valid TOML, TOML syntax error: {exc}")
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        fail(where, too_deep)
    if _depth(doc) > limits.MAX_NESTING:
        fail(where, too_deep)
    tables = doc.get("run")
    if isinstance(tables, list) and len(tables) > limits.MAX_RUNS:
        fail(where, f"the manifest has {len(tables):,} [[run]] tables; phoid reads at most "
                     f"{limits.MAX_RUNS:,} runs per set (MAX_RUNS)")
    _misplaced_tables(where, doc)
    return doc


# the manifest's top-level tables: a key of one of these names inside another table is a
# top-level key written below a table's header (TOML puts it in that table), which the reader
# would otherwise keep as that table's unknown key and ignore (the stated delay lost)
_TOP_TABLES = ("loop", "units", "fixed", "run")
# tables whose keys are the user's own (docs/format.md): any name is theirs to use
_FREE_TABLES = ("metadata",)


def _misplaced_tables(where: str, doc: dict[str, Any]) -> None:
    """Refuse a top-level table's name used as a key inside another table (one line)."""
    for name, value in doc.items():
        if name in _FREE_TABLES:
            continue
        runs = name == "run" and isinstance(value, list)
        for i, table in enumerate(value if runs else [value], start=1):
            if not isinstance(table, dict):
                continue
            for key in _TOP_TABLES:
                if key in table:
                    label = f"[[run]] {i}" if runs else f"[{name}]"
                    fail(where, f"{label} {key}: '{key}' names a top-level table of the "
                                 f"manifest ([{key}]), but below the {label} header TOML puts "
                                 f"it in that table, where phoid would ignore it: move it above "
                                 "the first table header, or write it as its own table")


def _depth(doc: Any) -> int:
    """Nesting depth of tables and arrays (iterative: no recursion limit to hit)."""
    deepest = 0
    stack = [(doc, 1)]
    while stack:
        value, level = stack.pop()
        if level > deepest:
            deepest = level
            if deepest > limits.MAX_NESTING:
                break
        children = value.values() if isinstance(value, dict) else value
        stack.extend((v, level + 1) for v in children if isinstance(v, dict | list))
    return deepest
