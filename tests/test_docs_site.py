"""The documentation site (docs/, ``make docs``): every public name is in the API reference.

The reference lists each public name by hand in an ``autosummary`` block of
docs/reference/api/<package>.md, one page per package; this checks those lists against the
``__all__`` of ``phoid`` and of every public subpackage (one that is not private and defines
``__all__``), found by walking the package, so a new public name or subpackage without a
reference entry fails here. It reads the sources only: it needs neither Sphinx nor the
``docs`` extra. Building the site itself (warnings as errors, tutorials executed) takes
50-90 s on two cores: ``make docs`` does it, and so do the last two tests (the build, then the
home page and the tutorial in headless Chromium) when PHOID_DOCS_BUILD=1 and Sphinx is
installed (skipped otherwise).
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


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site built once from a clean state (-E) into a temporary folder: its html folder."""
    if not _HAVE_SPHINX:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]')")
    if os.environ.get("PHOID_DOCS_BUILD") != "1":
        pytest.skip("building the site takes ~50-90 s: `make docs` builds it; "
                    "PHOID_DOCS_BUILD=1 runs this test")
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
    # offline: MathJax is part of the site, and no page loads a script or a style sheet
    # from elsewhere
    assert (site / "_static" / "mathjax" / "tex-chtml.js").is_file()
    for page in site.rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        remote = re.findall(r'<(?:script|link)[^>]+(?:src|href)="(?:https?:)?//[^"]+"', text)
        assert not remote, f"{page.name} loads {remote[0]}"


@pytest.mark.slow
def test_site_in_a_browser(site: Path, tmp_path: Path) -> None:
    # the home page and the tutorial in headless Chromium, as tests/test_html_report.py opens
    # its reports: the maths typeset by the site's own MathJax, nothing fetched from the
    # network, and a screenshot of each (kept in tmp_path)
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
            shot = tmp_path / f"{name}.png"
            assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
    finally:
        driver.quit()
