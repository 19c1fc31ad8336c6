"""The README is a quick start (issue 30, item 2), and `make readme` checks its output excerpts.

What is checked here, on the README as committed (fast; `make readme` runs its blocks):

* at most 130 lines (the issue's acceptance: "README ≤ ~130 lines");
* every relative link and image points to a file of the repository, the figure a PNG of
  modest size;
* the Python example prints what it computes: every expression statement is a ``print``
  call (the issue: "5 of the 13 lines are bare expressions that print nothing");
* the first block that runs ``phoid`` activates the venv itself, so that it works pasted as is;
* the set-up names ``make demo`` and ``make test`` (the test command CI's ``.ci/run`` calls),
  both Makefile targets, and states the measured time of ``make demo`` with the install time
  of numpy, scipy and matplotlib apart (issue 30, item 3);
* every block that runs is followed by the output to expect, and at least five ``phoid``
  commands are shown.

And ``.ci/readme_check.py`` itself: the comparison of a block's output with the excerpt after
it, on made-up text, and the whole check on a made-up page (a real subprocess in a copy of the
checkout).
"""

from __future__ import annotations

import ast
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _load_check():
    spec = importlib.util.spec_from_file_location("readme_check", ROOT / ".ci" / "readme_check.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


check = _load_check()
TEXT = README.read_text(encoding="utf-8")
BLOCKS = check.blocks(TEXT)  # (first code line, kind, code, skip reason)
RUN = [b for b in BLOCKS if b[3] is None]


def test_readme_is_at_most_130_lines() -> None:
    # the acceptance: "README ≤ ~130 lines"
    assert len(TEXT.splitlines()) <= 130


def test_links_and_the_figure_are_files_of_the_repository() -> None:
    targets = re.findall(r"\]\(([^)\s]+)\)", TEXT)
    local = [t.split("#", 1)[0] for t in targets if not re.match(r"[a-z]+:", t)]
    assert local, "the README links into the documentation"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert missing == []
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", TEXT)
    assert len(images) == 1, images  # the issue: "a figure"
    figure = ROOT / images[0]
    data = figure.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    # a clone downloads it: 200 kB is about 6× the palette PNG phoid writes for it today
    assert len(data) < 200_000
    docs = [t for t in local if t.startswith("docs/") and t.endswith(".md")]
    assert len(docs) >= 5  # links into the site's source pages, readable on GitHub too


def _expression_statements(code: str) -> list[ast.Expr]:
    return [n for n in ast.walk(ast.parse(code)) if isinstance(n, ast.Expr)]


def test_python_examples_print_what_they_compute() -> None:
    blocks = [b for b in RUN if b[1] == "python"]
    assert blocks, "the README has a Python example"
    for line, _, code, _ in blocks:
        statements = _expression_statements(code)
        bare = [ast.unparse(n) for n in statements
                if not (isinstance(n.value, ast.Call) and isinstance(n.value.func, ast.Name)
                        and n.value.func.id == "print")]
        assert bare == [], f"README.md:{line}: expressions that print nothing as a script"
        assert statements, f"README.md:{line}: the example prints nothing"


def test_the_first_block_running_phoid_activates_the_venv() -> None:
    # a pasted block must work in a fresh shell after `make demo`: the venv activated before
    # the first `phoid`, or the command spelled .venv/bin/phoid
    sh = [b for b in RUN if b[1] == "sh" and re.search(r"(^|\s)phoid\s", b[2], re.M)]
    assert sh
    first = sh[0][2].splitlines()
    n = next(i for i, s in enumerate(first) if re.match(r"\s*phoid\s", s))
    before = "\n".join(first[:n])
    assert re.search(r"^\s*(\.|source)\s+\.venv/bin/activate\s*(#.*)?$", before, re.M), first


def test_setup_names_make_demo_and_make_test_and_states_the_time() -> None:
    setup = next(b for b in BLOCKS if "make demo" in b[2])
    assert "make test" in setup[2]
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert re.search(r"^demo:", makefile, re.M) and re.search(r"^test:", makefile, re.M)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert re.search(r"^make test$", ci, re.M)  # the README's test command is CI's
    # item 3: the wall time of `make demo` to the first table, the install time of numpy,
    # scipy and matplotlib stated apart
    start = TEXT.index("## Install")
    install = " ".join(TEXT[start:TEXT.index("\n## ", start + 1)].split())
    assert "numpy, scipy and matplotlib" in install
    assert len(re.findall(r"\d+(?:–\d+)? s\b", install)) >= 3, install


def test_every_block_that_runs_shows_the_output_to_expect() -> None:
    excerpts = check.expected_outputs(TEXT)
    without = [line for line, *_ in RUN if not excerpts.get(line)]
    assert without == []
    commands = [s for _, kind, code, _ in RUN if kind == "sh" for s in code.splitlines()
                if re.match(r"\s*phoid\s", s)]
    assert len(commands) >= 5  # the issue: "five commands with the output to expect"


# --- .ci/readme_check.py: output excerpts ---------------------------------------------------

SAMPLE = """\
Some prose.

```sh
phoid paper
```

```text
Table 1
… rows left out …
k (N/m)  64  …e-12
```

```sh
phoid identify x
```

A paragraph: the next text block is not this command's output.

```text
not an excerpt
```
"""


def test_expected_outputs_pairs_a_text_block_with_the_block_just_before_it() -> None:
    first = check.blocks(SAMPLE)[0][0]  # the key of the first block, as blocks() gives it
    excerpts = check.expected_outputs(SAMPLE)
    assert excerpts == {first: ["Table 1", "… rows left out …", "k (N/m)  64  …e-12"]}


@pytest.mark.parametrize(("stdout", "stderr", "missing"), [
    ("Table 1\nm 2\nk (N/m)    64   2.26e-12\n", "", []),  # spaces collapsed, … a wildcard
    ("k (N/m) 64 2.26e-12\nTable 1\n", "", ["k (N/m)  64  …e-12"]),  # out of order
    ("Table 1\n", "k (N/m) 64 4.1e-12\n", []),  # either stream
    ("Table 1\nk (N/m) 64 2.26e-11\n", "", ["k (N/m)  64  …e-12"]),  # a different value
    ("Table 1 (more)\nk (N/m) 64 1e-12\n", "", ["Table 1"]),  # whole lines only
])
def test_missing_lines(stdout: str, stderr: str, missing: list[str]) -> None:
    (excerpt,) = check.expected_outputs(SAMPLE).values()
    assert check.missing_lines(excerpt, stdout, stderr) == missing


def _run_check(tmp_path: Path, markdown: str) -> subprocess.CompletedProcess[str]:
    page = tmp_path / "page.md"
    page.write_text(markdown, encoding="utf-8")
    venv = Path(sys.prefix)
    if not (venv / "bin" / "phoid").is_file():
        pytest.skip(f"no phoid script in {venv}/bin: the check needs phoid's venv")
    return subprocess.run(
        [sys.executable, str(ROOT / ".ci" / "readme_check.py"), "--venv", str(venv),
         "--file", str(page), "--timeout", "60"],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)


def test_the_check_runs_a_page_activating_the_venv_and_compares_its_excerpt(
        tmp_path: Path) -> None:
    ok = """```sh
. .venv/bin/activate
echo "m = 2.000 ± 0.001 kg"; phoid --version
```

```text
m = 2.000 ± …
```
"""
    r = _run_check(tmp_path, ok)
    assert r.returncode == 0, r.stdout + r.stderr
    r = _run_check(tmp_path, ok.replace("m = 2.000 ± …", "m = 1.999 ± …"))
    assert r.returncode == 1
    assert "lacks these lines" in r.stderr and "m = 1.999 ± …" in r.stderr
    r = _run_check(tmp_path, "```sh\ntouch clutter.txt\n```\n")  # a file git would list
    assert r.returncode == 1 and "clutter.txt" in r.stderr
