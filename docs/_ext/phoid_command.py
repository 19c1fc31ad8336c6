"""The ``phoid-command`` directive: a shell command of the docs run at build time, with its output.

Each line of the directive's content is one command, run as written (``shlex`` split, no
shell) from a fresh temporary folder in which ``examples`` is the checkout's examples/ folder,
so that relative paths read as in the README and nothing is written into the checkout. ``phoid``
is the ``phoid`` script beside the Python that builds the site. The page shows ``$ command``
and what it printed (standard output and error). A command that exits non-zero, or runs past
the ``:timeout:`` option (seconds, default 120), fails the build.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.errors import ExtensionError
from sphinx.util.docutils import SphinxDirective

REPO = Path(__file__).resolve().parents[2]


class PhoidCommand(SphinxDirective):
    """Run the content's commands in a temporary folder and show each with its output."""

    has_content = True
    option_spec: ClassVar[dict[str, Callable[[str], object]]] = {
        "timeout": directives.positive_int
    }

    def run(self) -> list[nodes.Node]:
        """Run each command; return one literal block of the session."""
        timeout = self.options.get("timeout", 120)
        bindir = Path(sys.executable).parent
        env = dict(os.environ, COLUMNS="100", NO_COLOR="1", TERM="dumb")
        env["PATH"] = f"{bindir}{os.pathsep}{env.get('PATH', '')}"
        shown: list[str] = []
        with tempfile.TemporaryDirectory(prefix="phoid-docs-") as tmp:
            os.symlink(REPO / "examples", Path(tmp) / "examples")
            for line in self.content:
                if not line.strip():
                    continue
                argv = shlex.split(line)
                try:
                    done = subprocess.run(
                        argv, cwd=tmp, env=env, capture_output=True, text=True,
                        timeout=timeout, stdin=subprocess.DEVNULL, check=False,
                    )
                except (OSError, subprocess.TimeoutExpired) as exc:
                    raise ExtensionError(
                        f"{self.get_location()}: phoid-command {line!r} failed: {exc}"
                    ) from exc
                if done.returncode != 0:
                    raise ExtensionError(
                        f"{self.get_location()}: phoid-command {line!r} exited "
                        f"{done.returncode}: {done.stderr.strip()[-500:]}"
                    )
                shown.append(f"$ {line}")
                shown.append((done.stdout + done.stderr).rstrip("\n"))
        block = nodes.literal_block("\n".join(shown), "\n".join(shown))
        block["language"] = "text"
        return [block]


def setup(app: Sphinx) -> dict[str, object]:
    """Register the directive."""
    app.add_directive("phoid-command", PhoidCommand)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
