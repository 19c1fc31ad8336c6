"""`phoid CMD --help` names a flag bare and a value's type once (issue 30: every flag showed a
`<bool>` metavar, from typer's rich help panels, which print every option's type)."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from phoid.cli import app

runner = CliRunner()
COMMAND = typer.main.get_command(app)
NAMES = sorted(COMMAND.commands)


@pytest.mark.parametrize("name", ["", *NAMES])
def test_flags_show_no_metavar(name):
    args = [name, "--help"] if name else ["--help"]
    res = runner.invoke(app, args, terminal_width=100)
    assert res.exit_code == 0, res.output
    assert "<bool>" not in res.output
    cmd = COMMAND.commands[name] if name else COMMAND
    flags = [p for p in cmd.params if getattr(p, "is_flag", False) and not p.hidden]
    for p in flags:
        # the option's line: its names (", " between short and long, " / " before the
        # negative one), then two spaces and its help; a type would come right after a name
        longest = max(p.opts, key=len)
        line = next((x for x in res.output.splitlines()
                     if re.search(rf"(^|[ ,/]){re.escape(longest)}(\s|,|$)", x)), None)
        assert line is not None, f"{longest} missing from `phoid {name} --help`"
        assert not re.search(rf"{re.escape(longest)} <", line), line


def test_value_options_keep_their_type():
    # a flag loses its metavar, not an option that takes a value: --delay still says <float>
    res = runner.invoke(app, ["identify", "--help"], terminal_width=100)
    assert re.search(r"--delay <float>", res.output), res.output
    assert re.search(r"^\s+--json\s{2,}\S", res.output, re.M), res.output
