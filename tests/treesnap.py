"""A snapshot of a folder tree, to show that a command changed nothing outside its output folder.

Used by tests/test_output_safety.py and tests/test_property_cli.py.
"""

from __future__ import annotations

import os
from pathlib import Path


def snapshot(root: Path) -> dict[str, tuple]:
    """Every entry under root (links not followed): kind and content or link target."""
    snap: dict[str, tuple] = {}
    for here, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(here) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                snap[rel] = ("link", os.readlink(p))
            elif p.is_dir():
                snap[rel] = ("dir",)
            elif p.is_file():
                snap[rel] = ("file", p.read_bytes())
            else:
                snap[rel] = ("other",)
    return snap
