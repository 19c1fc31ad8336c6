"""The reader's limits (docs/limits.md), exported by :mod:`phoid.io`.

Every read stops at its limit (at most one block of :data:`BLOCK` bytes past it), so that no
input can make phoid read, decompress or hold without bound. The limits are generous for real
recordings: a 10 kHz, 1-hour run is 3.6e7 rows.
"""

from __future__ import annotations

__all__ = [
    "BLANK_CHECKED_AFTER",
    "BLOCK",
    "MAX_BLANK_SHARE",
    "MAX_DATA_BYTES",
    "MAX_LINES",
    "MAX_LINE_BYTES",
    "MAX_MANIFEST_BYTES",
    "MAX_NESTING",
    "MAX_RUNS",
    "MAX_SET_ROWS",
]

MAX_MANIFEST_BYTES = 2 * 2**20
"""Largest manifest (``experiment.toml``) read, bytes (2 MiB: about 40 000 ``[[run]]``
tables)."""
MAX_NESTING = 32
"""Deepest nesting of tables and arrays in a manifest."""
MAX_RUNS = 20_000
"""Most ``[[run]]`` tables in one set."""
MAX_LINES = 50_000_000
"""Most lines in one data file: the header, the data rows and the blank lines (5e7)."""
MAX_LINE_BYTES = 2**20
"""Longest line of a data file, bytes (1 MiB)."""
MAX_DATA_BYTES = 4 * 2**30
"""Largest data file, bytes after decompression (4 GiB)."""
MAX_SET_ROWS = 200_000_000
"""Most data rows in all the runs of one set together (2e8: 4.8 GB as t, x, u doubles)."""
MAX_BLANK_SHARE = 0.9
"""Largest share of a data file's bytes (after decompression) that may be blank space —
spaces, tabs, carriage returns, vertical tabs and form feeds — checked once
:data:`BLANK_CHECKED_AFTER` bytes are read: a file that is nearly all blank (a gzip of
gigabytes of blank lines) is refused within a fraction of a second, not after
:data:`MAX_DATA_BYTES`. A CSV padded to fixed-width columns is at most about 75 % blank."""
BLANK_CHECKED_AFTER = 64 * 2**20
"""Bytes of a data file (after decompression) read before :data:`MAX_BLANK_SHARE` applies."""
BLOCK = 2**20
"""Bytes read (or decompressed) at a time: memory while reading is this plus the data."""
