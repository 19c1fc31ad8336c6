"""Sphinx configuration of phoid's documentation site (``make docs``; docs/about.md says why).

The site builds offline: no intersphinx, no remote images or fonts fetched at build time.
Commands shown with their output (``phoid-command``, docs/_ext/phoid_command.py) and the
tutorials (myst-nb) are executed while the site is built, so the output a page shows is what
this checkout prints.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))

import phoid  # noqa: E402

project = "phoid"
author = "the phoid developers"
copyright = "the phoid developers, MIT licence"
release = phoid.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # MathJax 3 copied into the site: maths render offline
    "numpydoc",
    "myst_nb",  # MyST Markdown (myst-parser) and executed notebooks
    "phoid_command",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "**/generated/*.md", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# MyST: the existing pages use $…$ maths, tables and heading anchors (format.md#the-units-table)
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 4
# pages link to files of the repository outside docs/ (src/…, examples/…, tests/…): they are
# not pages of the site, so MyST cannot resolve them; the link text stays, without a target.
# Only that one kind of warning is silenced; every other warning fails the build (-W).
suppress_warnings = ["myst.xref_missing"]

# tutorials: executed on every build (no cache to go stale), a failing cell fails the build
nb_execution_mode = "force"
nb_execution_timeout = 120
nb_execution_raise_on_error = True
nb_execution_show_tb = True

# the API reference: one page per public name, from the numpydoc docstrings
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"members": False}
autodoc_typehints = "none"  # the numpydoc Parameters sections give the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "pydata_sphinx_theme"
html_title = f"phoid {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "icon_links": [],
}
html_static_path: list[str] = []
html_last_updated_fmt = None

# --- one index entry per class -------------------------------------------------------------
# A class in phoid.__all__ is also in its subpackage's __all__ (phoid.Estimate is
# phoid.methods.Estimate): autodoc gives each page the class's canonical name
# (phoid.methods.estimate.Estimate), which Sphinx would see described twice. The first page of
# the reference's order (REFERENCE_ORDER: its API toctree) indexes it; the others show it
# with :no-index:.
REFERENCE_ORDER = [
    line.strip().removeprefix("api/")
    for line in (DOCS / "reference" / "index.md").read_text(encoding="utf-8").splitlines()
    if line.strip().startswith("api/")
]


def _not_indexed() -> set[str]:
    import importlib
    import inspect

    seen: set[int] = set()
    repeated: set[str] = set()
    for package in REFERENCE_ORDER:
        module = importlib.import_module(package)
        for name in module.__all__:
            obj = getattr(module, name)
            if not inspect.isclass(obj):
                continue
            if id(obj) in seen:
                repeated.add(f"{package}.{name}")
            seen.add(id(obj))
    return repeated


autosummary_context = {"phoid_not_indexed": _not_indexed()}


# --- docstrings written for the terminal -----------------------------------------------------
# A constant's docstring is its type's: it is replaced by the constant's value.
# phoid's docstrings write |z| for a modulus and headed lists ("Modules\n-------") in module
# docstrings. In reStructuredText the first is a substitution and the second a section, which
# cannot stand inside a directive; both are rewritten here, after numpydoc, for the site only.
_LITERAL = re.compile(r"(``.+?``|`[^`]+`)")


def _escape_bars(line: str) -> str:
    parts = _LITERAL.split(line)
    return "".join(p if i % 2 else p.replace("|", r"\|") for i, p in enumerate(parts))


def _rewrite_docstring(app, what, name, obj, options, lines):
    if what in ("data", "attribute") and obj.__doc__ == type(obj).__doc__:
        # a constant (phoid.__version__, phoid.io.MAX_RUNS): its type's docstring says nothing
        value = repr(obj)
        lines[:] = [f"Value: ``{value if len(value) <= 200 else value[:200] + ' …'}``"]
        return
    out: list[str] = []
    literal_indent: int | None = None
    for i, line in enumerate(lines):
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if literal_indent is not None and stripped and indent <= literal_indent:
            literal_indent = None
        underline = lines[i + 1] if i + 1 < len(lines) else ""
        if (what == "module" and stripped and underline.strip()
                and set(underline.strip()) <= set("-=~") and len(underline.strip()) >= 3
                and indent == len(underline) - len(underline.lstrip())):
            out.append(" " * indent + f".. rubric:: {stripped}")
            continue
        if (what == "module" and out and out[-1].lstrip().startswith(".. rubric::")
                and stripped and set(stripped) <= set("-=~") and len(stripped) >= 3):
            out.append("")
            continue
        if literal_indent is None and not stripped.startswith((">>>", "...")):
            line = _escape_bars(line)
        if stripped.endswith("::") and literal_indent is None:
            literal_indent = indent
        out.append(line)
    lines[:] = out


def setup(app):
    from pygments.lexers.special import TextLexer

    app.add_lexer("csv", TextLexer)  # docs/format.md's record examples: shown as plain text
    app.connect("autodoc-process-docstring", _rewrite_docstring, priority=900)
