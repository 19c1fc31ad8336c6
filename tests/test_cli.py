"""The command line: `phoid simulate` and `phoid identify`, output contract and bad input."""

import json
import shutil

import pytest
from typer.testing import CliRunner

from phoid.cli import app

runner = CliRunner()


def one_line_error(result, *needles):
    """Exit status 2, a single 'phoid: error:' line on stderr naming the needles, no traceback."""
    assert result.exit_code == 2, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phoid: error:"), result.stderr
    assert "Traceback" not in result.output
    for n in needles:
        assert n in err[0], (n, err[0])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sets") / "sim"
    r = runner.invoke(app, ["simulate", str(out), "--P", "0.25:25:10", "--D", "0.6:6:10",
                            "--noise", "1e-4", "--quantum", "1e-6", "--offset", "-3e-4",
                            "--seed", "5", "--duration", "12"])
    assert r.exit_code == 0, r.output
    return out


def test_simulate_then_identify_json(simulated):
    r = runner.invoke(app, ["identify", str(simulated), "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)  # stdout holds exactly one JSON object
    truth = {"m": 2.0, "c": 1.0, "k": 64.0}  # the plant given to `phoid simulate`
    for q, v in truth.items():
        assert abs(data[q]["value"] - v) < 3 * data[q]["stderr"]  # 3-sigma, one seeded set
    assert data["delay"]["source"] == "given" and len(data["runs"]) == 10


def test_identify_text_and_plots(simulated, tmp_path):
    r = runner.invoke(app, ["identify", str(simulated), "--plots", str(tmp_path / "p")])
    assert r.exit_code == 0, r.output
    assert "m = " in r.stdout and "k = " in r.stdout
    pngs = sorted(p.name for p in (tmp_path / "p").glob("*.png"))
    assert {"lines.png", "mk-ellipse.png", "run01.png"} <= set(pngs)
    assert len(pngs) == 12  # 10 runs (<stem>.png) + the lines + the (m, k) ellipse


def test_identify_ols_and_no_compensation(simulated):
    r = runner.invoke(app, ["identify", str(simulated), "--json", "--estimator", "ols",
                            "--no-compensation"])
    assert r.exit_code == 0, r.output
    ols = json.loads(r.stdout)
    gls = json.loads(runner.invoke(app, ["identify", str(simulated), "--json"]).stdout)
    # the paper's OLS lines ignore each run's precision: a different, less precise estimate
    assert ols["c"]["value"] != gls["c"]["value"] and ols["c"]["stderr"] > gls["c"]["stderr"]
    r = runner.invoke(app, ["identify", str(simulated), "--no-compensation"])
    one_line_error(r, "--no-compensation", "--estimator ols")


def test_identify_missing_set(tmp_path):
    one_line_error(runner.invoke(app, ["identify", str(tmp_path / "nope")]), "nope")


def test_identify_bad_manifest_names_file(simulated, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(simulated, bad)
    (bad / "experiment.toml").write_text("format = 'phoid/1'\n[[run]\nfile = 'x'\n")
    one_line_error(runner.invoke(app, ["identify", str(bad)]), "experiment.toml")


def test_identify_bad_cell_names_file_run_and_column(simulated, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(simulated, bad)
    import gzip

    f = bad / "run03.csv.gz"
    lines = gzip.decompress(f.read_bytes()).decode().splitlines()
    lines[56] = lines[56].split(",")[0] + ",abc," + lines[56].split(",")[2]
    f.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    one_line_error(runner.invoke(app, ["identify", str(bad)]), "run03.csv.gz", "'x'", "57")


def test_identify_same_gains(tmp_path):
    out = tmp_path / "same"
    # with noise: noise-free runs with the same gains are byte-identical, which the reader
    # refuses before identification sees the gains (tests/test_hostile_io.py)
    r = runner.invoke(app, ["simulate", str(out), "--P", "5,5,5", "--D", "1", "--duration", "6",
                            "--noise", "1e-6", "--seed", "1"])
    assert r.exit_code == 0, r.output
    one_line_error(runner.invoke(app, ["identify", str(out)]), "same gains")


def test_simulate_bad_values(tmp_path):
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "a"), "--m", "-1"]), "--m")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "b"), "--P", "1,2",
                                       "--D", "1,2,3"]), "same number")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "c"), "--P", "1:x:3"]), "--P")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "d"), "--delay", "-0.1"]),
                   "delay")


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        # an unknown [loop] key is refused rather than ignored (it could change the model)
        (lambda t: t.replace("[loop]\n", "[loop]\nsampling = 1\n", 1),
         ("[loop] sampling", "unknown key")),
        # a digital loop's delay is delay_samples: a continuous delay beside it is ambiguous
        (lambda t: t.replace("[loop]\n", "[loop]\nsample_time = 0.001\n", 1),
         ("sample_time", "delay_samples", "one or the other")),
    ],
)
def test_identify_refuses_keys_it_cannot_honour(simulated, tmp_path, edit, needles):
    bad = tmp_path / "later"
    shutil.copytree(simulated, bad)
    manifest = bad / "experiment.toml"
    manifest.write_text(edit(manifest.read_text()))
    assert needles[0].split()[-1] in manifest.read_text()
    one_line_error(runner.invoke(app, ["identify", str(bad)]), *needles)


def test_unexpected_failure_is_one_line_exit_1(monkeypatch, capsys):
    # a fault inside phoid (not the user's) still never shows a traceback
    import phoid.cli as cli
    import phoid.paper as paper

    def boom(**_kw):
        raise RuntimeError("root certification failed\nsecond line")

    monkeypatch.setattr(paper, "reproduce_table1", boom)
    monkeypatch.setattr("sys.argv", ["phoid", "paper"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error" in err[0] and "root certification" in err[0]


# --------------------------------------------------------------------------------------------
# usage errors through the console entry point (phoid.cli.main, as the installed `phoid` runs
# it): one line on stderr and exit status 2, like every other error, instead of typer's framed
# multi-line box


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["identify"], "Missing argument"),
        (["identify", "--bogus", "x"], "--bogus"),
        (["design", "--runs", "1e9", "--m", "1", "--c", "1", "--k", "1", "--delay", "0.01"],
         "--runs"),
        (["simulate", "out", "--fs", "fast"], "--fs"),
        (["nosuchcommand"], "nosuchcommand"),
    ],
)
def test_usage_errors_are_one_line(tmp_path, args, needle):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "phoid.cli", *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), proc.stderr
    assert needle in lines[0] and "--help" in lines[0]
    assert proc.stdout == ""
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_entry_point_exit_statuses(tmp_path):
    # no arguments: the help on standard output (status 2, as before); --help and --version: 0
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", "phoid.cli", *args], cwd=tmp_path,
                              capture_output=True, text=True, timeout=120)

    bare = run()
    assert bare.returncode == 2 and "identify" in bare.stdout
    assert run("--help").returncode == 0
    ver = run("--version")
    assert ver.returncode == 0 and ver.stdout.startswith("phoid ")
