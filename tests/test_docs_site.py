"""The documentation site (docs/, ``make docs``): every public name is in the API reference.

The reference lists each public name by hand in an ``autosummary`` block of
docs/reference/api/<package>.md, one page per package; this checks those lists against the
``__all__`` of ``phoid`` and of every public subpackage (one that is not private and defines
``__all__``), found by walking the package, so a new public name or subpackage without a
reference entry fails here. It reads the sources only: it needs neither Sphinx nor the
``docs`` extra. Building the site itself (warnings as errors, tutorials executed) takes
about 100 s on two cores: ``make docs`` does it (CI runs it before the tests). The last two
tests check a built site (its pages, then the home page and a tutorial in headless Chromium,
a screenshot of each among the tests' artefacts, conftest's ``artefact``): the one ``make
docs`` left in docs/_build/html when it is newer than every source it was built from (docs/,
src/phoid, examples/; the stamp ``make docs`` writes after a build without warnings), else,
with PHOID_DOCS_BUILD=1, one built here into a temporary folder; without either they are
skipped, with the reason.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import phoid

DOCS = Path(__file__).resolve().parents[1] / "docs"
API = DOCS / "reference" / "api"


def _public_packages() -> dict[str, list[str]]:
    """Every public package of phoid that defines ``__all__``, with its ``__all__``."""
    found = {"phoid": list(phoid.__all__)}
    for info in pkgutil.walk_packages(phoid.__path__, prefix="phoid."):
        if not info.ispkg or any(part.startswith("_") for part in info.name.split(".")):
            continue
        module = importlib.import_module(info.name)
        if hasattr(module, "__all__"):
            found[info.name] = list(module.__all__)
    return found


def _listed(page: Path) -> tuple[str | None, list[str]]:
    """The ``currentmodule`` of a reference page and the names of its autosummary block."""
    text = page.read_text(encoding="utf-8")
    current = re.search(r"^\.\. currentmodule:: (\S+)$", text, re.MULTILINE)
    block = re.search(r"^\.\. autosummary::\n((?:   .*\n|\n)*)", text, re.MULTILINE)
    names: list[str] = []
    if block:
        for line in block.group(1).splitlines():
            entry = line.strip()
            if entry and not entry.startswith(":"):
                names.append(entry)
    return (current.group(1) if current else None), names


def _api_toctree() -> list[str]:
    index = (DOCS / "reference" / "index.md").read_text(encoding="utf-8")
    return [line.strip().removeprefix("api/") for line in index.splitlines()
            if line.strip().startswith("api/")]


def test_the_reader_sees_a_missing_name(tmp_path: Path) -> None:
    # the checker itself: a page that lists two names gives those two, under its module
    page = tmp_path / "phoid.x.md"
    page.write_text("# x\n\n```{eval-rst}\n.. currentmodule:: phoid.x\n\n.. autosummary::\n"
                    "   :toctree: generated\n\n   alpha\n   Beta\n```\n", encoding="utf-8")
    assert _listed(page) == ("phoid.x", ["alpha", "Beta"])


def test_every_public_package_has_a_reference_page_in_the_toctree() -> None:
    packages = _public_packages()
    # phoid, phoid.methods (and its forced and friction subpackages), phoid.fits, … : the
    # walk must find the subpackages at all, or the next test would check nothing
    assert {"phoid", "phoid.methods", "phoid.io", "phoid.dynamics"} <= set(packages)
    toctree = _api_toctree()
    missing_pages = sorted(p for p in packages if not (API / f"{p}.md").is_file())
    assert not missing_pages, f"no page docs/reference/api/<name>.md for {missing_pages}"
    missing_toc = sorted(set(packages) - set(toctree))
    assert not missing_toc, f"not in docs/reference/index.md's API toctree: {missing_toc}"


@pytest.mark.parametrize("package", sorted(_public_packages()))
def test_every_public_name_is_in_the_reference(package: str) -> None:
    exported = _public_packages()[package]
    current, listed = _listed(API / f"{package}.md")
    assert current == package, f"{package}.md documents the names of {current}"
    missing = sorted(set(exported) - set(listed), key=str.lower)
    assert not missing, f"public names of {package} missing from the reference: {missing}"
    extra = sorted(set(listed) - set(exported), key=str.lower)
    assert not extra, f"the reference of {package} lists names not in its __all__: {extra}"
    assert len(listed) == len(set(listed)), f"{package}.md lists a name twice"


def test_docs_extra_and_make_target_exist() -> None:
    root = DOCS.parent
    pyproject = (root / "pyproject.toml").read_text(encoding="utf-8")
    docs_extra = re.search(r"^docs = \[(.*?)\]", pyproject, re.MULTILINE | re.DOTALL)
    assert docs_extra, "no docs extra in pyproject.toml"
    for package in ("sphinx", "numpydoc", "pydata-sphinx-theme", "myst-parser", "myst-nb"):
        assert f'"{package}>=' in docs_extra.group(1), f"docs extra lacks {package}"
    makefile = (root / "Makefile").read_text(encoding="utf-8")
    recipe = re.search(r"^docs:.*\n((?:\t.*\n)+)", makefile, re.MULTILINE)
    assert recipe, "no docs target in the Makefile"
    assert "-W" in recipe.group(1) and "--keep-going" in recipe.group(1)


_HAVE_SPHINX = all(importlib.util.find_spec(name) is not None
                   for name in ("sphinx", "numpydoc", "myst_nb", "pydata_sphinx_theme"))
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


#: what ``make docs`` builds, and the stamp it writes there after a build without warnings
BUILT = DOCS / "_build" / "html"
BUILT_STAMP = BUILT / ".phoid-docs-ok"
#: the sources a build is made from: a file here newer than the stamp makes the build stale
SOURCES = (DOCS, DOCS.parent / "src" / "phoid", DOCS.parent / "examples")
#: compiled files a build or a test may leave beside the sources (the rig's C controller)
BUILT_SUFFIXES = frozenset({".pyc", ".so", ".o", ".dll", ".dylib", ".a", ".elf", ".hex"})


def newest_source(roots: tuple[Path, ...] = SOURCES) -> tuple[float, Path | None]:
    """The newest file under ``roots`` (mtime, path), build outputs and caches left out."""
    newest: tuple[float, Path | None] = (0.0, None)
    for root in roots:
        for path in root.rglob("*"):
            rel = path.relative_to(root).parts
            if (any(part in ("_build", "generated", "__pycache__") or part.startswith(".")
                    for part in rel) or path.suffix in BUILT_SUFFIXES or not path.is_file()):
                continue
            mtime = path.stat().st_mtime
            if mtime > newest[0]:
                newest = (mtime, path)
    return newest


def fresh_build(html: Path = BUILT, stamp: Path = BUILT_STAMP,
                roots: tuple[Path, ...] = SOURCES) -> str | None:
    """None when ``html`` holds a build newer than every source, else why it does not."""
    if not stamp.is_file() or not (html / "index.html").is_file():
        return f"no finished `make docs` build in {html}"
    when, path = newest_source(roots)
    if when > stamp.stat().st_mtime:
        return f"the build in {html} is older than {path}"
    return None


def test_a_source_newer_than_the_build_makes_it_stale(tmp_path: Path) -> None:
    # the freshness rule itself, on a made-up tree: a stamp newer than every source is fresh;
    # a source touched after it, or no stamp, is not (mtimes set explicitly: no sleeping)
    src, html = tmp_path / "docs", tmp_path / "html"
    (src / "_build").mkdir(parents=True)
    html.mkdir()
    page, index, stamp = src / "page.md", html / "index.html", html / ".ok"
    for f in (page, index):
        f.write_text("x", encoding="utf-8")
    assert fresh_build(html, stamp, (src,)) is not None  # no stamp yet
    stamp.write_text("", encoding="utf-8")
    os.utime(page, (1_000_000, 1_000_000))
    os.utime(stamp, (2_000_000, 2_000_000))
    (src / "_build" / "late.html").write_text("x", encoding="utf-8")  # outputs do not count
    (src / "rig.so").write_text("x", encoding="utf-8")  # nor compiled files
    assert fresh_build(html, stamp, (src,)) is None
    os.utime(page, (3_000_000, 3_000_000))
    assert "page.md" in (fresh_build(html, stamp, (src,)) or "")


def test_make_docs_writes_the_stamp_only_after_a_clean_build() -> None:
    # the fixture below trusts docs/_build/html only where `make docs` stamped it, which it
    # must do after sphinx succeeded (the recipe's lines run in order, stopping at a failure)
    makefile = (DOCS.parent / "Makefile").read_text(encoding="utf-8")
    recipe = re.search(r"^docs:.*\n((?:\t.*\n)+)", makefile, re.MULTILINE)
    assert recipe, "no docs target in the Makefile"
    lines = recipe.group(1).splitlines()
    build = next(i for i, line in enumerate(lines) if "sphinx" in line)
    made = [i for i, line in enumerate(lines) if "touch" in line and BUILT_STAMP.name in line]
    gone = [i for i, line in enumerate(lines) if "rm -f" in line and BUILT_STAMP.name in line]
    # removed before the build (a failed build leaves no stamp), written after it
    assert made and gone and gone[0] < build < made[0], lines
    assert "&&" not in lines[build] and "||" not in lines[build] and lines[build].lstrip()[0] != "-"
    assert "docs/_build/html" in lines[build]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A built site's html folder: `make docs`'s when it is fresh, else (PHOID_DOCS_BUILD=1)
    one built once from a clean state (-E) into a temporary folder."""
    if os.environ.get("PHOID_DOCS_BUILD") != "1":
        stale = fresh_build()
        if stale is None:
            return BUILT
        pytest.skip(f"{stale}: `make docs` builds the site (~100 s); PHOID_DOCS_BUILD=1 "
                    "builds it here")
    if not _HAVE_SPHINX:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]')")
    out = tmp_path_factory.mktemp("site")
    # -W: any warning (a malformed docstring, a broken cross-reference, a failing tutorial
    # cell or phoid-command) fails the build; -E: no saved environment
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-E", "-q",
         "-d", str(out / "doctrees"), str(DOCS), str(out / "html")],
        capture_output=True, text=True, timeout=600, check=False,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    return out / "html"


@pytest.mark.slow
def test_site_builds_with_warnings_as_errors(site: Path) -> None:
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "parametric" in index
    started = (site / "getting-started.html").read_text(encoding="utf-8")
    # the commands' output, made at build time: Table 1's heading from `phoid paper`
    assert "Table 1" in started
    tutorial = (site / "tutorials" / "pho-example-set.html").read_text(encoding="utf-8")
    assert "m = " in tutorial
    # every tutorial executed (myst-nb writes each cell's output; a failing cell fails the
    # build) and the two on measured records say which record they show
    for page in ("emps-axis", "pendulum-free-decay", "fleet-batch-trend", "overdamped-design"):
        text = (site / "tutorials" / f"{page}.html").read_text(encoding="utf-8")
        assert 'class="cell_output' in text, page
    for page in ("emps-axis", "pendulum-free-decay"):
        text = (site / "tutorials" / f"{page}.html").read_text(encoding="utf-8")
        # the box a cell displays (bold: <strong>), not the cell's code that writes it
        shows = [s for s in ("<strong>This page shows the real",
                             "<strong>This page shows a synthetic stand-in") if s in text]
        assert len(shows) == 1, (page, shows)
    # the user guide's pages and phoid.batch's reference
    for page in ("guide/free-friction", "guide/inloop", "guide/batch", "guide/design",
                 "reference/api/phoid.batch"):
        assert (site / f"{page}.html").is_file(), page
    # offline: MathJax is part of the site, and no page loads a script or a style sheet
    # from elsewhere
    assert (site / "_static" / "mathjax" / "tex-chtml.js").is_file()
    for page in site.rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        remote = re.findall(r'<(?:script|link)[^>]+(?:src|href)="(?:https?:)?//[^"]+"', text)
        assert not remote, f"{page.name} loads {remote[0]}"


@pytest.mark.slow
def test_site_in_a_browser(site: Path, artefact) -> None:
    # the home page and the tutorial in headless Chromium, as tests/test_html_report.py opens
    # its reports: the maths typeset by the site's own MathJax, nothing fetched from the
    # network, and a screenshot of each (kept among the tests' artefacts: conftest's artefact)
    if importlib.util.find_spec("selenium") is None:
        pytest.skip("selenium is not installed (the `test` extra has it)")
    for path in (CHROMIUM, CHROMEDRIVER):
        if not path.is_file():
            pytest.skip(f"{path} is absent: install Debian's chromium and chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    opts = Options()
    opts.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                "--window-size=1300,1800"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    try:
        for name, page in (("home", "index.html"),
                           ("tutorial", "tutorials/pho-example-set.html")):
            driver.get((site / page).as_uri())
            # both pages write maths ($P_i$, $D_i$): MathJax turns each into an mjx-container
            WebDriverWait(driver, 30).until(
                lambda d: d.execute_script(
                    "return document.querySelectorAll('mjx-container').length") > 0)
            fetched = driver.execute_script(
                "return performance.getEntriesByType('resource').map(e => e.name)")
            assert all(u.startswith(("file:", "data:")) for u in fetched), fetched
            shot = artefact(f"{name}.png")
            assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
    finally:
        driver.quit()
